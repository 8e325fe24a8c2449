"""Joint offsets with the cell's uncertain quantities as prior-constrained unknowns.

Unknowns (named, see ``PARAMETERS``): the six joint offsets δ (deg), the block pose (corner
``c`` in mm, orientation ``[rx, ry, rz]`` in deg, Staubli convention), the tool frame in the
flange (position mm, orientation deg), the speed of sound ``c_w`` (m/s) and the DH table's
lengths and twists (``d``, ``a`` in mm, ``α`` in deg). Each has a prior: the profile's value
with the profile's declared one-sigma tolerance (``[sample] position_std_mm``,
``rotation_std_deg``; ``[tool]`` likewise; the sound speed from ``[water] temperature_c`` ±
``temperature_std_c`` through Marczak's c(T); ``[robot] dh_length_std_mm``,
``dh_angle_std_deg`` for a table that was not identified on this robot); the offsets get a broad
prior (``OFFSET_PRIOR_STD_DEG``) that only regularises what the data cannot see. Each face
measurement (``ucal.calibration.model``) contributes three rows

    r_tilt = tilt_components(b(q+δ)) / σ_tilt                         model eq. (1), two rows
    r_dist = (n_k·(p(q'+δ) − c)/cos θ − (c_w/c_0)·d) / σ_d           model eq. (2)

with ``d`` the water path computed with the profile's sound speed ``c_0``, read at the
readings ``q'`` (``distance_joints``), where the beam may be θ off normal (cos θ = −n_k·b); each
prior one row
``(x − x_prior)/σ_prior``. ``scipy.optimize.least_squares`` minimises the sum of squares and
returns its own (forward-difference) Jacobian ``J`` of the whole augmented problem.

Uncertainty: ``Cov = (JᵀJ)⁻¹`` of the augmented problem is the covariance of every unknown
with the nuisance unknowns marginalised (their priors enter as rows, so the declared
tolerances propagate into the offsets' std), multiplied by ``max(1, χ²ᵣ)`` when the data
disagree with the model. Physics decides what that std carries:

* the block's yaw and δ1 are one rotation about the base axis: no measurement separates them,
  so ``std(δ1) ≥ rotation_std_deg[2]`` in the robot's base frame; the callers hold the yaw as
  placed and give δ1 relative to the block (``ucal.calibration.gauge``), absolute only with a
  doweled, levelled fixture;
* at one J1 azimuth, a block tilt about the joint-2 axis and δ2 are one rotation about that
  axis (the corner takes up the translation): ``std(δ2)`` carries the tilt tolerance unless
  the block is also seen from another J1 azimuth (configuration ``"j1"`` of the sequence);
* a constant time-of-flight delay and the tool's offset along the beam shift every water path
  alike: the block corner along the three normals absorbs them (they are not fitted apart);
* with the beam on the joint-6 axis, δ6 turns nothing the data see (only the tool tilt's
  azimuth, itself a tolerance).

A joint whose std exceeds ``max_std_deg`` and whose variance comes mainly from a prior (its own
broad prior: the data do not see it; a tolerance: it is confounded with that quantity) is
reported unobservable with the reason, and keeps its profile value.

Fit quality: ``χ²`` over all rows has ``dof`` = number of data rows (every unknown has a prior
row); ``verdict`` is ``misfit`` when P(χ²_dof > χ²) < ``MISFIT_P``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import OptimizeResult, least_squares
from scipy.special import chdtrc

from ucal.acoustics import sound_speed_m_s
from ucal.calibration.model import (
    FACE_NAMES,
    CellGeometry,
    FaceMeasurement,
    beam_and_tcp,
    distance_joints,
)
from ucal.cell import CellProfile
from ucal.kinematics.dh import RobotModel, transform

#: Broad prior on each offset (deg): keeps a direction the data cannot see finite, nothing more.
OFFSET_PRIOR_STD_DEG = 10.0
#: Probability below which the χ² of the fit is called a misfit.
MISFIT_P = 1e-3
#: A joint whose std exceeds this and comes mainly from a prior is reported unobservable.
MAX_STD_DEG = 0.02

OFFSETS = tuple(f"J{j}" for j in range(1, 7))
BLOCK = ("block_x_mm", "block_y_mm", "block_z_mm", "block_rx_deg", "block_ry_deg", "block_rz_deg")
TOOL = ("tool_x_mm", "tool_y_mm", "tool_z_mm", "tool_rx_deg", "tool_ry_deg", "tool_rz_deg")
SOUND = ("sound_speed_m_s",)
#: The DH table's lengths and twists (the θ offsets are the joint offsets themselves).
DH = tuple(f"dh{i}_{k}" for i in range(1, 7) for k in ("d_mm", "a_mm", "alpha_deg"))
PARAMETERS = OFFSETS + BLOCK + TOOL + SOUND + DH
#: Hayati's twist of the parallel axes 2-3 (``calibrate --level full``; a table that holds it
#: turns it into link 2's ``beta_deg``).
BETA = ("dh2_beta_deg",)
#: The reflector plate relative to the plane of its touched points: height along that plane's
#: normal at their centroid, tilts towards its in-plane axes e1, e2 (``ucal.toolframe.fit``).
PLATE = ("plate_h_mm", "plate_t1_deg", "plate_t2_deg")
#: A constant electronic delay in every time of flight (round trip, ns).
DELAY = ("tof_delay_ns",)
#: Prior of the delay when the cell states none (ns): probe, cable and pulser zero not
#: measured; 50 ns ≈ 0.04 mm of water path.
DELAY_PRIOR_STD_NS = 50.0

#: What a prior stands for, in the words of a reason for a user.
PRIOR_MEANING = {
    "block_x_mm": "the block position tolerance",
    "block_y_mm": "the block position tolerance",
    "block_z_mm": "the block position tolerance",
    "block_rx_deg": "the block tilt tolerance ([sample] rotation_std_deg)",
    "block_ry_deg": "the block tilt tolerance ([sample] rotation_std_deg)",
    "block_rz_deg": "the block yaw tolerance ([sample] rotation_std_deg; block yaw and J1 are "
    "one rotation about the base axis)",
    "tool_x_mm": "the tool position tolerance",
    "tool_y_mm": "the tool position tolerance",
    "tool_z_mm": "the tool position tolerance",
    "tool_rx_deg": "the tool orientation tolerance",
    "tool_ry_deg": "the tool orientation tolerance",
    "tool_rz_deg": "the tool orientation tolerance",
    "sound_speed_m_s": "the water temperature tolerance",
    **{
        n: "the kinematic model's tolerance ([robot] dh_length_std_mm, dh_angle_std_deg)"
        for n in DH + BETA
    },
    "plate_h_mm": "the plate height tolerance ([reflector] points_std_mm)",
    "plate_t1_deg": "the plate tilt tolerance ([reflector] points_std_mm)",
    "plate_t2_deg": "the plate tilt tolerance ([reflector] points_std_mm)",
    "tof_delay_ns": f"the unmeasured electronic delay (0 ± {DELAY_PRIOR_STD_NS:g} ns)",
    **{
        n: f"the prior of {n}'s offset ([calibration] std_deg; wide when not calibrated)"
        for n in OFFSETS
    },
}


@dataclass(frozen=True)
class CellPrior:
    """What the profile believes, with its one-sigma tolerances (mm, deg, °C)."""

    model: RobotModel
    offsets_deg: np.ndarray
    tool_position_mm: np.ndarray
    tool_rotation_deg: np.ndarray
    block_position_mm: np.ndarray
    block_rotation_deg: np.ndarray
    water_temperature_c: float
    tool_position_std_mm: np.ndarray = field(default_factory=lambda: np.full(3, 1.0))
    tool_rotation_std_deg: np.ndarray = field(default_factory=lambda: np.full(3, 0.5))
    block_position_std_mm: np.ndarray = field(default_factory=lambda: np.full(3, 5.0))
    block_rotation_std_deg: np.ndarray = field(default_factory=lambda: np.full(3, 0.5))
    water_temperature_std_c: float = 2.0
    dh_length_std_mm: float = 0.2
    dh_angle_std_deg: float = 0.02
    #: Height of the step on the block's XY face (mm) and its one sigma (0: no step; the cell
    #: then has no length standard).
    step_mm: float = 0.0
    step_std_mm: float = 0.0

    @property
    def sound_speed_m_s(self) -> float:
        """Profile sound speed c_0 (m/s): the one the water paths were computed with."""
        return float(sound_speed_m_s(self.water_temperature_c))

    @property
    def sound_speed_std_m_s(self) -> float:
        """One sigma of c_0 from the temperature tolerance: |dc/dT|·σ_T (≈ 3 m/s/°C at 20 °C)."""
        t = self.water_temperature_c
        slope = (sound_speed_m_s(t + 0.01) - sound_speed_m_s(t - 0.01)) / 0.02
        return float(abs(slope) * self.water_temperature_std_c)

    def values(self) -> np.ndarray:
        """Prior values in ``PARAMETERS`` order."""
        dh = self.model.dh[:, 1:4].ravel()
        return np.concatenate(
            [
                self.offsets_deg,
                self.block_position_mm,
                self.block_rotation_deg,
                self.tool_position_mm,
                self.tool_rotation_deg,
                [self.sound_speed_m_s],
                dh,
            ]
        ).astype(float)

    def stds(self) -> np.ndarray:
        """Prior one-sigmas in ``PARAMETERS`` order."""
        return np.concatenate(
            [
                np.full(6, OFFSET_PRIOR_STD_DEG),
                self.block_position_std_mm,
                self.block_rotation_std_deg,
                self.tool_position_std_mm,
                self.tool_rotation_std_deg,
                [self.sound_speed_std_m_s],
                np.tile([self.dh_length_std_mm, self.dh_length_std_mm, self.dh_angle_std_deg], 6),
            ]
        ).astype(float)


def prior_from_profile(profile: CellProfile) -> CellPrior:
    """The ``CellPrior`` of a ``CellProfile`` (tolerances from its std keys)."""
    p = profile
    return CellPrior(
        model=p.model,
        offsets_deg=np.asarray(p.joint_offsets_deg, float),
        tool_position_mm=np.asarray(p.tool_position_mm, float),
        tool_rotation_deg=np.asarray(p.tool_rotation_deg, float),
        block_position_mm=np.asarray(p.sample_position_mm, float),
        block_rotation_deg=np.asarray(p.sample_rotation_deg, float),
        water_temperature_c=float(p.water_temperature_c),
        tool_position_std_mm=np.broadcast_to(p.tool_position_std_mm, 3).astype(float),
        tool_rotation_std_deg=np.broadcast_to(p.tool_rotation_std_deg, 3).astype(float),
        block_position_std_mm=np.broadcast_to(p.sample_position_std_mm, 3).astype(float),
        block_rotation_std_deg=np.broadcast_to(p.sample_rotation_std_deg, 3).astype(float),
        water_temperature_std_c=float(p.water_temperature_std_c),
        dh_length_std_mm=float(p.dh_length_std_mm),
        dh_angle_std_deg=float(p.dh_angle_std_deg),
        step_mm=0.0 if p.step is None else float(p.step.height_mm),
        step_std_mm=0.0 if p.step is None else float(p.step.height_std_mm),
    )


def offsets_prior_std_deg(profile: object) -> np.ndarray:
    """What a profile knows of its joint offsets (deg, one sigma): ``[calibration] std_deg``
    where calibrate determined them, ``OFFSET_PRIOR_STD_DEG`` (wide) for a joint it did not
    determine or a profile never calibrated."""
    std = getattr(profile, "joint_offsets_std_deg", None)
    if std is None:
        return np.full(6, OFFSET_PRIOR_STD_DEG)
    std = np.asarray(std, float)
    return np.where(np.isfinite(std) & (std > 0), std, OFFSET_PRIOR_STD_DEG)


class ParameterTable:
    """Named unknowns with a mask of the free ones (pybotics / robot_calibration style)."""

    def __init__(
        self,
        names: tuple[str, ...],
        values: np.ndarray,
        prior_stds: np.ndarray,
        free: np.ndarray | None = None,
    ):
        self.names = tuple(names)
        self.values = np.array(values, float)
        self.prior = self.values.copy()
        self.prior_stds = np.array(prior_stds, float)
        self.free = np.ones(len(names), bool) if free is None else np.array(free, bool)
        self._index = {n: i for i, n in enumerate(self.names)}
        self._positions: dict[tuple[str, ...], np.ndarray] = {}

    def index(self, name: str) -> int:
        return self._index[name]

    def get(self, names: tuple[str, ...], values: np.ndarray | None = None) -> np.ndarray:
        """Values of ``names`` (from ``values``, a full vector, or the table)."""
        v = self.values if values is None else values
        idx = self._positions.get(names)
        if idx is None:  # the solvers ask for the same groups hundreds of times
            idx = self._positions[names] = np.array([self._index[n] for n in names], int)
        return v[idx]

    def expand(self, x_free: np.ndarray) -> np.ndarray:
        """Full value vector with the free entries replaced by ``x_free``."""
        v = self.values.copy()
        v[self.free] = x_free
        return v

    @property
    def free_names(self) -> tuple[str, ...]:
        return tuple(n for n, f in zip(self.names, self.free, strict=True) if f)


@dataclass(frozen=True)
class ResidualRow:
    """One measurement's normalised residuals (dimensionless) and its label."""

    label: str
    tilt: tuple[float, float]
    distance: float

    @property
    def norm(self) -> float:
        return float(np.sqrt(self.tilt[0] ** 2 + self.tilt[1] ** 2 + self.distance**2))


