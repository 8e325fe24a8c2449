"""The report as one self-contained HTML page: h.CSS inline, figures as ``data:`` URIs.

The page opens with its verdict: what was calibrated, how well (each one sigma against the
tolerance it is judged by), what was verified and with what verdict, what is not determined and
what would determine it; every statement of it and every table below read the same judgement
(``ucal.report.verdict``). The page loads nothing: no script, no font, no stylesheet or image
from elsewhere. Everything taken from the profile, its history or a record is escaped. It prints
to A4 as one flowing document (no forced page break: a figure or a short table is kept whole,
a long table breaks between rows), black on white, and reads in grey: states are written out,
not only coloured.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace
from importlib.metadata import PackageNotFoundError, version

import numpy as np

from ucal.profile.models import KNOWN_MODELS, load_model
from ucal.report import figures
from ucal.report import html as h
from ucal.report import verdict as v
from ucal.report.gather import Calibration, CellReport, IsoFacts, VerifyPicture, Write
from ucal.report.story import history_section


def _ucal_version() -> str:
    try:
        return version("ucal")
    except PackageNotFoundError:
        return "unknown"


def _state(w: Write) -> str:
    return f"undone {h.e(h.when(w.entry.undone_time))}" if w.entry.undone else "applied"


def _write_title(w: Write) -> str:
    state = (
        f'<span class="state">undone {h.e(h.when(w.entry.undone_time))}</span>'
        if w.entry.undone
        else '<span class="state">applied</span>'
    )
    return f"history write #{w.entry.id}, {h.e(h.when(w.entry.time))} ({state})"


# ---------------------------------------------------------------------------------------------
# the page


def render_page(report: CellReport) -> str:
    """The whole page for ``report`` (a str of HTML)."""
    parts = [
        _header(report),
        _verdict(report),
        _cell(report),
        _calibrations(report),
        _tools(report),
        _verify(report),
        _lost_motion(report),
        history_section(report),
    ]
    title = f"ucal report: {report.path.name}"
    return (
        "<!DOCTYPE html>\n"
        '<html lang="en"><head><meta charset="utf-8">'
        '<meta name="viewport" content="width=device-width, initial-scale=1">'
        f"<title>{h.e(title)}</title><style>{h.CSS}</style></head><body>\n"
        + "\n".join(parts)
        + "\n</body></html>\n"
    )


def _header(r: CellReport) -> str:
    hist = (
        f"{len(r.writes)} recorded writes in <code>{h.e(r.history_dir)}</code>"
        if r.writes
        else "no recorded write (the profile was never rewritten by ucal)"
    )
    meta = h.kv(
        [
            ("profile", f"<code>{h.e(r.path)}</code>"),
            ("SHA-256", f"<code>{h.e(r.profile_sha256)}</code>"),
            ("history", hist),
            ("report made", h.e(r.generated.strftime("%Y-%m-%d %H:%M:%S UTC"))),
            ("by", f"ucal {h.e(_ucal_version())}"),
        ]
    )
    return (
        f"<header><h1>Robot cell report: {h.e(r.profile.model.name)}, "
        f"<code>{h.e(r.path.name)}</code></h1>"
        '<p class="muted">The cell as its profile and the profile\'s history hold it. '
        "Lengths in mm, angles in degrees; ± values and σ are one standard deviation unless "
        "marked 3σ. A quantity is <em>determined</em> when its σ is within its tolerance, "
        "<em>not determined</em> when it exceeds it.</p>"
        f'<div class="meta">{meta}</div></header>'
    )


def quantities(r: CellReport) -> list[v.Quantity]:
    """Every quantity the verdict judges, in the page's order."""
    cal = r.current_calibration
    out = [] if cal is None else v.joint_quantities(cal)
    out += v.tool_quantities(r)
    out.append(v.dh_quantity(r))
    lost = v.lost_motion_quantities(cal)
    if all(q.state == v.NOT_MEASURED for q in lost):
        first = lost[0]
        out.append(replace(first, name="lost motion, J1-J6"))
    else:
        out += lost
    drift = v.drift_quantity(r)
    if drift is not None:
        out.append(drift)
    return out


