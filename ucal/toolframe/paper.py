"""Paper 002's formulation of the tool-frame calibration: constrained least squares by KKT.

Paper 002 (Zhang, Wang, Guo, Sensors 23, 8820, 2023) §3; its equations were images and are
re-derived here.

Frames. ``{B}`` the robot base, ``{E}`` the flange (end effector), ``{T}`` the tool frame,
``{N}`` a frame at the incidence point. With the flange pose ``(R_E, p_E)`` from the
controller (forward kinematics of the joint readings, profile offsets applied) and the tool
frame ``(R_T, p_T)`` relative to the flange::

    (5)  T_BT = T_BE · T_ET
    (6)  T_BN = T_BE · T_ET · ΔL,     ΔL = Trans(0, 0, Δl)

The beam leaves the tool centre ``p_T`` along the tool's z axis ``a_T`` (third column of
``R_T``) and travels the water path ``Δl`` (from the time of flight) to the incidence point::

    (7)  N = p_E + R_E · (Δl · a_T + p_T)
    (8)  |a_T|² = a_Tx² + a_Ty² + a_Tz² = 1

Plane of the reflector through three touched points A, B, C (here: the least-squares plane of
``ucal.toolframe.plane``)::

    (9)  n = (B − A) × (C − A)
    (10) n · (x − A) = 0
    (11) n · (N − A) = 0                              (N lies on the reflector)

With m incidence points, the unknowns ``t = (p_T, a_T)`` (6) solve::

    (12) min f(t) = Σ_i ( n · (N_i(t) − A) )²
    (13) subject to c(t) = |a_T|² − 1 = 0

Substituting (7), each residual is linear in t:
``r_i = g_i · p_T + Δl_i g_i · a_T − y_i`` with ``g_i = R_E,iᵀ n`` and
``y_i = n·A − n·p_E,i``; so ``f = |J t − y|²``, ``J_i = [g_iᵀ, Δl_i g_iᵀ]`` (m × 6).
Lagrange function and first-order (KKT) conditions::

    (14) L(t, λ) = f(t) + λ c(t)
    (15) ∇L = ∇f(t*) + λ* ∇c(t*) = 0,    c(t*) = 0

with ``∇f = 2 Jᵀ(J t − y)``, ``∇c = (0, 2 a_T)``. They are solved by Newton's method on the
seven equations F(t, λ) = 0, whose Jacobian is the KKT matrix::

    [ 2 JᵀJ + 2 λ D    2 D t ] [δt]     [ 2 Jᵀ(J t − y) + 2 λ D t ]
    [ 2 (D t)ᵀ          0    ] [δλ] = − [ tᵀ D t − 1             ],   D = diag(0, 0, 0, 1, 1, 1)

(steps by least squares, so that a singular KKT matrix gives the minimum-norm step). The
second-order sufficient condition (paper 002: "the Hesse matrix ... positive definite") is
checked on the tangent space of the constraint: ``Zᵀ (2 JᵀJ + 2 λ D) Z ≻ 0`` with Z (6 × 5) an
orthonormal basis of the null space of ``∇cᵀ``.

What the data can separate. An echo exists only within ~0.3° of normal incidence (25 MHz,
6 mm), where ``R_E a_T ≈ −n`` and therefore ``g_i ≈ −a_T`` for every point, whatever the
flange orientation: J has rank ≈ 2 and only ``a_T·p_T`` and the beam's alignment are well
determined; the offsets across the beam and the beam's tilt rest on the sub-degree scatter of
the incidence angles. This is why the paper needs ~70 points for stable results (its Fig. 8)
and reports errors of 0.5–4.5 mm and up to 1.2° (its Table 3). ``ucal.toolframe.exact``
measures what this formulation cannot see.

Units: mm, unit vectors; angles in degrees at the interface.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np

from ucal.toolframe.plane import Plane

log = logging.getLogger(__name__)

_D = np.diag([0.0, 0.0, 0.0, 1.0, 1.0, 1.0])


@dataclass(frozen=True)
class PaperSolution:
    """Result of the KKT solution of paper 002, eqs. 12–15."""

    position_mm: np.ndarray  # p_T (3,), flange frame
    beam: np.ndarray  # a_T (3,), unit, flange frame
    multiplier: float  # λ*
    iterations: int
    converged: bool
    second_order_ok: bool  # reduced Hessian positive definite
    reduced_hessian_eig: np.ndarray  # (5,) eigenvalues of Zᵀ ∇²L Z (mm⁻⁰, relative units)
    rms_residual_mm: float  # rms of n·(N_i − A)
    std_position_mm: np.ndarray  # (3,) one-sigma from the Jacobian and the residual scatter
    std_beam_deg: float  # one-sigma of the beam direction per tilt axis
    condition: float  # condition number of Zᵀ JᵀJ Z
    notes: list[str] = field(default_factory=list)


def design(
    flange_rot: np.ndarray, flange_pos_mm: np.ndarray, paths_mm: np.ndarray, plane: Plane
) -> tuple[np.ndarray, np.ndarray]:
    """J (m, 6) and y (m,) of the residuals ``r = J t − y`` (paper 002, eqs. 7, 11, 12)."""
    g = np.einsum("mji,j->mi", np.asarray(flange_rot, float), plane.normal)  # R_Eᵀ n
    paths = np.asarray(paths_mm, float)
    jac = np.concatenate([g, paths[:, None] * g], axis=1)
    y = plane.offset_mm - np.asarray(flange_pos_mm, float) @ plane.normal
    return jac, y


def residuals_mm(
    t: np.ndarray,
    flange_rot: np.ndarray,
    flange_pos_mm: np.ndarray,
    paths_mm: np.ndarray,
    plane: Plane,
) -> np.ndarray:
    """``n·(N_i − A)`` (mm) for ``t = (p_T, a_T)`` (paper 002, eqs. 7 and 11)."""
    jac, y = design(flange_rot, flange_pos_mm, paths_mm, plane)
    return np.asarray(jac @ np.asarray(t, float) - y)


def _null_basis(v: np.ndarray) -> np.ndarray:
    """Orthonormal basis (6, 5) of the vectors orthogonal to v (6,)."""
    _, _, vt = np.linalg.svd(v[None, :])
    return vt[1:].T


def solve_paper(
    flange_rot: np.ndarray,
    flange_pos_mm: np.ndarray,
    paths_mm: np.ndarray,
    plane: Plane,
    position0_mm: np.ndarray,
    beam0: np.ndarray,
    path_std_mm: float | None = None,
    max_iter: int = 50,
    tol: float = 1e-8,
) -> PaperSolution:
    """Solve paper 002, eqs. 12–13 by Newton's method on the KKT conditions (eq. 15).

    ``flange_rot`` (m, 3, 3) and ``flange_pos_mm`` (m, 3): flange poses at the incidence
    points; ``paths_mm`` (m,): water paths Δl_i; ``position0_mm``, ``beam0``: the starting tool
    (the profile's nominal). ``path_std_mm``: one-sigma of a water path, used for the standard
    deviations when there are too few points to estimate it from the residuals. Converged
    when a Newton step moves no parameter by more than ``tol`` relative to the largest (the
    KKT matrix of near-normal data is ill-conditioned, so steps stall at ~1e-9 of rounding).
    """
    jac, y = design(flange_rot, flange_pos_mm, paths_mm, plane)
    m = len(y)
    a0 = np.asarray(beam0, float)
    t = np.concatenate([np.asarray(position0_mm, float), a0 / np.linalg.norm(a0)])
    jtj, jty = jac.T @ jac, jac.T @ y
    # initial multiplier: least-squares fit of ∇f + λ∇c = 0
    grad = 2.0 * (jtj @ t - jty)
    dc = 2.0 * _D @ t
    lam = float(-(dc @ grad) / (dc @ dc))
    converged = False
    it = 0
    for it in range(1, max_iter + 1):  # noqa: B007 (reported after the loop)
        dt_ = _D @ t
        f_vec = np.concatenate([2.0 * (jtj @ t - jty) + 2.0 * lam * dt_, [t @ dt_ - 1.0]])
        kkt = np.zeros((7, 7))
        kkt[:6, :6] = 2.0 * jtj + 2.0 * lam * _D
        kkt[:6, 6] = 2.0 * dt_
        kkt[6, :6] = 2.0 * dt_
        step = np.linalg.lstsq(kkt, -f_vec, rcond=None)[0]
        t = t + step[:6]
        lam = lam + float(step[6])
        if np.max(np.abs(step[:6])) < tol * max(1.0, float(np.max(np.abs(t)))):
            converged = True
            break
    # second-order sufficient condition on the constraint's tangent space
    z = _null_basis(2.0 * _D @ t)
    h_red = z.T @ (2.0 * jtj + 2.0 * lam * _D) @ z
    eig = np.linalg.eigvalsh(0.5 * (h_red + h_red.T))
    scale = max(float(np.max(np.abs(eig))), 1e-300)
    second_order_ok = bool(eig[0] > 1e-10 * scale)
    r = jac @ t - y
    rms = float(np.sqrt(np.mean(r**2)))
    dof = m - 5
    if dof > 0:
        sigma = float(np.sqrt(r @ r / dof))
        if path_std_mm is not None:
            sigma = max(sigma, path_std_mm)
    else:
        sigma = path_std_mm if path_std_mm is not None else float("nan")
    jz = z.T @ jtj @ z
    ev = np.linalg.eigvalsh(0.5 * (jz + jz.T))
    condition = float(ev[-1] / ev[0]) if ev[0] > 0 else float("inf")
    cov = z @ np.linalg.pinv(jz, rcond=1e-15) @ z.T * sigma**2
    std_p = np.sqrt(np.maximum(np.diag(cov)[:3], 0.0))
    a = t[3:] / np.linalg.norm(t[3:])
    # beam tilt one-sigma: rms of the two components of cov(a) across a
    proj = np.eye(3) - np.outer(a, a)
    cov_a = proj @ cov[3:, 3:] @ proj
    std_beam = float(np.degrees(np.sqrt(max(np.trace(cov_a), 0.0) / 2.0)))
    notes = []
    if not second_order_ok:
        notes.append(
            "second-order condition fails: the reduced Hessian of the Lagrange "
            f"function is not positive definite (smallest eigenvalue {eig[0]:.3g}); "
            "the points do not determine every tool parameter"
        )
    if condition > 1e8:
        notes.append(
            f"ill-conditioned (condition number {condition:.3g}): at normal incidence "
            "the distances to a flat plate see only a_T·p_T; the offsets across the "
            "beam rest on the scatter of the incidence angles"
        )
    log.info(
        "paper 002 KKT: %d iterations, λ %.4g, rms %.4g mm, cond %.3g", it, lam, rms, condition
    )
    return PaperSolution(
        t[:3].copy(),
        a,
        lam,
        it,
        converged,
        second_order_ok,
        eig,
        rms,
        std_p,
        std_beam,
        condition,
        notes,
    )
