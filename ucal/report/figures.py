"""The report's figures: matplotlib drawings returned as self-contained SVG ``data:`` URIs.

Each figure is its own SVG document inside an ``<img>``, so that the ids matplotlib gives its
elements cannot clash between figures, and the text is drawn as paths (no font to load). They
are drawn to read in grey: black and greys, told apart by marker and hatching, never by colour
alone.
"""

from __future__ import annotations

import base64
import io
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from matplotlib.figure import Figure
    from matplotlib.typing import RcKeyType

    from ucal.report.checks import CheckFacts
    from ucal.report.gather import Calibration, ToolCalibration

#: Width of a figure (inches): the text width of an A4 page with 15 mm margins, about.
PAGE_WIDTH_IN = 7.0
#: The bands drawn on the residual plot (residual / sigma).
BANDS = (1.0, 3.0)
STYLE: dict[RcKeyType, Any] = {
    "font.size": 8.0,
    "axes.titlesize": 9.0,
    "axes.labelsize": 8.0,
    "axes.edgecolor": "#333333",
    "axes.grid": True,
    "grid.color": "#d9d9d9",
    "grid.linewidth": 0.6,
    "svg.fonttype": "path",  # glyphs as paths: nothing to load, the same everywhere
    "svg.hashsalt": "ucal-report",  # the same ids, hence the same page, for the same profile
}


def _figure(width_in: float, height_in: float) -> Figure:
    # matplotlib only for the figures: importing it costs a command most of a second
    from matplotlib.figure import Figure

    return Figure(figsize=(width_in, height_in), layout="constrained")


def svg_uri(fig: Figure) -> str:
    """``fig`` as a ``data:image/svg+xml;base64,...`` URI (no date or creator in it)."""
    import matplotlib

    buf = io.BytesIO()
    with matplotlib.rc_context(STYLE):
        fig.savefig(
            buf,
            format="svg",
            metadata={"Date": None, "Creator": None, "Format": None, "Type": None},
        )
    return "data:image/svg+xml;base64," + base64.b64encode(buf.getvalue()).decode("ascii")


def png_uri(png: bytes) -> str:
    """A PNG file's bytes as a ``data:image/png;base64,...`` URI."""
    return "data:image/png;base64," + base64.b64encode(png).decode("ascii")


def _history_panels(
    names: Sequence[str],
    unit: Sequence[str],
    labels: Sequence[str],
    values: np.ndarray,
    stds: np.ndarray,
    kept: np.ndarray,
    title: str,
) -> Figure:
    """One panel per quantity (2 x 3): its value at each write (x), with ±3σ bars.

    ``values``, ``stds`` (NaN: not determined) and ``kept`` (True: not measured by that write,
    kept from the profile) are (writes, quantities).
    """
    import matplotlib

    with matplotlib.rc_context(STYLE):
        fig = _figure(PAGE_WIDTH_IN, 4.2)
        axes = fig.subplots(2, 3)
        x = np.arange(len(labels))
        for k, ax in enumerate(axes.flat):
            if k >= len(names):
                ax.set_visible(False)
                continue
            measured = ~kept[:, k]
            err = np.where(np.isfinite(stds[:, k]), 3.0 * stds[:, k], 0.0)
            ax.errorbar(
                x[measured],
                values[measured, k],
                yerr=err[measured],
                fmt="o",
                color="black",
                markersize=4.5,
                capsize=4,
                elinewidth=1.2,
                label="measured ±3σ",
            )
            if np.any(~measured):
                ax.plot(
                    x[~measured],
                    values[~measured, k],
                    "s",
                    markerfacecolor="white",
                    markeredgecolor="#555555",
                    markersize=5,
                    label="kept (not measured)",
                )
            if len(labels) > 1:
                ax.plot(x, values[:, k], color="#999999", linewidth=0.8, zorder=0)
            ax.set_title(f"{names[k]} ({unit[k]})")
            ax.set_xticks(x, labels)
            ax.set_xlim(-0.6, len(labels) - 0.4)
            ax.ticklabel_format(axis="y", useOffset=False)
            if len(labels) <= 3:
                for xi, v, e, m in zip(x, values[:, k], err, measured, strict=True):
                    # + 0.0: no "-0.0000"
                    text = f"{round(v, 4) + 0.0:.4f}" + (f"\n±{e:.4f} (3σ)" if m and e > 0 else "")
                    ax.annotate(
                        text,
                        (xi, v),
                        xytext=(7, 0),
                        textcoords="offset points",
                        va="center",
                        fontsize=7,
                    )
        handles, legend_labels = [], []
        for ax in axes.flat:
            for h, lab in zip(*ax.get_legend_handles_labels(), strict=True):
                if lab not in legend_labels:
                    handles.append(h)
                    legend_labels.append(lab)
        fig.legend(handles, legend_labels, loc="outside lower center", ncols=2, frameon=False)
        fig.suptitle(title)
    return fig


def _write_label(cal: Calibration | ToolCalibration) -> str:
    if cal.write is None:
        return "profile"
    return f"#{cal.write.entry.id}" + (" undone" if cal.write.entry.undone else "")