def _calibrated_words(r: CellReport) -> str:
    """What was calibrated, in one sentence (HTML)."""
    cal = r.current_calibration
    if cal is None:
        text = "Joint offsets: <strong>never calibrated</strong> (zero)."
    else:
        src = "no recorded write" if cal.write is None else f"history write #{cal.write.entry.id}"
        seen = [j for j in range(1, 7) if j not in cal.unobservable_joints]
        fit = cal.fit
        text = (
            f"Joint offsets of {h.e(_joint_list(seen))} at the <strong>{h.e(cal.level or '—')}"
            f"</strong> level (method {h.e(cal.method or '—')}, {h.e(h.when(cal.date))}, {src}), "
            f"fit <span class=state>{h.e(fit.verdict or 'not recorded')}</span>"
            + (
                f" (χ²ᵣ {h.num(fit.chi2_reduced, 3)} on {fit.dof} degrees of freedom)"
                if fit.chi2_reduced is not None and fit.dof is not None
                else ""
            )
            + (
                f"; {h.e(_joint_list(list(cal.unobservable_joints)))} kept from the profile"
                if cal.unobservable_joints
                else ""
            )
            + "; the block's pose measured with them."
        )
        if cal.approach:
            text += f" The offsets hold for postures approached {h.e(_approach(cal.approach))}."
    tool = (
        f" Tool frame measured by tool-frame (history write #{r.tools[-1].write.entry.id}, "
        f"{h.e(h.when(r.tools[-1].write.entry.time))})."
        if r.tools
        else " Tool frame: from its drawing (no tool-frame write)."
    )
    return text + tool


def _approach(name: str) -> str:
    return {
        "positive": "from below on every joint (each joint ending its move in its positive "
        "direction)",
        "centre": "at the middle of each joint's lost motion",
    }.get(name, name)


def _joint_list(joints: Sequence[int]) -> str:
    if not joints:
        return "no joint"
    if len(joints) > 2 and list(joints) == list(range(joints[0], joints[-1] + 1)):
        return f"J{joints[0]}-J{joints[-1]}"
    return ", ".join(f"J{j}" for j in joints)


def _verdict(r: CellReport) -> str:
    """The verdict at the top: what was calibrated, how well, what was verified, what is not
    determined and what would determine it."""
    qs = quantities(r)
    short, verified = v.verify_state(r.verify, r)
    cal = r.current_calibration
    if cal is None:
        head = "Not calibrated"
    elif cal.fit.verdict not in (None, "ok"):
        head = f"Calibrated, fit {cal.fit.verdict}"
    else:
        head = "Calibrated"
    facts = r.verify.facts if r.verify is not None else None
    head += (
        "; not verified"
        if r.verify is None
        else f"; verified on {facts.cell_words}: {short}"
        if facts is not None
        else f"; verify: {short}"
    )
    open_ = [q for q in qs if not q.determined]
    lead = (
        f'<p class="lead"><strong>{h.e(head)}.</strong> '
        f"{len(qs) - len(open_)} of the {len(qs)} quantities below are determined, "
        f"{len(open_)} are not ({h.e(', '.join(q.name for q in open_))}).</p>"
    )
    how_well = [
        f"{h.e(q.name)}: σ {h.e(q.std)} ≤ {h.e(q.tolerance)}" for q in qs if q.determined and q.std
    ]
    not_determined = [
        f"<strong>{h.e(q.name)}</strong>, {h.e(q.state)}"
        + (
            f" (σ {h.e(q.std)}, tolerance {h.e(q.tolerance)})"
            if "—" not in (q.std, q.tolerance)
            else ""
        )
        + (f": {h.e(q.why)}" if q.why else "")
        for q in open_
    ]
    if facts is not None and facts.marginal:
        not_determined.append(
            f"<strong>the verify {'pass' if facts.passed else 'failure'}</strong>, not "
            f"determined (marginal): {h.e(v.would_determine_verify(facts, r))}"
        )
    rows = [
        ("calibrated", _calibrated_words(r)),
        ("how well", _items(how_well) if how_well else "nothing determined"),
        ("verified", h.e(verified[:1].upper() + verified[1:]) + "."),
        ("not determined", _items(not_determined) if not_determined else "nothing"),
    ]
    for rehearsal in r.rehearsals:
        rows.append(("rehearsal", h.e(_rehearsal_words(rehearsal))))
    table = h.table(
        ["quantity", "value", "σ", "tolerance", "state"],
        [_quantity_row(q, q.name) for q in qs],
        [False, False, False, False, False],
        "wide",
    )
    return (
        '<section class="verdict"><h2>Verdict</h2>'
        + lead
        + h.kv(rows)
        + "<h3>Each quantity against its tolerance</h3>"
        + table
        + "</section>"
    )


