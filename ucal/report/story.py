"""The report's history: every write ucal made to the profile as what changed, when and why,
with its undo (``history_section``)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from ucal.check.growth import temperature_rise_k
from ucal.report import figures
from ucal.report import html as h
from ucal.report.checks import CheckFacts
from ucal.report.gather import CellReport, Change, Write

#: Longest value shown in the history table's "what changed" (characters), then "…".
MAX_VALUE_CHARS = 160


#: Profile keys the history names in words, with their unit and how to show a change.
NAMED_KEYS: dict[str, tuple[str, str]] = {
    "calibration.joint_offsets_deg": ("joint offsets", "deg"),
    "sample.position_mm": ("block corner", "mm"),
    "sample.rotation_deg": ("block rotation", "deg"),
    "tool.position_mm": ("tool position", "mm"),
    "tool.rotation_deg": ("tool rotation", "deg"),
    "calibration.sound_speed_m_s": ("sound speed", "m/s"),
    "calibration.backlash_deg": ("lost motion", "deg"),
}


def history_section(r: CellReport) -> str:
    """The history part of the page: each write in sentences, oldest first, then the notes."""
    title = "6. History: what changed, when, why"
    if not r.writes and not r.checks:
        return h.empty_part(title, "No recorded write: ucal never rewrote this profile.")
    out = [h.part(title)]
    if r.writes:
        out.append(
            f"<p>Every write ucal made, oldest first; the version each replaced is kept in "
            f"<code>{h.e(r.history_dir)}</code> (<code>ucal profile undo</code> restores it).</p>"
        )
        out.append('<ol class="history">' + "".join(_write_item(w) for w in r.writes) + "</ol>")
    else:
        out.append("<p>No recorded write: ucal never rewrote this profile.</p>")
    for note in r.notes:
        out.append(h.note(h.e(note)))
    checks = checks_part(r.checks)
    if checks:
        out.append(checks)
    out.append("</section>")
    return "\n".join(out)


def _write_item(w: Write) -> str:
    """One write as sentences: when, which command and what it wrote, why (its recorded
    reason), the values that changed, and its undo."""
    when_ = h.e(w.entry.time.replace("T", " ")[:16] + " UTC")
    what = {
        "calibrate": "joint offsets and the block's pose measured and written",
        "tool-frame": "tool frame measured and written",
    }.get(w.command, "profile written")
    head = (
        f"<strong>{when_} — <code>{h.e(w.command)}</code></strong> (write #{w.entry.id}): "
        f"{what}; why: <em>{h.e(w.entry.reason)}</em>."
    )
    state = (
        f" <strong>Undone</strong> {h.e(h.when(w.entry.undone_time))}: the version before it "
        "was restored."
        if w.entry.undone
        else ""
    )
    return f"<li>{head}{state}{_changes(w.changes)}</li>"


def _changes(changes: Sequence[Change] | None) -> str:
    """What a write changed: the named values before → after, then the other keys by name."""
    if changes is None:
        return " What it changed is not known: the version it left is kept nowhere."
    if not changes:
        return " It changed comments or layout only."
    named = [c for c in changes if c.key in NAMED_KEYS]
    others = [c.key for c in changes if c.key not in NAMED_KEYS]
    items = []
    for c in named:
        name, unit = NAMED_KEYS[c.key]
        items.append(f"{h.e(name)} ({unit}): {h.e(_change_values(c))}")
    if others:
        tables = sorted({"[" + k.split(".", 1)[0] + "]" for k in others if "." in k})
        items.append(
            f"and {len(others)} further keys"
            + (f" of {h.e(', '.join(tables))}" if tables else "")
            + " (stds, gauge, fit figures, drawn values)"
        )
    return '<ul class="changes">' + "".join(f"<li>{i}</li>" for i in items) + "</ul>"


def _change_values(c: Change) -> str:
    """``before → after``, per joint for six values (J1 0.0000 → 0.7992, ...)."""
    before, after = c.before, c.after
    if c.key == "calibration.backlash_deg":
        # -1: not measured
        def lost(x: Any) -> str:
            if not isinstance(x, list):
                return _value(x)
            return "not measured" if all(y < 0 for y in x) else _value(x)

        return f"{lost(before)} → {lost(after)}"
    if (
        isinstance(before, list)
        and isinstance(after, list)
        and len(before) == len(after) == 6
        and c.key.startswith("calibration.")
    ):
        return ", ".join(
            f"J{j + 1} {_value(b)} → {_value(a)}"
            for j, (b, a) in enumerate(zip(before, after, strict=True))
            if b != a
        )
    return f"{_value(before)} → {_value(after)}"


def _value(v: Any) -> str:
    """A profile value in a few characters: numbers to 6 significant digits."""
    if v is None:
        return "(absent)"
    if isinstance(v, bool):
        return str(v).lower()
    if isinstance(v, float):
        return f"{v + 0.0:.6g}"
    if isinstance(v, list) and v and all(isinstance(x, dict) for x in v):
        return f"table of {len(v)} rows"
    if isinstance(v, list):
        text = "[" + ", ".join(_value(x) for x in v) + "]"
    elif isinstance(v, dict):
        text = "{" + ", ".join(f"{k} = {_value(x)}" for k, x in v.items()) + "}"
    else:
        text = str(v)
    return text if len(text) <= MAX_VALUE_CHARS else text[: MAX_VALUE_CHARS - 1] + "…"


def checks_part(checks: Sequence[CheckFacts]) -> str:
    """The checks in the history part (HTML): a table, and the growth's trend where any check
    fitted it; empty for a cell never checked."""
    if not checks:
        return ""
    rows = []
    for c in checks:
        growth = (
            "—"
            if c.growth_ppm is None
            else f"{h.num(c.growth_ppm, 1)} ± {h.num(c.growth_std_ppm, 1)}"
            + f" ({h.num(temperature_rise_k(c.growth_ppm), 1)} K)"
        )
        against = "reference" if c.reference else f"against #{c.compared_with}"
        named = ", ".join(c.named) if c.named else "nothing moved"
        rows.append(
            [f"#{c.id}", h.when_cell(c.time), h.e(against), h.e(c.verdict), h.e(named), growth]
        )
    out = [
        "<h3>Checks</h3>",
        "<p>Every <code>ucal check</code> of the cell, oldest first (the profile is never "
        "written by one); the arm's growth is its DH lengths' common stretch since the "
        "reference, in ppm and as the warmer aluminium arm it means.</p>",
        h.table(
            ["check", "when", "compared", "verdict", "named", "arm growth (ppm, 1σ)"],
            rows,
            [False, False, False, False, False, True],
        ),
    ]
    if any(c.growth_ppm is not None for c in checks):
        last = next(c for c in reversed(checks) if c.growth_ppm is not None)
        out.append(
            h.figure(
                figures.growth_figure(checks),
                "the arm's growth at each check",
                f"The last check (#{last.id}) measured the arm "
                f"{h.num(last.growth_ppm, 1)} ± {h.num(last.growth_std_ppm, 1)} ppm longer "
                f"than at its reference, tolerance ±{h.num(last.growth_tolerance_ppm, 0)} ppm: "
                "a rising trend is an arm warming (let it reach its working temperature "
                "before a run, or check at the temperature it scans at).",
            )
        )
    return "\n".join(out)
