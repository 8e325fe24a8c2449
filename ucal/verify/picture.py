"""The picture ``ucal verify`` writes: the verdict and each point's deviation against tolerance.

Drawn to be read without the README, and printed in grey:

* the title holds the verdict (PASSED or FAILED, and "marginal" when it could go the other way
  within what verify measures to) and what it rests on: the largest deviation after
  calibration against the tolerance;
* left: every point's deviation after calibration on each block axis, signed, at a scale where
  the tolerance band (±tolerance, shaded, dashed edges) fills most of the height, or, when a
  point is outside it, where that point shows; the axes are told apart by marker shape and
  fill, not by colour alone; the orientations the points were commanded in are separated and
  named;
* right: the largest deviation per axis before and after calibration, told apart by shade and
  hatching, with the tolerance as a dashed line; a log scale (said on the axis) when "before"
  is more than ``LOG_RATIO`` times the rest; when "before" is the profile as it is (no
  calibration in its history), a sentence saying so instead of two identical sets of bars;
* below: what the figures are relative to (the gauge), the notes, the points not measured.

Laid out by matplotlib's constrained layout, the text below wrapped to the figure's width.
"""

from __future__ import annotations

import textwrap
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from matplotlib.figure import Figure

    from ucal.verify.measure import VerifyResult

#: What ``verify`` appends to the profile's stem for its picture, unless ``--plot`` names one.
PICTURE_SUFFIX = ".verify.png"
#: Figure width (in) and resolution (dpi) of the PNG: 1440 pixels wide.
WIDTH_IN = 12.0
DPI = 120
#: Height of the plots (in) and of each line of text below them.
PLOTS_IN = 5.6
LINE_IN = 0.19
#: Characters per line of the text below the plots (8 pt over the figure's width).
WRAP_CHARS = 185
#: "before" more than this many times the largest other figure: a log scale.
LOG_RATIO = 20.0
#: The block axes: marker, fill and colour of each (shape and fill tell them apart in grey).
AXIS_STYLE: dict[str, dict[str, Any]] = {
    "X": {"marker": "o", "color": "#1b3a6b", "mfc": "#1b3a6b"},
    "Y": {"marker": "s", "color": "#b34700", "mfc": "white"},
    "Z": {"marker": "^", "color": "#2e7d32", "mfc": "#bdbdbd"},
}
#: "before" and "after" bars: fill and hatching (shade and pattern tell them apart in grey).
BAR_STYLE: dict[str, dict[str, Any]] = {
    "before": {"color": "#d9d9d9", "hatch": "///", "edgecolor": "#4d4d4d"},
    "after": {"color": "#404040", "hatch": "", "edgecolor": "black"},
}


def verify_picture_path(profile_path: str | Path) -> Path:
    """The picture ``verify`` writes by default: ``cell.toml`` → ``cell.verify.png`` beside it."""
    p = Path(profile_path)
    return p.with_name(p.stem + PICTURE_SUFFIX)


@dataclass(frozen=True)
class PictureText:
    """What the picture says beside its data."""

    name: str = ""  # the profile's file name
    tolerance_mm: float = 0.5
    marginal: bool = False
    before_source: str = ""  # where the "before" offsets come from
    before_is_after: bool = False  # both passes commanded with the same profile
    gauge_note: str = ""
    notes: tuple[str, ...] = ()


def verdict_title(result: VerifyResult, text: PictureText) -> str:
    """The title: the verdict, then the largest deviation after calibration against the
    tolerance."""
    worst = float(np.max(result.stats("after")["max"]))
    ok = worst <= text.tolerance_mm
    verdict = ("PASSED" if ok else "FAILED") + (" (marginal)" if text.marginal else "")
    head = f"{text.name}: verify {verdict}" if text.name else f"verify {verdict}"
    return (
        f"{head}\nlargest deviation {_after_name(text)}: {worst:.3f} mm "
        f"{'≤' if ok else '>'} tolerance {text.tolerance_mm:g} mm "
        f"({result.plan.points} points, block axes)"
    )


