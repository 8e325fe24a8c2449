"""The picture ``verify`` writes: what it says, and that nothing in it is clipped or overlaps."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
import tomlkit
from matplotlib.figure import Figure
from matplotlib.text import Text

from ucal.profile import default_profile_text, profile_from_data
from ucal.verify.measure import PointResult, VerifyResult
from ucal.verify.picture import AXIS_STYLE, BAR_STYLE, PictureText, plot_verify, verify_figure
from ucal.verify.plan import plan_verify

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
GAUGE = (
    "positions relative to the block (gauge: block): every deviation is measured against the "
    "block's faces; J1 is calibrated relative to the block as placed, so in the robot's base "
    "frame the points are where the profile puts them only to ±5.7 mm"
)


@pytest.fixture(scope="module")
def plan():
    profile = profile_from_data(tomlkit.parse(default_profile_text("tx90")), "cell.toml")
    return plan_verify(profile, 20)


def result_of(plan, before_mm: np.ndarray, after_mm: np.ndarray) -> VerifyResult:
    """A result whose points deviate by ``before_mm`` / ``after_mm`` (n, 3) from the nominal."""
    points = []
    for target in plan.targets:
        dev = (before_mm if target.pass_name == "before" else after_mm)[target.index]
        nominal = plan.nominal_mm[target.index]
        points.append(
            PointResult(
                target.pass_name,
                target.index,
                nominal,
                target.joints_deg,
                (),
                nominal,
                nominal + dev,
                0.0,
            )
        )
    return VerifyResult(plan, points, moves=0, reads=0)


def texts(fig: Figure) -> list[Text]:
    """Every visible text of the figure with something written in it."""
    return [t for t in fig.findobj(Text) if t.get_visible() and t.get_text().strip()]


def check_layout(fig: Figure) -> None:
    """Every text inside the figure, no two texts overlapping."""
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()  # type: ignore[attr-defined]  # Agg
    frame = fig.bbox
    boxes = [(t.get_text(), t.get_window_extent(renderer)) for t in texts(fig)]
    for text, box in boxes:
        assert box.x0 >= frame.x0 - 0.5 and box.x1 <= frame.x1 + 0.5, text
        assert box.y0 >= frame.y0 - 0.5 and box.y1 <= frame.y1 + 0.5, text
    for (a, box_a), (b, box_b) in itertools.combinations(boxes, 2):
        assert not box_a.overlaps(box_b), (a, b)
    assert fig.get_tightbbox(renderer).width <= frame.width / fig.dpi + 1e-6


def test_a_passing_run_says_so_and_draws_the_tolerance(plan, tmp_path) -> None:
    n = plan.points
    rng = np.random.default_rng(1)
    after = np.tile([0.21, 0.22, -0.06], (n, 1)) + rng.normal(0.0, 0.01, (n, 3))
    before = np.tile([-15.2, 2.3, 3.2], (n, 1))
    result = result_of(plan, before, after)
    text = PictureText(name="cell.toml", tolerance_mm=0.5, gauge_note=GAUGE)
    fig = verify_figure(result, text)
    title = fig.get_suptitle()
    worst = np.max(np.abs(after))
    assert title.startswith("cell.toml: verify PASSED")
    assert f"{worst:.3f} mm ≤ tolerance 0.5 mm" in title and "20 points" in title
    points_ax, bars_ax, notes_ax = fig.axes
    # each point's deviation at a scale where the tolerance band fills most of the height
    assert points_ax.get_ylim() == pytest.approx((-0.675, 0.675))
    assert "deviation after calibration (mm)" in points_ax.get_ylabel()
    assert points_ax.get_xlabel().startswith("point")
    dashed = [
        line.get_ydata()[0]
        for line in points_ax.get_lines()
        if line.get_linestyle() == "--" and len(set(line.get_ydata())) == 1
    ]
    assert sorted(dashed) == [-0.5, 0.5]
    legend = [t.get_text() for t in points_ax.get_legend().get_texts()]
    assert legend == ["ΔX", "ΔY", "ΔZ", "tolerance ±0.5 mm"]
    # told apart without colour: marker shapes, and fills, differ
    markers = {line.get_marker() for line in points_ax.get_lines() if line.get_marker() != "None"}
    assert markers == {s["marker"] for s in AXIS_STYLE.values()} and len(markers) == 3
    assert len({s["mfc"] for s in AXIS_STYLE.values()}) == 3
    assert BAR_STYLE["before"]["hatch"] != BAR_STYLE["after"]["hatch"]
    # before ~15 mm, after ~0.2 mm: a log scale, said on the axis
    assert bars_ax.get_yscale() == "log" and "log scale" in bars_ax.get_ylabel()
    bar_legend = [t.get_text() for t in bars_ax.get_legend().get_texts()]
    assert bar_legend == ["tolerance 0.5 mm", "before calibration", "after calibration"]
    assert "gauge: block" in notes_ax.texts[0].get_text()
    # the orientations named above the points
    assert {t.get_text() for t in points_ax.texts} == {
        "beam straight down",
        "tool turned 180°",
        "beam tilted 15°",
    }
    check_layout(fig)
    path = plot_verify(result, tmp_path / "v.png", text)
    assert path.read_bytes()[:8] == PNG_MAGIC


def test_a_failing_run_says_so_and_shows_the_points_outside(plan) -> None:
    n = plan.points
    after = np.tile([2.3, -1.0, 0.6], (n, 1))
    result = result_of(plan, np.tile([15.9, 5.8, 4.4], (n, 1)), after)
    notes = ("the tool check finds the tool 1.0 mm off across the beam",) * 2
    fig = verify_figure(result, PictureText("cell.toml", 0.5, True, notes=notes))
    assert fig.get_suptitle().startswith("cell.toml: verify FAILED (marginal)")
    assert "2.300 mm > tolerance 0.5 mm" in fig.get_suptitle()
    points_ax, bars_ax, notes_ax = fig.axes
    low, high = points_ax.get_ylim()
    assert high >= 2.3 and low <= -1.0  # the points outside the band are in the picture
    assert bars_ax.get_yscale() == "linear"  # 15.9 is less than 20 times 2.3
    assert notes_ax.texts[0].get_text().count("• ") == 2
    check_layout(fig)


def test_before_equal_to_after_is_said_not_drawn_twice(plan) -> None:
    n = plan.points
    dev = np.tile([-16.2, 5.5, 3.6], (n, 1))
    source = "no calibration in the profile's history: zero offsets"
    text = PictureText("cell.toml", 0.5, before_source=source, before_is_after=True)
    fig = verify_figure(result_of(plan, dev, dev), text)
    assert "with the profile as it is: 16.200 mm" in fig.get_suptitle()
    _, bars_ax, _ = fig.axes
    labels = [t.get_text() for t in bars_ax.get_legend().get_texts()]
    assert labels == ["tolerance 0.5 mm", "with the profile as it is"]
    [why] = [t.get_text() for t in bars_ax.texts if t.get_text().startswith("No")]
    assert why.startswith("No 'before' bars") and "zero offsets" in why.replace("\n", " ")
    check_layout(fig)