def _quantity_row(q: v.Quantity, name: str, why: bool = False) -> list[str]:
    """A quantity's cells: its name as given, value, σ, tolerance, state (and why)."""
    cells = [
        h.e(name),
        h.e(q.value),
        h.e(q.std),
        h.e(q.tolerance),
        f'<span class="state">{h.e(q.state)}</span>',
    ]
    return cells + [h.e(q.why)] if why else cells


def _items(items: Sequence[str]) -> str:
    return '<ul class="plain">' + "".join(f"<li>{i}</li>" for i in items) + "</ul>"


def _rehearsal_words(p: VerifyPicture) -> str:
    """A rehearsal's verify in one sentence (plain text)."""
    name = p.path.name
    if p.facts is None:
        return f"{name}: a verify picture of another cell; not a verdict on this one"
    return (
        f"{p.modified.strftime('%Y-%m-%d %H:%M UTC')}, on {p.facts.cell_words}: "
        f"{v.verify_words(p.facts)}. Not a verdict on this cell: its picture, {name}, is "
        "not shown"
    )


def _dh_origin(r: CellReport) -> str:
    name = r.nominal_model.name
    if r.identified_dh:
        return (
            f"{name}, DH table identified by calibrate --level full ([calibration] dh), in "
            f"place of the [robot] table"
        )
    if r.nominal_model.dh_source == "shipped":
        return f"{name}, the shipped DH table (the profile has no [robot] dh)"
    if name in KNOWN_MODELS and np.allclose(r.nominal_model.dh, load_model(name).dh):
        return f"{name}, [robot] dh: the shipped table (not identified)"
    return f"{name}, [robot] dh of the profile (not identified; differs from the shipped table)"


def _dh_table(dh: np.ndarray, beta: np.ndarray | None, r: CellReport) -> str:
    p = r.profile
    model = p.model
    with_beta = beta is not None and bool(np.any(beta != 0.0))
    head = ["joint", "θ offset", "d (mm)", "a (mm)", "α"] + (["β"] if with_beta else [])
    head += ["min", "max", "joint offset"]
    rows = []
    for j in range(6):
        row = [f"J{j + 1}"] + [h.num(float(v), 4) for v in dh[j]]
        if with_beta:
            assert beta is not None
            row.append(h.num(float(beta[j]), 4))
        row += [
            h.num(float(model.joint_min_deg[j]), 1),
            h.num(float(model.joint_max_deg[j]), 1),
            h.num(float(p.joint_offsets_deg[j]), 6),
        ]
        rows.append(row)
    return h.table(head, rows, [False] + [True] * (len(head) - 1))