def _lines_below(result: VerifyResult, text: PictureText) -> list[str]:
    """The text under the plots, wrapped: gauge, notes, points not measured."""
    items = [text.gauge_note, *text.notes, *(s.reason() for s in result.skipped)]
    lines: list[str] = []
    for item in filter(None, items):
        wrapped = textwrap.wrap(item[0].upper() + item[1:], WRAP_CHARS - 2)
        lines += ["• " + wrapped[0], *("  " + w for w in wrapped[1:])]
    return lines


def verify_figure(result: VerifyResult, text: PictureText) -> Figure:
    """The picture of ``result`` (module docstring) as a matplotlib figure (not shown)."""
    # matplotlib only for the picture: importing it costs a command a second at start-up
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    below = _lines_below(result, text)
    text_in = LINE_IN * len(below) + 0.1
    fig = Figure(figsize=(WIDTH_IN, PLOTS_IN + text_in + 0.9), dpi=DPI, layout="constrained")
    FigureCanvasAgg(fig)  # drawn without pyplot: no display, no global state
    grid = fig.add_gridspec(2, 2, width_ratios=[1.5, 1], height_ratios=[PLOTS_IN, text_in])
    points_ax = fig.add_subplot(grid[0, 0])
    bars_ax = fig.add_subplot(grid[0, 1])
    notes_ax = fig.add_subplot(grid[1, :])
    fig.suptitle(verdict_title(result, text), fontsize=13, fontweight="bold")
    _draw_points(points_ax, result, text.tolerance_mm, _after_name(text))
    _draw_bars(bars_ax, result, text)
    notes_ax.set_axis_off()
    notes_ax.text(
        0.0, 1.0, "\n".join(below), va="top", ha="left", fontsize=8, transform=notes_ax.transAxes
    )
    return fig


def plot_verify(result: VerifyResult, path: str | Path, text: PictureText | None = None) -> Path:
    """Save the picture of ``result`` (PNG, or any format matplotlib knows by the suffix)."""
    fig = verify_figure(result, text or PictureText())
    out = Path(path)
    fig.savefig(out, dpi=DPI)
    return out


def _after_name(text: PictureText) -> str:
    """What the "after" pass is: after calibration, or the profile never calibrated."""
    return "with the profile as it is" if text.before_is_after else "after calibration"


def _draw_points(ax: Any, result: VerifyResult, tolerance_mm: float, after_name: str) -> None:
    """Each point's signed deviation after calibration per block axis, the tolerance band,
    the orientations' groups."""
    after = result.measured("after")
    index = np.array([p.index + 1 for p in after])
    dev = result.deviations("after")
    worst = float(np.max(np.abs(dev))) if dev.size else 0.0
    # the band fills most of the height; a point outside it widens the scale to show it
    limit = max(1.35 * tolerance_mm, 1.12 * worst)
    ax.axhspan(-tolerance_mm, tolerance_mm, color="#ececec", zorder=0)
    for y in (-tolerance_mm, tolerance_mm):
        ax.axhline(y, color="black", linestyle="--", linewidth=1.0, zorder=1)
    ax.axhline(0.0, color="#7f7f7f", linewidth=0.6, zorder=1)
    for k, (axis, style) in enumerate(AXIS_STYLE.items()):
        ax.plot(
            index + 0.22 * (k - 1),  # the three axes of a point side by side
            dev[:, k],
            linestyle="none",
            ms=6,
            mew=1.3,
            label=f"Δ{axis}",
            zorder=3,
            **style,
        )
    n = result.plan.points
    # the orientations the points were commanded in: separated, named above the plot
    group_of = np.array(result.plan.group_of) if result.plan.group_of else np.zeros(n, int)
    for g, group in enumerate(result.plan.groups):
        members = np.flatnonzero(group_of == g) + 1
        if not len(members):
            continue
        if members[0] > 1:
            ax.axvline(members[0] - 0.5, color="#7f7f7f", linestyle=":", linewidth=1.0)
        ax.text(
            0.5 * (members[0] + members[-1]),
            1.01,
            _group_label(group.name),
            transform=ax.get_xaxis_transform(),
            ha="center",
            va="bottom",
            fontsize=8,
        )
    ax.set_xlim(0.4, n + 0.6)
    ax.set_ylim(-limit, limit)
    ax.set_xticks(_point_ticks(n))
    ax.set_xlabel("point (as numbered in the --json output)")
    ax.set_ylabel(f"deviation {after_name} (mm)")
    ax.set_title(
        f"{after_name[0].upper()}{after_name[1:]}: each point's deviation per block axis",
        pad=16,
        fontsize=11,
    )
    ax.grid(True, axis="y", color="#d0d0d0", linewidth=0.6)
    handles, labels = ax.get_legend_handles_labels()
    from matplotlib.patches import Patch

    handles.append(Patch(facecolor="#ececec", edgecolor="black", linestyle="--"))
    labels.append(f"tolerance ±{tolerance_mm:g} mm")
    ax.legend(handles, labels, loc="upper center", bbox_to_anchor=(0.5, -0.13), ncol=4, fontsize=9)


