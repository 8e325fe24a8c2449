"""Full kinematic identification (``calibrate --level full``): which parameters the
measurements determine, and their values with honest standard deviations.

Model. The unknowns of ``ucal.model.fit`` (joint offsets, block pose, tool frame, sound
speed and its drift over the run, each joint's lost motion where it is read from both sides,
the DH lengths ``d``, ``a`` and twists ``α`` of every link) plus Hayati's twist ``β₂``
of the nearly parallel axes 2 and 3 (``A₂ = Rz(θ)·Tz(d)·Tx(a)·Rx(α)·Ry(β)``): a modified DH
model. Every unknown has the profile's value and tolerance as its prior; the measurements are
the face measurements of ``ucal.model.geometry`` (normal-incidence postures and water
paths), taken in many arm configurations (``ucal.model.postures``).

Identifiability, from the data Jacobian ``J`` (rows in units of their σ, columns per prior σ)
at the profile's values: the nuisance quantities (block pose, tool frame) and the joint offsets span
what the cell itself can do; each kinematic parameter is then taken in table order and kept if
its column adds a direction that span lacks (relative residual of its projection above
``REDUNDANT_REL``), else it is *not identifiable*: a nuisance carried with its prior, as every
other uncertain quantity is, reported as not determined (its tolerance stands). Held at its
nominal value instead, its error (within its tolerance: ``d₅``, ``a₅`` 0.3 mm on a real arm)
had nowhere to go but the residuals and the parameters it duplicates: a misfit on most real
tables, or a TCP error no result stated (``tests/system/test_full_level_real_tables.py``).
Physics says which (``redundancy_reason``):

* ``d₁`` moves the whole arm along axis 1 like the block's height; the base frame is a gauge;
* ``d₃`` and ``d₂`` both slide along the parallel axes 2 and 3: only their sum is seen (and
  Hayati's ``β₂`` replaces what a ``d`` would do on that link);
* link 6 and the tool are one rigid body: the tool frame absorbs ``d₆``, ``a₆``, ``α₆``.

The sound speed is tested last, against everything: the water paths measure lengths in units
of the sound speed, so a common scale of every length and of ``c`` is invisible to them.
Without a length standard it stays an unknown, and the scale comes from the declared
tolerances of the DH lengths and the thermometer (``scale_note``): the std of each length
carries it. A step of known height on the block's XY face (``[step]``, ``ucal.cell.Step``) is
such a standard: a water path read over its top and one read over the face beside it differ
by the robot's displacement along the normal less the step's height, which no sound speed
enters. Its top is taken as a plane ``step_mm`` above the face (an unknown with the height's
certificate as prior); only the water paths read over it are used: its tilt (a gauge block
wrung not quite flat) is not known to the postures' thousandths of a degree.

(Edge scans do not give the scale on this block: an edge's position across the beam is
measured from the corner, which time of flight places only up to the tool's unknown offset
along the beam — a larger block is a shorter tool in the same data. A length across the beam
needs two opposite edges of one face, which the block's free edges are not.)

A kinematic parameter that is independent but weakly seen (its data information below its
prior's, or a std above ``PRIOR_DOMINATED`` of its tolerance) is fitted with its prior and
reported as prior-dominated (e.g. ``d₅``, ``a₅``: they shift the flange across the beam, which
a plane seen at normal incidence does not show): its value stays within its tolerance of the
nominal one and its std says so. Each joint's compliance is an unknown too
(``ucal.model.load``), its torque taken at the readings plus the offsets: on a cell never
calibrated the profile's offsets are degrees off the arm's, which moves the torques'
differences between postures by tenths of a N·m per degree (a soft J2's sag by µrad:
micrometres at the tool, above the water paths' noise), so where the fitted offsets stand
further than ``LOAD_OFFSETS_DEG`` from the profile's the fit is made again with the torques
taken at them (an arm of 1e5 N·m/rad whose offsets were 1° off, every other quantity as the
world's: χ²ᵣ 2.6, a misfit, with the profile's; 0.7 with the fitted ones). Joint offsets follow
the offsets level: J1 relative to the block as placed (the block gauge, ``ucal.model.gauge``),
unobservable (kept) when their large std comes from a prior (J6 with the beam on its axis).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, replace
from typing import Any

import numpy as np
from scipy.optimize import approx_fprime
from scipy.spatial.transform import Rotation

from ucal.kinematics.dh import RobotModel
from ucal.model.fit import (
    BETA,
    BLOCK,
    DH,
    MAX_STD_DEG,
    OFFSETS,
    PARAMETERS,
    SOUND,
    TOOL,
    CellFit,
    CellPrior,
    ExtraRows,
    MeasurementArrays,
    ParameterTable,
    RunEffects,
    data_residuals,
    hold_unseen,
    reference_time_min,
    solve_cell,
    table_geometry,
)
from ucal.model.gauge import BLOCK_YAW, J1Gauge, gauged_offsets
from ucal.model.geometry import (
    CellGeometry,
    FaceMeasurement,
    beam_and_tcp,
    distance_joints,
)
from ucal.model.least_squares import cell_table, hold_unloaded
from ucal.model.load import COMPLIANCE, PostureLoad
from ucal.model.priors import twists_deg
from ucal.model.stiffness import JointStiffness, identified_stiffness

#: Evaluations of the residuals the full level's fit may spend: from a fresh cell's offsets,
#: degrees from the profile's, with the table free, the trust region crawls along the
#: offsets' and the links' correlations for hundreds of them (the offsets level's 200 left
#: fits far from their minimum, called misfits, their tool dragged 4σ); one that converges
#: sooner stops there.
FULL_MAX_EVALUATIONS = 2000
#: Height of the step on the block's XY face (mm): the length standard.
STEP = ("step_mm",)
#: The unknowns of the full level: the offsets level's (Hayati's twist of axes 2-3 among
#: them: ``cell_table``), each joint's compliance (``ucal.model.load``) and the step's height.
FULL_PARAMETERS = PARAMETERS + BETA + COMPLIANCE + STEP
#: The kinematic parameters the full level identifies (besides the joint offsets), table order.
KINEMATIC = DH + BETA
#: A kinematic column whose residual after projection on the kept columns is below this share
#: of its norm duplicates them (redundant or a gauge).
REDUNDANT_REL = 1e-3
#: A kinematic column whose norm (every measurement's residual, per σ, for one prior σ of the
#: parameter) is below this is seen by none: what is left is the rounding of a translation
#: across every beam (d5, a5 on a block turned off the base axes: 5e-7), not information.
UNSEEN_NORM = 1e-3

#: Fitted offsets further than this from the profile's (deg) are fitted again with the torques
#: taken at them (``solve_full``).
LOAD_OFFSETS_DEG = 0.01

#: A parameter whose std is above this share of its tolerance is reported prior-dominated.
PRIOR_DOMINATED = 0.5

_ROW_KEYS = ("d_mm", "a_mm", "alpha_deg")
#: The columns of ``[calibration] dh_std`` (``ucal.profile.read.DH_STD_KEYS``).
_STD_KEYS = (*_ROW_KEYS, "beta_deg")


def full_table(prior: CellPrior) -> ParameterTable:
    """``FULL_PARAMETERS`` with the profile's values and tolerances: ``cell_table``'s, and the
    step's (0, known, when the cell has none)."""
    cell = cell_table(prior)
    return ParameterTable(
        FULL_PARAMETERS,
        np.append(cell.prior, prior.step_mm),
        np.append(cell.prior_stds, prior.step_std_mm),
    )


