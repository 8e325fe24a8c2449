"""Cartesian tool path → continuous joint path in one arm configuration (paper 004 §3–4).

Each point's eight closed-form solutions (``ucal.kinematics.ik``) are computed in one
vectorised call; the path is then walked point by point. Each point takes, of its in-range
solutions in the previous point's arm configuration (the VAL3 ``config``,
``ucal.kinematics.configuration``), the one nearest the previous point by paper 004's
weighted shortest distance (eq. 16 of ``ik``), as long as no joint steps more than a limit
(``MAX_STEP_DEG``) into it. Where none does (the configuration's solution has left the joint
ranges, or keeping it would flip the wrist), the point takes the nearest in-range solution
of any configuration and the path records a ``PathChange`` there: the configuration
changes, or a joint jumps. A controller cannot follow such a row in a straight line (a VAL3
``movel`` keeps its configuration) and a joint move to it swings the arm: ``ucal path``
refuses the path unless asked for it.

Because both wrist roots (θ5 and −θ5) are candidates and joints 4 and 6 may use their ±360°
equivalents, a path through a wrist singularity keeps θ4 continuous (θ5 changes sign, a
change of the wrist's configuration) instead of the 180° jump of a per-point atan2 solution
(paper 004, Figs. 4–5). At the singular point itself θ4 keeps the previous value and θ6 takes
the rest.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from ucal.errors import InputError, UnreachableError
from ucal.kinematics.configuration import ArmConfig, configuration_codes
from ucal.kinematics.dh import N_JOINTS, RobotModel
from ucal.kinematics.ik import (
    SINGULAR_EPS,
    flange_from_tool,
    ik_all,
    select_in_range,
    weighted_distance,
)
from ucal.kinematics.rotations import pose_to_matrix

log = logging.getLogger(__name__)


def max_joint_step_deg(joints_deg: np.ndarray) -> float:
    """Largest change of any joint between consecutive rows of (n, 6) readings (deg)."""
    j = np.asarray(joints_deg, dtype=float)
    if len(j) < 2:
        return 0.0
    return float(np.max(np.abs(np.diff(j, axis=0))))


#: Largest change of any joint (deg) between consecutive points that a path takes without a
#: ``PathChange``: a scan's points are millimetres apart, so a larger step is a swing (the arm
#: round the back, a wrist flip) that the controller would make between two measurements.
MAX_STEP_DEG = 30.0

#: The joint whose reading decides each part of the configuration (0-based), and what a change
#: of that part is when the joint jumps or moves within the step limit, for the message.
_PART_JOINT = {"shoulder": 0, "elbow": 2, "wrist": 4}
_SWING = {
    "shoulder": "the arm swings round the back",
    "elbow": "the elbow folds over",
    "wrist": "the wrist flips",
}
_ACROSS = {
    "shoulder": "the wrist centre crosses the plane of axis 1, a shoulder singularity",
    "elbow": "through the stretched elbow, a singularity",
    "wrist": "through the wrist singularity",
}


@dataclass(frozen=True)
class PathChange:
    """A point the path does not reach from the one before in that point's arm configuration
    within the step limit: the configuration changes there, or a joint jumps.

    ``point`` is the 1-based index of the pose moved into; ``before_deg``/``after_deg`` (6,)
    the readings of the two points; ``kept`` the joint (1-based) and step (deg) the previous
    configuration's nearest in-range solution would need, None if it has none in range.
    """

    point: int
    before: ArmConfig
    after: ArmConfig
    before_deg: np.ndarray
    after_deg: np.ndarray
    kept: tuple[int, float] | None
    limit_deg: float

    @property
    def changed(self) -> tuple[str, ...]:
        """The parts of the configuration that change (empty: a jump in one configuration)."""
        return self.before.changed(self.after)

    @property
    def joint(self) -> int:
        """The joint (1-based) that moves most into the point."""
        return int(np.argmax(np.abs(self.after_deg - self.before_deg))) + 1

    @property
    def step_deg(self) -> float:
        """That joint's change (deg, signed)."""
        j = self.joint - 1
        return float(self.after_deg[j] - self.before_deg[j])

    def describe(self) -> str:
        """One sentence: what changes, by how much, and why the path could not keep it."""
        j = self.joint
        step = (
            f"J{j} by {self.step_deg:+.2f} deg "
            f"({self.before_deg[j - 1]:.2f} to {self.after_deg[j - 1]:.2f})"
        )
        if not self.changed:
            return (
                f"{step}, more than the {self.limit_deg:g} deg a point may step, in the "
                f"configuration {self.before}: no solution inside the joint ranges is nearer"
            )
        parts = []
        for part in self.changed:
            k = _PART_JOINT[part]
            jumps = abs(self.after_deg[k] - self.before_deg[k]) > self.limit_deg
            how = _SWING[part] if jumps else _ACROSS[part]
            parts.append(
                f"the {part} from {getattr(self.before, part)} to {getattr(self.after, part)} "
                f"(J{k + 1} {self.before_deg[k]:.2f} to {self.after_deg[k]:.2f} deg: {how})"
            )
        if self.kept is None:
            why = f"no solution keeps {self.before} inside the joint ranges"
        else:
            why = (
                f"keeping {self.before} would turn J{self.kept[0]} by {self.kept[1]:+.2f} deg, "
                f"more than the {self.limit_deg:g} deg a point may step"
            )
        return f"the configuration changes: {', '.join(parts)}; largest step {step}; {why}"

    def to_json(self) -> dict[str, object]:
        return {
            "point": self.point,
            "changed": list(self.changed),
            "from": self.before.to_json(),
            "to": self.after.to_json(),
            "joint": self.joint,
            "step_deg": self.step_deg,
            "joints_before_deg": self.before_deg,
            "joints_after_deg": self.after_deg,
            "kept_joint": None if self.kept is None else self.kept[0],
            "kept_step_deg": None if self.kept is None else self.kept[1],
        }


