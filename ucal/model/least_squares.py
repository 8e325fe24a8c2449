"""The prior-augmented least squares of the calibration solvers and the covariance of their
unknowns (``ucal.model.fit``'s docstring has the model): ``solve_cell`` over face
measurements, ``solve_augmented`` over any rows, and what a fit found of the tank's drift and
the arm's lost motion (``RunEffects``).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Any, Protocol

import numpy as np
from scipy.optimize import OptimizeResult, least_squares

from ucal import interrupt
from ucal.model.geometry import FaceMeasurement, beam_and_tcp, distance_joints
from ucal.model.load import COMPLIANCE, unseen_compliance
from ucal.model.priors import (
    BACKLASH,
    BETA,
    BLOCK,
    DRIFT,
    OFFSETS,
    PARAMETERS,
    SOUND,
    CellPrior,
    ParameterTable,
    twists_deg,
)
from ucal.model.quality import MISFIT_P, FitQuality, fit_quality, verdict
from ucal.model.residuals import (
    MeasurementArrays,
    Reading,
    cell_geometry,
    data_residuals,
    reference_time_min,
    two_sided_joints,
)

#: A joint whose std exceeds this and comes mainly from a prior is reported unobservable.
MAX_STD_DEG = 0.02
#: Evaluations of the residuals a fit may spend (the offsets level's converges in tens).
MAX_EVALUATIONS = 200


def hold_unseen(table: ParameterTable, meas: Sequence[Reading]) -> None:
    """Hold at their priors (``table.free``) the unknowns no row of ``meas`` sees: the sound
    speed's drift unless two readings carry different times, and each joint's lost motion
    unless readings approach that joint from both sides.

    A one-sided joint's lost motion is a gauge, not an unknown. The offsets are those of the
    positive approach (the link at reading + offset when reached from below; from above it
    lags by the whole lost motion b, ``ucal.model.residuals.MeasurementArrays.lag``):
    readings all from below do not see b at all, readings all from above see only offset + b,
    one quantity. Left free with its prior, b would then add its tolerance to that offset's
    std for nothing the data could tell apart; held at 0, the offsets are those of the
    approach the readings had, with the std the data give them.
    """
    if DRIFT[0] in table.names and not sees_drift(meas):
        table.free[table.index(DRIFT[0])] = False
    if BACKLASH[0] in table.names:
        for name, seen in zip(BACKLASH, two_sided_joints(meas), strict=True):
            if not seen:
                table.free[table.index(name)] = False


def sees_drift(meas: Sequence[Reading]) -> bool:
    """Whether ``meas`` see the sound speed's drift: two readings at different times."""
    return len({m.time_min for m in meas if m.time_min is not None}) >= 2


@dataclass(frozen=True)
class ExtraRows:
    """Data rows of another kind of measurement, after the face measurements' (``solve_cell``):
    ``residuals`` maps the full value vector to one normalised row per label."""

    residuals: Callable[[np.ndarray], np.ndarray]
    labels: tuple[str, ...]


@dataclass(frozen=True)
class CellFit:
    """Solution of the prior-augmented problem."""

    table: ParameterTable
    estimate: np.ndarray  # full parameter vector
    cov: np.ndarray  # (n_free, n_free), marginal over the nuisance unknowns
    std: np.ndarray  # full vector, NaN for fixed parameters
    quality: FitQuality
    variance_share: dict[str, dict[str, float]]  # joint → {source: share of its variance}
    condition_number: float
    jac: np.ndarray | None = None  # Jacobian of the augmented residuals at the solution
    n_data: int = 0  # its first n_data rows are the measurements'
    time_ref_min: float = 0.0  # the time the sound speed is given at (``reference_time_min``)
    #: The readings whose gravity load the offsets hold (``ucal.model.load``); None: nothing
    #: weighs.
    load_posture_deg: np.ndarray | None = None

    def value(self, name: str) -> float:
        return float(self.estimate[self.table.index(name)])

    def sigma(self, name: str) -> float:
        return float(self.std[self.table.index(name)])