def step_residuals(
    table: ParameterTable,
    values: np.ndarray,
    model: RobotModel,
    meas: list[FaceMeasurement],
    c0_m_s: float,
    time_ref_min: float = 0.0,
    load: PostureLoad | None = None,
) -> np.ndarray:
    """Normalised residual of the water path of each measurement over the step's top (n,):
    the path to the XY face's plane, less ``step_mm``, along the beam, against the measured
    one (``ucal.model.fit.data_residuals``' distance row, for a plane ``step_mm`` up;
    ``time_ref_min``: the face measurements' reference time, ``reference_time_min``; ``load``:
    their torques' reference, ``CellPrior.posture_load``)."""
    if not meas:
        return np.zeros(0)
    rows = data_residuals(table, values, model, meas, c0_m_s, time_ref_min, load)
    geom = table_geometry(table, values, model)
    beam, _ = beam_and_tcp(
        geom, np.array([distance_joints(m) for m in meas]), table.get(OFFSETS, values)
    )
    cos_t = np.maximum(-beam @ geom.normal(2), 0.5)
    std = np.array([m.distance_std_mm for m in meas])
    return np.asarray(rows[:, 2] - table.get(STEP, values)[0] / cos_t / std)


def redundancy_reason(name: str, partners: list[str]) -> str:
    """Why kinematic parameter ``name`` is not identifiable, given what it duplicates."""
    if name == "dh1_d_mm":
        return (
            "moves the whole arm along joint 1's axis, as the block's height does: the base "
            "frame's height is a gauge"
        )
    if name in ("dh2_d_mm", "dh3_d_mm"):
        return (
            "axes 2 and 3 are parallel: d2 and d3 both slide along them and only their sum "
            "is seen (Hayati's beta_deg takes the place of a d on that link)"
        )
    if name in ("dh5_d_mm", "dh5_a_mm"):
        return (
            "moves the flange across the beam, which a plane seen at normal incidence does "
            "not show (as the tool's position across the beam)"
        )
    if name.startswith("dh6_"):
        return (
            "link 6 and the tool are one rigid body: the tool frame absorbs it "
            "(tool-frame measures the tool with it)"
        )
    if name == "dh1_alpha_deg" or name == "dh1_a_mm":
        return (
            "the block's pose absorbs it (the base frame is a gauge): same effect as "
            f"{_join(partners)}"
        )
    return f"its effect on every measurement equals a combination of {_join(partners)}"