@dataclass(frozen=True)
class FitQuality:
    """The ``fit`` object of SPEC.md, plus per-measurement residuals and the likely cause."""

    chi2_reduced: float
    dof: int
    rms_tilt_deg: float
    rms_distance_mm: float
    worst: str
    verdict: str
    cause: str = ""
    residuals: tuple[ResidualRow, ...] = ()
    prior_pulls: dict[str, float] = field(default_factory=dict)

    def to_json(self) -> dict:
        return {
            "chi2_reduced": self.chi2_reduced,
            "dof": self.dof,
            "rms_tilt_deg": self.rms_tilt_deg,
            "rms_distance_mm": self.rms_distance_mm,
            "worst": self.worst,
            "verdict": self.verdict,
        }


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

    def value(self, name: str) -> float:
        return float(self.estimate[self.table.index(name)])

    def sigma(self, name: str) -> float:
        return float(self.std[self.table.index(name)])


def measurement_label(m: FaceMeasurement) -> str:
    return f"{m.config}/{FACE_NAMES[m.face]}"


def _rpy_matrix(rxyz_deg: np.ndarray) -> np.ndarray:
    """``rpy_to_matrix`` for one triple, written out (it runs in the solver's inner loop)."""
    cx, cy, cz = np.cos(np.radians(rxyz_deg))
    sx, sy, sz = np.sin(np.radians(rxyz_deg))
    # Rx·Ry·Rz (Staubli convention)
    return np.array(
        [
            [cy * cz, -cy * sz, sy],
            [sx * sy * cz + cx * sz, -sx * sy * sz + cx * cz, -sx * cy],
            [-cx * sy * cz + sx * sz, cx * sy * sz + sx * cz, cx * cy],
        ]
    )