def _least_squares_with_priors(
    fun: Callable[[np.ndarray], np.ndarray],
    x0: np.ndarray,
    table: ParameterTable,
    tol: float,
    max_nfev: int,
) -> OptimizeResult:
    """``least_squares`` over ``table``'s free parameters, each scaled by its prior σ (at most
    1): its own forward-difference Jacobian, trust region, ``tol`` on every criterion."""
    x_scale = np.where(np.isfinite(table.prior_stds), np.minimum(table.prior_stds, 1.0), 1.0)

    def checked(x: np.ndarray) -> np.ndarray:
        # a signal whose KeyboardInterrupt was swallowed where it struck (an import's callback)
        # ends a fit of seconds at its next evaluation, not at the run's next step
        interrupt.check()
        return fun(x)

    return least_squares(
        checked,
        x0,
        jac="2-point",
        method="trf",
        x_scale=x_scale[table.free],
        xtol=tol,
        ftol=tol,
        gtol=tol,
        max_nfev=max_nfev,
    )


def cell_table(prior: CellPrior) -> ParameterTable:
    """``PARAMETERS`` and Hayati's twist ``β₂`` of the nearly parallel axes 2 and 3, with the
    profile's values and tolerances (β₂'s is the DH angle one, or what a full level identified).

    β₂ is carried at every level, as every DH quantity that moves the postures is: on a real
    arm it is as large as the tolerance of the other twists, and the offsets level that did not
    carry it wrote J1 relative to the block 0.030° off at a reported 0.0036° (8σ) on a TX90L
    whose β₂ was 1.35 times the angle tolerance (``tests/system/test_offsets_level_twist.py``)."""
    return ParameterTable(
        PARAMETERS + BETA + COMPLIANCE,
        np.concatenate(
            [prior.values(), [twists_deg(prior.model)[1]], prior.compliance_urad_per_nm]
        ),
        np.concatenate([prior.stds(), [prior.dh_stds()[1, 3]], prior.compliance_std_urad_per_nm]),
    )


class Loaded(Protocol):
    """Readings' gravity torques less the load posture's (N·m, (n, 6); ``ucal.model.load``)."""

    @property
    def load_nm(self) -> np.ndarray: ...


def hold_unloaded(table: ParameterTable, *arrays: Loaded) -> None:
    """Hold at their priors the compliances the readings' torques (of every one of
    ``arrays``) do not see (``ucal.model.load.unseen_compliance``): J1 about a vertical axis,
    or every joint where nothing weighs."""
    if COMPLIANCE[0] not in table.names:
        return
    idx = np.array([table.index(n) for n in COMPLIANCE])
    torques = np.vstack([a.load_nm for a in arrays])
    table.free[idx[unseen_compliance(torques, table.prior_stds[idx])]] = False


