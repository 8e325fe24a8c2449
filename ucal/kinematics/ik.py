"""Closed-form inverse kinematics of the TX90 family by arm–wrist separation (paper 004).

All eight solutions (shoulder front/back × elbow up/down × wrist no-flip/flip) are computed
in closed form and vectorised over any number of poses; one of them is then chosen by paper
004's weighted shortest distance to a reference configuration. Lengths in mm, angles in
degrees at the interface (radians only inside).

Derivation
----------
The equations of paper 004 were lost in extraction; they are re-derived here from the
standard DH model of ``ucal.kinematics.dh`` (``A_i = Rz(θ_i)·Tz(d_i)·Tx(a_i)·Rx(α_i)``), for
any table of the TX90 structure::

    α = (±90°, 0, ±90°, ±90°, −α_4, any),   a_4 = a_5 = d_5 = 0   (spherical wrist)

The shipped tables have α = (−90, 0, +90, −90, +90, 0), d = (0, 50, 0, L3, 0, 100),
a = (50, L2, 0, 0, 0, 0). Below, θ_i is the *kinematic* angle (reading + DH θ offset + joint
offset), c_i = cos θ_i, s_i = sin θ_i, σ_1 = sin α_1, σ_3 = sin α_3, σ_4 = −sin α_4 (all ±1).

Wrist centre. Axes 4, 5, 6 meet in W, the origin of frames 4 and 5. From
``T_56 = Rz(θ6)·Tz(d6)·Tx(a6)·Rx(α6)`` the flange origin is
``p = W + R_05·Rz(θ6)·(a6, 0, d6)ᵀ = W + R_06·Rx(−α6)·(a6, 0, d6)ᵀ``, so with the flange
pose (R_06, p)::

    (1)  W = p − R_06 · Rx(−α_6) · (a_6, 0, d_6)ᵀ          (= p − d_6·z_6 for the TX90)

W depends on θ1, θ2, θ3 only. Writing it in frame 1 (x_1, y_1 in the vertical arm plane,
z_1 = axis 2, horizontal) and multiplying out ``A_2·A_3·(0, 0, d_4, 1)ᵀ``::

    (2)  W_1 = ( a_2 c_2 + a_3 c_23 + σ_3 d_4 s_23,
                 a_2 s_2 + a_3 s_23 − σ_3 d_4 c_23,
                 d_2 + d_3 )                               with θ_23 = θ_2 + θ_3

Joint 1. Frame 1 has origin (a_1 c_1, a_1 s_1, d_1) and z_1 = −σ_1·(−s_1, c_1, 0), so the
lateral component of W − o_1 must equal D = d_2 + d_3 (the shoulder's lateral offset)::

    (3)  −s_1 W_x + c_1 W_y = −σ_1 D
    (4)  ρ sin(φ − θ_1) = −σ_1 D,   ρ = √(W_x² + W_y²),  φ = atan2(W_y, W_x)
    (5)  θ_1 = φ − asin(−σ_1 D / ρ)            (shoulder "front")
         θ_1 = φ − π + asin(−σ_1 D / ρ)        (shoulder "back")

Real iff ρ ≥ |D|; at ρ = |D| (W on the cylinder of radius D about axis 1) the two coincide.

Arm plane. With θ_1 known, the in-plane coordinates of W relative to axis 2 are::

    (6)  r = c_1 W_x + s_1 W_y − a_1,     u = σ_1 (W_z − d_1)

and (2) says ``(r, u) = a_2 (c_2, s_2) + L (cos(θ_23 − γ), sin(θ_23 − γ))`` with the
forearm length and angle::

    (7)  L = √(a_3² + d_4²),   γ = atan2(σ_3 d_4, a_3)

Joint 3, law of cosines in the triangle axis 2 – elbow – W::

    (8)  r² + u² = a_2² + L² + 2 a_2 L cos(θ_3 − γ)
    (9)  k = (r² + u² − a_2² − L²) / (2 a_2 L),   θ_3 = γ + atan2(±√(1 − k²), k)

(elbow up/down; real iff |k| ≤ 1; the elbow is stretched at k = ±1). Joint 2 by rotating
the triangle onto (r, u)::

    (10) θ_2 = atan2(u, r) − atan2(L sin(θ_3 − γ), a_2 + L cos(θ_3 − γ))

Wrist. With α_2 = 0 the arm's orientation is ``R_03 = Rz(θ_1)·Rx(α_1)·Rz(θ_2 + θ_3)·Rx(α_3)``
(translations do not rotate), and
``R_36 = R_03ᵀ · R_06 · Rx(α_6)ᵀ = Rz(θ_4)·Rx(α_4)·Rz(θ_5)·Rx(−α_4)·Rz(θ_6)``, and
``Rx(α_4)·Rz(θ_5)·Rx(−α_4)`` is a rotation by θ_5 about ``Rx(α_4)·e_z = (0, −sin α_4, 0)``,
i.e. ``Ry(σ_4 θ_5)``. So R_36 = M is a z-y-z Euler matrix with b = σ_4 θ_5::

    (11) M = Rz(θ_4)·Ry(b)·Rz(θ_6) =
           [[c4 cb c6 − s4 s6,  −c4 cb s6 − s4 c6,  c4 sb],
            [s4 cb c6 + c4 s6,  −s4 cb s6 + c4 c6,  s4 sb],
            [−sb c6,             sb s6,              cb  ]]
    (12) b = atan2(±√(M_02² + M_12²), M_22)          (wrist no-flip: +, flip: −)
    (13) θ_4 = atan2(M_12 / sb, M_02 / sb),   θ_6 = atan2(M_21 / sb, −M_20 / sb)

The flipped root is (θ_4 + π, −b, θ_6 + π). With (5) × (9) × (12) this gives the eight
solutions.

Wrist singularity (|sin b| < eps: axes 4 and 6 aligned). (13) is undefined: only
θ_4 + θ_6 (b ≈ 0) or θ_6 − θ_4 (b ≈ π) is determined. As paper 004 §2.2 prescribes, θ_4
keeps its reference (current) value; then ``Rz(−θ_4)·M = Ry(b)·Rz(θ_6)`` gives::

    (14) b = atan2(M'_02, M'_22),   θ_6 = atan2(M'_10, M'_11),   M' = Rz(−θ_4)·M

and the flipped root is again (θ_4 + π, −b, θ_6 + π).

Readings. Each kinematic angle is turned back into a joint reading (SPEC.md)::

    (15) reading_i = θ_i − θoffset_i − joint_offset_i,   wrapped into (−180°, 180°]

Selection (paper 004 §3). Joints whose range exceeds ±180° (4 and 6 of the TX90: ±270°)
may use the ±360° equivalent of a reading; each joint takes the in-range equivalent nearest
the reference. Of the solutions inside the joint ranges, the one with the least weighted
distance to the reference configuration θ_ref::

    (16) E = Σ_i w_i |θ_i − θ_ref,i|,    default w = (6, 5, 4, 3, 2, 1)

is returned (nearest first with ``all_solutions``). ``ik_branches`` says of each of the eight
why it is offered or not: the branch does not reach the pose (the wrist centre inside the
shoulder's lateral offset, eq. 5; beyond the stretched or inside the folded arm, eq. 9) or a
joint has no reading inside its range (which joint, and by how much).

Calibrated tables. A table identified on a robot (``[calibration] dh``: twists a few
hundredths of a degree off ±90°, Hayati's β₂, millimetre wrist offsets) has no closed form. Its
solutions are those of the nearest ideal table (``ideal_structure``: twists snapped to the
structure above, spherical wrist, no β), each refined by damped Newton (Levenberg–Marquardt)
steps on the calibrated model's geometric Jacobian until the flange pose agrees to
``REFINE_TOL_MM`` (and ``REFINE_TOL_RAD``): the same eight branches, chosen by the same rule.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from ucal.errors import InputError, UnreachableError
from ucal.kinematics.dh import N_JOINTS, RobotModel, fk, jacobian
from ucal.kinematics.rotations import rot_x

log = logging.getLogger(__name__)

#: Number of closed-form solutions: shoulder (2) × elbow (2) × wrist (2).
N_SOLUTIONS = 8

#: Paper 004's weights of the shortest-distance rule: joint 1 moves most mass, joint 6 least.
DEFAULT_WEIGHTS = np.array([6.0, 5.0, 4.0, 3.0, 2.0, 1.0])

#: |sin θ5| below which the wrist is treated as singular (axes 4 and 6 aligned).
SINGULAR_EPS = 1e-10

# Relative slack for the reachability tests (|k| <= 1, ρ >= |D|): rounding of a pose
# exactly on the workspace boundary must not make it unreachable.
_REACH_TOL = 1e-12

# Slack on the joint limits (deg), as RobotModel.within_limits: rounding only, never clipped.
_ANGLE_TOL_DEG = 1e-9


#: Refined solutions of a calibrated table agree with its forward kinematics to this (mm, rad).
REFINE_TOL_MM = 1e-9
REFINE_TOL_RAD = 1e-12
#: Largest deviation (deg, mm) of a calibrated table from the ideal structure that is refined.
MAX_SNAP_DEG = 1.0
MAX_SNAP_MM = 5.0


def _sign90(alpha_deg: float, what: str, model: RobotModel) -> float:
    s = np.sin(np.radians(alpha_deg))
    if abs(abs(s) - 1.0) > 1e-12:
        raise InputError(
            f"model {model.name!r}: {what} must be ±90° for closed-form IK, got {alpha_deg}°"
        )
    return float(np.sign(s))


def check_structure(model: RobotModel) -> None:
    """Raise ``InputError`` unless the DH table has the TX90 structure the closed form needs.

    Required: α1 = ±90°, α2 = 0, α3 = ±90°, α4 = ±90°, α5 = −α4 (any α6), and a spherical
    wrist a4 = a5 = d5 = 0 (mm).
    """
    al = model.alpha_deg
    _sign90(al[0], "alpha_1", model)
    _sign90(al[2], "alpha_3", model)
    s4 = _sign90(al[3], "alpha_4", model)
    if abs(np.sin(np.radians(al[1]))) > 1e-12 or np.cos(np.radians(al[1])) < 0:
        raise InputError(
            f"model {model.name!r}: alpha_2 must be 0° for closed-form IK, got {al[1]}°"
        )
    if abs(np.sin(np.radians(al[4])) + s4) > 1e-12:
        raise InputError(f"model {model.name!r}: alpha_5 must be -alpha_4 for closed-form IK")
    if abs(model.a_mm[3]) > 0 or abs(model.a_mm[4]) > 0 or abs(model.d_mm[4]) > 0:
        raise InputError(
            f"model {model.name!r}: the wrist is not spherical (a_4, a_5 and d_5 must be 0 mm)"
        )
    if model.a_mm[1] == 0 or (model.a_mm[2] == 0 and model.d_mm[3] == 0):
        raise InputError(
            f"model {model.name!r}: upper arm a_2 and forearm (a_3, d_4) must be non-zero"
        )


def wrap_deg(angle_deg: np.ndarray) -> np.ndarray:
    """Wrap angles (deg) into (−180, 180]."""
    a = np.asarray(angle_deg, dtype=float)
    w = np.mod(a + 180.0, 360.0) - 180.0
    return np.where(w == -180.0, 180.0, w)


def _rot_z(th: np.ndarray) -> np.ndarray:
    c, s = np.cos(th), np.sin(th)
    o, z = np.ones_like(th), np.zeros_like(th)
    return np.stack(
        [np.stack([c, -s, z], -1), np.stack([s, c, z], -1), np.stack([z, z, o], -1)], -2
    )


def ideal_structure(model: RobotModel) -> RobotModel:
    """``model`` itself if the closed form applies, else the nearest table of the TX90 structure
    (``check_structure``): twists rounded to 0/±90° (α5 = −α4), a4 = a5 = d5 = 0, no Hayati β.

    Raises ``InputError`` if the table is further from that structure than a calibration
    could make it (``MAX_SNAP_DEG``, ``MAX_SNAP_MM``).
    """
    if not model.has_twists:
        try:
            check_structure(model)
            return model
        except InputError:
            pass
    dh = model.dh.copy()
    for i, target in ((0, None), (1, 0.0), (2, None), (3, None), (4, None)):
        a = dh[i, 3]
        snapped = 90.0 * np.round(a / 90.0) if target is None else target
        if i == 4:
            snapped = -dh[3, 3]
        if abs(a - snapped) > MAX_SNAP_DEG:
            raise InputError(
                f"model {model.name!r}: alpha_{i + 1} = {a}° is not within "
                f"{MAX_SNAP_DEG}° of the TX90 structure's {snapped}°"
            )
        dh[i, 3] = snapped
    for i, c in ((3, 2), (4, 2), (4, 1)):
        if abs(dh[i, c]) > MAX_SNAP_MM:
            raise InputError(
                f"model {model.name!r}: the wrist is not spherical "
                f"({'da'[c - 1]}_{i + 1} = {dh[i, c]} mm)"
            )
        dh[i, c] = 0.0
    if np.any(np.abs(model.beta_deg) > MAX_SNAP_DEG):
        raise InputError(f"model {model.name!r}: a beta_deg above {MAX_SNAP_DEG}°")
    ideal = model.with_dh(dh, np.zeros(N_JOINTS))
    check_structure(ideal)
    return ideal


def refine(
    model: RobotModel,
    flange_T: np.ndarray,
    seeds_deg: np.ndarray,
    offsets_deg: np.ndarray | None = None,
    max_iter: int = 20,
) -> tuple[np.ndarray, np.ndarray]:
    """Refine joint readings (…, 6) so that ``model``'s flange reaches ``flange_T`` (…, 4, 4).

    Damped Newton steps ``Δθ = Jᵀ(JJᵀ + λ²I)⁻¹·e`` on the geometric Jacobian, with ``e`` the
    position error (mm) and the rotation vector of the orientation error (rad); λ is a hair
    (1e-9) so that a wrist singularity does not blow the step up. Returns the readings and
    whether each converged (``REFINE_TOL_MM``, ``REFINE_TOL_RAD``). NaN seeds stay NaN.
    """
    T = np.asarray(flange_T, float)
    q = np.array(seeds_deg, float)
    shape = q.shape[:-1]
    finite = np.all(np.isfinite(q), -1)
    qf = q[finite]
    Tf = np.broadcast_to(T, shape + (4, 4))[finite]
    ok = np.zeros(len(qf), bool)
    for _ in range(max_iter):
        cur = fk(model, qf, offsets_deg=offsets_deg)
        e_p = Tf[:, :3, 3] - cur[:, :3, 3]
        e_r = Rotation.from_matrix(Tf[:, :3, :3] @ np.swapaxes(cur[:, :3, :3], -1, -2)).as_rotvec()
        ok = (np.linalg.norm(e_p, axis=-1) < REFINE_TOL_MM) & (
            np.linalg.norm(e_r, axis=-1) < REFINE_TOL_RAD
        )
        if ok.all():
            break
        jac = jacobian(model, qf, offsets_deg=offsets_deg)
        e = np.concatenate([e_p, e_r], -1)
        jjt = jac @ np.swapaxes(jac, -1, -2) + 1e-18 * np.eye(6)
        step = np.swapaxes(jac, -1, -2) @ np.linalg.solve(jjt, e[..., None])
        qf = qf + np.degrees(step[..., 0])
    out = np.full(q.shape, np.nan)
    out[finite] = qf
    conv = np.zeros(shape, bool)
    conv[finite] = ok
    return out, conv


def ik_all(
    model: RobotModel,
    flange_T: np.ndarray,
    offsets_deg: np.ndarray | None = None,
    wrist_ref_deg: np.ndarray | float | None = None,
    singular_eps: float = SINGULAR_EPS,
) -> tuple[np.ndarray, np.ndarray]:
    """All eight joint solutions for flange poses (…, 4, 4): closed form (``ik_closed_form``),
    refined on ``model`` where it is a calibrated table (module docstring)."""
    ideal = ideal_structure(model)
    sols, valid = ik_closed_form(ideal, flange_T, offsets_deg, wrist_ref_deg, singular_eps)
    if ideal is model:
        return sols, valid
    T = np.asarray(flange_T, float)[..., None, :, :]
    refined, conv = refine(model, T, sols, offsets_deg)
    valid = valid & conv
    refined = np.where(valid[..., None], wrap_deg(refined), np.nan)
    return refined, valid


def ik_closed_form(
    model: RobotModel,
    flange_T: np.ndarray,
    offsets_deg: np.ndarray | None = None,
    wrist_ref_deg: np.ndarray | float | None = None,
    singular_eps: float = SINGULAR_EPS,
) -> tuple[np.ndarray, np.ndarray]:
    """All eight closed-form joint solutions for flange poses (…, 4, 4) in the base frame (mm).

    Returns ``(solutions_deg (…, 8, 6), valid (…, 8))``: joint *readings* in degrees,
    wrapped into (−180, 180] (reading = kinematic − DH θ offset − ``offsets_deg``), and
    whether each solution is real (the pose is reachable by that branch; joint ranges are
    not checked here). Invalid solutions are NaN. Solution index ``4·shoulder + 2·elbow +
    wrist``: shoulder 0 front / 1 back (eq. 5), elbow 0 / 1 the + / − root of eq. 9, wrist
    0 with σ4·θ5 ≥ 0 / 1 flipped (eq. 12).

    ``wrist_ref_deg`` (reading of joint 4, scalar or (…,)) is the value joint 4 keeps at a
    wrist singularity, |sin θ5| < ``singular_eps`` (default 0 kinematic).
    """
    check_structure(model)
    T = np.asarray(flange_T, dtype=float)
    shape = T.shape[:-2]
    th_off = model.theta_offset_deg.copy()
    if offsets_deg is not None:
        th_off = th_off + np.asarray(offsets_deg, dtype=float)
    d, a = model.d_mm, model.a_mm
    al = np.radians(model.alpha_deg)
    sg1, sg3 = np.sin(al[0]), np.sin(al[2])
    sg4 = -np.sin(al[3])

    R06 = T[..., :3, :3]
    p = T[..., :3, 3]
    # (1) wrist centre
    w_off = rot_x(-al[5]) @ np.array([a[5], 0.0, d[5]])
    W = p - R06 @ w_off
    wx, wy, wz = W[..., 0], W[..., 1], W[..., 2]

    # (3)–(5) joint 1, two roots: axis 0 of the (2,) stacks below
    D = d[1] + d[2]
    rho = np.hypot(wx, wy)
    phi = np.arctan2(wy, wx)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = -sg1 * D / rho
    ok1 = np.abs(ratio) <= 1.0 + _REACH_TOL
    asn = np.arcsin(np.clip(ratio, -1.0, 1.0))
    th1 = np.stack([phi - asn, phi - np.pi + asn], -1)  # (…, 2)
    c1, s1 = np.cos(th1), np.sin(th1)

    # (6) arm-plane coordinates of W
    r = c1 * wx[..., None] + s1 * wy[..., None] - a[0]
    u = np.broadcast_to((sg1 * (wz - d[0]))[..., None], r.shape)
    # (7)–(9) joint 3, two roots each: (…, 2 shoulder, 2 elbow)
    L = np.hypot(a[2], d[3])
    gam = np.arctan2(sg3 * d[3], a[2])
    k = (r * r + u * u - a[1] ** 2 - L * L) / (2.0 * a[1] * L)
    ok3 = np.abs(k) <= 1.0 + _REACH_TOL
    kc = np.clip(k, -1.0, 1.0)
    sq = np.sqrt(1.0 - kc * kc)
    e = np.arctan2(np.stack([sq, -sq], -1), kc[..., None])  # θ3 − γ
    th3 = gam + e
    # (10) joint 2
    th2 = np.arctan2(u, r)[..., None] - np.arctan2(L * np.sin(e), a[1] + L * np.cos(e))
    th1b = np.broadcast_to(th1[..., None], th2.shape)
    arm_ok = ok1[..., None, None] & ok3[..., None]  # (…, 2, 2)

    # (11) M = R03ᵀ·R06·Rx(α6)ᵀ with R03 = Rz(θ1)·Rx(α1)·Rz(θ2 + θ3)·Rx(α3) (α2 = 0), applied
    # row by row: elementwise over all poses and branches, no batched 3×3 products
    R = R06 @ rot_x(al[5]).T
    r0, r1, r2 = R[..., None, 0, :], R[..., None, 1, :], R[..., None, 2, :]
    c1v, s1v = c1[..., None], s1[..., None]
    n0 = c1v * r0 + s1v * r1  # Rz(θ1)ᵀ
    n1 = -s1v * r0 + c1v * r1
    ca, sa = np.cos(al[0]), np.sin(al[0])  # Rx(α1)ᵀ
    n1, n2 = ca * n1 + sa * r2, -sa * n1 + ca * r2
    th23 = th2 + th3
    c23, s23 = np.cos(th23)[..., None], np.sin(th23)[..., None]
    n0, n1, n2 = n0[..., None, :], n1[..., None, :], n2[..., None, :]
    m0 = c23 * n0 + s23 * n1  # Rz(θ2 + θ3)ᵀ
    m1 = -s23 * n0 + c23 * n1
    ca, sa = np.cos(al[2]), np.sin(al[2])  # Rx(α3)ᵀ
    M = np.stack([m0, ca * m1 + sa * n2, -sa * m1 + ca * n2], -2)  # (…, 2, 2, 3, 3)

    # (12)–(13) wrist, no-flip root; flipped root = (θ4 + π, −b, θ6 + π)
    sb = np.hypot(M[..., 0, 2], M[..., 1, 2])
    b = np.arctan2(sb, M[..., 2, 2])
    th4 = np.arctan2(M[..., 1, 2], M[..., 0, 2])
    th6 = np.arctan2(M[..., 2, 1], -M[..., 2, 0])
    singular = sb < singular_eps
    if np.any(singular):
        # (14): joint 4 keeps its reference, the rest goes into b and θ6
        if wrist_ref_deg is None:
            ref4 = np.zeros(shape)
        else:
            ref4 = np.broadcast_to(np.radians(np.asarray(wrist_ref_deg, float) + th_off[3]), shape)
        ref4 = np.broadcast_to(ref4[..., None, None], singular.shape)
        Mp = np.swapaxes(_rot_z(ref4), -1, -2) @ M
        th4 = np.where(singular, ref4, th4)
        b = np.where(singular, np.arctan2(Mp[..., 0, 2], Mp[..., 2, 2]), b)
        th6 = np.where(singular, np.arctan2(Mp[..., 1, 0], Mp[..., 1, 1]), th6)
    th5 = b / sg4
    wrist = np.stack(
        [np.stack([th4, th5, th6], -1), np.stack([th4 + np.pi, -th5, th6 + np.pi], -1)], -2
    )  # (…,2,2,2,3)

    arm = np.stack([th1b, th2, th3], -1)  # (…, 2, 2, 3)
    arm = np.broadcast_to(arm[..., None, :], wrist.shape)
    sol = np.concatenate([arm, wrist], -1).reshape(shape + (N_SOLUTIONS, N_JOINTS))
    valid = np.broadcast_to(arm_ok[..., None], wrist.shape[:-1]).reshape(shape + (N_SOLUTIONS,))
    # (15) kinematic angles → readings
    readings = wrap_deg(np.degrees(sol) - th_off)
    readings = np.where(valid[..., None], readings, np.nan)
    return readings, valid.copy()


def _as_weights(weights: np.ndarray | None) -> np.ndarray:
    w = DEFAULT_WEIGHTS if weights is None else np.asarray(weights, dtype=float)
    if w.shape != (N_JOINTS,) or np.any(w < 0) or not np.all(np.isfinite(w)):
        raise InputError(f"weights must be six non-negative numbers, got {w!r}")
    return w


def select_in_range(
    model: RobotModel, solutions_deg: np.ndarray, valid: np.ndarray, ref_deg: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Move each joint reading to its in-range ±360° equivalent nearest the reference.

    ``solutions_deg`` (…, m, 6), ``valid`` (…, m), ``ref_deg`` broadcastable to (…, 6).
    Returns ``(solutions_deg, in_range (…, m))``; a solution with a joint that has no
    equivalent inside ``[joint_min_deg, joint_max_deg]`` is marked out of range.
    """
    ref = np.asarray(ref_deg, dtype=float)[..., None, :]
    cand = solutions_deg[..., None] + np.array([-360.0, 0.0, 360.0])  # (…, m, 6, 3)
    lo = (model.joint_min_deg - _ANGLE_TOL_DEG)[:, None]
    hi = (model.joint_max_deg + _ANGLE_TOL_DEG)[:, None]
    inside = (cand >= lo) & (cand <= hi)
    dist = np.where(inside, np.abs(cand - ref[..., None]), np.inf)
    pick = np.argmin(dist, -1)
    chosen = np.take_along_axis(cand, pick[..., None], -1)[..., 0]
    ok = valid & np.all(np.any(inside, -1), -1)
    return np.where(ok[..., None], chosen, np.nan), ok


