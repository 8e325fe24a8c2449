"""Cartesian tool path → continuous joint path (paper 004 §3–4).

Each point's eight closed-form solutions (``ucal.kinematics.ik``) are computed in one
vectorised call; the path is then walked point by point and each point takes the in-range
solution nearest the previous one by paper 004's weighted shortest distance (eq. 16 of
``ik``). Because both wrist roots (θ5 and −θ5) are candidates and joints 4 and 6 may use
their ±360° equivalents, a path through a wrist singularity keeps θ4 continuous (θ5 changes
sign) instead of the 180° jump of a per-point atan2 solution (paper 004, Figs. 4–5). At the
singular point itself θ4 keeps the previous value and θ6 takes the rest.
"""

from __future__ import annotations

import logging

import numpy as np

from ucal.errors import InputError, UnreachableError
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


def cartesian_path_to_joints(
    model: RobotModel,
    poses: np.ndarray,
    tool_T: np.ndarray | None = None,
    offsets_deg: np.ndarray | None = None,
    start_deg: np.ndarray | None = None,
    weights: np.ndarray | None = None,
    singular_eps: float = SINGULAR_EPS,
) -> tuple[np.ndarray, float]:
    """Joint readings for a tool path of poses (n, 6) ``X, Y, Z, RX, RY, RZ`` (mm, deg).

    ``tool_T`` is the tool frame relative to the flange (4, 4), ``offsets_deg`` the joint
    zero offsets (taken out of the readings), ``start_deg`` the configuration the robot is
    in before the first point (the first point's reference; default zeros), ``weights`` the
    six weights of the shortest-distance rule (default (6, 5, 4, 3, 2, 1)).

    Returns ``(joints_deg (n, 6), max_step_deg)``, the largest change of any joint between
    consecutive points. Raises ``UnreachableError`` naming the first point (1-based) with no
    in-range solution.
    """
    poses = np.asarray(poses, dtype=float)
    if poses.ndim != 2 or poses.shape[1] != 6:
        raise InputError(f"path poses must be an (n, 6) array X,Y,Z,RX,RY,RZ, got {poses.shape}")
    if not np.all(np.isfinite(poses)):
        raise InputError("path poses must be finite numbers")
    n = len(poses)
    flange = flange_from_tool(pose_to_matrix(poses), tool_T)
    sols, real = ik_all(model, flange, offsets_deg, singular_eps=singular_eps)

    # kinematic θ5 of every solution, to spot the points that need the singular rule
    th5_off = model.theta_offset_deg[4] + (0.0 if offsets_deg is None else offsets_deg[4])
    sin5 = np.abs(np.sin(np.radians(sols[..., 4] + th5_off)))
    singular = np.any(real & (sin5 < singular_eps), -1)

    prev = np.zeros(N_JOINTS) if start_deg is None else np.asarray(start_deg, dtype=float)
    out = np.empty((n, N_JOINTS))
    for i in range(n):
        s_i, r_i = sols[i], real[i]
        if singular[i]:
            # paper 004 §2.2: joint 4 keeps its current value, joint 6 takes the rest
            s_i, r_i = ik_all(
                model, flange[i], offsets_deg, wrist_ref_deg=prev[3], singular_eps=singular_eps
            )
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
        prev = cand[int(np.argmin(cost))]
        out[i] = prev
    step = max_joint_step_deg(out)
    log.debug("path of %d points: largest joint step %.4f deg", n, step)
    return out, step