def _join(names: list[str]) -> str:
    return ", ".join(names) if names else "the others"


@dataclass(frozen=True)
class Identifiability:
    """What the measurements determine among the kinematic parameters."""

    rank: int  # numerical rank of the data Jacobian (all unknowns)
    n_parameters: int  # columns it has (free unknowns)
    identifiable: tuple[str, ...]  # kinematic parameters the data determine
    redundant: dict[str, str]  # not identifiable → why (carried with its prior)
    weak: tuple[str, ...]  # independent, but the prior dominates
    scale_note: str = ""  # the common scale of lengths and sound speed


def data_jacobian(
    prior: CellPrior,
    meas: list[FaceMeasurement],
    values: np.ndarray | None = None,
    steps: list[FaceMeasurement] | None = None,
) -> tuple[np.ndarray, tuple[str, ...]]:
    """Jacobian of the data residuals (rows per σ: the face measurements', then the water
    paths over the step's) against the unknowns of ``full_table`` that have a tolerance, per
    prior σ, at ``values`` (default: the profile's); and their names."""
    table = full_table(prior)
    hold_unseen(table, meas)  # the drift and lost motion these readings cannot see
    free = table.free & np.isfinite(table.prior_stds) & (table.prior_stds > 0)
    table.free = free
    v0 = table.values.copy() if values is None else np.asarray(values, float)
    if values is None:
        # what the postures see is the rigid arm's structure: the prior's sag (hundredths of a
        # degree) tilts each modelled beam off normal by as much, which lets a translation
        # across the beam (d5, a5) show at the thousandth of a sigma the test draws its line at
        v0[[table.index(n) for n in COMPLIANCE]] = 0.0
    c0 = prior.sound_speed_m_s
    t_ref = reference_time_min(meas)
    load = prior.posture_load(meas)
    arrays = MeasurementArrays.of(meas, t_ref, load) if meas else None
    if arrays is not None:
        hold_unloaded(table, arrays)
    free = table.free

    def fun(x: np.ndarray) -> np.ndarray:
        v = v0.copy()
        v[free] = x
        rows = (
            np.zeros(0)
            if arrays is None
            else data_residuals(table, v, prior.model, arrays, c0).ravel()
        )
        steps_r = step_residuals(table, v, prior.model, steps or [], c0, t_ref, load)
        return np.concatenate([rows, steps_r])

    stds = table.prior_stds[free]
    jac = approx_fprime(v0[free], fun, 1e-3 * stds)
    return jac * stds, table.free_names