def cell_geometry(table: ParameterTable, values: np.ndarray, model: RobotModel) -> CellGeometry:
    """The geometry (tool, block orientation) that a parameter vector describes."""
    tool = transform(table.get(TOOL[:3], values), _rpy_matrix(table.get(TOOL[3:], values)))
    return CellGeometry(model, tool, _rpy_matrix(table.get(BLOCK[3:], values)))


@dataclass(frozen=True)
class MeasurementArrays:
    """Face measurements as arrays, built once per fit (its residuals run hundreds of times)."""

    postures: np.ndarray  # (2n, 6): the peak postures, then where each water path was read
    faces: np.ndarray  # (n,)
    in_plane: np.ndarray  # (n, 2): each face's two in-plane block axes
    tilt_std_rad: np.ndarray  # (n,)
    distance_mm: np.ndarray  # (n,)
    distance_std_mm: np.ndarray

    @classmethod
    def of(cls, meas: list[FaceMeasurement]) -> MeasurementArrays:
        faces = np.array([m.face for m in meas], int)
        return cls(
            np.array(
                [m.joints_deg for m in meas] + [distance_joints(m) for m in meas], float
            ).reshape(-1, 6),
            faces,
            np.array([[i for i in range(3) if i != f] for f in faces], int),
            np.radians([m.tilt_std_deg for m in meas]),
            np.array([m.distance_mm for m in meas], float),
            np.array([m.distance_std_mm for m in meas], float),
        )


