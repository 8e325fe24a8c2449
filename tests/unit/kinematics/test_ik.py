"""Closed-form IK (arm–wrist separation, paper 004): accuracy, completeness, selection."""

from __future__ import annotations

import re

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from ucal.cell import PAPER_CALIBRATION_POSE_DEG
from ucal.errors import EXIT_SAFETY, InputError, UnreachableError
from ucal.kinematics.dh import RobotModel, fk, transform, wrist_centre
from ucal.kinematics.ik import (
    DEFAULT_WEIGHTS,
    configuration_name,
    ik,
    ik_all,
    ik_branches,
    ik_many,
    ik_solutions,
    wrap_deg,
)
from ucal.kinematics.rotations import rotation_angle_deg, rpy_to_matrix
from ucal.profile.models import KNOWN_MODELS, load_model

TOOL = transform([3.0, -4.0, 80.0], rpy_to_matrix([5.0, -10.0, 30.0]))


def _away_from_singularities(
    model: RobotModel, q: np.ndarray, offsets: np.ndarray | None = None
) -> np.ndarray:
    """Mask of configurations (n, 6) at least ~1° / 1 mm from the wrist, elbow, shoulder
    singularities (where the generating configuration is only recoverable to rounding)."""
    kin = q + model.theta_offset_deg + (0 if offsets is None else offsets)
    w = wrist_centre(model, q, offsets)
    lateral = abs(model.d_mm[1] + model.d_mm[2])
    return (
        (np.abs(np.sin(np.radians(kin[:, 4]))) > 0.02)
        & (np.abs(np.sin(np.radians(q[:, 2]))) > 0.02)  # elbow straight at θ3 = 0 here
        & (np.hypot(w[:, 0], w[:, 1]) > lateral + 1.0)
    )


