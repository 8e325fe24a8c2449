"""ISO 9283's poses and figures (``ucal.verify.iso9283``) against the standard's formulas."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ucal.iso9283 import orientation_figures, standard_figures
from ucal.profile import create_profile, load_profile
from ucal.verify.iso9283 import CYCLE_ORDER, cube_poses, plan_iso9283


def test_poses_lie_on_the_diagonal_plane_at_a_tenth_of_each_diagonal() -> None:
    centre, side = np.array([100.0, 200.0, 80.0]), 100.0
    poses = cube_poses(centre, side)
    assert poses[0] == pytest.approx(centre)
    corners = centre + 0.5 * side * np.array([[-1, -1, -1], [1, -1, -1], [1, 1, 1], [-1, 1, 1]])
    diagonal = side * np.sqrt(3.0)
    for p, corner in zip(poses[1:], corners, strict=True):
        # 10 % of the diagonal from its end, on the line to the centre
        assert np.linalg.norm(p - corner) == pytest.approx(0.1 * diagonal)
        assert np.cross(p - centre, corner - centre) == pytest.approx(np.zeros(3), abs=1e-9)
    # the plane C1-C2-C7-C8 contains the X axis and the (0, 1, 1) diagonal
    normal = np.array([0.0, 1.0, -1.0]) / np.sqrt(2.0)
    assert (poses - centre) @ normal == pytest.approx(np.zeros(5), abs=1e-9)


def test_figures_follow_the_standards_formulas_on_a_hand_worked_case() -> None:
    commanded = np.array([10.0, 0.0, 0.0])
    x = np.array([[10.1, 0.0, 0.0], [10.3, 0.0, 0.0], [10.2, 0.1, 0.0], [10.2, -0.1, 0.0]])
    fig = standard_figures(x, commanded)
    assert fig["ap_xyz"] == pytest.approx([0.2, 0.0, 0.0])
    assert float(fig["ap"]) == pytest.approx(0.2)
    # barycentre (10.2, 0, 0): every l_j is 0.1
    assert float(fig["l_mean"]) == pytest.approx(0.1)
    assert float(fig["s_l"]) == pytest.approx(0.0, abs=1e-12)
    assert float(fig["rp"]) == pytest.approx(0.1)
    abc = np.array([[0.01, 0.0, 0.0], [0.03, 0.0, 0.0]])
    ori = orientation_figures(abc)
    assert ori["ap_abc"] == pytest.approx([0.02, 0.0, 0.0])
    assert ori["rp_abc"][0] == pytest.approx(3.0 * np.std([0.01, 0.03], ddof=1))


@settings(max_examples=40, deadline=None)
@given(
    st.integers(min_value=2, max_value=30),
    st.floats(min_value=1e-3, max_value=0.1),
    st.integers(min_value=0, max_value=2**32 - 1),
)
def test_figures_batch_as_they_do_one_by_one(n: int, scale: float, seed: int) -> None:
    rng = np.random.default_rng(seed)
    x = rng.normal(size=(4, n, 3)) * scale + 5.0
    batch = standard_figures(x, np.full(3, 5.0))
    for k in range(4):
        one = standard_figures(x[k], np.full(3, 5.0))
        dist = np.linalg.norm(x[k] - x[k].mean(0), axis=1)
        assert float(one["rp"]) == pytest.approx(dist.mean() + 3.0 * dist.std(ddof=1))
        assert float(batch["rp"][k]) == pytest.approx(float(one["rp"]))
        assert float(batch["ap"][k]) == pytest.approx(np.linalg.norm(x[k].mean(0) - 5.0))


def test_the_plan_visits_p1_p5_p4_p3_p2_every_cycle(tmp_path) -> None:
    profile = load_profile(create_profile(tmp_path / "cell.toml", "tx90l"))
    plan = plan_iso9283(profile, cycles=3)
    assert plan.iso is not None and plan.iso.cycles == 3
    assert [t.index for t in plan.targets] == list(CYCLE_ORDER) * 3
    assert all(t.pass_name == "after" for t in plan.targets)
    assert plan.nominal_mm.shape == (5, 3)
    assert plan.iso.side_mm > 50.0
    # the same commanded readings at every visit of a pose: one command, repeated
    first = {t.index: t.joints_deg for t in plan.targets[:5]}
    for t in plan.targets:
        assert np.array_equal(t.joints_deg, first[t.index])
    with pytest.raises(ValueError, match="at least 2 cycles"):
        plan_iso9283(profile, cycles=1)
