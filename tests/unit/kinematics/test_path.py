"""Cartesian path → joint path: continuity through a wrist singularity (paper 004, Figs. 4–5),
one arm configuration, and the points where it changes or a joint jumps."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ucal.errors import InputError, UnreachableError
from ucal.kinematics.configuration import ArmConfig, arm_configs
from ucal.kinematics.dh import fk, transform
from ucal.kinematics.ik import ik_all, wrap_deg
from ucal.kinematics.path import MAX_STEP_DEG, max_joint_step_deg, plan_joint_path
from ucal.kinematics.rotations import matrix_to_pose, pose_to_matrix, rotation_angle_deg
from ucal.profile.models import load_model

TOOL = transform([0.0, 0.0, 80.0], np.eye(3))
#: Wrist-singular configuration (θ5 = 0) the arc passes through, joint 4 at 40°.
Q_SINGULAR = np.array([10.0, 20.0, 80.0, 40.0, 0.0, -30.0])


def _axis_rotation(axis: np.ndarray, angle_rad: float) -> np.ndarray:
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle_rad) * k + (1 - np.cos(angle_rad)) * k @ k


def cylinder_arc(
    model,
    q_mid: np.ndarray,
    radius_mm: float = 300.0,
    n: int = 100,
    step_deg: float = 0.3,
    mid_index: int = 33,
) -> np.ndarray:
    """Poses (n, 6) of a cylinder scan: the tool moves on a circle, its beam (+z) always
    towards the centre, its x axis tangential; point ``mid_index`` is FK(q_mid) exactly."""
    t_mid = fk(model, q_mid, TOOL)
    centre = t_mid[:3, 3] + radius_mm * t_mid[:3, 2]
    axis = t_mid[:3, 1]  # cylinder axis through the centre, across the motion
    poses = []
    for k in range(n):
        rot = _axis_rotation(axis, np.radians(step_deg * (k - mid_index)))
        t = np.eye(4)
        t[:3, :3] = rot @ t_mid[:3, :3]
        t[:3, 3] = centre + rot @ (t_mid[:3, 3] - centre)
        poses.append(t)
    poses = np.array(poses)
    # sanity of the construction: beam towards the centre everywhere
    to_centre = centre - poses[:, :3, 3]
    np.testing.assert_allclose(to_centre / radius_mm, poses[:, :3, 2], atol=1e-12)
    return matrix_to_pose(poses)


def test_arc_through_wrist_singularity_has_no_flip() -> None:
    model = load_model("tx90l")
    poses = cylinder_arc(model, Q_SINGULAR)
    path = plan_joint_path(model, poses, TOOL, start_deg=Q_SINGULAR)
    joints = path.joints_deg
    step = path.max_step_deg
    assert joints.shape == (100, 6)
    assert step == pytest.approx(max_joint_step_deg(joints))
    assert step < 5.0
    assert np.max(np.abs(np.diff(joints[:, 3]))) < 1.0
    # θ5 changes sign: the path really crosses the singularity
    assert joints[0, 4] < -1.0 and joints[-1, 4] > 1.0
    # at the singular point itself joint 4 keeps the previous value
    assert joints[33, 4] == pytest.approx(0.0, abs=1e-9)
    assert joints[33, 3] == pytest.approx(joints[32, 3], abs=1e-12)
    t = fk(model, joints, TOOL)
    want = pose_to_matrix(poses)
    assert np.max(np.linalg.norm(t[:, :3, 3] - want[:, :3, 3], axis=-1)) < 1e-9
    assert np.max(rotation_angle_deg(t[:, :3, :3], want[:, :3, :3])) < 1e-9
    assert np.all(model.within_limits(joints))


def test_naive_per_point_atan2_flips_joint_4_on_the_same_arc() -> None:
    """The traditional solution (θ5 ≥ 0 from atan2, same arm branch) jumps by ~180° (Fig. 4)."""
    model = load_model("tx90l")
    poses = cylinder_arc(model, Q_SINGULAR)
    flange = pose_to_matrix(poses) @ np.linalg.inv(TOOL)
    sols, valid = ik_all(model, flange)
    arm = np.argmin(np.max(np.abs(wrap_deg(sols[33, :, :3] - Q_SINGULAR[:3])), -1))
    naive = sols[:, arm - arm % 2]  # the wrist root with θ5 >= 0
    assert valid[:, arm].all()
    assert np.all(naive[:, 4] >= -1e-9)
    jump = np.max(np.abs(wrap_deg(np.diff(naive[:, 3]))))
    assert jump > 170.0
    path = plan_joint_path(model, poses, TOOL, start_deg=Q_SINGULAR)
    step = path.max_step_deg
    assert step < jump / 30


def test_joint_6_unwraps_beyond_180_within_its_range() -> None:
    model = load_model("tx90")
    t6 = np.linspace(0.0, 260.0, 53)
    q = np.tile([0.0, 10.0, 90.0, 0.0, 45.0, 0.0], (len(t6), 1))
    q[:, 5] = t6
    poses = matrix_to_pose(fk(model, q, TOOL))
    path = plan_joint_path(model, poses, TOOL)
    joints = path.joints_deg
    step = path.max_step_deg
    np.testing.assert_allclose(joints, q, atol=1e-7)
    assert step == pytest.approx(260.0 / 52, abs=1e-6)


def test_start_configuration_selects_the_branch_and_offsets_are_taken_out() -> None:
    model = load_model("tx90xl")
    offsets = np.array([1.0, -2.0, 0.5, 3.0, -1.5, 2.0])
    q0 = np.array([30.0, 20.0, 60.0, 10.0, 50.0, -20.0])
    q = q0 + np.outer(np.linspace(0, 1, 20), [5, 5, -10, 20, -10, 30])
    poses = matrix_to_pose(fk(model, q, TOOL, offsets))
    path = plan_joint_path(model, poses, TOOL, offsets, start_deg=q0)
    joints = path.joints_deg
    np.testing.assert_allclose(joints, q, atol=1e-7)
    # start from the back-shoulder branch of the first point: the path stays on that branch
    sols, valid = ik_all(model, pose_to_matrix(poses[0]) @ np.linalg.inv(TOOL), offsets)
    back = sols[4 + np.argmax(valid[4:])]
    path = plan_joint_path(model, poses, TOOL, offsets, start_deg=back)
    joints_b = path.joints_deg
    step_b = path.max_step_deg
    assert np.all(np.abs(wrap_deg(joints_b[:, 0] - q[:, 0])) > 90)
    assert step_b < 10.0


def test_unreachable_point_is_named() -> None:
    model = load_model("tx90")
    poses = matrix_to_pose(fk(model, np.zeros((4, 6)), TOOL))
    poses[2, :3] = [5000.0, 0.0, 0.0]
    with pytest.raises(UnreachableError, match="path point 3"):
        plan_joint_path(model, poses, TOOL)


def test_bad_input_shape() -> None:
    model = load_model("tx90")
    with pytest.raises(InputError):
        plan_joint_path(model, np.zeros((3, 5)))
    with pytest.raises(InputError):
        plan_joint_path(model, np.full((3, 6), np.nan))


#: A TX90L scan whose elbow (J3) runs into its 145° limit: the readings (41, 6) it is made of,
#: in one configuration up to the limit.
SWING = np.tile([30.0, 20.0, 120.0, 0.0, 40.0, 0.0], (41, 1))
SWING[:, 2] = np.linspace(125.0, 150.0, 41)
LEFTY = ArmConfig("lefty", "epositive", "wpositive")


def test_a_path_past_a_joint_limit_records_the_swing_round_the_back() -> None:
    """Beyond J3 = 145° no solution of the configuration is in range: the nearest one left
    is the other shoulder, J1 from 30° to about -134° (the issue's swing round the back)."""
    model = load_model("tx90l")
    poses = matrix_to_pose(fk(model, SWING, TOOL))
    path = plan_joint_path(model, poses, TOOL, start_deg=SWING[0])
    inside = SWING[:, 2] <= 145.0
    np.testing.assert_allclose(path.joints_deg[inside], SWING[inside], atol=1e-7)
    (change,) = path.changes
    assert change.point == int(inside.sum()) + 1 == 34
    assert change.changed == ("shoulder", "elbow", "wrist")
    assert change.before == LEFTY and change.after == ArmConfig("righty", "enegative", "wnegative")
    assert change.before_deg[0] == pytest.approx(30.0) and change.after_deg[0] < -130.0
    assert change.kept is None  # no solution of the configuration inside the ranges
    text = change.describe()
    assert "shoulder from lefty to righty" in text and "round the back" in text
    assert "J1 30.00 to -134.08" in text
    # the path stays in the new configuration after the change
    assert set(path.configs[33:]) == {change.after}
    assert path.configs == arm_configs(model, path.joints_deg)
    assert path.max_step_deg == pytest.approx(max_joint_step_deg(path.joints_deg))


def test_the_wrist_singularity_is_a_change_of_the_wrist() -> None:
    """Paper 004's continuous solution crosses θ5 = 0: J5 changes sign (kept: J4 would flip
    by 180°), recorded at the point after the singular one."""
    model = load_model("tx90l")
    poses = cylinder_arc(model, Q_SINGULAR)
    path = plan_joint_path(model, poses, TOOL, start_deg=Q_SINGULAR)
    assert path.max_step_deg < 5.0
    (change,) = path.changes
    assert change.changed == ("wrist",)
    assert change.before.wrist == "wnegative" and change.after.wrist == "wpositive"
    assert "through the wrist singularity" in change.describe()
    assert path.configs == arm_configs(model, path.joints_deg)


def test_a_step_beyond_the_limit_in_one_configuration_is_a_jump() -> None:
    model = load_model("tx90")
    q = np.tile([0.0, 10.0, 90.0, 0.0, 45.0, 0.0], (6, 1))
    q[:, 0] = np.arange(6) * 2.0
    poses = matrix_to_pose(fk(model, q, TOOL))
    assert plan_joint_path(model, poses, TOOL).changes == ()
    path = plan_joint_path(model, poses, TOOL, limit_deg=1.5)
    np.testing.assert_allclose(path.joints_deg, q, atol=1e-7)  # the same joints
    assert [c.point for c in path.changes] == [2, 3, 4, 5, 6]
    first = path.changes[0]
    assert first.changed == () and first.joint == 1 and first.step_deg == pytest.approx(2.0)
    assert "more than the 1.5 deg" in first.describe()
    with pytest.raises(InputError):
        plan_joint_path(model, poses, TOOL, limit_deg=0.0)


@settings(max_examples=40)
@given(
    seed=st.integers(0, 2**32 - 1),
    name=st.sampled_from(["tx90", "tx90l", "tx90xl"]),
    shoulder=st.sampled_from([1.0, -1.0]),
)
def test_hypothesis_a_walk_in_one_configuration_is_kept(
    seed: int, name: str, shoulder: float
) -> None:
    """Random walks of up to 3° per joint kept inside one configuration and away from its
    boundaries: the path gives the walk back, one configuration, no change."""
    model = load_model(name)
    rng = np.random.default_rng(seed)
    start = np.array([0.0, 30.0, 100.0, 10.0, 50.0, 0.0])
    if shoulder < 0:  # the arm reaching back over its base
        start = np.array([0.0, -40.0, -100.0, 10.0, -50.0, 0.0])
    q = [start]
    while len(q) < 30:
        nxt = q[-1] + rng.uniform(-3.0, 3.0, 6)
        if (
            model.within_limits(nxt)
            and 20.0 < abs(nxt[2]) < 130.0
            and 15.0 < abs(nxt[4]) < 110.0
            and arm_configs(model, nxt) == arm_configs(model, start)
        ):
            q.append(nxt)
    walk = np.array(q)
    poses = matrix_to_pose(fk(model, walk, TOOL))
    path = plan_joint_path(model, poses, TOOL, start_deg=walk[0])
    assert path.changes == ()
    np.testing.assert_allclose(path.joints_deg, walk, atol=1e-6)
    assert set(path.configs) == set(arm_configs(model, walk[:1]))
    assert path.max_step_deg <= MAX_STEP_DEG
