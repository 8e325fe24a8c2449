"""Paper 000's solution, equations 11–21, as the paper has it (first-order Taylor expansion).

Derivation for the TX90 family (DH table of ``ucal.kinematics.dh``; angles below are the
kinematic angles in the controller's convention, zero = arm straight up; a1 = a_1, d2 = d_2,
L2 = a_2 upper arm, L3 = d_4 forearm). The wrist centre W is the origin of frame 4:

    W = Rz(θ1)·[r, d2, z]ᵀ,  r = a1 + L2 sin θ2 + L3 sin θ23,  z = L2 cos θ2 + L3 cos θ23   (11a)

with θ23 = θ2 + θ3. Keeping the first order of the Taylor series (paper eqs. 8–10), a small
joint change moves W by

    δW = δθ1·∂W/∂θ1 + [c1, s1, 0]ᵀ·δr + [0, 0, 1]ᵀ·δz,
    δr = L2 c2 δθ2 + L3 c23 (δθ2 + δθ3),  δz = −L2 s2 δθ2 − L3 s23 (δθ2 + δθ3)        (11)

Joint-3 step δθ3 (others still): δW3 = [c1 L3 c23 δθ3, s1 L3 c23 δθ3, −L3 s23 δθ3]         (12)
  θ1  = atan2(σ·δW3y, σ·δW3x), σ = sign(c23 δθ3)       — horizontal direction of δW3     (13)
  h3  = δW3x c1 + δW3y s1 = L3 c23 δθ3
  θ23 = atan2(−δW3z / δθ3, h3 / δθ3)                   — from (12)                       (16)
Joint-2 step δθ2 (joint 3 back): h2 = δW2x c1 + δW2y s1, δz2 = δW2z
  L2 c2 = h2/δθ2 − L3 c23,  L2 s2 = −δz2/δθ2 − L3 s23   (the −s23·d4 term from (12))    (14)
  θ2  = atan2(L2 s2, L2 c2)                                                              (15)
  θ3  = θ23 − θ2                                                                         (17)

δW is measured at normal incidence: the change of the water path to face k equals the
displacement of W along the face normal n_k (``ucal.model.geometry``), so
δW = R_S·[Δd_0, Δd_1, Δd_2]ᵀ with R_S the block orientation.

The first-order expansion treats the chord of a finite step as the tangent at its start: for a
step Δ the chord of W's circle points along θ23 + Δ/2, so (16) returns θ23 biased by about half
the step. This is the paper's method and its bias; ``ucal.calibration.exact`` has none.

Wrist (eqs. 18–21): R63 = R30ᵀ·R60 (18). For the TX90 wrist (α4 = −90°, α5 = +90°)
R36 = Rz(θ4)·Ry(θ5)·Rz(θ6) (19), hence

    θ5 = atan2(±√(r13² + r23²), r33)                                                    (20)
    θ4 = atan2(±r23, ±r13),   θ6 = atan2(±r32, ∓r31)   (signs of sin θ5)                  (21)

R60 is measured, as in the paper, by the peak-echo postures against the block whose posture is
known: the beam a_T (flange frame) is normal to face k at posture q^k, so R60(q^ref)·a_T =
−n_ref, and with the relative wrist rotation read from the encoders, R60(q^ref)·R_rel·a_T =
−n_j for a second face j; the two directions fix R60(q^ref) (TRIAD). θ5 ≈ 0 is a singularity
(joints 4 and 6 collinear) and must be avoided by the plan.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np

from ucal.calibration.exact import OffsetSolution
from ucal.errors import InputError
from ucal.kinematics.dh import fk_frames, transform
from ucal.kinematics.rotations import matrix_to_rpy, rpy_to_matrix
from ucal.model.fit import MAX_STD_DEG, PRIOR_MEANING, CellPrior
from ucal.model.gauge import BLOCK_YAW, J1Gauge
from ucal.model.geometry import CellGeometry, FaceMeasurement, beam_and_tcp
from ucal.model.wrist import aim_wrist


def arm_lengths(geom: CellGeometry) -> tuple[float, float]:
    """(L2, L3) of a TX90-structured table; ``InputError`` for another structure."""
    dh = geom.model.dh
    expected = np.array([[0, -90], [-90, 0], [90, 90], [0, -90], [0, 90], [0, 0]], float)
    if not np.allclose(dh[:, [0, 3]], expected) or abs(dh[2, 1]) > 0 or abs(dh[2, 2]) > 0:
        raise InputError(
            "the paper's closed-form method needs a TX90-family DH structure; use --method exact"
        )
    return float(dh[1, 2]), float(dh[3, 1])


def wrist_centre_shift(
    geom: CellGeometry, before: dict[int, FaceMeasurement], after: dict[int, FaceMeasurement]
) -> np.ndarray:
    """δW (3,) in the base frame from the distance changes to the three faces."""
    delta_block = np.array([after[k].distance_mm - before[k].distance_mm for k in range(3)])
    return np.asarray(geom.block_rotation @ delta_block)


def _by_config(meas: list[FaceMeasurement]) -> dict[str, dict[int, FaceMeasurement]]:
    out: dict[str, dict[int, FaceMeasurement]] = {}
    for m in meas:
        out.setdefault(m.config, {})[m.face] = m
    for cfg in ("base", "j3", "j2"):
        if cfg not in out or len(out[cfg]) != 3:
            raise InputError(f"the paper's method needs all three faces in configuration {cfg!r}")
    return out


def arm_angles(geom: CellGeometry, meas: list[FaceMeasurement]) -> np.ndarray:
    """Kinematic θ1, θ2, θ3 (deg, reading convention) at the base configuration, eqs. 11–17."""
    _l2, l3 = arm_lengths(geom)
    cfg = _by_config(meas)
    base = cfg["base"][2].joints_deg
    step3 = np.radians(cfg["j3"][2].joints_deg[2] - base[2])
    step2 = np.radians(cfg["j2"][2].joints_deg[1] - base[1])
    dw3 = wrist_centre_shift(geom, cfg["base"], cfg["j3"])
    dw2 = wrist_centre_shift(geom, cfg["base"], cfg["j2"])
    # (13): the sign of c23 is that of the nominal θ23 (a ±5° offset cannot flip it unless the
    # forearm is within 5° of horizontal, which the plan avoids).
    sigma = np.sign(np.cos(np.radians(base[1] + base[2])) * step3)
    th1 = np.arctan2(sigma * dw3[1], sigma * dw3[0])
    c1, s1 = np.cos(th1), np.sin(th1)
    h3 = dw3[0] * c1 + dw3[1] * s1
    th23 = np.arctan2(-dw3[2] / step3, h3 / step3)  # (16)
    h2 = dw2[0] * c1 + dw2[1] * s1
    l2c2 = h2 / step2 - l3 * np.cos(th23)  # (14)
    l2s2 = -dw2[2] / step2 - l3 * np.sin(th23)
    th2 = np.arctan2(l2s2, l2c2)  # (15)
    th3 = th23 - th2  # (17)
    return np.degrees([th1, th2, th3])


def _triad(u1: np.ndarray, u2: np.ndarray, w1: np.ndarray, w2: np.ndarray) -> np.ndarray:
    """Rotation R with R·u1 = w1 exactly and R·u2 as close to w2 as possible."""

    def frame(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        e1 = a / np.linalg.norm(a)
        e2 = np.cross(a, b)
        e2 /= np.linalg.norm(e2)
        return np.column_stack([e1, e2, np.cross(e1, e2)])

    return np.asarray(frame(w1, w2) @ frame(u1, u2).T)


def wrist_angles(
    geom: CellGeometry,
    meas: list[FaceMeasurement],
    arm_deg: np.ndarray,
    ref_face: int = 2,
    other_face: int = 0,
) -> np.ndarray:
    """Kinematic θ4, θ5, θ6 (deg, reading convention) at the reference posture, eqs. 18–21."""
    cfg = _by_config(meas)["base"]
    q_ref = cfg[ref_face].joints_deg
    q_oth = cfg[other_face].joints_deg
    model = geom.model
    # Relative wrist rotation between the two postures from the encoder readings.
    f_ref = fk_frames(model, q_ref)
    f_oth = fk_frames(model, q_oth)
    r36_ref = f_ref[3, :3, :3].T @ f_ref[6, :3, :3]
    r36_oth = f_oth[3, :3, :3].T @ f_oth[6, :3, :3]
    r_rel = r36_ref.T @ r36_oth
    a_t = geom.beam_flange
    r60 = _triad(a_t, r_rel @ a_t, -geom.normal(ref_face), -geom.normal(other_face))
    q_arm = q_ref.copy()
    q_arm[:3] = arm_deg
    r30 = fk_frames(model, q_arm)[3, :3, :3]
    r63 = r30.T @ r60  # (18)
    # Remove the constant DH θ offsets of rows 4–6 (zero for the TX90 table).
    s5_sign = np.sign(np.sin(np.radians(q_ref[4] + model.theta_offset_deg[4]))) or 1.0
    th5 = np.arctan2(s5_sign * np.hypot(r63[0, 2], r63[1, 2]), r63[2, 2])  # (20)
    th4 = np.arctan2(s5_sign * r63[1, 2], s5_sign * r63[0, 2])  # (21)
    th6 = np.arctan2(s5_sign * r63[2, 1], -s5_sign * r63[2, 0])
    return np.asarray(np.degrees([th4, th5, th6]) - model.theta_offset_deg[3:])


def _wrap(angle_deg: np.ndarray) -> np.ndarray:
    return (np.asarray(angle_deg) + 180.0) % 360.0 - 180.0


def paper_offsets(geom: CellGeometry, meas: list[FaceMeasurement]) -> np.ndarray:
    """Offsets (deg) of all six joints by eqs. 11–21 (kinematic angle − reading)."""
    cfg = _by_config(meas)
    base = cfg["base"][2].joints_deg
    arm = arm_angles(geom, meas)
    wrist = wrist_angles(geom, meas, arm)
    return _wrap(np.concatenate([arm - base[:3], wrist - base[3:]]))


def solve_paper(
    geom: CellGeometry,
    meas: list[FaceMeasurement],
    prior_offsets_deg: np.ndarray,
    unobservable: tuple[int, ...] = (),
    condition_number: float = float("nan"),
    prior: CellPrior | None = None,
    reasons: dict[int, str] | None = None,
    max_std_deg: float = MAX_STD_DEG,
) -> OffsetSolution:
    """Offsets by the paper's method with an honest standard deviation.

    The variance of each offset is the sum of

    * the measurements' noise: each distance σ and posture σ propagated through the
      closed-form chain by central differences;
    * the cell's tolerances (``prior``): the block orientation, the beam direction in the flange
      (tool rx, ry) and the sound speed (a scale of every water path) propagated the same way —
      the equations take them as exact, so their errors pass straight into the offsets;
    * the first-order truncation error: ideal measurements are synthesised with the exact
      kinematics at the paper's own solution, and the paper's chain applied to them; what it
      returns minus that solution is its bias for this plan (about half the step on θ2 + θ3),
      taken as a one-sigma term because the method cannot remove it.

    ``unobservable`` (1-based, from the exact model's observability analysis of the same data)
    keep their prior values; so does a joint whose std exceeds ``max_std_deg`` mainly because
    of a tolerance (the paper's three configurations see the block from one J1 azimuth only).
    The block's yaw is taken as placed, so θ1 is relative to the block (the block gauge of
    ``ucal.model.gauge``): ``std_block_deg`` leaves the yaw's share out, ``std_deg``
    keeps it.
    """
    offsets = paper_offsets(geom, meas)
    noise = np.zeros(6)
    for i, m in enumerate(meas):
        for joint in (None, 3, 4, 5):  # None: the distance reading; else a wrist joint's
            h = 1e-4
            plus, minus = list(meas), list(meas)
            if joint is None:
                sigma = m.distance_std_mm
                plus[i] = _with(m, distance_mm=m.distance_mm + h)
                minus[i] = _with(m, distance_mm=m.distance_mm - h)
            else:
                sigma = m.tilt_std_deg
                dq = np.zeros(6)
                dq[joint] = h
                plus[i] = _with(m, joints_deg=m.joints_deg + dq)
                minus[i] = _with(m, joints_deg=m.joints_deg - dq)
            deriv = _wrap(paper_offsets(geom, plus) - paper_offsets(geom, minus)) / (2 * h)
            noise += (deriv * sigma) ** 2
    nuisance = _nuisance_variances(geom, meas, prior) if prior is not None else {}
    truncation = truncation_error(geom, meas, offsets)
    var = noise + truncation**2 + sum(nuisance.values(), np.zeros(6))
    std = np.sqrt(var)
    # the block gauge (ucal.model.gauge): the equations take the block's yaw as placed,
    # so relative to the block that tolerance is no error of theirs
    relative = {k: v for k, v in nuisance.items() if k != BLOCK_YAW}
    var_block = var - nuisance.get(BLOCK_YAW, np.zeros(6))
    std_block = np.sqrt(var_block)
    prior_off = np.asarray(prior_offsets_deg, float)
    why = dict(reasons or {})
    unobs = set(unobservable)
    for j in range(6):
        if j + 1 in unobs or std_block[j] <= max_std_deg or not relative:
            continue
        source, v = max(relative.items(), key=lambda kv: kv[1][j])
        if v[j] > 0.5 * var_block[j]:
            unobs.add(j + 1)
            why[j + 1] = (
                f"cannot be separated from {PRIOR_MEANING.get(source, source)} by "
                f"the paper's equations: {100 * v[j] / var_block[j]:.0f} % of its "
                f"variance relative to the block, std {std_block[j]:.3g} deg"
            )
    for j in unobs:
        offsets[j - 1] = prior_off[j - 1]
        std[j - 1] = np.nan
        std_block[j - 1] = np.nan
    yaw_std = 0.0 if prior is None else float(prior.block_rotation_std_deg[2])
    return OffsetSolution(
        offsets_deg=offsets,
        std_deg=std,
        unobservable_joints=tuple(sorted(unobs)),
        condition_number=condition_number,
        method="paper",
        truncation_deg=truncation,
        noise_std_deg=np.sqrt(noise),
        unobservable_reasons={j: why[j] for j in unobs if j in why},
        std_block_deg=std_block,
        gauge=J1Gauge(float(std_block[0]), yaw_std, max_std_deg),
    )


def _nuisance_variances(
    geom: CellGeometry, meas: list[FaceMeasurement], prior: CellPrior
) -> dict[str, np.ndarray]:
    """Variance (deg², per joint) that each tolerance of ``prior`` puts into the offsets."""
    base = paper_offsets(geom, meas)
    block_rpy = matrix_to_rpy(geom.block_rotation)
    tool_pos = geom.tool_matrix[:3, 3]
    tool_rpy = matrix_to_rpy(geom.tool_matrix[:3, :3])
    out: dict[str, np.ndarray] = {}

    def effect(g: CellGeometry, ms: list[FaceMeasurement]) -> np.ndarray:
        return _wrap(paper_offsets(g, ms) - base)

    for i, name in enumerate(("block_rx_deg", "block_ry_deg", "block_rz_deg")):
        h = float(prior.block_rotation_std_deg[i])
        if h > 0:
            d = np.zeros(3)
            d[i] = h
            g = replace(geom, block_rotation=rpy_to_matrix(block_rpy + d))
            out[name] = effect(g, meas) ** 2
    for i, name in enumerate(("tool_rx_deg", "tool_ry_deg")):
        h = float(prior.tool_rotation_std_deg[i])
        if h > 0:
            d = np.zeros(3)
            d[i] = h
            g = replace(geom, tool_matrix=transform(tool_pos, rpy_to_matrix(tool_rpy + d)))
            out[name] = effect(g, meas) ** 2
    rel = prior.sound_speed_std_m_s / prior.sound_speed_m_s
    if rel > 0:
        scaled = [_with(m, distance_mm=m.distance_mm * (1.0 + rel)) for m in meas]
        out["sound_speed_m_s"] = effect(geom, scaled) ** 2
    return out


def truncation_error(
    geom: CellGeometry, meas: list[FaceMeasurement], offsets_deg: np.ndarray
) -> np.ndarray:
    """The paper chain's own error (deg, per joint) at ``offsets_deg`` for these postures.

    Ideal measurements of a cell with offsets ``offsets_deg`` are synthesised with the exact
    forward kinematics at the measured arm configurations (the wrist aimed normal to each face,
    θ6 as measured), the water paths from a corner that reproduces the base configuration's;
    the paper's equations applied to them return ``offsets_deg`` plus their truncation error.
    """
    synth = []
    corner_local: dict[int, float] = {}
    for m in sorted(meas, key=lambda x: x.config != "base"):
        q = aim_wrist(geom, m.joints_deg, -geom.normal(m.face), offsets_deg)
        _, tcp = beam_and_tcp(geom, q, offsets_deg)
        proj = float(geom.normal(m.face) @ tcp)
        corner_local.setdefault(m.face, proj - m.distance_mm)
        synth.append(
            _with(
                m, joints_deg=q, distance_joints_deg=None, distance_mm=proj - corner_local[m.face]
            )
        )
    return np.asarray(np.abs(_wrap(paper_offsets(geom, synth) - offsets_deg)))


def _with(m: FaceMeasurement, **changes: Any) -> FaceMeasurement:
    return replace(m, **changes)