def solve_cell(
    prior: CellPrior,
    meas: list[FaceMeasurement],
    fixed: tuple[str, ...] = (),
    max_std_deg: float = MAX_STD_DEG,
    misfit_p: float = MISFIT_P,
    start: np.ndarray | None = None,
    tol: float = 1e-12,
    table: ParameterTable | None = None,
    extra: ExtraRows | None = None,
    max_evaluations: int = MAX_EVALUATIONS,
) -> CellFit:
    """Fit offsets, block, tool, sound speed and DH table to ``meas`` with the priors (module
    docstring).

    ``fixed`` names parameters held at their prior values (e.g. the DH table while predicting
    postures during a run); ``start`` is a full parameter vector to start from (a previous
    estimate), ``tol`` the solver's tolerances; ``table`` the unknowns if not ``PARAMETERS``
    with the prior's values and tolerances (``ucal.model.kinematic`` adds Hayati's twist);
    ``extra`` the rows of other measurements (``ucal.model.kinematic``'s edge crossings);
    ``max_evaluations`` of the residuals at most (the trust region stops there, converged or
    not).
    The sound speed's drift and each joint's lost motion are held where no reading sees them
    (``hold_unseen``).
    """
    if table is None:
        table = cell_table(prior)
    for name in fixed:
        table.free[table.index(name)] = False
    hold_unseen(table, meas)
    table.free &= table.prior_stds > 0  # a zero tolerance means "known exactly"
    c0 = prior.sound_speed_m_s
    n_extra = 0 if extra is None else len(extra.labels)
    n_data = 3 * len(meas) + n_extra

    t_ref = reference_time_min(meas)
    load = prior.posture_load(meas)
    arrays = MeasurementArrays.of(meas, t_ref, load)
    hold_unloaded(table, arrays)
    has_prior = np.isfinite(table.prior_stds) & table.free

    def rows(v: np.ndarray) -> np.ndarray:
        r_data = data_residuals(table, v, prior.model, arrays, c0).ravel()
        return r_data if extra is None else np.concatenate([r_data, extra.residuals(v)])

    def fun(x: np.ndarray) -> np.ndarray:
        v = table.expand(x)
        return np.concatenate([rows(v), (v - table.prior)[has_prior] / table.prior_stds[has_prior]])

    if start is not None:
        x0 = np.asarray(start, float)[table.free].copy()
    else:
        # Start the corner where eq. (2) puts it with the prior offsets (a hand-placed block
        # can be centimetres off; the least-squares start should not depend on that).
        x0 = _initial_corner(table, prior, meas, table.values[table.free].copy())
    sol = _least_squares_with_priors(fun, x0, table, tol, max_evaluations)
    jac = sol.jac
    res = sol.fun
    estimate = table.expand(sol.x)
    info = jac.T @ jac
    cov = np.linalg.pinv(info)
    chi2 = float(res @ res)
    dof = max(1, n_data)
    chi2_red = chi2 / dof
    scale = max(1.0, chi2_red)
    curvature = Curvature.of(prior, arrays.minutes, face_row_minutes(arrays.minutes))
    cov_scaled = cov * scale + curvature.covariance(table, jac, cov)
    std = np.full(len(table.names), np.nan)
    std[table.free] = np.sqrt(np.clip(np.diag(cov_scaled), 0.0, None))

    shares = _variance_shares(table, jac, cov, n_data)
    gains = {}
    if verdict(chi2, dof, misfit_p) == "misfit":
        gains = effect_gains(table, estimate, rows, res, jac, curvature)
    quality = fit_quality(
        table,
        estimate,
        prior,
        meas,
        res,
        n_data,
        chi2,
        dof,
        misfit_p,
        () if extra is None else extra.labels,
        gains,
    )
    if sol.status == 0 and quality.verdict == "misfit":  # stopped at max_evaluations
        quality = replace(quality, cause=unconverged_cause(max_evaluations, quality.cause))
    return CellFit(
        table,
        estimate,
        cov_scaled,
        std,
        quality,
        shares,
        _condition_number(table, jac[:n_data], std, max_std_deg),
        jac,
        n_data,
        t_ref,
        None if load is None else load.load_posture_deg,
    )


def curvature_std_m_s_per_min2(prior: CellPrior, minutes: np.ndarray) -> float:
    """One sigma of the drift's curvature c̈ over a run whose water paths were read at
    ``minutes``: the declared drift tolerance is how much the rate may differ from a steady
    one, so over the run's D minutes the rate may turn by it, |dc/dT|·``drift_std_c_per_min``
    / D (m/s per min²; 0 for readings at one time). The sound speed then departs from its
    fitted line by about c̈·D²/8, an eighth of the declared drift over the run. With a
    thermometer's log that has taken the turns out of the paths (``ucal.thermometer``), the
    departure left is the thermometer's, |dc/dT|·``logged_departure_std_c``: c̈ =
    8·|dc/dT|·σ_th/D² where smaller."""
    span_min = float(np.ptp(minutes)) if len(minutes) else 0.0
    if span_min <= 0.0:
        return 0.0
    declared = prior.drift_std_m_s_per_min / span_min
    if prior.logged_departure_std_c is None:
        return declared
    logged = 8.0 * prior.sound_speed_slope_m_s_per_c * prior.logged_departure_std_c / span_min**2
    return min(declared, logged)


