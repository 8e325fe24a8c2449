"""Targets for the controller's nominal arm that land the calibrated robot on the poses asked
for ("filtering", as RoboDK applies a calibration to a robot program).

A Staubli controller keeps its joint zeros in its arm configuration and moves with its own,
nominal model (the shipped DH table, no offsets); ucal does not edit either. What it can
change is the targets a program sends. Notation: ``C`` the calibrated model (``[calibration]
dh`` if present else ``[robot] dh``, with the joint offsets ``o``: actual = reading + o),
``N`` the controller's model (the shipped table of the same robot, zero offsets), ``T`` the
tool frame relative to the flange as ``ucal export val3`` hands it to the controller (the
profile's ``[tool]``; the model's joint-6 frame is the controller's flange frame),
``FK_M(q)`` the flange of model ``M`` at joint readings ``q``.

For each asked tool pose ``P`` (base frame, mm):

    (1)  q  = IK_C(P):   FK_C(q + o) · T = P
    (2)  P' = FK_N(q) · T

(1) is the calibrated model's inverse kinematics (``ucal.kinematics.path``: the solution
nearest the previous row's in its arm configuration, so the path stays on one branch and joints
4 and 6 take their ±360° equivalents continuously; the configurations are named with ``N``, as
the controller names them from ``q``); (2) the nominal model's forward kinematics of the same
readings. A VAL3 ``movel``/``movej`` to ``P'`` with tool ``T`` is solved by the controller's
own inverse kinematics, ``IK_N(P')``; in the configuration the arm is in (a ``movel`` keeps
it) that is ``q``, because ``FK_N(q) · T = P'`` and the closed form of ``N`` is exact. The
controller thus commands the readings ``q``; the real joints turn to ``q + o`` and the real
arm, which ``C`` models, puts the tool on ``FK_C(q + o) · T = P``.

What this does not correct: the straight line between two targets is interpolated on the
nominal model (the real tool leaves it by the change of the correction ``P' − P`` along the
segment, negligible for the millimetre corrections of a calibration over a scan's spacing),
and whatever the calibrated model itself does not describe (backlash, compliance).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from ucal.kinematics.dh import RobotModel, fk
from ucal.kinematics.path import MAX_STEP_DEG, JointPath, plan_joint_path
from ucal.kinematics.rotations import matrix_to_pose, pose_to_matrix, rotation_angle_deg

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class ControllerTargets:
    """Filtered targets of a path and what they correct.

    ``targets`` (n, 6): X, Y, Z, RX, RY, RZ (mm, deg) for the nominal arm; ``path``: the
    readings the controller reaches them with (``q`` of the module docstring), their arm
    configurations and where those change; ``correction_mm`` / ``correction_deg`` (n,): how far
    each target is from its asked pose (position, rotation angle).
    """

    targets: np.ndarray
    path: JointPath
    correction_mm: np.ndarray
    correction_deg: np.ndarray

    @property
    def joints_deg(self) -> np.ndarray:
        """The readings (n, 6) the controller reaches the targets with (deg)."""
        return self.path.joints_deg

    @property
    def max_step_deg(self) -> float:
        """The largest change of any joint between consecutive rows (deg)."""
        return self.path.max_step_deg


def controller_targets(
    calibrated: RobotModel,
    nominal: RobotModel,
    poses: np.ndarray,
    tool_T: np.ndarray,
    offsets_deg: np.ndarray | None = None,
    start_deg: np.ndarray | None = None,
    limit_deg: float = MAX_STEP_DEG,
) -> ControllerTargets:
    """Targets (n, 6) for ``nominal`` carrying ``tool_T`` (4, 4, relative to the flange) that
    put the ``calibrated`` robot (joint offsets ``offsets_deg``) on ``poses`` (n, 6:
    X, Y, Z, RX, RY, RZ in mm and deg), equations (1)–(2) of the module docstring.

    ``start_deg`` is the configuration before the first row (default zeros), ``limit_deg`` the
    largest joint step between rows in one configuration (``plan_joint_path``). Raises
    ``UnreachableError`` naming the first pose the calibrated robot cannot reach in range.
    """
    path = plan_joint_path(
        calibrated,
        poses,
        tool_T,
        offsets_deg,
        start_deg=start_deg,
        limit_deg=limit_deg,
        config_model=nominal,
    )
    joints = path.joints_deg
    target_T = fk(nominal, joints, tool_T)  # (2): zero offsets, the controller's own model
    asked_T = pose_to_matrix(np.asarray(poses, dtype=float))
    shift = np.linalg.norm(target_T[:, :3, 3] - asked_T[:, :3, 3], axis=-1)
    turn = rotation_angle_deg(asked_T[:, :3, :3], target_T[:, :3, :3])
    log.debug(
        "%d controller targets: corrections up to %.4f mm / %.4f deg",
        len(joints),
        float(np.max(shift)),
        float(np.max(turn)),
    )
    return ControllerTargets(matrix_to_pose(target_T), path, shift, turn)