def weighted_distance(
    solutions_deg: np.ndarray, ref_deg: np.ndarray, weights: np.ndarray | None = None
) -> np.ndarray:
    """Paper 004's shortest-distance measure Σ wᵢ|θᵢ − θᵢ_ref| (deg) (…, m, 6) → (…, m) (eq. 16)."""
    w = _as_weights(weights)
    ref = np.asarray(ref_deg, dtype=float)[..., None, :]
    return np.asarray(np.sum(w * np.abs(solutions_deg - ref), -1))


def flange_from_tool(target_T: np.ndarray, tool_T: np.ndarray | None) -> np.ndarray:
    """Flange pose (…, 4, 4) for a tool pose: ``flange = target · tool⁻¹`` (mm)."""
    T = np.asarray(target_T, dtype=float)
    if tool_T is None:
        return T
    return T @ np.linalg.inv(np.asarray(tool_T, dtype=float))


def ik_solutions(
    model: RobotModel,
    target_T: np.ndarray,
    tool_T: np.ndarray | None = None,
    offsets_deg: np.ndarray | None = None,
    near_deg: np.ndarray | None = None,
    weights: np.ndarray | None = None,
    singular_eps: float = SINGULAR_EPS,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """In-range solutions for many tool poses (…, 4, 4), sorted nearest first (vectorised).

    Returns ``(solutions_deg (…, 8, 6), in_range (…, 8), cost (…, 8))``: joint readings
    (deg) with joints moved to the in-range equivalent nearest ``near_deg`` (…, 6) or (6,)
    (default zeros), sorted by the weighted distance ``cost`` (eq. 16, deg); solutions that
    are unreachable or out of range come last, NaN, with ``in_range`` False and infinite cost.
    """
    flange = flange_from_tool(target_T, tool_T)
    shape = flange.shape[:-2]
    ref = np.zeros(N_JOINTS) if near_deg is None else np.asarray(near_deg, dtype=float)
    ref = np.broadcast_to(ref, shape + (N_JOINTS,))
    sols, real = ik_all(
        model, flange, offsets_deg, wrist_ref_deg=ref[..., 3], singular_eps=singular_eps
    )
    sols, ok = select_in_range(model, sols, real, ref)
    cost = np.where(ok, weighted_distance(np.nan_to_num(sols), ref, weights), np.inf)
    order = np.argsort(cost, -1, kind="stable")
    sols = np.take_along_axis(sols, order[..., None], -2)
    return sols, np.take_along_axis(ok, order, -1), np.take_along_axis(cost, order, -1)


def ik_many(
    model: RobotModel,
    target_T: np.ndarray,
    tool_T: np.ndarray | None = None,
    offsets_deg: np.ndarray | None = None,
    near_deg: np.ndarray | None = None,
    weights: np.ndarray | None = None,
    singular_eps: float = SINGULAR_EPS,
) -> tuple[np.ndarray, np.ndarray]:
    """Nearest in-range solution for each of many tool poses (…, 4, 4); never raises.

    Returns ``(joints_deg (…, 6), ok (…,))``; rows with ``ok`` False (unreachable or out of
    range) are NaN. ``near_deg`` is the reference (…, 6) or (6,), default zeros.
    """
    sols, ok, _ = ik_solutions(
        model, target_T, tool_T, offsets_deg, near_deg, weights, singular_eps
    )
    return sols[..., 0, :], ok[..., 0]


def ik(
    model: RobotModel,
    target_T: np.ndarray,
    tool_T: np.ndarray | None = None,
    offsets_deg: np.ndarray | None = None,
    near_deg: np.ndarray | None = None,
    weights: np.ndarray | None = None,
    all_solutions: bool = False,
    singular_eps: float = SINGULAR_EPS,
) -> np.ndarray:
    """Joint readings (deg) that put the tool at ``target_T`` (4, 4, base frame, mm).

    ``tool_T`` is the tool frame relative to the flange (4, 4; default none), ``offsets_deg``
    the joint zero offsets (actual = reading + offset; taken out of the result), ``near_deg``
    the reference configuration (default zeros) and ``weights`` the six weights of paper
    004's shortest-distance rule (default (6, 5, 4, 3, 2, 1)). Returns the nearest in-range
    solution (6,), or with ``all_solutions`` every in-range solution (k, 6), nearest first.
    At a wrist singularity joint 4 keeps its reference value.

    Raises ``UnreachableError`` (exit 4) if no solution reaches the pose inside the ranges.
    """
    T = np.asarray(target_T, dtype=float)
    if T.shape != (4, 4):
        raise ValueError(f"target_T must be (4, 4), got {T.shape}; use ik_many for batches")
    sols, ok, _ = ik_solutions(model, T, tool_T, offsets_deg, near_deg, weights, singular_eps)
    if not ok[0]:
        flange = flange_from_tool(T, tool_T)
        _, real = ik_all(model, flange, offsets_deg)
        pos = ", ".join(f"{v:.3f}" for v in T[:3, 3])
        if not real.any():
            why = "outside the workspace of the arm"
        else:
            why = f"all {int(real.sum())} solutions are outside the joint ranges"
        raise UnreachableError(f"pose at ({pos}) mm is unreachable for {model.name}: {why}")
    return np.asarray(sols[ok] if all_solutions else sols[0])


#: Words for the branch bits of ``ik_closed_form``'s index ``4·shoulder + 2·elbow + wrist``.
#: On the TX90 tables elbow "positive" is J3 >= 0 and wrist "positive" J5 >= 0 (with zero
#: offsets), as the controller's configuration names them.
SHOULDER_NAMES = ("front", "back")
ELBOW_NAMES = ("positive", "negative")
WRIST_NAMES = ("positive", "negative")


def configuration_name(index: int) -> str:
    """The arm configuration of solution ``index`` (0…7): "shoulder front, elbow positive,
    wrist negative"."""
    return (
        f"shoulder {SHOULDER_NAMES[index >> 2]}, elbow {ELBOW_NAMES[(index >> 1) & 1]}, "
        f"wrist {WRIST_NAMES[index & 1]}"
    )


@dataclass(frozen=True)
class IkBranch:
    """One of the eight closed-form solutions of a tool pose, offered or not."""

    index: int  # 4·shoulder + 2·elbow + wrist, as ``ik_closed_form``
    configuration: str  # ``configuration_name(index)``
    joints_deg: np.ndarray  # (6,) readings (in-range equivalents if offered); NaN: no solution
    cost: float  # eq. 16 distance to the reference (deg); inf when not offered
    reason: str | None  # why it is not offered; None: every joint inside its range


def ik_branches(
    model: RobotModel,
    target_T: np.ndarray,
    tool_T: np.ndarray | None = None,
    offsets_deg: np.ndarray | None = None,
    near_deg: np.ndarray | None = None,
    weights: np.ndarray | None = None,
    singular_eps: float = SINGULAR_EPS,
) -> list[IkBranch]:
    """All eight solutions for one tool pose ``target_T`` (4, 4), offered ones (inside the
    joint ranges, as ``ik(all_solutions=True)`` returns them) nearest first, then the others,
    each with the reason it is not offered: the branch does not reach the pose (which part of
    the arm cannot), or the joints out of range and by how much (deg). Never raises for an
    unreachable pose."""
    T = np.asarray(target_T, dtype=float)
    if T.shape != (4, 4):
        raise ValueError(f"target_T must be (4, 4), got {T.shape}")
    flange = flange_from_tool(T, tool_T)
    ref = np.zeros(N_JOINTS) if near_deg is None else np.asarray(near_deg, dtype=float)
    raw, real = ik_all(model, flange, offsets_deg, wrist_ref_deg=ref[3], singular_eps=singular_eps)
    sols, ok = select_in_range(model, raw, real, ref)
    cost = np.where(ok, weighted_distance(np.nan_to_num(sols), ref, weights), np.inf)
    unreached = _unreached(ideal_structure(model), flange)
    out = []
    for i in range(N_SOLUTIONS):
        if ok[i]:
            reason, joints = None, sols[i]
        elif real[i]:
            reason, joints = _out_of_range(model, raw[i]), raw[i]
        else:
            reason, joints = (
                unreached[i >> 1]
                or "no such solution: the calibrated table's refinement did not converge",
                raw[i],
            )
        out.append(IkBranch(i, configuration_name(i), joints, float(cost[i]), reason))
    return sorted(out, key=lambda b: b.cost)  # stable: as ``ik_solutions`` orders them


def _unreached(model: RobotModel, flange_T: np.ndarray) -> list[str | None]:
    """Why each arm branch (2·shoulder + elbow) of the closed form does not reach the flange
    pose (None where it does): eqs. 1–9 again, in words and millimetres."""
    d, a = model.d_mm, model.a_mm
    al = np.radians(model.alpha_deg)
    W = flange_T[:3, 3] - flange_T[:3, :3] @ rot_x(-al[5]) @ np.array([a[5], 0.0, d[5]])
    lateral = abs(d[1] + d[2])
    rho = float(np.hypot(W[0], W[1]))
    if rho < lateral * (1.0 - _REACH_TOL):
        inside = (
            f"no such solution: the wrist centre is {rho:.1f} mm from axis 1, inside the "
            f"shoulder's lateral offset {lateral:g} mm"
        )
        return [inside] * 4
    if rho == 0.0:
        return ["no such solution: the wrist centre is on axis 1 (joint 1 is undetermined)"] * 4
    sg1 = np.sin(al[0])
    asn = np.arcsin(np.clip(-sg1 * (d[1] + d[2]) / rho, -1.0, 1.0))
    phi = np.arctan2(W[1], W[0])
    L = np.hypot(a[2], d[3])
    out: list[str | None] = []
    for th1 in (phi - asn, phi - np.pi + asn):
        r = np.cos(th1) * W[0] + np.sin(th1) * W[1] - a[0]
        u = sg1 * (W[2] - d[0])
        reach = float(np.hypot(r, u))
        k = (reach**2 - a[1] ** 2 - L * L) / (2.0 * a[1] * L)
        why: str | None = None
        if k > 1.0 + _REACH_TOL:
            why = (
                f"no such solution: the wrist centre is {reach:.1f} mm from axis 2, beyond the "
                f"stretched arm's {a[1] + L:.1f} mm"
            )
        elif k < -1.0 - _REACH_TOL:
            why = (
                f"no such solution: the wrist centre is {reach:.1f} mm from axis 2, inside the "
                f"folded arm's {abs(a[1] - L):.1f} mm"
            )
        out += [why, why]
    return out


def _out_of_range(model: RobotModel, readings_deg: np.ndarray) -> str:
    """The joints of a real solution that have no reading (±360°) inside their range, each
    with how far its nearest equivalent is outside (deg)."""
    parts = []
    for j in range(N_JOINTS):
        lo, hi = model.joint_min_deg[j], model.joint_max_deg[j]
        cand = readings_deg[j] + np.array([-360.0, 0.0, 360.0])
        beyond = np.maximum(lo - cand, cand - hi)
        best = int(np.argmin(beyond))
        if beyond[best] <= _ANGLE_TOL_DEG:
            continue
        v = cand[best]
        side = f"below its minimum {lo:g}" if v < lo else f"above its maximum {hi:g}"
        parts.append(f"J{j + 1} at {v:.2f} deg is {beyond[best]:.2f} deg {side} deg")
    return "out of range: " + "; ".join(parts)