def face_row_minutes(minutes: np.ndarray) -> np.ndarray:
    """Each row's t − t_ref for face readings at ``minutes`` (n,): two tilts and a water path
    per reading (``ucal.model.residuals.data_residuals``' order), (3n,)."""
    return np.repeat(np.asarray(minutes, float), 3)


def curvature_rows(sound_column: np.ndarray, row_minutes: np.ndarray) -> np.ndarray:
    """The rows' derivative by the drift's curvature c̈: each row's derivative by the sound
    speed (``sound_column``, a column of the Jacobian) × ½(t − t_ref)², ``row_minutes``
    giving t − t_ref for the first rows (0 for a row without a time), 0 on the rest (the
    priors' rows). A row the sound speed does not enter (a tilt, an edge crossing) is 0."""
    g = np.zeros(len(sound_column))
    n = len(row_minutes)
    g[:n] = sound_column[:n] * 0.5 * np.asarray(row_minutes, float) ** 2
    return g


def considered_covariance(
    jac: np.ndarray, cov: np.ndarray, g: np.ndarray, sigma: float
) -> np.ndarray:
    """The covariance a parameter not fitted (a consider parameter, 0 ± ``sigma``) adds to
    the fitted unknowns: they move by −(JᵀJ)⁻¹Jᵀg per unit of it, ``g`` the rows' derivative
    by it, ``cov`` = (JᵀJ)⁻¹ (unscaled)."""
    shift = cov @ (jac.T @ g)
    return np.outer(shift, shift) * sigma**2


def curvature_covariance(
    table: ParameterTable,
    jac: np.ndarray,
    cov: np.ndarray,
    row_minutes: np.ndarray,
    sigma: float,
) -> np.ndarray:
    """The covariance the drift's curvature adds to the free unknowns, not fitted (a
    consider parameter): a real tank does not warm at a steady rate (it approaches the room
    exponentially, a heater cycles), so each water path's sound speed departs from the fitted
    ``c + ċ·(t − t_ref)`` by ½·c̈·(t − t_ref)², c̈ = 0 ± ``sigma``
    (``curvature_std_m_s_per_min2``). ``row_minutes``: each data row's t − t_ref, the first
    rows of ``jac`` (``face_row_minutes`` for face readings; tool-frame's peaks and edge
    crossings give their own). Zero where the drift is not free (held, or readings at one
    time) or the sound speed is held."""
    g = curvature_column(table, jac, row_minutes)
    if g is None:
        n_free = int(np.sum(table.free))
        return np.zeros((n_free, n_free))
    return considered_covariance(jac, cov, g, sigma)


#: The drift's curvature c̈ (m/s per min²) where a misfit is tested against it: not an unknown.
CURVATURE = "sound_speed_curvature_m_s_per_min2"


def curvature_column(
    table: ParameterTable, jac: np.ndarray, row_minutes: np.ndarray
) -> np.ndarray | None:
    """The rows' derivative by the drift's curvature c̈ (``curvature_rows`` of the sound
    speed's column of ``jac``); None where the drift or the sound speed is not free."""
    names = table.free_names
    if DRIFT[0] not in names or SOUND[0] not in names:
        return None
    return curvature_rows(jac[:, names.index(SOUND[0])], row_minutes)


@dataclass(frozen=True)
class Curvature:
    """The drift's curvature over one run, a consider parameter of its fit: each data row's
    t − t_ref (``curvature_covariance``) and c̈'s one sigma (``curvature_std_m_s_per_min2``)."""

    row_minutes: np.ndarray
    std_m_s_per_min2: float

    @classmethod
    def of(cls, prior: CellPrior, minutes: np.ndarray, row_minutes: np.ndarray) -> Curvature:
        """The curvature of a run whose water paths were read at ``minutes`` (t − t_ref), its
        data rows at ``row_minutes``."""
        return cls(np.asarray(row_minutes, float), curvature_std_m_s_per_min2(prior, minutes))

    def covariance(self, table: ParameterTable, jac: np.ndarray, cov: np.ndarray) -> np.ndarray:
        """What it adds to the free unknowns' covariance (``curvature_covariance``)."""
        return curvature_covariance(table, jac, cov, self.row_minutes, self.std_m_s_per_min2)


