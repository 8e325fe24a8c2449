"""What the calibration cannot see, in millimetres at the tool centre over the scanning region.

An echo at normal incidence measures the beam's direction and the water path along it; some of
the cell's quantities move the tool centre in ways neither shows (row 5's ``d`` and ``a`` shift
the flange across the beam; the tool's offset along the beam and a constant delay shift every
water path alike). The fit keeps each of them at its prior (the profile's tolerance), or holds
it at its nominal value (the full level's redundant parameters), and the offsets it writes are
right only up to what those priors allow. This module says how much that is where it matters:
the tool centre over the scanning region about the calibration pose
(``ucal.model.kinematic.scanning_postures``), in the block's frame (the base frame's yaw and
height are gauges of the cell; a scan is made relative to the part).

Derivation. Let ``A`` be the Jacobian of the fit's augmented residuals at the solution
(``CellFit.jac``: the measurement rows, then one prior row ``(x_p − x̄_p)/σ_p`` per unknown),
``N = AᵀA``. A small error ``ε`` in the rows moves the estimate by ``δx = −N⁻¹Aᵀε``; a prior
that is off by one sigma is ``ε = e_p`` on its own row, so the estimate moves by
``δx_p = −N⁻¹ Aᵀ e_p = −N⁻¹ a_pᵀ``, ``a_p`` the prior row (``1/σ_p`` in column ``p``). The
tool centre at posture ``q`` in the block frame, ``f(x, q) = R_S(x)ᵀ (p_tcp(x, q) − c(x))``,
moves by ``G δx_p`` with ``G = ∂f/∂x``. The priors' errors are independent, so their
contributions add in variance: ``Σ_f(q) = Σ_p (G N⁻¹ a_pᵀ)(G N⁻¹ a_pᵀ)ᵀ``; the measurement
rows' share is the noise that the offsets' stds already state and is not part of it.

A quantity held at its nominal value (not an unknown of the fit) with a tolerance ``σ_h`` is a
"consider" parameter: one sigma of it changes the data rows by ``σ_h·∂r/∂h``; the fit absorbs
what it can, ``δx_h = −N⁻¹ Aᵀ (σ_h ∂r/∂h)``, and the tool centre moves by
``σ_h (∂f/∂h + G δx_h/σ_h)`` — zero for a gauge the fit takes up entirely (the base frame's
height, the block's yaw against J1), the full effect for one nothing sees.

All derivatives are central differences of the same forward kinematics the fit uses. The
covariance is scaled like the fit's (``max(1, χ²ᵣ)``). Reported: per posture the one-sigma
magnitude ``√tr Σ_f``, its mean and maximum over the region, and each quantity's largest
one-sigma displacement.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ucal.cell import CellProfile
from ucal.kinematics.dh import RobotModel
from ucal.model.fit import (
    OFFSETS,
    SOUND,
    CellFit,
    ExtraRows,
    data_residuals,
    prior_from_profile,
    table_geometry,
)
from ucal.model.geometry import FaceMeasurement, beam_and_tcp
from ucal.model.kinematic import KINEMATIC, STEP, scanning_postures, step_residuals
from ucal.model.load import COMPLIANCE, URAD_DEG, PostureLoad
from ucal.model.targets import calibration_pose

#: The quantities no echo may see well enough: the kinematic model's lengths and twists, and
#: the sound speed (with the lengths, one common scale that time of flight does not show).
#: Link 6 is left to the tool: they are one rigid body, and tool-frame measures the tool with
#: it (its stds are the tool's).
UNSEEN = tuple(n for n in KINEMATIC if not n.startswith("dh6_")) + SOUND + STEP + COMPLIANCE
#: Postures drawn over the scanning region, and their seed (the same region every run).
REGION_POSTURES = 100
REGION_SEED = 0
#: A quantity whose largest one-sigma displacement is below this (mm) is not listed.
LISTED_ABOVE_MM = 5e-4
#: Relative step of the central differences (of a prior σ, or of 1 where there is none).
_STEP = 1e-3


@dataclass(frozen=True)
class TcpBudget:
    """The one-sigma tool-centre error over the scanning region that the priors allow (mm)."""

    mean_mm: float
    max_mm: float
    postures: int
    #: Each quantity's largest one-sigma displacement over the region (mm), largest first.
    by_quantity: dict[str, float]

    def to_json(self) -> dict[str, object]:
        return {
            "mean": self.mean_mm,
            "max": self.max_mm,
            "postures": self.postures,
            "by_quantity": dict(self.by_quantity),
        }


def _tcp(
    fit: CellFit,
    model: RobotModel,
    values: np.ndarray,
    q: np.ndarray,
    load_nm: np.ndarray | None = None,
) -> np.ndarray:
    """The tool centre at readings ``q`` (n, 6) in the base frame (n, 3), cell ``values``;
    each joint given by its compliance under ``load_nm`` (n, 6: the postures' torques less the
    load posture's, ``ucal.model.load``) where the fit has the compliances."""
    table = fit.table
    if load_nm is not None and COMPLIANCE[0] in table.names:
        q = q + load_nm * (URAD_DEG * table.get(COMPLIANCE, values))
    _, tcp = beam_and_tcp(table_geometry(table, values, model), q, table.get(OFFSETS, values))
    return tcp


def _without_rigid_motion(points_mm: np.ndarray) -> np.ndarray:
    """The projector (3n, 3n) that takes a small displacement of ``points_mm`` (n, 3), raveled,
    to what is left after the rigid motion that best explains it (``ω × p + t``)."""
    p = points_mm - points_mm.mean(axis=0)
    n = len(p)
    b = np.zeros((n, 3, 6))
    b[:, :, 3:] = np.eye(3)
    # ω × p = −[p]× ω
    b[:, 0, 1], b[:, 0, 2] = p[:, 2], -p[:, 1]
    b[:, 1, 0], b[:, 1, 2] = -p[:, 2], p[:, 0]
    b[:, 2, 0], b[:, 2, 1] = p[:, 1], -p[:, 0]
    flat = b.reshape(3 * n, 6)
    return np.eye(3 * n) - flat @ np.linalg.pinv(flat)


def _step(fit: CellFit, i: int) -> float:
    s = fit.table.prior_stds[i]
    return _STEP * (float(s) if np.isfinite(s) and s > 0 else 1.0)


def tcp_budget(
    fit: CellFit,
    model: RobotModel,
    meas: list[FaceMeasurement],
    c0_m_s: float,
    pose_deg: np.ndarray,
    extra: ExtraRows | None = None,
    postures: int = REGION_POSTURES,
    quantities: tuple[str, ...] = UNSEEN,
    load: PostureLoad | None = None,
) -> TcpBudget:
    """The tool-centre error over the scanning region about ``pose_deg`` that the priors and
    tolerances of ``quantities`` allow, fitted or held (module docstring). ``meas`` and
    ``extra``: the data rows of ``fit`` (its Jacobian's first ``fit.n_data`` rows), ``c0_m_s``
    the sound speed their water paths were computed with; ``load``: the torques' reference of
    the fit's rows (``CellPrior.posture_load``), under which the region's postures give."""
    if fit.jac is None:
        raise ValueError("the fit kept no Jacobian")
    table, v0 = fit.table, fit.estimate
    q = scanning_postures(pose_deg, postures, REGION_SEED, model)
    load_nm = None if load is None else load.relative_nm(q)
    project = _without_rigid_motion(_tcp(fit, model, v0, q, load_nm))
    free = np.flatnonzero(table.free)
    a = np.asarray(fit.jac, float)
    n_inv = np.linalg.pinv(a.T @ a)
    scale = np.sqrt(max(1.0, fit.quality.chi2_reduced))

    def along(i: int, direction: np.ndarray) -> np.ndarray:
        """Central difference of the tool centres along unknown ``i`` plus ``direction`` (the
        fit's answer, over the free unknowns), per unit of ``i``; rigid motion taken out."""
        h = _step(fit, i)
        d = np.zeros(len(v0))
        d[i] = 1.0
        d[free] += direction
        diff = _tcp(fit, model, v0 + h * d, q, load_nm) - _tcp(fit, model, v0 - h * d, q, load_nm)
        return np.asarray(project @ diff.ravel() / (2.0 * h))

    def data_rows(values: np.ndarray) -> np.ndarray:
        rows = (
            data_residuals(table, values, model, meas, c0_m_s, load=load).ravel()
            if meas
            else np.zeros(0)
        )
        return rows if extra is None else np.concatenate([rows, extra.residuals(values)])

    contrib: dict[str, np.ndarray] = {}
    for name in quantities:
        if name not in table.names:
            continue
        i = table.index(name)
        sigma = table.prior_stds[i]
        if not (np.isfinite(sigma) and sigma > 0):
            continue  # known exactly
        if table.free[i]:
            # one sigma of its prior row: δx = −N⁻¹ a_pᵀ, a_p = e_p/σ_p (``along`` adds e_p)
            k = int(np.searchsorted(free, i))
            contrib[name] = scale * along(i, -n_inv[:, k] / sigma - _unit(k, len(free)))
        else:
            h = _step(fit, i)
            e = np.zeros(len(v0))
            e[i] = h
            dr = (data_rows(v0 + e) - data_rows(v0 - e)) / (2.0 * h)  # ∂r/∂h, data rows
            rows = np.zeros(a.shape[0])
            rows[: len(dr)] = dr
            contrib[name] = sigma * along(i, -n_inv @ (a.T @ rows))

    per = {k: np.linalg.norm(c.reshape(-1, 3), axis=1) for k, c in contrib.items()}
    total = np.sqrt(sum((p**2 for p in per.values()), np.zeros(len(q))))
    listed = {k: float(p.max()) for k, p in per.items() if p.max() > LISTED_ABOVE_MM}
    return TcpBudget(
        float(total.mean()),
        float(total.max()),
        len(q),
        dict(sorted(listed.items(), key=lambda kv: -kv[1])),
    )


def _unit(k: int, n: int) -> np.ndarray:
    e = np.zeros(n)
    e[k] = 1.0
    return e


def calibration_budget(
    profile: CellProfile,
    fit: CellFit | None,
    meas: list[FaceMeasurement],
    steps: list[FaceMeasurement] | None = None,
) -> TcpBudget | None:
    """``tcp_budget`` of a calibration's fit over the scanning region about its calibration
    pose, the water paths over the step (the full level's length standard) among its data
    rows; None without a fit (the paper's method)."""
    if fit is None or fit.jac is None:
        return None
    prior = prior_from_profile(profile)
    c0 = prior.sound_speed_m_s
    load = prior.posture_load(meas)
    extra = None
    if steps:
        table = fit.table
        extra = ExtraRows(
            lambda v: step_residuals(table, v, prior.model, steps, c0, load=load),
            tuple(f"{m.config}/step" for m in steps),
        )
    return tcp_budget(fit, prior.model, meas, c0, calibration_pose(profile), extra, load=load)