def _cell(r: CellReport) -> str:
    p = r.profile
    out = [h.part("1. The cell"), f"<h3>Robot: {h.e(_dh_origin(r))}</h3>"]
    out.append(
        "<p>Standard DH rows (θ offset, α, β in degrees), the joint ranges (deg) and the joint "
        "offsets of [calibration] (deg; actual angle = encoder reading + offset; how well each "
        "is known: the verdict).</p>"
    )
    out.append(_dh_table(p.model.dh, p.model.beta_deg, r))
    if r.identified_dh:
        out.append("<p>The [robot] table the identified one replaces:</p>")
        nominal = r.nominal_model
        out.append(
            h.table(
                ["joint", "θ offset", "d (mm)", "a (mm)", "α"],
                [
                    [f"J{j + 1}"] + [h.num(float(v), 4) for v in nominal.dh[j]]
                    for j in range(len(nominal.dh))
                ],
                [False, True, True, True, True],
            )
        )
    tool_src = (
        "as stated in the profile: no tool-frame write in its history"
        if not r.tools
        else f"written by tool-frame, history write #{r.tools[-1].write.entry.id}"
    )
    out.append("<h3>Tool, block, plate, water, transducer</h3>")
    rows = [
        ("tool position", f"{h.nums(p.tool_position_mm)} mm ± {h.nums(p.tool_position_std_mm)}"),
        ("tool rotation", f"{h.nums(p.tool_rotation_deg)} deg ± {h.nums(p.tool_rotation_std_deg)}"),
        ("tool: source", h.e(tool_src)),
        (
            "block corner",
            f"{h.nums(p.sample_position_mm, 3)} mm ± {h.nums(p.sample_position_std_mm, 3)}",
        ),
        (
            "block rotation",
            f"{h.nums(p.sample_rotation_deg, 3)} deg ± {h.nums(p.sample_rotation_std_deg, 3)}",
        ),
        ("block face size", f"{h.num(p.sample_face_size_mm, 1)} mm"),
    ]
    if p.reflector_points_mm is None:
        rows.append(("plate", "no [reflector] in the profile"))
    else:
        pts = "<br>".join(h.nums(pt, 3) for pt in np.asarray(p.reflector_points_mm))
        rows.append(("plate points", f"{pts}<br>± {h.num(p.reflector_points_std_mm, 3)} mm each"))
    cal = r.current_calibration
    speed = (
        f"; sound speed {h.num(cal.sound_speed_m_s, 2)} m/s as last calibrated"
        if cal is not None and cal.sound_speed_m_s is not None
        else ""
    )
    rows += [
        (
            "water",
            f"{h.num(p.water_temperature_c, 1)} °C ± {h.num(p.water_temperature_std_c, 1)}{speed}",
        ),
        (
            "transducer",
            f"{h.num(p.frequency_mhz, 2)} MHz, element {h.num(p.element_diameter_mm, 2)} mm",
        ),
    ]
    if p.step is not None:
        rows.append(
            (
                "step",
                f"height {h.num(p.step.height_mm, 3)} ± {h.num(p.step.height_std_mm, 3)} mm, "
                f"centre {h.nums(p.step.centre_mm, 1)} mm, size {h.num(p.step.size_mm, 1)} mm",
            )
        )
    out.append(h.kv(rows))
    out.append("</section>")
    return "\n".join(out)


def _calibrations(r: CellReport) -> str:
    title = "2. Calibrations"
    if not r.calibrations:
        return h.empty_part(
            title,
            "No calibration: the profile's history holds no calibrate write and the profile no "
            "[calibration] offsets.",
        )
    figure = h.figure(
        figures.offsets_figure(r.calibrations),
        "joint offsets per calibrate write with 3-sigma bars",
        "Each joint's offset as written by each calibrate (x: history write), bars ±3σ "
        "(the true offset lies within them); an open square is a joint the run could not "
        "determine, its offset kept from the profile.",
    )
    out = [h.part(title), figure]
    if not any(c.residuals for c in r.calibrations):
        out.append(
            h.note(
                "The profile and its history hold each calibration's result and fit summary, "
                "not the residual of each measurement: those come from a record of the run. "
                "Calibrate with <code>--record run.jsonl</code> and give the record to the "
                "report: <code>ucal report PROFILE -o report.html --record run.jsonl</code>."
            )
        )
    current = r.current_calibration
    for n, cal in reversed(list(enumerate(r.calibrations, 1))):
        out.append(_calibration(cal, n, cal is current))
    out.append("</section>")
    return "\n".join(out)