#: The run's effects a misfit is tested against (``effect_gains``).
EFFECTS = DRIFT + BACKLASH


def effect_gains(
    table: ParameterTable,
    estimate: np.ndarray,
    rows: Callable[[np.ndarray], np.ndarray],
    res: np.ndarray,
    jac: np.ndarray,
    curvature: Curvature | None = None,
) -> dict[str, float]:
    """How much of the χ² each of the run's effects (``EFFECTS``, and the drift's
    ``curvature`` where given) would remove, were it free beyond its prior: the score test at
    the solution, Δχ² = (g⊥·r)²/|g⊥|², with ``g`` the effect's column of the data rows
    (``rows``: the full vector to them; the curvature's ``curvature_column``) and ``g⊥`` its
    part outside the fit's columns ``jac`` (residuals ``res``). An effect the readings cannot
    see (no time, one-sided approach) has no such part and is left out."""
    base = rows(estimate)
    out: dict[str, float] = {}
    for name in EFFECTS:
        if name not in table.names:
            continue
        i = table.index(name)
        step = 1e-3 * (table.prior_stds[i] if table.prior_stds[i] > 0 else 1e-3)
        v = estimate.copy()
        v[i] += step
        g = np.zeros(len(res))
        g[: len(base)] = (rows(v) - base) / step
        out.update(score_gain(name, g, res, jac))
    bend = None if curvature is None else curvature_column(table, jac, curvature.row_minutes)
    if bend is not None:
        out.update(score_gain(CURVATURE, bend, res, jac))
    return out


def score_gain(name: str, g: np.ndarray, res: np.ndarray, jac: np.ndarray) -> dict[str, float]:
    """``{name: Δχ²}`` of the score test of one column ``g`` of the rows (``effect_gains``),
    or {} where the fit's columns ``jac`` already hold it."""
    basis, _ = np.linalg.qr(jac)
    g_perp = g - basis @ (basis.T @ g)
    norm2 = float(g_perp @ g_perp)
    if norm2 > 1e-9 * float(g @ g) and norm2 > 0.0:
        return {name: float(g_perp @ res) ** 2 / norm2}
    return {}


def _initial_corner(
    table: ParameterTable, prior: CellPrior, meas: list[FaceMeasurement], x0: np.ndarray
) -> np.ndarray:
    """Corner from eq. (2), n_k·c = n_k·p − d, averaged per face (prior offsets and tool)."""
    if not all(table.free[table.index(n)] for n in BLOCK[:3]):
        return x0
    geom = cell_geometry(table, table.values, prior.model)
    coord = geom.block_rotation.T @ table.get(BLOCK[:3])
    for k in range(3):
        vals = [
            geom.normal(k) @ beam_and_tcp(geom, distance_joints(m), prior.offsets_deg)[1]
            - m.distance_mm
            for m in meas
            if m.face == k
        ]
        if vals:
            coord[k] = float(np.mean(vals))
    corner = geom.block_rotation @ coord
    x = x0.copy()
    free_names = table.free_names
    for i, n in enumerate(BLOCK[:3]):
        x[free_names.index(n)] = corner[i]
    return x


def _variance_shares(
    table: ParameterTable, jac: np.ndarray, cov: np.ndarray, n_data: int
) -> dict[str, dict[str, float]]:
    """Share of each offset's variance from the data and from each prior.

    The estimate's sensitivity to the rows is ``K = Cov·Jᵀ``; with unit-variance rows the
    variance of parameter j is Σ_rows K_jr², split here by row: the data rows together, and
    each prior row by the parameter it constrains.
    """
    k = cov @ jac.T
    free = table.free_names
    prior_rows = [n for n in free if np.isfinite(table.prior_stds[table.index(n)])]
    out: dict[str, dict[str, float]] = {}
    for name in OFFSETS:
        if name not in free:
            continue
        j = free.index(name)
        contrib = k[j] ** 2
        total = float(contrib.sum()) or 1.0
        shares = {"data": float(contrib[:n_data].sum()) / total}
        for r, pn in enumerate(prior_rows):
            shares[pn] = float(contrib[n_data + r]) / total
        out[name] = shares
    return out


