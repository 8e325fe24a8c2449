"""The unknowns of the calibration solvers: their names, the profile's values and tolerances
as priors (``CellPrior``), and the table of named parameters with the mask of the free ones
(``ParameterTable``). The model they enter is in ``ucal.model.fit``'s docstring.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from ucal.acoustics import sound_speed_m_s, sound_speed_slope_m_s_per_c
from ucal.cell import STANDARD_GRAVITY_M_S2, CellProfile
from ucal.kinematics.dh import RobotModel
from ucal.kinematics.gravity import BodyWeights
from ucal.model.load import COMPLIANCE, PostureLoad, model_bodies

#: Gravity in the robot's base frame (m/s²): a floor-mounted arm.
GRAVITY_M_S2 = np.array([0.0, 0.0, -STANDARD_GRAVITY_M_S2])

#: Broad prior on each offset (deg): keeps a direction the data cannot see finite, nothing more.
OFFSET_PRIOR_STD_DEG = 10.0
#: A joint whose std exceeds this and comes mainly from a prior is reported unobservable.
MAX_STD_DEG = 0.02

OFFSETS = tuple(f"J{j}" for j in range(1, 7))
BLOCK = ("block_x_mm", "block_y_mm", "block_z_mm", "block_rx_deg", "block_ry_deg", "block_rz_deg")
TOOL = ("tool_x_mm", "tool_y_mm", "tool_z_mm", "tool_rx_deg", "tool_ry_deg", "tool_rz_deg")
SOUND = ("sound_speed_m_s",)
#: The DH table's lengths and twists (the θ offsets are the joint offsets themselves).
DH = tuple(f"dh{i}_{k}" for i in range(1, 7) for k in ("d_mm", "a_mm", "alpha_deg"))
#: How fast the sound speed changes during the run (m/s per minute): the tank warming or cooling.
DRIFT = ("sound_speed_drift_m_s_per_min",)
#: Lost motion per joint (deg): the link lags its encoder by half of it, against the direction
#: of the joint's last motion.
BACKLASH = tuple(f"backlash_J{j}" for j in range(1, 7))
PARAMETERS = OFFSETS + BLOCK + TOOL + SOUND + DH + DRIFT + BACKLASH
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


def twists_deg(model: RobotModel) -> np.ndarray:
    """Hayati's twists of ``model`` (6,; deg), zeros where it states none."""
    return np.zeros(6) if model.beta_deg is None else np.asarray(model.beta_deg, float)


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
    "sound_speed_drift_m_s_per_min": "the tank's drift tolerance ([water] drift_std_c_per_min; "
    "about a thermometer log's drift where one was given)",
    **{n: "the lost motion tolerance ([robot] backlash_std_deg)" for n in BACKLASH},
    **{
        n: "the kinematic model's tolerance ([robot] dh_length_std_mm, dh_angle_std_deg; "
        "[calibration] dh_std where the full level identified it)"
        for n in DH + BETA
    },
    "plate_h_mm": "the plate height tolerance ([reflector] points_std_mm)",
    "plate_t1_deg": "the plate tilt tolerance ([reflector] points_std_mm)",
    "plate_t2_deg": "the plate tilt tolerance ([reflector] points_std_mm)",
    **{
        n: "the joints' stiffness tolerance ([robot] stiffness_nm_per_rad, stiffness_std_fraction: "
        "how far the arm gives under its own weight and the tool's)"
        for n in COMPLIANCE
    },
    "tof_delay_ns": f"the unmeasured electronic delay (0 ± {DELAY_PRIOR_STD_NS:g} ns)",
    **{
        n: f"the prior of {n}'s offset ([calibration] std_deg; wide when not calibrated)"
        for n in OFFSETS
    },
}