def _calibration(cal: Calibration, n: int, current: bool) -> str:
    if cal.write is None:
        title = "the profile's [calibration] (no recorded write)"
        reason = ""
    else:
        title = _write_title(cal.write)
        reason = f"<p>Recorded reason: <code>{h.e(cal.write.entry.reason)}</code></p>"
    out = [
        '<section class="calibration">',
        f"<h3>Calibration {n}{' (current)' if current else ''}: {title}</h3>",
        reason,
    ]
    fit = cal.fit
    verdict = h.e(fit.verdict or "not recorded")
    if fit.verdict and fit.verdict != "ok":
        verdict = f'<span class="bad">{verdict}</span>'
    out.append(
        h.kv(
            [
                ("method, level", f"{h.e(cal.method or '—')}, {h.e(cal.level or '—')}"),
                ("run date", h.e(h.when(cal.date))),
                ("fit verdict", verdict),
                (
                    "χ² reduced (dof)",
                    f"{h.num(fit.chi2_reduced, 3)} ({'—' if fit.dof is None else fit.dof})",
                ),
                (
                    "rms tilt, rms distance",
                    "not recorded in the profile (the run's record has them)"
                    if fit.rms_tilt_deg is None and fit.rms_distance_mm is None
                    else f"{_sci(fit.rms_tilt_deg)} deg, {_sci(fit.rms_distance_mm)} mm",
                ),
                ("worst measurement", h.e(fit.worst or "—")),
                ("sound speed", f"{h.num(cal.sound_speed_m_s, 2)} m/s"),
                ("condition number", h.num(cal.condition_number, 1)),
            ]
        )
    )
    out.append(
        h.table(
            ["quantity", "offset", "σ", "tolerance", "state", "why, or what would determine it"],
            [_quantity_row(q, q.name, why=True) for q in v.joint_quantities(cal)],
            [False, True, True, True, False, False],
            "wide",
        )
    )
    if cal.dh is not None:
        out.append("<p>Identified DH table ([calibration] dh):</p>")
        beta = cal.beta_deg if cal.beta_deg is not None else np.zeros(6)
        out.append(
            h.table(
                ["joint", "θ offset", "d (mm)", "a (mm)", "α", "β"],
                [
                    [f"J{j + 1}"] + [h.num(float(v), 4) for v in cal.dh[j]] + [h.num(beta[j], 4)]
                    for j in range(6)
                ],
                [False] + [True] * 5,
            )
        )
    if cal.residuals:
        assert cal.record is not None
        out.append(
            h.figure(
                figures.residuals_figure(cal),
                "normalised residual of each measurement",
                f"{len(cal.residuals)} measurements, from the record "
                f"<code>{h.e(cal.record)}</code>: each residual divided by its noise; a fit that "
                "agrees with its noise keeps almost all within ±3.",
            )
        )
    out.append("</section>")
    return "\n".join(out)


def _sci(value: float | None) -> str:
    if value is None or not np.isfinite(value):
        return "—"
    return f"{value:.3g}"


def _tools(r: CellReport) -> str:
    title = "3. Tool frame"
    if not r.tools:
        p = r.profile
        return h.empty_part(
            title,
            "No tool-frame write in the history: the tool is the profile's "
            f"({h.nums(p.tool_position_mm)} mm, {h.nums(p.tool_rotation_deg)} deg), from its "
            "drawing.",
        )
    figure = h.figure(
        figures.tool_figure(r.tools),
        "tool frame per tool-frame write with 3-sigma bars",
        "The tool frame relative to the flange as written by each tool-frame (x: history "
        "write), bars ±3σ. The rotation about the beam (rz) is not measured by an echo: "
        "its σ is the profile's tolerance.",
    )
    out = [h.part(title), figure]
    rows = []
    for t in reversed(r.tools):
        write = f"#{t.write.entry.id}, {_state(t.write)}<br>{h.when_cell(t.write.entry.time)}"
        for name, unit, values, stds in (
            ("position", "mm", t.position_mm, t.position_std_mm),
            ("rotation", "deg", t.rotation_deg, t.rotation_std_deg),
        ):
            cells = [
                h.num(float(v)) + ("" if stds is None else f" ± {h.num(float(s))}")
                for v, s in zip(values, stds if stds is not None else values, strict=True)
            ]
            rows.append([write, f"{name} ({unit})", *cells])
            write = ""
    out.append(
        h.table(
            ["write", "", "x | rx", "y | ry", "z | rz"],
            rows,
            [False, False, True, True, True],
            "wide",
        )
    )
    out.append("</section>")
    return "\n".join(out)