def _group_label(name: str) -> str:
    return {
        "down": "beam straight down",
        "turned": "tool turned 180°",
        "tilted": "beam tilted 15°",
    }.get(name, name)


def _point_ticks(n: int) -> list[int]:
    """Every point's number up to 30 points, else every 5th."""
    step = 1 if n <= 30 else 5
    return [i for i in range(1, n + 1) if i == 1 or i % step == 0]


def _draw_bars(ax: Any, result: VerifyResult, text: PictureText) -> None:
    """Largest |deviation| per axis before and after calibration, the tolerance line; a
    sentence instead of "before" when it is the same profile."""
    passes = ("after",) if text.before_is_after else ("before", "after")
    values = {p: np.array(result.stats(p)["max"]) if result.measured(p) else None for p in passes}
    shown = [v for v in values.values() if v is not None]
    everything = np.concatenate([*shown, [text.tolerance_mm]])
    rest = np.concatenate(
        [*(v for p, v in values.items() if p != "before" and v is not None), [text.tolerance_mm]]
    )
    log = bool(np.max(everything) > LOG_RATIO * np.max(rest))
    width = 0.36 if len(passes) == 2 else 0.5
    x = np.arange(3)
    for j, p in enumerate(passes):
        v = values[p]
        if v is None:
            continue
        offset = (j - 0.5 * (len(passes) - 1)) * width
        name = f"{p} calibration" if p == "before" else _after_name(text)
        bars = ax.bar(x + offset, v, width, label=name, linewidth=1.0, **BAR_STYLE[p])
        ax.bar_label(bars, fmt="%.3f", fontsize=8, padding=2)
    ax.axhline(
        text.tolerance_mm,
        color="black",
        linestyle="--",
        linewidth=1.2,
        label=f"tolerance {text.tolerance_mm:g} mm",
    )
    ax.set_xticks(x, [f"Δ{a}" for a in "XYZ"])
    # room above the bars for their figures (and the sentence instead of "before")
    headroom = 2.0 if text.before_is_after else 1.25
    if log:
        ax.set_yscale("log")
        low = max(float(np.min(everything[everything > 0])) / 3.0, 1e-4)
        ax.set_ylim(low, float(np.max(everything)) * 4.0 * headroom)
        ax.set_ylabel("largest |deviation| (mm, log scale)")
    else:
        ax.set_ylim(0.0, float(np.max(everything)) * headroom)
        ax.set_ylabel("largest |deviation| (mm)")
    ax.set_title("Largest deviation per block axis", pad=16, fontsize=11)
    ax.grid(True, axis="y", color="#d0d0d0", linewidth=0.6)
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.08), ncol=3, fontsize=9)
    if text.before_is_after:
        why = textwrap.fill(
            "No 'before' bars: 'before' is the profile as it is, so both passes commanded the "
            f"same points ({text.before_source}).",
            46,
        )
        ax.text(
            0.03,
            0.97,
            why,
            transform=ax.transAxes,
            va="top",
            ha="left",
            fontsize=8,
            bbox={"facecolor": "white", "edgecolor": "#7f7f7f", "boxstyle": "round"},
        )