def offsets_figure(calibrations: Sequence[Calibration]) -> str:
    """Joint offsets at each calibrate write, one panel per joint, ±3σ bars (SVG URI)."""
    values = np.array([c.offsets_deg for c in calibrations])
    stds = np.array(
        [c.std_deg if c.std_deg is not None else np.full(6, np.nan) for c in calibrations]
    )
    kept = np.array([[j + 1 in c.unobservable_joints for j in range(6)] for c in calibrations])
    fig = _history_panels(
        [f"J{j + 1}" for j in range(6)],
        ["deg"] * 6,
        [_write_label(c) for c in calibrations],
        values,
        stds,
        kept,
        "Joint offsets written by each calibrate (history write #), bars ±3σ",
    )
    return svg_uri(fig)


def tool_figure(tools: Sequence[ToolCalibration]) -> str:
    """Tool frame at each tool-frame write, one panel per coordinate, ±3σ bars (SVG URI)."""
    values = np.array([np.concatenate([t.position_mm, t.rotation_deg]) for t in tools])
    stds = np.array(
        [
            np.concatenate(
                [
                    t.position_std_mm if t.position_std_mm is not None else np.full(3, np.nan),
                    t.rotation_std_deg if t.rotation_std_deg is not None else np.full(3, np.nan),
                ]
            )
            for t in tools
        ]
    )
    fig = _history_panels(
        ["x", "y", "z", "rx", "ry", "rz"],
        ["mm"] * 3 + ["deg"] * 3,
        [_write_label(t) for t in tools],
        values,
        stds,
        np.zeros(values.shape, bool),
        "Tool frame (flange) written by each tool-frame (history write #), bars ±3σ",
    )
    return svg_uri(fig)


def residuals_figure(cal: Calibration) -> str:
    """Each measurement's normalised residuals (tilt a, tilt b, distance), ±1σ and ±3σ bands
    (SVG URI)."""
    import matplotlib

    rows = cal.residuals
    labels = [r.label for r in rows]
    series = (  # name, values, fill, hatch: told apart in grey
        ("tilt a", [r.tilt[0] for r in rows], "black", None),
        ("tilt b", [r.tilt[1] for r in rows], "#9a9a9a", "////"),
        ("distance", [r.distance for r in rows], "white", "xxx"),
    )
    with matplotlib.rc_context(STYLE):
        fig = _figure(PAGE_WIDTH_IN, 3.4)
        ax = fig.subplots()
        x = np.arange(len(rows))
        width = 0.27
        for i, (name, values, fill, hatch) in enumerate(series):
            ax.bar(
                x + (i - 1) * width,
                values,
                width,
                label=name,
                color=fill,
                hatch=hatch,
                edgecolor="black",
                linewidth=0.6,
            )
        for band, dash in zip(BANDS, (":", "--"), strict=True):
            for sign in (1.0, -1.0):
                ax.axhline(sign * band, color="#444444", linestyle=dash, linewidth=0.8)
        ax.axhline(0.0, color="black", linewidth=0.8)
        ax.set_xticks(x, labels, rotation=60 if len(rows) > 8 else 0, ha="right")
        ax.set_xlim(-0.6, len(rows) - 0.4)
        top = max(3.5, float(np.max(np.abs([v for _, vs, _, _ in series for v in vs]), initial=0)))
        ax.set_ylim(-1.1 * top, 1.1 * top)
        ax.set_ylabel("residual / σ")
        ax.set_xlabel("measurement (dotted ±1σ, dashed ±3σ)")
        ax.legend(ncols=3, loc="upper right", fontsize=7)
        ax.set_title("Residual of each measurement, in units of its noise")
    return svg_uri(fig)


def growth_figure(checks: Sequence[CheckFacts]) -> str:
    """The arm's growth at each check that fitted it (ppm, ±3σ bars), its tolerance band and
    the temperature rise it means on the right axis (SVG URI)."""
    import matplotlib

    from ucal.cell import ALUMINIUM_EXPANSION_PER_K

    shown = [c for c in checks if c.growth_ppm is not None]
    x = np.arange(len(shown))
    y = np.array([c.growth_ppm for c in shown], float)
    err = np.array([3.0 * (c.growth_std_ppm or 0.0) for c in shown], float)
    tol = max(c.growth_tolerance_ppm for c in shown)
    with matplotlib.rc_context(STYLE):
        fig = _figure(PAGE_WIDTH_IN, 2.6)
        ax = fig.subplots()
        ax.axhspan(-tol, tol, color="#eeeeee", zorder=0, label=f"tolerance ±{tol:g} ppm")
        ax.axhline(0.0, color="#777777", linewidth=0.8)
        ax.errorbar(x, y, yerr=err, fmt="o", color="black", markersize=4.5, capsize=4, label="±3σ")
        if len(shown) > 1:
            ax.plot(x, y, color="#999999", linewidth=0.8, zorder=1)
        ax.set_xticks(x, [f"#{c.id}" for c in shown])
        ax.set_xlim(-0.6, len(shown) - 0.4)
        ax.set_xlabel("check (history #)")
        ax.set_ylabel("growth since the reference (ppm)")
        per_k = ALUMINIUM_EXPANSION_PER_K * 1e6  # ppm per K
        right = ax.secondary_yaxis(
            "right",
            functions=(lambda ppm: np.asarray(ppm) / per_k, lambda k: np.asarray(k) * per_k),
        )
        right.set_ylabel("as a warmer arm (K)")
        ax.legend(loc="upper left", frameon=False)
        fig.suptitle("The arm's growth at each check, bars ±3σ")
    return svg_uri(fig)