def _verify(r: CellReport) -> str:
    out = [h.part("4. Last verify of this cell")]
    pic = r.verify
    if pic is None:
        out.append(
            "<p>No verify of this cell beside the profile: run <code>ucal verify PROFILE</code> "
            "(it measures the positioning error before and after calibration).</p>"
        )
    else:
        since = ""
        if pic.writes_since:
            ids = ", ".join(f"#{w.entry.id} ({w.command})" for w in pic.writes_since)
            since = (
                f" The profile was written since ({ids}): the picture shows the cell as an "
                "earlier version of the profile held it."
            )
        facts = pic.facts
        said = (
            " It carries no record of its run (drawn by an older ucal): its title holds the "
            "verdict."
            if facts is None
            else f" On {facts.cell_words}: {v.verify_words(facts)}."
        )
        out.append(
            h.figure(
                figures.png_uri(pic.png),
                "positioning error before and after calibration, drawn by verify",
                f"<code>{h.e(pic.path)}</code>, drawn "
                f"{h.e(pic.modified.strftime('%Y-%m-%d %H:%M'))}"
                " UTC by <code>ucal verify</code>. Title: the verdict and the largest "
                "deviation after calibration against the tolerance (mm). Left: each point's "
                "deviation after calibration per block axis (mm), the tolerance band shaded. "
                f"Right: the largest deviation per axis before and after calibration (mm)."
                f"{h.e(said)}{h.e(since)}",
            )
        )
        if facts is not None and facts.iso9283 is not None:
            out.append(_iso9283(facts.iso9283))
    rule = (
        "verify writes nothing into the profile or its history; its picture carries the facts "
        "of its run. A verify against a world file (<code>--sim WORLD</code>) is a rehearsal "
        "on the cell that file describes, not on this one: its picture is "
        "<code>PROFILE.verify.WORLD.png</code>, named in the verdict, not shown here."
    )
    out.append(h.note(rule))
    out.append("</section>")
    return "\n".join(out)


def _iso9283(iso: IsoFacts) -> str:
    """An ISO 9283 verify's figures: AP and RP per pose with one sigma (mm)."""
    rows = [
        [h.e(name), f"{ap:.4f} ± {ap_std:.4f}", f"{rp:.4f} ± {rp_std:.4f}"]
        for name, ap, ap_std, rp, rp_std in iso.poses
    ]
    return (
        f"<p>ISO 9283 (7.2): the five poses of a {iso.side_mm:.0f} mm cube over the block, "
        f"{iso.cycles} cycles, in the block's frame. AP: how far the mean attained position "
        "is from the commanded one; RP: how far the attained positions spread about their "
        "mean (l̄ + 3·S<sub>l</sub>); ± one sigma of each, the measurement's and the few "
        "cycles' own.</p>" + h.table(["pose", "AP (mm)", "RP (mm)"], rows, [False, True, True])
    )


def _lost_motion(r: CellReport) -> str:
    out = [h.part("5. Lost motion and drift")]
    cal = r.current_calibration
    out.append(
        f"<p>Lost motion (backlash) per joint, deg: {h.e(v.lost_motion_words(cal))}. A joint with "
        "lost motion b reached from the other side than the offsets hold for is off by b/2."
        "</p>"
    )
    lost = v.lost_motion_quantities(cal)
    out.append(
        h.table(
            ["joint", "lost motion", "σ", "tolerance", "state"],
            [_quantity_row(q, q.name.split()[0]) for q in lost],
            [False, True, True, True, False],
            "short",
        )
    )
    hows = sorted({q.why for q in lost if q.why})
    if hows:
        out.append(f"<p>{h.e('; '.join(h[:1].upper() + h[1:] for h in hows))}.</p>")
    drift = v.drift_quantity(r)
    if drift is None:
        out.append("<p>Drift of the sound speed during a run: <strong>not measured</strong>.</p>")
    else:
        out.append(
            f"<p>Sound speed drift during the last calibration (the tank warming or cooling): "
            f"{h.e(drift.value)} ± {h.e(drift.std)}, {h.e(drift.state)} against "
            f"{h.e(drift.tolerance)}.</p>"
        )
    out.append("</section>")
    return "\n".join(out)