def table_geometry(table: ParameterTable, values: np.ndarray, model: RobotModel) -> CellGeometry:
    """``cell_geometry`` with the DH lengths and twists of ``values`` (and Hayati's β₂ when the
    table has it) in ``model``."""
    dh = model.dh.copy()
    dh[:, 1:4] = table.get(DH, values).reshape(6, 3)
    beta = None
    if BETA[0] in table.names:
        beta = np.zeros(6) if model.beta_deg is None else model.beta_deg.copy()
        beta[1] = table.get(BETA, values)[0]
    return cell_geometry(table, values, model.with_dh(dh, beta))


def data_residuals(
    table: ParameterTable,
    values: np.ndarray,
    model: RobotModel,
    meas: list[FaceMeasurement] | MeasurementArrays,
    c0_m_s: float,
) -> np.ndarray:
    """Normalised measurement residuals (n, 3): two tilt rows, one distance row each."""
    arr = meas if isinstance(meas, MeasurementArrays) else MeasurementArrays.of(meas)
    n = len(arr.faces)
    geom = table_geometry(table, values, model)
    offsets = table.get(OFFSETS, values)
    corner = table.get(BLOCK[:3], values)
    scale = table.get(SOUND, values)[0] / c0_m_s
    both, tcp_both = beam_and_tcp(geom, arr.postures, offsets)  # one FK call
    beam, beam_d, tcp = both[:n], both[n:], tcp_both[n:]
    rot = geom.block_rotation
    normal = rot[:, arr.faces].T  # (n, 3)
    basis = rot.T[arr.in_plane]  # (n, 2, 3)
    out = np.empty((n, 3))
    out[:, :2] = np.einsum("nkj,nj->nk", basis, beam) / arr.tilt_std_rad[:, None]  # tilts
    # Along the beam to the face: the TOF may be read a few tenths of a degree off normal,
    # where the path is n·(p − c)/cos θ (2 µm longer at 0.36° and 100 mm).
    cos_t = np.maximum(-np.einsum("nj,nj->n", normal, beam_d), 0.5)
    path = np.einsum("nj,nj->n", normal, tcp - corner) / cos_t
    out[:, 2] = (path - scale * arr.distance_mm) / arr.distance_std_mm
    return out


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
    return least_squares(
        fun,
        x0,
        jac="2-point",
        method="trf",
        x_scale=x_scale[table.free],
        xtol=tol,
        ftol=tol,
        gtol=tol,
        max_nfev=max_nfev,
    )


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
) -> CellFit:
    """Fit offsets, block, tool, sound speed and DH table to ``meas`` with the priors (module
    docstring).

    ``fixed`` names parameters held at their prior values (e.g. the DH table while predicting
    postures during a run); ``start`` is a full parameter vector to start from (a previous
    estimate), ``tol`` the solver's tolerances; ``table`` the unknowns if not ``PARAMETERS``
    with the prior's values and tolerances (``ucal.calibration.full`` adds Hayati's twist);
    ``extra`` the rows of other measurements (``ucal.calibration.full``'s edge crossings).
    """
    if table is None:
        table = ParameterTable(PARAMETERS, prior.values(), prior.stds())
    for name in fixed:
        table.free[table.index(name)] = False
    table.free &= table.prior_stds > 0  # a zero tolerance means "known exactly"
    c0 = prior.sound_speed_m_s
    n_extra = 0 if extra is None else len(extra.labels)
    n_data = 3 * len(meas) + n_extra
    has_prior = np.isfinite(table.prior_stds) & table.free

    arrays = MeasurementArrays.of(meas)

    def fun(x: np.ndarray) -> np.ndarray:
        v = table.expand(x)
        r_data = data_residuals(table, v, prior.model, arrays, c0).ravel()
        r_prior = (v - table.prior)[has_prior] / table.prior_stds[has_prior]
        if extra is None:
            return np.concatenate([r_data, r_prior])
        return np.concatenate([r_data, extra.residuals(v), r_prior])

    if start is not None:
        x0 = np.asarray(start, float)[table.free].copy()
    else:
        # Start the corner where eq. (2) puts it with the prior offsets (a hand-placed block
        # can be centimetres off; the least-squares start should not depend on that).
        x0 = _initial_corner(table, prior, meas, table.values[table.free].copy())
    sol = _least_squares_with_priors(fun, x0, table, tol, 200)
    jac = sol.jac
    res = sol.fun
    estimate = table.expand(sol.x)
    info = jac.T @ jac
    cov = np.linalg.pinv(info)
    chi2 = float(res @ res)
    dof = max(1, n_data)
    chi2_red = chi2 / dof
    scale = max(1.0, chi2_red)
    cov_scaled = cov * scale
    std = np.full(len(table.names), np.nan)
    std[table.free] = np.sqrt(np.clip(np.diag(cov_scaled), 0.0, None))

    shares = _variance_shares(table, jac, cov, n_data)
    quality = _quality(
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
    )
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
    )


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