def _condition_number(
    table: ParameterTable, jac_data: np.ndarray, std: np.ndarray, max_std_deg: float
) -> float:
    """Condition number of the column-scaled data Jacobian over the offsets the data determine,
    the block corner and the sound speed (the unknowns the measurements are meant to fix)."""
    free = table.free_names
    cols = [
        free.index(n)
        for n in OFFSETS + BLOCK[:3] + SOUND
        if n in free and (n not in OFFSETS or std[table.index(n)] <= max_std_deg)
    ]
    js = jac_data[:, cols]
    js = js / np.maximum(np.linalg.norm(js, axis=0), 1e-300)
    s = np.linalg.svd(js, compute_uv=False)
    return float(s[0] / s[-1]) if s[-1] > 0 else float("inf")


# any measurement type: the prior-augmented fit and its uncertainty


@dataclass(frozen=True)
class AugmentedFit:
    """Solution of a prior-augmented least-squares problem over a ``ParameterTable``.

    ``cov`` (free × free) is ``(JᵀJ)⁻¹`` scaled by ``max(1, χ²ᵣ)``; ``gain`` = ``(JᵀJ)⁻¹·Jᵀ``
    (unscaled) maps unit-variance rows to parameters, so a quantity's variance splits by row.
    """

    table: ParameterTable
    estimate: np.ndarray
    cov: np.ndarray
    std: np.ndarray
    jac: np.ndarray
    res: np.ndarray
    gain: np.ndarray
    n_data: int
    chi2: float

    def value(self, name: str) -> float:
        return float(self.estimate[self.table.index(name)])

    def sigma(self, name: str) -> float:
        return float(self.std[self.table.index(name)])

    @property
    def dof(self) -> int:
        """Data rows less the free unknowns that have no prior row."""
        t = self.table
        no_prior = int(np.sum(t.free & ~np.isfinite(t.prior_stds)))
        return max(1, self.n_data - no_prior)

    @property
    def prior_rows(self) -> list[str]:
        """Names of the parameters whose prior rows follow the data rows, in order."""
        t = self.table
        return [n for n in t.free_names if np.isfinite(t.prior_stds[t.index(n)])]

    def gradient(self, weights: dict[str, float | np.ndarray]) -> np.ndarray:
        """Free-parameter gradient of ``Σ w·x`` (one row per entry of array weights)."""
        free = self.table.free_names
        rows = np.atleast_2d(
            np.column_stack([np.atleast_1d(np.asarray(w, float)) for w in weights.values()])
        )
        g = np.zeros((rows.shape[0], len(free)))
        for j, name in enumerate(weights):
            if name in free:
                g[:, free.index(name)] = rows[:, j]
        return g

    def shares(self, gradient: np.ndarray) -> dict[str, float]:
        """Share of the variance of ``gradient·x`` (summed over its rows) from the data and
        from each prior (by parameter name)."""
        contrib = (np.atleast_2d(gradient) @ self.gain) ** 2
        contrib = contrib.sum(0)
        total = float(contrib.sum()) or 1.0
        out = {"data": float(contrib[: self.n_data].sum()) / total}
        for r, name in enumerate(self.prior_rows):
            out[name] = float(contrib[self.n_data + r]) / total
        return out


def unconverged_cause(evaluations: int, cause: str) -> str:
    """A misfit's cause when the fit stopped at its limit of ``evaluations`` before it
    converged: its residuals are then the fit's as much as the cell's, and what they would
    name (``cause``) is said as such."""
    return (
        f"the fit stopped at its limit of {evaluations} evaluations before it converged (a "
        "start far from the cell: a fresh profile's offsets, a block far from where it is "
        f"declared), so the misfit may be the fit's, not the cell's; its residuals say: {cause}"
    )


