"""Wrist postures that point the beam along a given direction, holding the arm still.

The wrist joints (4–6) turn the beam about the wrist centre W without moving W, so the arm
configuration fixes W and the wrist alone chooses the beam direction (arm–wrist separation,
paper 000 §4.2). Two wrist joints suffice to aim a beam; the third is kept near a reference.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.optimize import least_squares

from ucal.errors import SafetyError
from ucal.kinematics.dh import fk_frames, model_angles_rad
from ucal.kinematics.rotations import angle_between_deg, rot_x
from ucal.model.geometry import CellGeometry, beam_and_tcp

WRIST = (3, 4, 5)  # 0-based indices of joints 4, 5, 6


def aim_wrist(
    geom: CellGeometry,
    joints_deg: np.ndarray,
    direction: np.ndarray,
    offsets_deg: np.ndarray,
    keep_weight: float = 1e-3,
) -> np.ndarray:
    """Joint readings (6,) with joints 1–3 from ``joints_deg`` and joints 4–6 chosen so that the
    beam (model ``geom`` with ``offsets_deg``) points along the unit ``direction``.

    Joint 6 is held at its reading in ``joints_deg`` (it fixes the free rotation about the beam
    when the beam is on its axis) and joints 4 and 5 are solved in closed form
    (``_aim_closed_form``), the branch nearest to the start; where joint 6 held cannot point
    the beam, least squares over all three with a small ``keep_weight`` (per degree) pulling
    them toward the start.
    """
    q0 = np.array(joints_deg, float)
    target = np.asarray(direction, float) / np.linalg.norm(direction)

    def aim_error_deg(q: np.ndarray) -> float:
        beam, _ = beam_and_tcp(geom, q, offsets_deg)
        return float(angle_between_deg(beam, target))

    q = _aim_closed_form(geom, q0, target, offsets_deg)
    # The closed form assumes the DH wrist (no Hayati twist on links 4-5): check it.
    err = math.inf if q is None else aim_error_deg(q)
    if q is None or err > 1e-6:
        q = _aim_least_squares(geom, q0, target, offsets_deg, keep_weight)
        err = aim_error_deg(q)
    if err > 1e-6:
        raise SafetyError(
            f"the wrist cannot point the beam along {np.round(target, 4).tolist()} "
            f"from arm joints {np.round(q0[:3], 3).tolist()} (best {err:.3f}° off)"
        )
    return q


def _aim_closed_form(
    geom: CellGeometry, q0: np.ndarray, target: np.ndarray, offsets_deg: np.ndarray
) -> np.ndarray | None:
    """Joints 4 and 5 pointing the beam along ``target`` with joints 1–3 and 6 from ``q0``.

    With ``R_i = Rz(θ_i)·Rx(α_i)`` the beam in frame 3 is ``b = R_4·R_5·R_6·a_T``. Let
    ``c = Rx(α_5)·R_6·a_T`` (known) and ``w = Rz(θ_5)·c``; the z row of ``Rz(θ_4)·Rx(α_4)·w = b``
    does not involve θ_4: ``sin α_4·w_y + cos α_4·c_z = b_z``, and ``w_y = ρ·sin(θ_5 + φ)`` with
    ``ρ = |c_xy|``, ``φ = atan2(c_y, c_x)``: two θ_5. Then θ_4 turns ``Rx(α_4)·w`` onto ``b`` about
    z. None if no solution (|w_y| > ρ) or the wrist is degenerate (sin α_4 ≈ 0).
    """
    model = geom.model
    frames = fk_frames(model, q0, offsets_deg)
    theta = model_angles_rad(model, q0, offsets_deg)
    alpha = np.radians(model.alpha_deg)
    b = frames[3, :3, :3].T @ target
    r6 = frames[5, :3, :3].T @ frames[6, :3, :3]
    c = rot_x(alpha[4]) @ r6 @ geom.beam_flange
    s4, c4 = np.sin(alpha[3]), np.cos(alpha[3])
    rho = float(np.hypot(c[0], c[1]))
    if abs(s4) < 1e-6 or rho < 1e-9:
        return None
    wy = (b[2] - c4 * c[2]) / s4
    if abs(wy) > rho:
        return None
    phi = np.arctan2(c[1], c[0])
    best = None
    for t5 in (np.arcsin(wy / rho) - phi, np.pi - np.arcsin(wy / rho) - phi):
        w = np.array(
            [np.cos(t5) * c[0] - np.sin(t5) * c[1], np.sin(t5) * c[0] + np.cos(t5) * c[1], c[2]]
        )
        v = np.array([w[0], c4 * w[1] - s4 * w[2]])
        t4 = np.arctan2(b[1], b[0]) - np.arctan2(v[1], v[0])
        q = q0.copy()
        for j, t in ((3, t4), (4, t5)):
            # A change of model angle is the same change of reading; the turn nearest q0.
            q[j] = q0[j] + (np.degrees(t - theta[j]) + 180.0) % 360.0 - 180.0
        dist = float(np.sum((q[3:5] - q0[3:5]) ** 2))
        if best is None or dist < best[0]:
            best = (dist, q)
    return None if best is None else best[1]


def _aim_least_squares(
    geom: CellGeometry,
    q0: np.ndarray,
    target: np.ndarray,
    offsets_deg: np.ndarray,
    keep_weight: float,
) -> np.ndarray:
    """Joints 4–6 by least squares from ``q0``'s wrist, regularised toward it, then polished."""

    def resid(w: np.ndarray) -> np.ndarray:
        q = q0.copy()
        q[3:] = w
        beam, _ = beam_and_tcp(geom, q, offsets_deg)
        return np.concatenate([beam - target, keep_weight * np.radians(w - q0[3:])])

    sol = least_squares(resid, q0[3:], xtol=1e-15, ftol=1e-15, gtol=1e-15, max_nfev=200)

    def aim_only(w: np.ndarray) -> np.ndarray:
        return resid(w)[:3]

    # The regularised optimum trades a hair of aim for closeness; polish the aim alone from it.
    sol = least_squares(
        aim_only, sol.x, method="trf", xtol=1e-15, ftol=1e-15, gtol=1e-15, max_nfev=200
    )
    q = q0.copy()
    q[3:] = sol.x
    return q