def _residual_share(cols: np.ndarray, c: np.ndarray) -> tuple[float, np.ndarray]:
    """Share of ``c`` outside the span of ``cols`` and its coefficients on them."""
    norm = float(np.linalg.norm(c))
    if norm == 0.0:
        return 0.0, np.zeros(cols.shape[1])
    if cols.shape[1] == 0:
        return 1.0, np.zeros(0)
    coef, *_ = np.linalg.lstsq(cols, c, rcond=None)
    return float(np.linalg.norm(c - cols @ coef)) / norm, coef


def identifiability(
    js: np.ndarray, names: tuple[str, ...], redundant_rel: float = REDUNDANT_REL
) -> Identifiability:
    """Classify the kinematic parameters (module docstring) from the data Jacobian ``js``
    (``data_jacobian``) with columns ``names``."""
    col = {n: js[:, i] for i, n in enumerate(names)}
    kept = [n for n in OFFSETS + BLOCK + TOOL + STEP if n in col]
    redundant: dict[str, str] = {}
    identifiable: list[str] = []
    weak: list[str] = []
    for name in KINEMATIC:
        if name not in col:
            continue
        cols = np.column_stack([col[n] for n in kept])
        share, coef = _residual_share(cols, col[name])
        if np.linalg.norm(col[name]) < UNSEEN_NORM:
            share, coef = 0.0, np.zeros(len(kept))
        if share < redundant_rel:
            order = np.argsort(-np.abs(coef))
            partners = [kept[i] for i in order[:2] if abs(coef[i]) > 0.1 * np.abs(coef).max()]
            redundant[name] = redundancy_reason(name, partners)
            continue
        kept.append(name)
        identifiable.append(name)
        # information beyond the prior: the column's part the others cannot explain, in σ
        if share * np.linalg.norm(col[name]) < 1.0:
            weak.append(name)
    note = ""
    if SOUND[0] in col:
        # with the step's height held (its prior is the length standard: the data alone cannot
        # tell a higher step from a longer robot in faster water)
        cols = np.column_stack([col[n] for n in kept if n not in STEP])
        share, _ = _residual_share(cols, col[SOUND[0]])
        if share < redundant_rel:
            note = (
                "the water paths measure lengths in units of the sound speed: a common scale "
                "of every length and of the sound speed is not seen, so the scale comes "
                "from the DH length tolerance and the thermometer"
            )
        elif STEP[0] in col:
            note = (
                "the water paths over the step and beside it measure its height, which the "
                "sound speed does not enter: the step's height tolerance sets the common "
                "scale of every length and of the sound speed"
            )
    norms = np.linalg.norm(js, axis=0)
    seen = np.where(norms < UNSEEN_NORM, 0.0, js / np.maximum(norms, 1e-300))
    s = np.linalg.svd(seen, compute_uv=False)
    rank = int(np.sum(s > redundant_rel * s[0]))
    return Identifiability(
        rank,
        len(names),
        tuple(identifiable),
        redundant,
        tuple(n for n in identifiable if n in weak),
        note,
    )


def _fields_json(self: Any) -> dict[str, Any]:
    """A plain dataclass as its JSON object: every field by name."""
    return asdict(self)


@dataclass(frozen=True)
class IdentifiedParameter:
    """A kinematic parameter as the full level found it (deg or mm)."""

    value: float
    std: float | None  # None: not identifiable, carried with its prior (not determined)
    nominal: float
    status: str  # "identified", "prior-dominated" or "not identifiable"

    to_json = _fields_json


@dataclass(frozen=True)
class LengthStandard:
    """The step's height as its water paths and its prior put it (mm)."""

    step_mm: float
    std_mm: float
    nominal_mm: float  # the certificate's
    tolerance_mm: float
    measurements: int  # water paths over the step

    to_json = _fields_json