def _quality(
    table: ParameterTable,
    estimate: np.ndarray,
    prior: CellPrior,
    meas: list[FaceMeasurement],
    res: np.ndarray,
    n_data: int,
    chi2: float,
    dof: int,
    misfit_p: float,
    extra_labels: tuple[str, ...] = (),
) -> FitQuality:
    n_face = 3 * len(meas)
    r = res[:n_face].reshape(-1, 3)
    rows = tuple(
        ResidualRow(measurement_label(m), (float(r[i, 0]), float(r[i, 1])), float(r[i, 2]))
        for i, m in enumerate(meas)
    ) + tuple(
        ResidualRow(label, (0.0, 0.0), float(v))
        for label, v in zip(extra_labels, res[n_face:n_data], strict=True)
    )
    tilt_deg = np.array([r[i, :2] * m.tilt_std_deg for i, m in enumerate(meas)])
    dist_mm = np.array([r[i, 2] * m.distance_std_mm for i, m in enumerate(meas)])
    free = table.free_names
    prior_names = [n for n in free if np.isfinite(table.prior_stds[table.index(n)])]
    pulls = {n: float(v) for n, v in zip(prior_names, res[n_data:], strict=True)}
    worst_row = max(rows, key=lambda x: x.norm)
    worst_pull = max(
        ((n, v) for n, v in pulls.items() if n not in OFFSETS),
        key=lambda kv: abs(kv[1]),
        default=("", 0.0),
    )
    worst = worst_row.label
    if abs(worst_pull[1]) > worst_row.norm:
        worst = f"prior {worst_pull[0]}"
    p_value = float(chdtrc(dof, chi2))  # χ² survival function (scipy.stats.chi2.sf)
    verdict = "misfit" if p_value < misfit_p else "ok"
    cause = likely_cause(rows, pulls, table, estimate, prior) if verdict == "misfit" else ""
    return FitQuality(
        chi2_reduced=chi2 / dof,
        dof=dof,
        rms_tilt_deg=float(np.sqrt(np.mean(tilt_deg**2))),
        rms_distance_mm=float(np.sqrt(np.mean(dist_mm**2))),
        worst=worst,
        verdict=verdict,
        cause=cause,
        residuals=rows,
        prior_pulls=pulls,
    )