def beam_jacobian(
    geom: CellGeometry,
    joints_deg: np.ndarray,
    offsets_deg: np.ndarray,
    joints: tuple[int, ...] = WRIST,
    h_deg: float = 1e-4,
) -> np.ndarray:
    """d(beam)/d(joint) (3, len(joints)) in 1/deg by central differences."""
    cols = []
    for j in joints:
        dq = np.zeros(6)
        dq[j] = h_deg
        bp, _ = beam_and_tcp(geom, joints_deg + dq, offsets_deg)
        bm, _ = beam_and_tcp(geom, joints_deg - dq, offsets_deg)
        cols.append((bp - bm) / (2 * h_deg))
    return np.array(cols).T


def search_joints(
    geom: CellGeometry, joints_deg: np.ndarray, offsets_deg: np.ndarray, basis: np.ndarray
) -> tuple[tuple[int, int], np.ndarray]:
    """The two wrist joints that steer the beam best across a face, and their 2×2 map.

    ``basis`` (2, 3) holds the face's in-plane axes; the map M (2, 2) takes joint steps (deg) to
    tilt components (rad). The pair with the largest |det M| is chosen (best conditioned).
    """
    jac = basis @ beam_jacobian(geom, joints_deg, offsets_deg)  # (2, 3)
    best: tuple[int, int] | None = None
    best_det = -1.0
    for a, b in ((0, 1), (0, 2), (1, 2)):
        m = jac[:, [a, b]]
        det = abs(np.linalg.det(m))
        if det > best_det:
            best, best_det = (WRIST[a], WRIST[b]), det
    assert best is not None, "the beam Jacobian is not finite"  # any |det| beats -1 otherwise
    m = jac[:, [WRIST.index(best[0]), WRIST.index(best[1])]]
    return best, m