@dataclass(frozen=True)
class FullSolution:
    """The identified kinematic model with the fit behind it."""

    cell: CellFit
    ident: Identifiability
    offsets_deg: np.ndarray  # kept from the profile where unobservable; J1 in the block gauge
    std_deg: np.ndarray  # absolute one sigma, NaN where unobservable
    unobservable_reasons: dict[int, str]  # 1-based joint → why
    model: RobotModel  # the identified DH table (nominal where kept)
    parameters: dict[str, IdentifiedParameter] = field(default_factory=dict)
    #: The step's height as its water paths and its prior put it (None without a step).
    length_standard: LengthStandard | None = None
    #: One sigma relative to the block as placed, and how J1 is known (``ucal.model.gauge``).
    std_block_deg: np.ndarray | None = None
    gauge: J1Gauge | None = None
    #: Each joint's compliance as the fit found it (``ucal.model.stiffness``).
    stiffness: tuple[JointStiffness, ...] = ()

    @property
    def unobservable_joints(self) -> tuple[int, ...]:
        return tuple(sorted(self.unobservable_reasons))

    method = "exact"

    #: The paper method's truncation error (``judge`` reads it of any solution): none here.
    truncation_deg = None

    @property
    def cell_fit(self) -> CellFit:
        """The fit behind the solution (``ucal.calibration.procedure.judge`` reads it)."""
        return self.cell

    @property
    def sound_speed_m_s(self) -> float:
        return self.cell.value(SOUND[0])

    @property
    def sound_speed_std_m_s(self) -> float:
        return self.cell.sigma(SOUND[0])

    @property
    def effects(self) -> RunEffects:
        """The tank's drift and the arm's lost motion as the fit found them."""
        return RunEffects.of(self.cell)

    def dh_rows(self) -> list[dict[str, float]]:
        """The identified table as ``[calibration] dh`` rows (SPEC.md), ``beta_deg`` where not 0."""
        rows = []
        for i, row in enumerate(self.model.dh):
            r = {
                "theta_offset_deg": float(row[0]),
                "d_mm": round(float(row[1]), 6),
                "a_mm": round(float(row[2]), 6),
                "alpha_deg": round(float(row[3]), 7),
            }
            beta = twists_deg(self.model)[i]
            if beta != 0.0:
                r["beta_deg"] = round(float(beta), 7)
            rows.append(r)
        return rows

    def dh_std(self) -> np.ndarray:
        """The identified table's one sigmas as later solvers may take them as priors (6, 4:
        each row's ``d_mm, a_mm, alpha_deg, beta_deg``; NaN: not determined,
        ``written_dh_std``)."""
        return written_dh_std(self.cell, self.parameters)

    def dh_std_rows(self) -> list[dict[str, float]]:
        """``dh_std`` as ``[calibration] dh_std`` rows: every kinematic parameter of the row,
        −1 where not determined (the [robot] tolerance stands)."""
        std = self.dh_std()
        rows: list[dict[str, float]] = [{} for _ in range(6)]
        for name in KINEMATIC:
            row, col = _position(name)
            v = std[row, col]
            rows[row][_STD_KEYS[col]] = _round_up(v) if np.isfinite(v) else -1.0
        return rows

    def to_json(self) -> dict[str, Any]:
        """The ``identification`` object of ``calibrate --level full --json``."""
        return {
            "rank": self.ident.rank,
            "unknowns": self.ident.n_parameters,
            "parameters": {name: p.to_json() for name, p in self.parameters.items()},
            "not_identifiable": dict(self.ident.redundant),
            "prior_dominated": list(self.ident.weak),
            "scale": self.ident.scale_note,
            "length_standard": (
                None if self.length_standard is None else self.length_standard.to_json()
            ),
            "stiffness": [s.to_json() for s in self.stiffness],
        }


def _round_up(std: float) -> float:
    """``std`` to four significant digits, never below it (a std written is a promise)."""
    out = float(f"{std:.4g}")
    if out < std:
        out = float(f"{out + 10.0 ** (np.floor(np.log10(std)) - 3):.4g}")
    return out


def _position(name: str) -> tuple[int, int]:
    """Row (0-based link) and ``_STD_KEYS`` column of a kinematic parameter (``dh2_a_mm``)."""
    return int(name[2]) - 1, _STD_KEYS.index(name.split("_", 1)[1])


