"""Checks every planned target passes before the first motion (``SafetyError``, exit 4)."""

from __future__ import annotations

import numpy as np

from ucal.cell import CellProfile
from ucal.errors import SafetyError

#: Room kept inside the joint ranges of joints 4–6 for a wrist search around a planned posture.
SEARCH_MARGIN_DEG = 8.0


def check_joints(
    profile: CellProfile, q: np.ndarray, label: str, wrist_margin_deg: float = SEARCH_MARGIN_DEG
) -> None:
    """Joint readings ``q`` (deg) inside the ranges, with ``wrist_margin_deg`` kept on joints
    4–6, and θ5 (kinematic, offsets applied) at least the profile's singularity margin from 0."""
    model = profile.model
    lo = model.joint_min_deg.copy()
    hi = model.joint_max_deg.copy()
    lo[3:] += wrist_margin_deg
    hi[3:] -= wrist_margin_deg
    bad = [j + 1 for j in range(6) if not lo[j] <= q[j] <= hi[j]]
    if bad:
        raise SafetyError(
            f"plan {label}: joint(s) {bad} at "
            f"{np.round(q[np.array(bad) - 1], 2).tolist()} deg leave the joint "
            f"range (keeping {wrist_margin_deg:g} deg on joints 4-6 for the wrist "
            "search)"
        )
    theta5 = q[4] + model.theta_offset_deg[4] + profile.joint_offsets_deg[4]
    margin = profile.procedure.singularity_margin_deg
    if abs(np.sin(np.radians(theta5))) < np.sin(np.radians(margin)):
        raise SafetyError(
            f"plan {label}: joint 5 at {theta5:.2f} deg is within {margin:g} deg "
            "of the wrist singularity"
        )