#: A pull beyond this many of its prior's σ is evidence that something is absorbed there, not
#: by itself the cause.
FAR_PULL_SIGMA = 10.0
#: How far from its profile value each kind of quantity can physically be (the sound speed: the
#: range of water from 0 to 70 °C, m/s); a fit beyond it explains nothing about the cell.
PHYSICAL_SPAN: dict[str, float | tuple[float, float]] = {
    "sound_speed_m_s": (1400.0, 1560.0),
    "block_x_mm": 50.0,
    "block_y_mm": 50.0,
    "block_z_mm": 50.0,
    "block_rx_deg": 5.0,
    "block_ry_deg": 5.0,
    "block_rz_deg": 10.0,
    "tool_x_mm": 5.0,
    "tool_y_mm": 5.0,
    "tool_z_mm": 10.0,
    "tool_rx_deg": 5.0,
    "tool_ry_deg": 5.0,
    "tool_rz_deg": 10.0,
    **{n: 2.0 for n in DH if n.endswith("_mm")},
    **{n: 0.5 for n in DH if n.endswith("_deg")},
}


def physically_possible(name: str, value: float, profile_value: float) -> bool:
    """Whether a fitted quantity lies where a real cell could put it (``PHYSICAL_SPAN``)."""
    span = PHYSICAL_SPAN.get(name)
    if span is None:
        return True
    if isinstance(span, tuple):
        return span[0] <= value <= span[1]
    return abs(value - profile_value) <= span


def residual_pattern(rows: tuple[ResidualRow, ...]) -> str:
    """What the residuals' order shows, or "": water paths that trend with the order of the
    readings (their time) point at a drift, not at a quantity of the cell."""
    dist = np.array([r.distance for r in rows], float)
    if len(dist) < 6 or float(np.std(dist)) == 0.0:
        return ""
    order = np.arange(len(dist), dtype=float)
    corr = float(np.corrcoef(order, dist)[0, 1])
    if abs(corr) < 0.8:
        return ""
    return (
        f"the water-path residuals trend with the order of the readings (correlation {corr:+.2f} "
        "with their time): a drift during the run, most often the tank warming or cooling (the "
        "sound speed changing); let the water settle, or measure again and compare"
    )