def _max_angle_diff(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.max(np.abs(wrap_deg(a - b)), -1)


def _check_solutions(model, target, sols, valid, tool=None, offsets=None):
    """Every valid solution reproduces the target: max position (mm) and angle (deg) errors."""
    t = fk(model, np.where(valid[..., None], sols, 0.0), tool, offsets)
    pos = np.linalg.norm(t[..., :3, 3] - target[..., None, :3, 3], axis=-1)
    want = np.broadcast_to(target[..., None, :3, :3], t.shape[:-2] + (3, 3))
    ang = rotation_angle_deg(t[..., :3, :3], want)
    return np.max(np.where(valid, pos, 0.0)), np.max(np.where(valid, ang, 0.0))


@pytest.mark.parametrize("name", KNOWN_MODELS)
def test_ten_thousand_random_poses_round_trip(name: str) -> None:
    model = load_model(name)
    rng = np.random.default_rng(2024)
    q = rng.uniform(model.joint_min_deg, model.joint_max_deg, (14000, 6))
    q = q[_away_from_singularities(model, q)][:10000]
    assert len(q) == 10000
    target = fk(model, q)
    sols, valid = ik_all(model, target)
    assert sols.shape == (10000, 8, 6) and valid.shape == (10000, 8)
    assert np.all(np.isnan(sols[~valid]))
    assert np.all((sols[valid] > -180.0) & (sols[valid] <= 180.0))
    pos, ang = _check_solutions(model, target, sols, valid)
    assert pos < 1e-9 and ang < 1e-9
    # the generating configuration is one of the eight (joint angles modulo 360)
    diff = np.nanmin(np.where(valid, _max_angle_diff(sols, q[:, None, :]), np.inf), -1)
    assert np.max(diff) < 1e-7


def test_round_trip_with_tool_and_offsets() -> None:
    model = load_model("tx90l")
    rng = np.random.default_rng(7)
    offsets = rng.uniform(-5, 5, 6)
    q = rng.uniform(model.joint_min_deg, model.joint_max_deg, (6000, 6))
    q = q[_away_from_singularities(model, q, offsets)]
    target = fk(model, q, TOOL, offsets)
    sols, ok, cost = ik_solutions(model, target, TOOL, offsets, near_deg=q)
    pos, ang = _check_solutions(model, target, sols, ok, TOOL, offsets)
    assert pos < 1e-9 and ang < 1e-9
    # nearest to the generating readings is the generating readings, at zero distance
    assert np.all(ok[:, 0])
    np.testing.assert_allclose(sols[:, 0], q, atol=1e-7)
    np.testing.assert_allclose(cost[:, 0], 0.0, atol=1e-5)
    assert np.all(np.diff(np.where(np.isfinite(cost), cost, 1e300), axis=-1) >= 0)


@settings(max_examples=300, deadline=None)
@given(name=st.sampled_from(KNOWN_MODELS), u=st.lists(st.floats(0.0, 1.0), min_size=6, max_size=6))
def test_hypothesis_every_solution_exact_and_generator_found(name: str, u: list[float]) -> None:
    model = load_model(name)
    q = model.joint_min_deg + np.array(u) * (model.joint_max_deg - model.joint_min_deg)
    assume(_away_from_singularities(model, q[None])[0])
    target = fk(model, q)
    sols, valid = ik_all(model, target)
    pos, ang = _check_solutions(model, target, sols, valid)
    assert pos < 1e-9 and ang < 1e-9
    assert np.min(_max_angle_diff(sols[valid], q)) < 1e-7
    got = ik(model, target, near_deg=q)
    np.testing.assert_allclose(got, q, atol=1e-7)


def test_eight_distinct_solutions_and_branch_layout() -> None:
    model = load_model("tx90xl")
    q = np.array([20.0, 10.0, 60.0, 30.0, 45.0, -20.0])
    sols, valid = ik_all(model, fk(model, q))
    assert valid.all()
    # index 4·shoulder + 2·elbow + wrist: the wrist pair shares the arm, flips 4/5/6
    for k in range(0, 8, 2):
        np.testing.assert_allclose(sols[k, :3], sols[k + 1, :3], atol=1e-12)
        np.testing.assert_allclose(sols[k + 1, 4], -sols[k, 4], atol=1e-9)
        np.testing.assert_allclose(
            wrap_deg(sols[k + 1, [3, 5]] - sols[k, [3, 5]] - 180.0), 0, atol=1e-9
        )
    # shoulder front/back differ in joint 1; elbow roots differ in joint 3
    assert abs(wrap_deg(sols[0, 0] - sols[4, 0])) > 90.0
    assert abs(sols[0, 2] - sols[2, 2]) > 10.0
    assert len({tuple(np.round(s, 6)) for s in sols}) == 8


def test_unreachable_far_pose() -> None:
    model = load_model("tx90")
    target = transform([3000.0, 0.0, 0.0], np.eye(3))
    _, valid = ik_all(model, target)
    assert not valid.any()
    with pytest.raises(UnreachableError, match="outside the workspace") as e:
        ik(model, target)
    assert e.value.exit_code == EXIT_SAFETY
    joints, ok = ik_many(model, np.stack([target, fk(model, np.zeros(6))]))
    assert ok.tolist() == [False, True]
    assert np.all(np.isnan(joints[0]))


def test_unreachable_inside_workspace_but_outside_joint_ranges() -> None:
    base = load_model("tx90l")
    narrow = RobotModel(
        "narrow", base.dh, [0, -130, -145, -270, -115, -270], [10, 147.5, 145, 270, 140, 270]
    )
    target = fk(base, np.array([90.0, 10.0, 60.0, 0.0, 30.0, 0.0]))
    with pytest.raises(UnreachableError, match="outside the joint ranges"):
        ik(narrow, target)


def test_branches_offer_what_ik_offers_and_say_why_not_the_others() -> None:
    """All eight, each once: the in-range ones as ``ik(all_solutions=True)`` returns them (same
    order), the others with the joint out of range and by how much."""
    model = load_model("tx90l")
    offsets = np.array([0.4, -0.3, 0.2, 0.5, -0.25, 0.1])
    near = np.array([20.0, 10.0, 90.0, 0.0, 60.0, 0.0])
    target = fk(model, np.array([22.0, 12.0, 99.0, 0.0, 67.0, -158.0]), TOOL, offsets)
    branches = ik_branches(model, target, TOOL, offsets, near_deg=near)
    assert sorted(b.index for b in branches) == list(range(8))
    offered = [b for b in branches if b.reason is None]
    expected = ik(model, target, TOOL, offsets, near_deg=near, all_solutions=True)
    np.testing.assert_array_equal(np.array([b.joints_deg for b in offered]), expected)
    rejected = [b for b in branches if b.reason is not None]
    assert len(offered) == 4 and len(rejected) == 4
    raw, _ = ik_all(model, target @ np.linalg.inv(TOOL), offsets)
    for b in rejected:
        assert b.configuration == configuration_name(b.index) and b.cost == np.inf
        # here only J5 leaves its range: the message gives the reading and the excess
        j5 = raw[b.index, 4]
        limit = model.joint_max_deg[4] if j5 > 0 else model.joint_min_deg[4]
        side = "above its maximum" if j5 > 0 else "below its minimum"
        assert b.reason == (
            f"out of range: J5 at {j5:.2f} deg is {abs(j5 - limit):.2f} deg {side} {limit:g} deg"
        )
    # the names follow the sign of J3 (elbow) and J5 (wrist) on the shipped tables
    for b in offered:
        assert ("elbow positive" in b.configuration) == (b.joints_deg[2] > 0)
        assert ("wrist positive" in b.configuration) == (b.joints_deg[4] > 0)


def test_branches_that_do_not_reach_the_pose_say_which_part_of_the_arm_cannot() -> None:
    model = load_model("tx90l")  # upper arm 500, forearm 550 mm: stretched 1050 mm
    # arm stretched forward: the shoulder-back branches would need 100 mm (2·a1) more
    branches = ik_branches(model, fk(model, np.array([0.0, 60.0, 5.0, 0.0, 30.0, 0.0])))
    back = [b for b in branches if b.index >= 4]
    assert all(np.isnan(b.joints_deg).all() for b in back)
    assert all(
        re.fullmatch(
            r"no such solution: the wrist centre is 1\d{3}\.\d mm from axis 2, beyond the "
            r"stretched arm's 1050\.0 mm",
            b.reason or "",
        )
        for b in back
    )
    assert all(b.reason is None for b in branches if b.index < 4)
    # the wrist centre 10 mm from axis 1, inside the shoulder's 50 mm lateral offset
    flange = transform([10.0, 0.0, 600.0], np.eye(3))  # wrist centre 100 mm below
    branches = ik_branches(model, flange)
    assert {b.reason for b in branches} == {
        "no such solution: the wrist centre is 10.0 mm from axis 1, inside the shoulder's "
        "lateral offset 50 mm"
    }
    with pytest.raises(UnreachableError):
        ik(model, flange)


def test_joints_4_and_6_use_their_360_equivalents_nearest_reference() -> None:
    model = load_model("tx90l")
    q = np.array([10.0, 20.0, 80.0, 250.0, 35.0, -230.0])
    target = fk(model, q)
    np.testing.assert_allclose(
        ik(model, target, near_deg=[10, 20, 80, 240, 35, -220]), q, atol=1e-7
    )
    got = ik(model, target, near_deg=[10, 20, 80, -100, 35, 100])
    np.testing.assert_allclose(got, [10, 20, 80, -110, 35, 130], atol=1e-7)
    for s in ik(model, target, all_solutions=True):
        assert model.within_limits(s)


def test_wrist_singularity_keeps_joint_4_at_reference() -> None:
    model = load_model("tx90xl")
    q = np.array([15.0, 25.0, 70.0, 40.0, 0.0, -30.0])
    target = fk(model, q)
    for ref4 in (-120.0, 0.0, 33.0, 200.0):
        got = ik(model, target, near_deg=[15, 25, 70, ref4, 0, 0])
        assert got[3] == pytest.approx(ref4, abs=1e-9)
        assert got[4] == pytest.approx(0.0, abs=1e-6)
        # only θ4 + θ6 is determined: θ6 takes the rest (modulo 360)
        assert wrap_deg(got[3] + got[5] - 10.0) == pytest.approx(0.0, abs=1e-6)
        t = fk(model, got)
        assert np.linalg.norm(t[:3, 3] - target[:3, 3]) < 1e-9
        assert rotation_angle_deg(t[:3, :3], target[:3, :3]) < 1e-9


def test_selection_uses_weighted_shortest_distance() -> None:
    model = load_model("tx90l")
    target = fk(model, PAPER_CALIBRATION_POSE_DEG)
    near = np.array([0.0, 0.0, 90.0, 0.0, 0.0, 0.0])
    sols = ik(model, target, near_deg=near, all_solutions=True)
    cost = np.sum(DEFAULT_WEIGHTS * np.abs(sols - near), -1)
    assert np.all(np.diff(cost) >= 0)
    np.testing.assert_allclose(ik(model, target, near_deg=near), sols[0])
    np.testing.assert_allclose(
        ik(model, target, near_deg=PAPER_CALIBRATION_POSE_DEG),
        PAPER_CALIBRATION_POSE_DEG,
        atol=1e-9,
    )
    # weights decide: all weight on joint 6 picks the solution with the smallest |Δθ6|
    w6 = np.array([0, 0, 0, 0, 0, 1.0])
    got = ik(model, target, near_deg=near, weights=w6)
    assert abs(got[5] - near[5]) == pytest.approx(np.min(np.abs(sols[:, 5] - near[5])))
    with pytest.raises(InputError):
        ik(model, target, weights=[1, 2, 3])


def test_ik_many_matches_ik() -> None:
    model = load_model("tx90")
    rng = np.random.default_rng(11)
    q = rng.uniform(model.joint_min_deg, model.joint_max_deg, (50, 6))
    q = q[_away_from_singularities(model, q)]
    near = q + rng.normal(0, 2, q.shape)
    joints, ok = ik_many(model, fk(model, q, TOOL), TOOL, near_deg=near)
    assert ok.all()
    for i in range(len(q)):
        np.testing.assert_allclose(
            joints[i], ik(model, fk(model, q[i], TOOL), TOOL, near_deg=near[i]), atol=1e-9
        )


def test_rejects_dh_table_without_the_tx90_structure() -> None:
    base = load_model("tx90")
    dh = base.dh.copy()
    dh[4, 1] = 20.0  # d5 ≠ 0: the wrist is no longer spherical
    with pytest.raises(InputError, match="spherical"):
        ik_all(base.with_dh(dh), fk(base, np.zeros(6)))
    dh = base.dh.copy()
    dh[1, 3] = 90.0
    with pytest.raises(InputError, match="alpha_2"):
        ik_all(base.with_dh(dh), fk(base, np.zeros(6)))


def test_other_table_of_the_same_structure() -> None:
    """Lengths are read from the table: a made-up arm with d1, a3, d3, a6 and flipped signs."""
    dh = np.array(
        [
            [10.0, 300.0, 80.0, 90.0],
            [-90.0, 30.0, 400.0, 0.0],
            [90.0, 20.0, 35.0, -90.0],
            [0.0, 420.0, 0.0, 90.0],
            [0.0, 0.0, 0.0, -90.0],
            [5.0, 90.0, 12.0, 20.0],
        ]
    )
    model = RobotModel(
        "odd", dh, [-180, -130, -145, -270, -115, -270], [180, 147.5, 145, 270, 140, 270]
    )
    rng = np.random.default_rng(5)
    q = rng.uniform(model.joint_min_deg, model.joint_max_deg, (3000, 6))
    kin = q + model.theta_offset_deg
    q = q[(np.abs(np.sin(np.radians(kin[:, 4]))) > 0.02)]
    target = fk(model, q)
    sols, valid = ik_all(model, target)
    pos, ang = _check_solutions(model, target, sols, valid)
    assert pos < 1e-9 and ang < 1e-9
    diff = np.nanmin(np.where(valid, _max_angle_diff(sols, q[:, None, :]), np.inf), -1)
    assert np.max(diff) < 1e-7