def solve_augmented(
    table: ParameterTable,
    data_fn: Callable[[np.ndarray], np.ndarray],
    x0: np.ndarray,
    tol: float = 1e-12,
    max_nfev: int = 200,
    measured: tuple[str, ...] = (),
    curvature: Curvature | None = None,
) -> AugmentedFit:
    """Minimise ``|data_fn(v)|² + Σ ((v − prior)/σ)²`` over the free parameters of ``table``
    (``data_fn`` takes the full value vector and returns normalised data residuals).

    ``measured`` names the quantities the run exists to measure: their priors (a drawing's
    tolerance) still enter the solution, but their pulls are not counted in the χ² that
    judges the fit and scales the covariance. ``curvature``: the drift's curvature over the
    data rows, added to the covariance as in ``solve_cell`` (not fitted)."""
    has_prior = np.isfinite(table.prior_stds) & table.free
    n_data = len(data_fn(table.expand(x0)))

    def fun(x: np.ndarray) -> np.ndarray:
        v = table.expand(x)
        return np.concatenate(
            [data_fn(v), (v - table.prior)[has_prior] / table.prior_stds[has_prior]]
        )

    sol = _least_squares_with_priors(fun, x0, table, tol, max_nfev)
    cov = np.linalg.pinv(sol.jac.T @ sol.jac)
    prior_names = [n for n, f in zip(table.names, has_prior, strict=True) if f]
    counted = np.concatenate([np.ones(n_data, bool), [n not in measured for n in prior_names]])
    chi2 = float(sol.fun[counted] @ sol.fun[counted])
    no_prior = int(np.sum(table.free & ~np.isfinite(table.prior_stds)))
    cov_scaled = cov * max(1.0, chi2 / max(1, n_data - no_prior))
    if curvature is not None:
        cov_scaled = cov_scaled + curvature.covariance(table, sol.jac, cov)
    std = np.full(len(table.names), np.nan)
    std[table.free] = np.sqrt(np.clip(np.diag(cov_scaled), 0.0, None))
    return AugmentedFit(
        table, table.expand(sol.x), cov_scaled, std, sol.jac, sol.fun, cov @ sol.jac.T, n_data, chi2
    )


#: A joint's lost motion is reported measured only where its std is below this share of its
#: prior's: read from both sides, the data determine it (J6 with the beam on its axis is read
#: from both sides and still left at its prior).
MEASURED_SHARE = 0.5


@dataclass(frozen=True)
class RunEffects:
    """What a fit found of the tank's drift (m/s per min) and each joint's lost motion (deg):
    a drift no reading saw keeps its prior (0 ± its tolerance); lost motion is measured only
    where readings approached the joint from both sides and determine it (std below
    ``MEASURED_SHARE`` of the prior's; NaN elsewhere)."""

    drift_m_s_per_min: float
    drift_std_m_s_per_min: float
    backlash_deg: np.ndarray  # (6,)
    backlash_std_deg: np.ndarray  # (6,)

    @classmethod
    def of(cls, cell: CellFit | AugmentedFit) -> RunEffects:
        table = cell.table
        drift, drift_std = 0.0, float("nan")
        if DRIFT[0] in table.names:
            i = table.index(DRIFT[0])
            drift = cell.value(DRIFT[0])
            drift_std = cell.sigma(DRIFT[0]) if table.free[i] else float(table.prior_stds[i])
        backlash, backlash_std = np.full(6, np.nan), np.full(6, np.nan)
        for j, name in enumerate(BACKLASH):
            if name not in table.names or not table.free[table.index(name)]:
                continue
            if cell.sigma(name) < MEASURED_SHARE * table.prior_stds[table.index(name)]:
                backlash[j], backlash_std[j] = cell.value(name), cell.sigma(name)
        return cls(drift, drift_std, backlash, backlash_std)

    def to_json(self) -> dict[str, Any]:
        """The fields of ``calibrate --json`` (SPEC.md: null where not measured)."""

        def listed(v: np.ndarray) -> list[float | None]:
            return [float(x) if np.isfinite(x) else None for x in v]

        return {
            "backlash_deg": listed(self.backlash_deg),
            "backlash_std_deg": listed(self.backlash_std_deg),
            "sound_speed_drift_m_s_per_min": self.drift_m_s_per_min,
            "sound_speed_drift_m_s_per_min_std": self.drift_std_m_s_per_min,
        }