def likely_cause(
    rows: tuple[ResidualRow, ...],
    pulls: dict[str, float],
    table: ParameterTable,
    estimate: np.ndarray,
    prior: CellPrior,
) -> str:
    """A sentence naming the most likely cause of a misfit, from where the misfit sits.

    If the priors carry most of the χ² (the data fit, but only by moving a quantity beyond its
    tolerance), the cell is outside its declared tolerance (block placed worse than stated,
    water warmer, tool off). A quantity dragged beyond ``FAR_PULL_SIGMA`` is named as evidence;
    dragged where no real cell could put it (``PHYSICAL_SPAN``), it is not offered as the cause:
    the residuals' pattern is (a drift over the run), or the message says that the model does
    not explain the data. Otherwise the measurements themselves disagree with the model:
    residuals mostly in the water paths point at the kinematic model (link lengths), mostly in
    the tilts at the tool frame or the block's faces.
    """
    tilt2 = sum(r.tilt[0] ** 2 + r.tilt[1] ** 2 for r in rows)
    dist2 = sum(r.distance**2 for r in rows)
    nuisance = {n: p for n, p in pulls.items() if not n.startswith("J")}
    prior2 = sum(p**2 for p in nuisance.values())
    pattern = residual_pattern(rows)
    if nuisance and prior2 > tilt2 + dist2:
        name, pull = max(nuisance.items(), key=lambda kv: abs(kv[1]))
        value = estimate[table.index(name)]
        prior_v = table.prior[table.index(name)]
        what = PRIOR_MEANING.get(name, name)
        evidence = (
            f"{name} fitted at {value:.4g}, {abs(pull):.1f}σ from the profile's {prior_v:.4g}"
        )
        if not physically_possible(name, float(value), float(prior_v)):
            return (
                f"the model does not explain the data: to fit them it drags {evidence}, where no "
                f"cell can be (evidence, not a cause); "
                + (
                    pattern
                    or "look for what the model lacks: lost motion (residuals that change sign "
                    "with the approach direction), a drift over the run (residuals that trend "
                    "with time), the transducer's frequency or size, or the DH table"
                )
            )
        if abs(pull) > FAR_PULL_SIGMA and pattern:
            return f"{pattern} ({evidence}, absorbing it)"
        return f"{evidence}: the cell is outside {what}; correct the profile or widen its tolerance"
    if pattern:
        return pattern
    if dist2 >= tilt2:
        return (
            "the water paths disagree with the kinematic model across the stepped "
            "configurations (link lengths or joint twists differ from the DH table): "
            "calibrate with --level full, or check the sound speed and the block faces"
        )
    return (
        "the normal-incidence postures disagree with the model: check the tool frame "
        "(run tool-frame) and that the block's faces are flat and perpendicular; a "
        "kinematic model error (--level full) can also show here"
    )


# ---------------------------------------------------------------------------------------------
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


def solve_augmented(
    table: ParameterTable,
    data_fn: Callable[[np.ndarray], np.ndarray],
    x0: np.ndarray,
    tol: float = 1e-12,
    max_nfev: int = 200,
    measured: tuple[str, ...] = (),
) -> AugmentedFit:
    """Minimise ``|data_fn(v)|² + Σ ((v − prior)/σ)²`` over the free parameters of ``table``
    (``data_fn`` takes the full value vector and returns normalised data residuals).

    ``measured`` names the quantities the run exists to measure: their priors (a drawing's
    tolerance) still enter the solution, but their pulls are not counted in the χ² that
    judges the fit and scales the covariance."""
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
    std = np.full(len(table.names), np.nan)
    std[table.free] = np.sqrt(np.clip(np.diag(cov_scaled), 0.0, None))
    return AugmentedFit(
        table, table.expand(sol.x), cov_scaled, std, sol.jac, sol.fun, cov @ sol.jac.T, n_data, chi2
    )


def verdict(chi2: float, dof: int, misfit_p: float = MISFIT_P) -> str:
    """``misfit`` when P(χ²_dof > χ²) < ``misfit_p``, else ``ok``."""
    return "misfit" if float(chdtrc(dof, chi2)) < misfit_p else "ok"