@dataclass(frozen=True)
class JointPath:
    """Joint readings of a tool path and their arm configurations.

    ``joints_deg`` (n, 6) readings (deg); ``configs`` the VAL3 configuration of each row;
    ``changes`` the points where the configuration changes or a joint steps more than
    ``limit_deg`` (empty: one configuration, every step within the limit); ``max_step_deg``
    the largest change of any joint between consecutive points.
    """

    joints_deg: np.ndarray
    configs: tuple[ArmConfig, ...]
    changes: tuple[PathChange, ...]
    max_step_deg: float
    limit_deg: float


def plan_joint_path(
    model: RobotModel,
    poses: np.ndarray,
    tool_T: np.ndarray | None = None,
    offsets_deg: np.ndarray | None = None,
    start_deg: np.ndarray | None = None,
    weights: np.ndarray | None = None,
    singular_eps: float = SINGULAR_EPS,
    limit_deg: float = MAX_STEP_DEG,
    config_model: RobotModel | None = None,
) -> JointPath:
    """Joint readings for a tool path of poses (n, 6) ``X, Y, Z, RX, RY, RZ`` (mm, deg), kept in
    one arm configuration where the joint ranges allow (module docstring).

    ``tool_T`` is the tool frame relative to the flange (4, 4), ``offsets_deg`` the joint
    zero offsets (taken out of the readings), ``start_deg`` the readings the robot is at before
    the first point (that point takes the solution nearest them, in any configuration; default
    zeros), ``weights`` the six weights of the shortest-distance rule (default (6, 5, 4, 3, 2,
    1)), ``limit_deg`` the largest joint step (deg) between points in one configuration, and
    ``config_model`` the DH table the configurations are named with (the controller's;
    default ``model``).

    Raises ``UnreachableError`` naming the first point (1-based) with no in-range solution;
    configuration changes and jumps are returned (``JointPath.changes``), not raised.
    """
    poses = np.asarray(poses, dtype=float)
    if poses.ndim != 2 or poses.shape[1] != 6:
        raise InputError(f"path poses must be an (n, 6) array X,Y,Z,RX,RY,RZ, got {poses.shape}")
    if not np.all(np.isfinite(poses)):
        raise InputError("path poses must be finite numbers")
    if not limit_deg > 0.0:
        raise InputError(
            f"the joint step limit must be a positive number of degrees, got {limit_deg}"
        )
    names = model if config_model is None else config_model
    n = len(poses)
    flange = flange_from_tool(pose_to_matrix(poses), tool_T)
    sols, real = ik_all(model, flange, offsets_deg, singular_eps=singular_eps)
    codes = configuration_codes(names, sols)  # ±360° equivalents keep their configuration

    # kinematic θ5 of every solution, to spot the points that need the singular rule
    th5_off = model.theta_offset_deg[4] + (0.0 if offsets_deg is None else offsets_deg[4])
    sin5 = np.abs(np.sin(np.radians(sols[..., 4] + th5_off)))
    singular = np.any(real & (sin5 < singular_eps), -1)

    prev = np.zeros(N_JOINTS) if start_deg is None else np.asarray(start_deg, dtype=float)
    prev_code = -1  # before the first point: any configuration
    out = np.empty((n, N_JOINTS))
    out_codes = np.empty(n, dtype=int)
    changes: list[PathChange] = []
    for i in range(n):
        s_i, r_i, c_i = sols[i], real[i], codes[i]
        if singular[i]:
            # paper 004 §2.2: joint 4 keeps its current value, joint 6 takes the rest
            s_i, r_i = ik_all(
                model, flange[i], offsets_deg, wrist_ref_deg=prev[3], singular_eps=singular_eps
            )
            c_i = configuration_codes(names, s_i)
        cand, ok = select_in_range(model, s_i, r_i, prev)
        if not ok.any():
            x, y, z = poses[i, :3]
            why = (
                "outside the workspace of the arm"
                if not r_i.any()
                else "every solution is outside the joint ranges"
            )
            raise UnreachableError(
                f"path point {i + 1} at ({x:.3f}, {y:.3f}, {z:.3f}) mm is "
                f"unreachable for {model.name}: {why}"
            )
        cost = np.where(ok, weighted_distance(np.nan_to_num(cand), prev, weights), np.inf)
        step = np.max(np.abs(np.nan_to_num(cand) - prev), -1)
        same = ok & (c_i == prev_code)
        kept = int(np.argmin(np.where(same, cost, np.inf))) if same.any() else None
        if kept is not None and step[kept] <= limit_deg:
            pick = kept
        else:
            pick = int(np.argmin(cost))
            if i > 0:
                changes.append(
                    _change(i, prev, cand, pick, kept, prev_code, int(c_i[pick]), limit_deg)
                )
        prev, prev_code = cand[pick], int(c_i[pick])
        out[i], out_codes[i] = prev, prev_code
    max_step = max_joint_step_deg(out)
    log.debug(
        "path of %d points: largest joint step %.4f deg, %d configuration change(s) or jump(s)",
        n,
        max_step,
        len(changes),
    )
    configs = tuple(ArmConfig.from_code(int(c)) for c in out_codes)
    return JointPath(out, configs, tuple(changes), max_step, float(limit_deg))


def _change(
    i: int,
    prev: np.ndarray,
    cand: np.ndarray,
    pick: int,
    kept: int | None,
    prev_code: int,
    code: int,
    limit_deg: float,
) -> PathChange:
    """The ``PathChange`` into point ``i`` (0-based): from ``prev`` to candidate ``pick``;
    ``kept`` the previous configuration's nearest in-range candidate, if any."""
    kept_step = None
    if kept is not None:
        d = cand[kept] - prev
        j = int(np.argmax(np.abs(d)))
        kept_step = (j + 1, float(d[j]))
    return PathChange(
        point=i + 1,
        before=ArmConfig.from_code(prev_code),
        after=ArmConfig.from_code(code),
        before_deg=prev.copy(),
        after_deg=cand[pick].copy(),
        kept=kept_step,
        limit_deg=float(limit_deg),
    )
