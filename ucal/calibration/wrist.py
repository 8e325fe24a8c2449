"""Wrist postures that point the beam along a given direction, holding the arm still.

The wrist joints (4–6) turn the beam about the wrist centre W without moving W, so the arm
configuration fixes W and the wrist alone chooses the beam direction (arm–wrist separation,
paper 000 §4.2). Two wrist joints suffice to aim a beam; the third is kept near a reference.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import least_squares

from ucal.calibration.model import CellGeometry, beam_and_tcp
from ucal.errors import SafetyError
from ucal.kinematics.rotations import angle_between_deg

WRIST = (3, 4, 5)  # 0-based indices of joints 4, 5, 6


def aim_wrist(geom: CellGeometry, joints_deg: np.ndarray, direction: np.ndarray,
              offsets_deg: np.ndarray, keep_weight: float = 1e-3) -> np.ndarray:
    """Joint readings (6,) with joints 1–3 from ``joints_deg`` and joints 4–6 chosen so that the
    beam (model ``geom`` with ``offsets_deg``) points along the unit ``direction``.

    Solved by least squares started from ``joints_deg``'s wrist; a small ``keep_weight`` (per
    degree) keeps the solution near that start, which picks the wrist branch without a flip and
    fixes the free rotation about the beam when the beam is on the joint-6 axis.
    """
    q0 = np.array(joints_deg, float)
    target = np.asarray(direction, float) / np.linalg.norm(direction)

    def resid(w: np.ndarray) -> np.ndarray:
        q = q0.copy()
        q[3:] = w
        beam, _ = beam_and_tcp(geom, q, offsets_deg)
        return np.concatenate([beam - target, keep_weight * np.radians(w - q0[3:])])

    sol = least_squares(resid, q0[3:], xtol=1e-15, ftol=1e-15, gtol=1e-15, max_nfev=200)

    def aim_only(w: np.ndarray) -> np.ndarray:
        return resid(w)[:3]

    # The regularised optimum trades a hair of aim for closeness; polish the aim alone from it.
    sol = least_squares(aim_only, sol.x, method="trf", xtol=1e-15, ftol=1e-15, gtol=1e-15,
                        max_nfev=200)
    q = q0.copy()
    q[3:] = sol.x
    beam, _ = beam_and_tcp(geom, q, offsets_deg)
    err = float(angle_between_deg(beam, target))
    if err > 1e-6:
        raise SafetyError(f"the wrist cannot point the beam along {np.round(target, 4).tolist()} "
                          f"from arm joints {np.round(q0[:3], 3).tolist()} (best {err:.3f}° off)")
    return q


def beam_jacobian(geom: CellGeometry, joints_deg: np.ndarray, offsets_deg: np.ndarray,
                  joints: tuple[int, ...] = WRIST, h_deg: float = 1e-4) -> np.ndarray:
    """d(beam)/d(joint) (3, len(joints)) in 1/deg by central differences."""
    cols = []
    for j in joints:
        dq = np.zeros(6)
        dq[j] = h_deg
        bp, _ = beam_and_tcp(geom, joints_deg + dq, offsets_deg)
        bm, _ = beam_and_tcp(geom, joints_deg - dq, offsets_deg)
        cols.append((bp - bm) / (2 * h_deg))
    return np.array(cols).T


def search_joints(geom: CellGeometry, joints_deg: np.ndarray, offsets_deg: np.ndarray,
                  basis: np.ndarray) -> tuple[tuple[int, int], np.ndarray]:
    """The two wrist joints that steer the beam best across a face, and their 2×2 map.

    ``basis`` (2, 3) holds the face's in-plane axes; the map M (2, 2) takes joint steps (deg) to
    tilt components (rad). The pair with the largest |det M| is chosen (best conditioned).
    """
    jac = basis @ beam_jacobian(geom, joints_deg, offsets_deg)  # (2, 3)
    best, best_det = None, -1.0
    for a, b in ((0, 1), (0, 2), (1, 2)):
        m = jac[:, [a, b]]
        det = abs(np.linalg.det(m))
        if det > best_det:
            best, best_det = (WRIST[a], WRIST[b]), det
    m = jac[:, [WRIST.index(best[0]), WRIST.index(best[1])]]
    return best, m