class Posed(Protocol):
    """A reading taken at a posture: its joint readings (deg, (6,))."""

    @property
    def joints_deg(self) -> np.ndarray: ...


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
    #: One sigma of each row's ``d_mm, a_mm, alpha_deg, beta_deg`` (6, 4) where the full level
    #: identified them (``[calibration] dh_std``), NaN elsewhere; None: none identified.
    dh_std: np.ndarray | None = None
    #: Height of the step on the block's XY face (mm) and its one sigma (0: no step; the cell
    #: then has no length standard).
    step_mm: float = 0.0
    step_std_mm: float = 0.0
    #: How fast the tank may warm or cool during a run (°C/min, one sigma).
    drift_std_c_per_min: float = 0.05
    #: With a thermometer's log (``ucal.thermometer``): how far the tank may still depart from a
    #: steady drift over the run (°C, one sigma: ``[water] thermometer_std_c``); None without.
    logged_departure_std_c: float | None = None
    #: The drift's prior mean (°C/min): the tank's drift as a thermometer's log measured it over
    #: the run (``ucal.thermometer``); 0 without a log.
    drift_prior_c_per_min: float = 0.0
    #: Lost motion each joint may have (deg, one sigma; (6,)).
    backlash_std_deg: np.ndarray = field(default_factory=lambda: np.full(6, 0.01))
    #: Each joint's compliance (µrad per N·m) and its one sigma (``ucal.model.load``); the
    #: arm's and tool's weights (None: nothing weighs) and the posture whose load the offsets
    #: hold (None: the run's first reading).
    compliance_urad_per_nm: np.ndarray = field(default_factory=lambda: np.zeros(6))
    compliance_std_urad_per_nm: np.ndarray = field(default_factory=lambda: np.zeros(6))
    bodies: BodyWeights | None = None
    load_posture_deg: np.ndarray | None = None
    #: The offsets the torques are taken at (None: ``offsets_deg``): the full level's fitted
    #: ones where they stand far from the profile's (``ucal.model.kinematic.solve_full``).
    load_offsets_deg: np.ndarray | None = None

    def posture_load(self, meas: Sequence[Posed]) -> PostureLoad | None:
        """The torques of a run whose readings are ``meas`` relative to the load posture's
        (``load_posture_deg``, else the first reading's posture); None where nothing weighs
        or no reading is given."""
        if self.bodies is None or (self.load_posture_deg is None and not len(meas)):
            return None
        ref = meas[0].joints_deg if self.load_posture_deg is None else self.load_posture_deg
        at = self.offsets_deg if self.load_offsets_deg is None else self.load_offsets_deg
        return PostureLoad.of(self.model, self.bodies, at, np.asarray(ref, float))

    @property
    def sound_speed_m_s(self) -> float:
        """Profile sound speed c_0 (m/s): the one the water paths were computed with."""
        return float(sound_speed_m_s(self.water_temperature_c))

    @property
    def sound_speed_slope_m_s_per_c(self) -> float:
        """|dc/dT| at the profile's temperature (m/s per °C; ≈ 3 at 20 °C, Marczak)."""
        return abs(sound_speed_slope_m_s_per_c(self.water_temperature_c))

    @property
    def sound_speed_std_m_s(self) -> float:
        """One sigma of c_0 from the temperature tolerance: |dc/dT|·σ_T."""
        return self.sound_speed_slope_m_s_per_c * self.water_temperature_std_c

    @property
    def drift_prior_m_s_per_min(self) -> float:
        """The drift's prior mean in m/s per min (``drift_prior_c_per_min``)."""
        return self.sound_speed_slope_m_s_per_c * self.drift_prior_c_per_min

    @property
    def drift_std_m_s_per_min(self) -> float:
        """One sigma of the sound speed's drift: |dc/dT|·``drift_std_c_per_min``."""
        return self.sound_speed_slope_m_s_per_c * self.drift_std_c_per_min

    def dh_stds(self) -> np.ndarray:
        """Prior one-sigmas of the DH table (6, 4: each row's ``d_mm, a_mm, alpha_deg,
        beta_deg``): what the full level identified (``dh_std``) where it did, the [robot]
        tolerances (``dh_length_std_mm``, ``dh_angle_std_deg``) elsewhere."""
        length, angle = self.dh_length_std_mm, self.dh_angle_std_deg
        tolerance = np.tile([length, length, angle, angle], (6, 1))
        if self.dh_std is None:
            return tolerance
        return np.where(np.isfinite(self.dh_std), self.dh_std, tolerance)

    def dh_prior_stds(self) -> np.ndarray:
        """Prior one-sigmas of the unknowns ``DH`` (18,: each row's d, a, α), ``dh_stds``."""
        return self.dh_stds()[:, :3].ravel()

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
                # the drift (its log's, else none) and the lost motion: none unless the data
                # show them
                [self.drift_prior_m_s_per_min],
                np.zeros(6),
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
                self.dh_prior_stds(),
                [self.drift_std_m_s_per_min],
                np.broadcast_to(self.backlash_std_deg, 6),
            ]
        ).astype(float)


def prior_from_profile(profile: CellProfile) -> CellPrior:
    """The ``CellPrior`` of a ``CellProfile`` (tolerances from its std keys; the DH table's
    from ``[calibration] dh_std`` where the full level identified it, ``CellPrior.dh_stds``)."""
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
        dh_std=None if p.dh_std is None else np.asarray(p.dh_std, float),
        step_mm=0.0 if p.step is None else float(p.step.height_mm),
        step_std_mm=0.0 if p.step is None else float(p.step.height_std_mm),
        drift_std_c_per_min=float(p.drift_std_c_per_min),
        logged_departure_std_c=float(p.thermometer_std_c) if p.tank_logged else None,
        drift_prior_c_per_min=float(p.logged_drift_c_per_min),
        backlash_std_deg=np.broadcast_to(p.backlash_std_deg, 6).astype(float),
        **_compliance(p),
    )


def _compliance(p: CellProfile) -> dict[str, Any]:
    """``CellPrior``'s compliance fields of a profile (``ucal.model.load``)."""
    k = np.asarray(p.stiffness_nm_per_rad, float)
    c = np.divide(1e6, k, out=np.zeros(6), where=k > 0.0)
    bodies = model_bodies(
        p.model,
        p.link_mass_kg,
        p.link_centre_of_mass_mm,
        p.tool_mass_kg,
        p.tool_centre_of_mass_mm,
        GRAVITY_M_S2,
    )
    return {
        "compliance_urad_per_nm": c,
        "compliance_std_urad_per_nm": c * p.stiffness_std_pct / 100.0,
        "bodies": bodies,
        "load_posture_deg": p.load_posture_deg,
    }


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
        return np.asarray(v[idx])

    def expand(self, x_free: np.ndarray) -> np.ndarray:
        """Full value vector with the free entries replaced by ``x_free``."""
        v = self.values.copy()
        v[self.free] = x_free
        return v

    @property
    def free_names(self) -> tuple[str, ...]:
        return tuple(n for n, f in zip(self.names, self.free, strict=True) if f)
