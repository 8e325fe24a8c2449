"""Checks every planned target passes before the first motion (``SafetyError``, exit 4).

The limits are the procedures' common ones: room for the wrist search inside the joint ranges,
the θ5 singularity margin of the profile, a water path that keeps the tool clear of the face it
measures, and a beam that meets the face inside its edges.
"""

from __future__ import annotations

import numpy as np

from ucal.calibration.model import FACE_NAMES, CellGeometry, beam_and_tcp
from ucal.cell import CellProfile
from ucal.errors import SafetyError

#: Room kept inside the joint ranges of joints 4–6 for a wrist search around a planned posture.
SEARCH_MARGIN_DEG = 8.0
#: Closest the tool centre may come to a face it measures (mm of water path).
MIN_WATER_PATH_MM = 20.0
#: Distance kept between the beam's hit point on a face and the face's edges (mm).
EDGE_MARGIN_MM = 20.0


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


def face_hit(
    geom: CellGeometry,
    q: np.ndarray,
    offsets_deg: np.ndarray,
    corner_mm: np.ndarray,
    face: int,
    face_size_mm: float,
) -> tuple[float, float]:
    """Where the beam at readings ``q`` meets ``face`` of a block with its corner at
    ``corner_mm``: the water path (mm, tool centre to the face along its normal) and the hit
    point's distance from the face's nearest edge (mm)."""
    beam, tcp = beam_and_tcp(geom, q, offsets_deg)
    local = geom.block_rotation.T @ (tcp - corner_mm)
    path = float(local[face])
    hit = local + path * (geom.block_rotation.T @ beam)
    edge = min(min(hit[i], face_size_mm - hit[i]) for i in range(3) if i != face)
    return path, float(edge)


def check_face(
    profile: CellProfile,
    geom: CellGeometry,
    q: np.ndarray,
    face: int,
    offsets_deg: np.ndarray,
    label: str,
) -> float:
    """The beam at ``q`` meets ``face`` of the profile's block inside its edges
    (``EDGE_MARGIN_MM``) with the tool at least ``MIN_WATER_PATH_MM`` from it; the water path
    (mm). ``SafetyError`` naming ``label`` otherwise."""
    path, edge = face_hit(
        geom, q, offsets_deg, profile.sample_matrix[:3, 3], face, profile.sample_face_size_mm
    )
    name = FACE_NAMES[face]
    if path < MIN_WATER_PATH_MM:
        raise SafetyError(
            f"plan {label}: the tool centre would be {path:.1f} mm from face {name} "
            f"(minimum {MIN_WATER_PATH_MM:g} mm)"
        )
    if edge < EDGE_MARGIN_MM:
        raise SafetyError(
            f"plan {label}: the beam would meet face {name} {edge:.1f} mm from its edge "
            f"(minimum {EDGE_MARGIN_MM:g} mm)"
        )
    return path
