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

The arm bent by gravity. A calibrated arm whose joints give (``ucal.model.load``) stands at
``θ = q + o + s(θ)``, where ``s(θ) = c·(τ(θ) − τ(θ_L))`` is each joint's compliance times its
gravity torque at the posture it stands in less that of the load posture ``q_L`` whose sag the
offsets hold (``[calibration] load_posture_deg``). The readings must then put the *bent* arm
on ``P``: with ``θ* = IK_C(P) + o`` the link angles of (1),

    (1')  q  = θ* − o − s(θ*)

is the fixed point of ``q = θ* − o − s(q + o + s)``, the posture's own torque; as the posture
the arm is to stand in is known, the iteration ends in one step and leaves no error. (The
solvers take the torque at ``q + o``, before the sag: that differs from (1') by ``ρ·s``,
``ρ = |∂τ/∂θ|·c`` ≤ 0.006 at 1e5 N·m/rad: 0.15 µm at the tool where the sag is 0.26 mm.) (2) then
names ``q`` for the nominal arm as before; the controller, which knows no sag, commands ``q``,
and the arm bends onto ``P``. Where nothing weighs, no joint gives or no load posture is
known, ``s = 0`` and (1') is (1).

What this does not correct: the straight line between two targets is interpolated on the
nominal model (the real tool leaves it by the change of the correction ``P' − P`` along the
segment, negligible for the millimetre corrections of a calibration over a scan's spacing),
and whatever the calibrated model itself does not describe (backlash, the sag of a joint the
profile states rigid).
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from ucal.errors import UnreachableError
from ucal.kinematics.configuration import arm_configs
from ucal.kinematics.dh import RobotModel, fk
from ucal.kinematics.path import MAX_STEP_DEG, JointPath, max_joint_step_deg, plan_joint_path
from ucal.kinematics.rotations import matrix_to_pose, pose_to_matrix, rotation_angle_deg

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class ControllerTargets:
    """Filtered targets of a path and what they correct.

    ``targets`` (n, 6): X, Y, Z, RX, RY, RZ (mm, deg) for the nominal arm; ``path``: the
    readings the controller reaches them with (``q`` of the module docstring), their arm
    configurations and where those change; ``correction_mm`` / ``correction_deg`` (n,): how far
    each target is from its asked pose (position, rotation angle); ``sag_deg`` (n, 6): each
    joint's deflection the readings make up for, (1') of the module docstring (None: the arm
    is taken as rigid), and ``deflection_mm`` (n,): how far that moved each target.
    """

    targets: np.ndarray
    path: JointPath
    correction_mm: np.ndarray
    correction_deg: np.ndarray
    sag_deg: np.ndarray | None = None
    deflection_mm: np.ndarray | None = None

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
    sag_deg: Callable[[np.ndarray], np.ndarray] | None = None,
) -> ControllerTargets:
    """Targets (n, 6) for ``nominal`` carrying ``tool_T`` (4, 4, relative to the flange) that
    put the ``calibrated`` robot (joint offsets ``offsets_deg``) on ``poses`` (n, 6:
    X, Y, Z, RX, RY, RZ in mm and deg), equations (1)–(2) of the module docstring.

    ``start_deg`` is the configuration before the first row (default zeros), ``limit_deg`` the
    largest joint step between rows in one configuration (``plan_joint_path``). ``sag_deg``
    gives each link's deflection (deg, (n, 6)) beyond reading + offset at readings whose
    reading + offset is the posture it bends in (``ucal.model.load.Deflection.sag_deg``): the
    readings then make up for it, (1'). Raises ``UnreachableError`` naming the first pose the
    calibrated robot cannot reach in range.
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
    sag = None if sag_deg is None else np.asarray(sag_deg(path.joints_deg), float)
    rigid = path.joints_deg
    if sag is not None:
        path = _bent_path(path, calibrated, nominal, sag)
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
    moved = None
    if sag is not None:
        rigid_T = fk(nominal, rigid, tool_T)
        moved = np.linalg.norm(target_T[:, :3, 3] - rigid_T[:, :3, 3], axis=-1)
        log.debug("the arm's deflection moved the targets by up to %.4f mm", float(np.max(moved)))
    return ControllerTargets(matrix_to_pose(target_T), path, shift, turn, sag, moved)


def _bent_path(
    path: JointPath, calibrated: RobotModel, nominal: RobotModel, sag_deg: np.ndarray
) -> JointPath:
    """``path`` with each row's readings less its links' deflection, (1'), named again with
    ``nominal``'s configurations; ``UnreachableError`` naming the first row the deflection
    takes outside the joint ranges."""
    joints = path.joints_deg - sag_deg
    inside = calibrated.within_limits(joints)
    if not np.all(inside):
        i = int(np.argmin(inside))
        j = int(
            np.argmax(
                (joints[i] < calibrated.joint_min_deg) | (joints[i] > calibrated.joint_max_deg)
            )
        )
        raise UnreachableError(
            f"path point {i + 1}: J{j + 1} at {joints[i, j]:.4f} deg once the arm's sag under "
            f"gravity ({sag_deg[i, j]:+.4f} deg) is made up for is outside its range "
            f"[{calibrated.joint_min_deg[j]:g}, {calibrated.joint_max_deg[j]:g}] deg"
        )
    return replace(
        path,
        joints_deg=joints,
        configs=arm_configs(nominal, joints),
        max_step_deg=max_joint_step_deg(joints),
    )