def written_dh_std(cell: CellFit, params: dict[str, IdentifiedParameter]) -> np.ndarray:
    """One sigma of each kinematic parameter the full level determined (6, 4: each row's
    ``d_mm, a_mm, alpha_deg, beta_deg``; NaN elsewhere), for later solvers to take as
    independent priors in place of the [robot] tolerance.

    A prior per parameter drops the correlations between them. Alone, the marginal stds would
    then promise more than the fit knows of a combination whose parameters are positively
    correlated (the upper arm and the forearm share the scale of every length): a diagonal
    covariance ``k·diag(C)`` covers ``C`` in every direction when ``k`` is the largest
    eigenvalue of the parameters' correlation matrix, so each std is inflated by √k (about 2
    on the example cell), up to its prior's (the [robot] tolerance, or what an earlier full
    level wrote: a prior-dominated parameter keeps it). A parameter not identifiable (carried
    with its prior, its effect shared with the parameters it duplicates) is not determined:
    NaN, and the [robot] tolerance stands.
    """
    out = np.full((6, 4), np.nan)
    names = [n for n, p in params.items() if p.std is not None and np.isfinite(p.std)]
    if not names:
        return out
    free = cell.table.free_names
    idx = [free.index(n) for n in names]
    cov = cell.cov[np.ix_(idx, idx)]
    s = np.sqrt(np.clip(np.diag(cov), 1e-300, None))
    k = max(1.0, float(np.linalg.eigvalsh(cov / np.outer(s, s)).max()))
    for name in names:
        prior = float(cell.table.prior_stds[cell.table.index(name)])
        out[_position(name)] = min(float(np.sqrt(k) * cell.sigma(name)), prior)
    return out


def solve_full(
    prior: CellPrior,
    meas: list[FaceMeasurement],
    fixed: tuple[str, ...] = (),
    max_std_deg: float = MAX_STD_DEG,
    structure: Identifiability | None = None,
    steps: list[FaceMeasurement] | None = None,
) -> FullSolution:
    """Identify the kinematic model from ``meas`` (module docstring).

    The identifiability is judged on the data Jacobian at the profile's values (the errors a
    calibration corrects are far too small to change it): ``structure``, that of every posture
    the block allows (``FullPlan.structure``), separates what no measurement can see from what
    these few postures happen not to (those stay unknowns with their priors: prior-dominated);
    without it, ``meas`` alone is judged. The redundant parameters are carried with their
    priors (the table written as fitted, their stds not determined). ``fixed`` names unknowns
    held at the profile's values (e.g. the tool orientation for ``--beam fixed``). ``steps``:
    the measurements over the step's top (the length standard; the step's height is then an
    unknown with its prior).
    """
    steps = steps or []
    ident = (
        structure
        if structure is not None
        else identifiability(*data_jacobian(prior, meas, steps=steps))
    )
    c0 = prior.sound_speed_m_s
    t_ref = reference_time_min(meas)

    def fit(at: CellPrior, start: np.ndarray | None) -> tuple[CellFit, PostureLoad | None]:
        table = full_table(at)
        load = at.posture_load(meas)
        extra = ExtraRows(
            lambda v: step_residuals(table, v, at.model, steps, c0, t_ref, load),
            tuple(f"{m.config}/step" for m in steps),
        )
        # the block gauge (ucal.model.gauge): the block's yaw held as placed, J1 relative
        cell = solve_cell(
            at,
            meas,
            fixed=fixed + (() if steps else STEP) + (BLOCK_YAW,),
            max_std_deg=max_std_deg,
            table=table,
            extra=extra if steps else None,
            max_evaluations=FULL_MAX_EVALUATIONS,
            start=start,
        )
        return cell, load

    cell, load = fit(prior, None)
    fitted = cell.table.get(OFFSETS, cell.estimate)
    if load is not None and np.max(np.abs(fitted - prior.offsets_deg)) > LOAD_OFFSETS_DEG:
        # the torques at the links as fitted, not as the profile put them (module docstring)
        cell, load = fit(replace(prior, load_offsets_deg=fitted), cell.estimate)
    gauged = gauged_offsets(
        cell, prior.offsets_deg, float(prior.block_rotation_std_deg[2]), max_std_deg
    )
    dh = prior.model.dh.copy()
    beta = twists_deg(prior.model).copy()
    params: dict[str, IdentifiedParameter] = {}
    for name in KINEMATIC:
        i = cell.table.index(name)
        nominal = float(cell.table.prior[i])
        value, sigma = cell.value(name), cell.sigma(name)
        if name in ident.redundant:
            # a nuisance carried with its prior: the table as fitted (the parameters it
            # duplicates took the rest of its effect), not determined
            params[name] = IdentifiedParameter(value, None, nominal, "not identifiable")
        else:
            weak = name in ident.weak or sigma > PRIOR_DOMINATED * cell.table.prior_stds[i]
            params[name] = IdentifiedParameter(
                value, sigma, nominal, "prior-dominated" if weak else "identified"
            )
        row, col = _position(name)
        if name in BETA:
            beta[row] = value
        else:
            dh[row, 1 + col] = value
    model = prior.model.with_dh(dh, beta, "calibrate --level full")
    standard = None
    if steps:
        i = cell.table.index(STEP[0])
        standard = LengthStandard(
            cell.value(STEP[0]),
            cell.sigma(STEP[0]),
            float(cell.table.prior[i]),
            float(cell.table.prior_stds[i]),
            len(steps),
        )
    return FullSolution(
        cell,
        ident,
        gauged.offsets_deg,
        gauged.std_deg,
        gauged.reasons,
        model,
        params,
        standard,
        gauged.std_block_deg,
        gauged.gauge,
        identified_stiffness(cell, load, np.array([m.joints_deg for m in meas])),
    )


