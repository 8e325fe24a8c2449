"""Filtered targets: reached by the controller's nominal model, they put the calibrated robot on
the poses asked for (``ucal.kinematics.filtering``)."""

from __future__ import annotations

import numpy as np
import pytest

from ucal.errors import UnreachableError
from ucal.kinematics.dh import RobotModel, fk, transform
from ucal.kinematics.filtering import controller_targets
from ucal.kinematics.ik import ik
from ucal.kinematics.path import plan_joint_path
from ucal.kinematics.rotations import (
    matrix_to_pose,
    pose_to_matrix,
    rotation_angle_deg,
    rpy_to_matrix,
)
from ucal.profile.models import controller_model, load_model

TOOL = transform([3.0, -2.0, 85.0], rpy_to_matrix([1.0, -4.0, 30.0]))
#: The issue's bound on where the calibrated robot lands: 0.01 mm (and 0.001°).
LANDING_MM = 0.01
LANDING_DEG = 0.001


def identified(nominal: RobotModel, rng: np.random.Generator) -> RobotModel:
    """A table as `calibrate --level full` identifies one: lengths off by tenths of a mm,
    twists by hundredths of a degree, a Hayati β₂."""
    dh = nominal.dh.copy()
    dh[:, 1:3] += rng.normal(0.0, 0.3, (6, 2)) * (nominal.dh[:, 1:3] != 0.0)
    dh[:, 3] += rng.normal(0.0, 0.02, 6)
    beta = np.zeros(6)
    beta[1] = 0.03
    return nominal.with_dh(dh, beta, "identified")


def random_walk(model: RobotModel, rng: np.random.Generator, n: int) -> np.ndarray:
    """Joint readings (n, 6) of a path: steps of up to 3° per joint, inside the ranges, the
    wrist kept 15° or more from its singularity."""
    q = [np.array([10.0, 30.0, 100.0, 20.0, 40.0, 10.0])]
    while len(q) < n:
        nxt = q[-1] + rng.uniform(-3.0, 3.0, 6)
        if model.within_limits(nxt) and 15.0 < nxt[4] < 120.0:
            q.append(nxt)
    return np.array(q)


def landing(
    calibrated: RobotModel,
    offsets: np.ndarray,
    nominal: RobotModel,
    targets: np.ndarray,
    asked: np.ndarray,
    start: np.ndarray,
) -> tuple[float, float]:
    """Largest position (mm) and rotation (deg) error of the calibrated robot at the readings
    the nominal model's IK gives for ``targets``, solved as a controller does: continuously
    from ``start``, no offsets."""
    path = plan_joint_path(nominal, targets, TOOL, start_deg=start)
    readings = path.joints_deg
    reached = fk(calibrated, readings, TOOL, offsets)
    want = pose_to_matrix(asked)
    mm = np.linalg.norm(reached[:, :3, 3] - want[:, :3, 3], axis=-1)
    deg = rotation_angle_deg(want[:, :3, :3], reached[:, :3, :3])
    return float(np.max(mm)), float(np.max(deg))


@pytest.mark.parametrize("name", ["tx90", "tx90l", "tx90xl"])
def test_a_filtered_path_lands_the_calibrated_robot(name: str) -> None:
    rng = np.random.default_rng(24)
    shipped = load_model(name)
    nominal = controller_model(shipped)
    calibrated = identified(shipped, rng)
    offsets = rng.uniform(-0.5, 0.5, 6)
    q = random_walk(calibrated, rng, 60)
    asked = matrix_to_pose(fk(calibrated, q, TOOL, offsets))

    out = controller_targets(calibrated, nominal, asked, TOOL, offsets, start_deg=q[0])

    np.testing.assert_allclose(out.joints_deg, q, atol=1e-7)
    # the targets really differ: half a degree of offset is millimetres at the tool
    assert np.max(out.correction_mm) > 1.0
    mm, deg = landing(calibrated, offsets, nominal, out.targets, asked, q[0])
    assert mm < LANDING_MM and deg < LANDING_DEG, (mm, deg)
    # without the filter the nominal model misses by the calibration
    mm_raw, _ = landing(calibrated, offsets, nominal, asked, asked, q[0])
    assert mm_raw > 1.0


def test_random_postures_each_land() -> None:
    """Random reachable postures over the workspace, each its own one-point path started
    from the posture (any branch: shoulder, elbow and wrist both ways)."""
    rng = np.random.default_rng(7)
    shipped = load_model("tx90l")
    nominal = controller_model(shipped)
    calibrated = identified(shipped, rng)
    offsets = rng.uniform(-0.5, 0.5, 6)
    worst = (0.0, 0.0)
    count = 0
    while count < 40:
        q = rng.uniform(calibrated.joint_min_deg, calibrated.joint_max_deg)
        if abs(np.sin(np.radians(q[4] + offsets[4]))) < np.sin(np.radians(10.0)):
            continue
        asked = matrix_to_pose(fk(calibrated, q, TOOL, offsets))[None]
        out = controller_targets(calibrated, nominal, asked, TOOL, offsets, start_deg=q)
        readings = ik(nominal, pose_to_matrix(out.targets[0]), TOOL, near_deg=q)
        reached = fk(calibrated, readings, TOOL, offsets)
        want = pose_to_matrix(asked[0])
        mm = float(np.linalg.norm(reached[:3, 3] - want[:3, 3]))
        deg = float(rotation_angle_deg(want[:3, :3], reached[:3, :3]))
        worst = (max(worst[0], mm), max(worst[1], deg))
        count += 1
    assert worst[0] < LANDING_MM and worst[1] < LANDING_DEG, worst


def test_an_uncalibrated_robot_gets_its_own_poses() -> None:
    nominal = load_model("tx90l")
    q = random_walk(nominal, np.random.default_rng(3), 10)
    asked = matrix_to_pose(fk(nominal, q, TOOL))
    out = controller_targets(nominal, controller_model(nominal), asked, TOOL, start_deg=q[0])
    assert np.max(out.correction_mm) < 1e-8 and np.max(out.correction_deg) < 1e-8


def test_unreachable_pose_names_the_point() -> None:
    nominal = load_model("tx90l")
    asked = np.array([[600.0, 0.0, 300.0, 180.0, 0.0, 0.0], [4000.0, 0.0, 0.0, 0.0, 0.0, 0.0]])
    with pytest.raises(UnreachableError, match="path point 2"):
        controller_targets(nominal, nominal, asked, TOOL)
