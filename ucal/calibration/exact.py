"""Exact joint-offset solution: nonlinear least squares over the full forward kinematics.

``solve_exact_with_priors`` is the solver ``ucal calibrate`` uses: it carries the block pose,
the tool frame and the sound speed as unknowns with the profile's tolerances as priors
(``ucal.model.fit``) and reports honest standard deviations, the fit quality and why a
joint is unobservable. ``solve_exact`` below is the previous, offsets-only solver (block
orientation, tool and sound speed taken as exact); it is kept for the comparison in
``benchmarks/realistic.py`` and for predicting postures during a run.

Previous solver. Unknowns: the six joint offsets δ (deg) and the block corner c (mm, base frame;
the block's orientation is taken as known, its position is not). Every face measurement contributes
(see ``ucal.model.geometry``):

    r_tilt = tilt_components(b(q+δ)) / σ_tilt            two residuals, eq. (1)
    r_dist = (n_k·(p(q+δ) − c) − d) / σ_d                  one residual, eq. (2)

No Taylor expansion is made, so finite joint steps cause no bias (the first-order method of
paper 000 assigns the chord direction of a δθ3 step, i.e. θ2+θ3 at the middle of the step, to
its start: a bias of half the step). The block corner absorbs the tool's offset along the beam
and any constant delay of the time-of-flight reading.

Observability: the weighted Jacobian J (columns scaled to unit norm) is decomposed by SVD;
a right singular vector with a singular value below ``rank_tol``·s_max is a direction the data
cannot see. Joints that carry weight in such a direction, or whose standard deviation exceeds
``max_std_deg``, are reported unobservable, held at their profile values and the problem is
solved again without them. Example: with the beam on the joint-6 axis, θ6 never changes the
beam direction nor the distance, so its column of J is zero.

Beam direction: the tool's beam direction in the flange frame, a_T, can be fitted too (two
more unknowns: a tilt of the nominal beam). Its tilt magnitude is seen by the data; its azimuth
about the joint-6 axis trades off with θ6. So ``beam="auto"`` fits it when the nominal beam lies
on the joint-6 axis (θ6 is unobservable anyway, and an unmodelled tool tilt would bias θ4, θ5)
and keeps it fixed for a deliberately angled tool (which makes θ6 observable).

Uncertainty: Cov = (JᵀJ)⁻¹ of the weighted problem (the weights come from the measured TOF and
posture repeatability), scaled by the reduced χ² when that exceeds one.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares

from ucal.model.fit import (
    MAX_STD_DEG,
    CellFit,
    CellPrior,
    FitQuality,
    solve_cell,
)
from ucal.model.gauge import BLOCK_YAW, J1Gauge, gauged_offsets
from ucal.model.geometry import (
    CellGeometry,
    FaceMeasurement,
    beam_and_tcp,
    beam_on_axis,
    distance_joints,
    tilt_components,
)


@dataclass(frozen=True)
class OffsetSolution:
    """Result of a solver: offsets (deg), their standard deviations (NaN = unobservable)."""

    offsets_deg: np.ndarray
    std_deg: np.ndarray
    unobservable_joints: tuple[int, ...]  # 1-based
    condition_number: float
    method: str
    corner_mm: np.ndarray | None = None
    rms_tilt_deg: float = float("nan")
    rms_distance_mm: float = float("nan")
    chi2_reduced: float = float("nan")  # of the solver's own fit
    fit: FitQuality | None = None
    sound_speed_m_s: float = float("nan")
    sound_speed_std_m_s: float = float("nan")
    #: 1-based joint → why it is unobservable (the data do not see it, or which tolerance it
    #: cannot be separated from).
    unobservable_reasons: dict[int, str] = field(default_factory=dict)
    #: The fit with the cell's tolerances as priors (``solve_exact_with_priors``): values,
    #: stds and each unknown's variance shares.
    cell_fit: CellFit | None = None
    #: The beam direction in the flange frame the solver used, and whether it fitted it
    #: (``solve_exact``).
    beam_flange: np.ndarray | None = None
    beam_fitted: bool = False
    #: The paper method's first-order truncation error and its noise std per joint (deg).
    truncation_deg: np.ndarray | None = None
    noise_std_deg: np.ndarray | None = None
    #: One sigma relative to the block as placed (``ucal.model.gauge``; J1's without the
    #: block's yaw tolerance), and how J1 is known; None for the previous solver.
    std_block_deg: np.ndarray | None = None
    gauge: J1Gauge | None = None


def solve_exact_with_priors(
    prior: CellPrior,
    meas: list[FaceMeasurement],
    max_std_deg: float = MAX_STD_DEG,
    fixed: tuple[str, ...] = (),
) -> OffsetSolution:
    """Offsets with the cell's uncertain quantities as prior-constrained unknowns, in the
    block gauge (``ucal.model.gauge``: the block's yaw held as placed, J1 relative to it).

    A joint whose std exceeds ``max_std_deg`` while less than half of its variance comes from
    the measurements is reported unobservable (profile value kept) with the prior that
    dominates it as the reason; a joint whose large std comes from the data stays observable
    (the caller judges it out of tolerance).
    """
    cell = solve_cell(prior, meas, fixed=fixed + (BLOCK_YAW,), max_std_deg=max_std_deg)
    gauged = gauged_offsets(
        cell, prior.offsets_deg, float(prior.block_rotation_std_deg[2]), max_std_deg
    )
    return OffsetSolution(
        offsets_deg=gauged.offsets_deg,
        std_deg=gauged.std_deg,
        unobservable_joints=tuple(sorted(gauged.reasons)),
        condition_number=cell.condition_number,
        method="exact",
        corner_mm=np.array([cell.value(n) for n in ("block_x_mm", "block_y_mm", "block_z_mm")]),
        rms_tilt_deg=cell.quality.rms_tilt_deg,
        rms_distance_mm=cell.quality.rms_distance_mm,
        chi2_reduced=cell.quality.chi2_reduced,
        fit=cell.quality,
        sound_speed_m_s=cell.value("sound_speed_m_s"),
        sound_speed_std_m_s=cell.sigma("sound_speed_m_s"),
        unobservable_reasons=gauged.reasons,
        cell_fit=cell,
        std_block_deg=gauged.std_block_deg,
        gauge=gauged.gauge,
    )


def _initial_corner(
    geom: CellGeometry, meas: list[FaceMeasurement], offsets_deg: np.ndarray
) -> np.ndarray:
    """Corner estimate from eq. (2): n_k·c = n_k·p − d, averaged per face."""
    coord = np.zeros(3)
    for k in range(3):
        vals = [
            geom.normal(k) @ beam_and_tcp(geom, distance_joints(m), offsets_deg)[1] - m.distance_mm
            for m in meas
            if m.face == k
        ]
        coord[k] = np.mean(vals) if vals else 0.0
    return geom.block_rotation @ coord


def tilted_beam(geom: CellGeometry, tilt_rad: np.ndarray | None) -> np.ndarray:
    """Nominal beam (flange frame) tilted by two small components (rad) across it."""
    a = geom.beam_flange
    if tilt_rad is None:
        return a
    e1 = np.cross(a, [1.0, 0.0, 0.0] if abs(a[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(a, e1)
    v = a + tilt_rad[0] * e1 + tilt_rad[1] * e2
    return np.asarray(v / np.linalg.norm(v))


def residuals(
    geom: CellGeometry,
    meas: list[FaceMeasurement],
    offsets_deg: np.ndarray,
    corner_mm: np.ndarray,
    beam_flange: np.ndarray | None = None,
) -> np.ndarray:
    """Weighted residual vector (3 per measurement)."""
    q = np.array([m.joints_deg for m in meas])
    beam, _ = beam_and_tcp(geom, q, offsets_deg, beam_flange)
    _, tcp = beam_and_tcp(geom, np.array([distance_joints(m) for m in meas]), offsets_deg)
    out = np.empty((len(meas), 3))
    for i, m in enumerate(meas):
        out[i, :2] = tilt_components(geom, beam[i], m.face) / np.radians(m.tilt_std_deg)
        n = geom.normal(m.face)
        out[i, 2] = (n @ (tcp[i] - corner_mm) - m.distance_mm) / m.distance_std_mm
    return out.ravel()


def solve_exact(
    geom: CellGeometry,
    meas: list[FaceMeasurement],
    prior_offsets_deg: np.ndarray,
    rank_tol: float = 1e-6,
    max_std_deg: float = 0.5,
    beam: str = "auto",
) -> OffsetSolution:
    """Joint offsets from face measurements by nonlinear least squares (see module docstring).

    ``beam``: "fixed" (the profile's tool), "fit" (fit the beam direction too) or "auto".
    """
    prior = np.asarray(prior_offsets_deg, float)
    fit_beam = beam == "fit" or (beam == "auto" and beam_on_axis(geom))
    free = list(range(6))
    while True:
        x, jac, res = _fit(geom, meas, prior, free, fit_beam)
        js = jac / np.maximum(np.linalg.norm(jac, axis=0), 1e-300)
        _, s, vt = np.linalg.svd(js, full_matrices=False)
        weak = set()
        for sv, v in zip(s, vt, strict=True):
            if sv < rank_tol * s[0]:
                # One joint per null direction: the one it moves most. Several joints can share
                # a direction (e.g. θ5, θ6 and the beam azimuth); fixing the main one may free
                # the rest.
                i = int(np.argmax(np.abs(v[: len(free)])))
                if abs(v[i]) > 0.2:
                    weak.add(free[i])
                break
        cov, scale = _covariance(jac, res)
        std_free = np.sqrt(np.clip(np.diag(cov)[: len(free)], 0, None)) * scale
        if not weak:
            weak = {
                j
                for i, j in enumerate(free)
                if not np.isfinite(std_free[i]) or std_free[i] > max_std_deg
            }
        if not weak:
            break
        free = [j for j in free if j not in weak]
        if not free:
            break
    offsets = prior.copy()
    std = np.full(6, np.nan)
    for i, j in enumerate(free):
        offsets[j] = x[i]
        std[j] = std_free[i]
    corner = x[len(free) : len(free) + 3]
    beam_vec = tilted_beam(geom, x[len(free) + 3 :] if fit_beam else None)
    r = residuals(geom, meas, offsets, corner, beam_vec).reshape(-1, 3)
    tilt_rms = float(
        np.sqrt(np.mean([(r[i, :2] * np.radians(m.tilt_std_deg)) ** 2 for i, m in enumerate(meas)]))
    )
    dist_rms = float(
        np.sqrt(np.mean([(r[i, 2] * m.distance_std_mm) ** 2 for i, m in enumerate(meas)]))
    )
    return OffsetSolution(
        offsets_deg=offsets,
        std_deg=std,
        unobservable_joints=tuple(sorted(j + 1 for j in range(6) if j not in free)),
        condition_number=float(s[0] / s[-1]) if s[-1] > 0 else float("inf"),
        method="exact",
        corner_mm=corner,
        rms_tilt_deg=float(np.degrees(tilt_rms)),
        rms_distance_mm=dist_rms,
        chi2_reduced=float(res @ res / max(1, len(res) - len(x))),
        beam_flange=beam_vec,
        beam_fitted=fit_beam,
    )


def _fit(
    geom: CellGeometry,
    meas: list[FaceMeasurement],
    prior: np.ndarray,
    free: list[int],
    fit_beam: bool = False,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    n = len(free)

    def fun(x: np.ndarray) -> np.ndarray:
        off = prior.copy()
        off[free] = x[:n]
        beam_vec = tilted_beam(geom, x[n + 3 : n + 5]) if fit_beam else None
        return residuals(geom, meas, off, x[n : n + 3], beam_vec)

    x0 = np.concatenate(
        [prior[free], _initial_corner(geom, meas, prior), np.zeros(2) if fit_beam else np.zeros(0)]
    )
    scale = np.concatenate([np.full(n, 1.0), np.full(3, 10.0), np.full(2 if fit_beam else 0, 0.01)])
    sol = least_squares(
        fun, x0, method="lm", xtol=1e-15, ftol=1e-15, gtol=1e-15, x_scale=scale, max_nfev=4000
    )
    jac = _jacobian(fun, sol.x)
    return sol.x, jac, fun(sol.x)


def _jacobian(
    fun: Callable[[np.ndarray], np.ndarray], x: np.ndarray, h: float = 1e-6
) -> np.ndarray:
    """Central-difference Jacobian (more accurate than the solver's forward one)."""
    cols = []
    for i in range(len(x)):
        dx = np.zeros_like(x)
        dx[i] = h
        cols.append((fun(x + dx) - fun(x - dx)) / (2 * h))
    return np.array(cols).T


def _covariance(jac: np.ndarray, res: np.ndarray) -> tuple[np.ndarray, float]:
    dof = max(1, len(res) - jac.shape[1])
    chi2 = float(res @ res) / dof
    cov = np.linalg.pinv(jac.T @ jac)
    return cov, float(np.sqrt(max(1.0, chi2)))