def ideal_measurements(
    geom: CellGeometry,
    corner_mm: np.ndarray,
    postures: list[tuple[str, int, np.ndarray]],
    offsets_deg: np.ndarray,
    distance_std_mm: float = 1e-3,
    tilt_std_deg: float = 1e-3,
    path_scale: float = 1.0,
) -> list[FaceMeasurement]:
    """Measurements of a cell ``geom`` (block corner ``corner_mm``) at normal-incidence
    ``postures`` ``(config label, face, joints (6,))``: the water path along the face normal,
    times ``path_scale`` (the ratio of the assumed to the true sound speed)."""
    out = []
    for label, face, q in postures:
        _, tcp = beam_and_tcp(geom, np.asarray(q, float), offsets_deg)
        d = float(geom.normal(face) @ (tcp - np.asarray(corner_mm, float)))
        out.append(
            FaceMeasurement(
                label, face, np.asarray(q, float), d * path_scale, distance_std_mm, tilt_std_deg
            )
        )
    return out


#: The scanning region around a calibration pose (deg, ±): the arm ±20°, the wrist ±90/30/90°.
SCAN_HALF_RANGE_DEG = np.array([20.0, 20.0, 20.0, 90.0, 30.0, 90.0])


def scanning_postures(
    pose_deg: np.ndarray, n: int, seed: int = 0, model: RobotModel | None = None
) -> np.ndarray:
    """``n`` joint readings (n, 6) drawn uniformly in the scanning region about ``pose_deg``
    (``SCAN_HALF_RANGE_DEG``), inside ``model``'s joint ranges if given."""
    rng = np.random.default_rng(seed)
    q = np.asarray(pose_deg, float) + rng.uniform(-1.0, 1.0, (n, 6)) * SCAN_HALF_RANGE_DEG
    if model is not None:
        q = np.clip(q, model.joint_min_deg, model.joint_max_deg)
    return np.asarray(q)


def aligned_errors_mm(
    points_mm: np.ndarray, truth_mm: np.ndarray, scale: bool = False
) -> np.ndarray:
    """Distances (n,) between ``points_mm`` and ``truth_mm`` (n, 3) after the rigid motion that
    best aligns them (least squares; the base frame is a gauge the measurements cannot fix);
    with ``scale``, after the best similarity (what is left once the common scale of lengths,
    which time of flight cannot see, is taken out)."""
    p = np.asarray(points_mm, float)
    t = np.asarray(truth_mm, float)
    pc, tc = p.mean(0), t.mean(0)
    rot, _ = Rotation.align_vectors(t - tc, p - pc)
    moved = rot.apply(p - pc)
    k = float(np.sum(moved * (t - tc)) / np.sum(moved * moved)) if scale else 1.0
    return np.asarray(np.linalg.norm(k * moved + tc - t, axis=1))
