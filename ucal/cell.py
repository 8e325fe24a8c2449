"""What a cell is made of: the profile (what we believe) and the world (the simulator's truth).

Both are plain frozen dataclasses; ``ucal.profile`` reads/writes profiles and ``ucal.world``
reads world files. Units: mm and degrees throughout.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from drivers.controller.client import DEFAULT_TIMEOUTS
from drivers.pulser.base import PulserSettings
from drivers.pulser.registers import RegisterMap
from ucal.kinematics.dh import RobotModel, transform
from ucal.kinematics.rotations import rpy_to_matrix

if TYPE_CHECKING:  # the A-scan code (scipy.signal) loads only where echoes are timed
    from ucal.echo.ascan import ReferenceEcho

#: Paper 000, §5.1: the calibration pose of the TX90L (deg).
PAPER_CALIBRATION_POSE_DEG = np.array([30.53, 31.15, 109.49, 0.0, 39.36, 30.54])


@dataclass(frozen=True)
class TemperatureLog:
    """A thermometer's log as read from its file.

    ``time_min`` (n,): strictly increasing; minutes of the simulated cell's clock since it
    started (``wall_clock`` False: a world file's ``[water] temperature_log``, a rehearsal's
    thermometer), or minutes since the Unix epoch (``wall_clock`` True: a logger's times);
    ``temperature_c`` (n,): the readings (°C). Between readings the water follows the straight
    line between them; before the first and after the last it stays at that reading.
    """

    path: Path
    time_min: np.ndarray
    temperature_c: np.ndarray
    wall_clock: bool = False

    def at(self, t_min: float) -> float:
        """The temperature (°C) the log gives at ``t_min`` (its own time base)."""
        return float(np.interp(t_min, self.time_min, self.temperature_c))


@dataclass(frozen=True)
class Procedure:
    """Procedure settings (``[procedure]`` in the profile; every key optional)."""

    calibration_pose_deg: np.ndarray | None = None  # None: computed with IK from the block pose
    water_path_mm: float = 100.0  # nominal TCP-to-face distance; ±5° offsets move W by ~90 mm
    step_deg: float = 2.0  # δθ3 and δθ2 of paper 000
    speed: float = 0.3  # fraction of the controller's maximum speed
    singularity_margin_deg: float = 10.0  # |θ5| must stay above this in every planned target
    tof_averages: int = 16  # pulser averaging for distance readings
    verify_tolerance_mm: float = 0.5  # largest deviation of a point on any axis `verify` passes


@dataclass(frozen=True)
class ControllerTimeouts:
    """``[controller]`` in the profile: how long the controller link may take (s; every key
    optional). The settle timeout bounds each move; the others are the driver's
    (``drivers.controller.client.DEFAULT_TIMEOUTS``)."""

    connect_timeout_s: float = DEFAULT_TIMEOUTS["connect_timeout_s"]
    first_state_timeout_s: float = DEFAULT_TIMEOUTS["first_state_timeout_s"]
    state_timeout_s: float = DEFAULT_TIMEOUTS["state_timeout_s"]
    reply_timeout_s: float = DEFAULT_TIMEOUTS["reply_timeout_s"]
    halt_timeout_s: float = DEFAULT_TIMEOUTS["halt_timeout_s"]
    settle_timeout_s: float = 60.0

    def driver_options(self) -> dict[str, float]:
        """The driver's timeouts as ``open_controller`` keyword arguments."""
        return {key: getattr(self, key) for key in DEFAULT_TIMEOUTS}


@dataclass(frozen=True)
class PulserConfig:
    """``[pulser]`` in the profile: how ucal talks to the pulser-receiver (every key optional).

    ``register_map``: the Modbus register map of the device (``drivers.pulser.map_file``),
    read and validated from ``register_map_path``; None: ucal's own map. ``timeout_s``: the
    link's margin, how long a request waits for its answer beyond what the instrument was asked
    to do (a reading's averages at the PRF, ``drivers.pulser.base.ReadingWait``); ``retries``:
    how often a request that got no byte back is asked again before the device counts as
    silent. ``timing``: who times the echo,
    ``"gate"`` (the instrument's own gate) or ``"ascan"`` (ucal, from the digitised A-scan,
    ``ucal.echo``); ``reference_echo``: the cell's reference echo for that, read from
    ``reference_echo_path`` (None: captured on the block at the start of a run).
    """

    register_map_path: Path | None = None
    register_map: RegisterMap | None = None
    timeout_s: float = 1.0
    retries: int = 1
    timing: str = "gate"
    reference_echo_path: Path | None = None
    reference_echo: ReferenceEcho | None = None
    by_hand: SetByHand | None = None

    @property
    def set_by_hand(self) -> bool:
        """Whether the cell's pulser-receiver is set on its front panel (``kind = "manual"``)."""
        return self.by_hand is not None


#: ``[pulser] input_noise_uv`` unless the profile says: a quiet pulser-receiver's noise
#: referred to its input (µV rms a sample, over a 50 MHz band; 50 Ω alone give 6 µV), the
#: simulated receiver's (``ucal.sim.cell.DEFAULT_NOISE_FLOOR``) to within 1 dB.
DEFAULT_INPUT_NOISE_UV = 2.2


@dataclass(frozen=True)
class SetByHand:
    """``[pulser]`` of a pulser-receiver set on its front panel (``kind = "manual"``): the
    settings it holds (``panel``: ``gain_db``, ``prf_hz``, ``pulse_voltage_v``,
    ``damping_ohm``, ``high_pass_mhz``, ``low_pass_mhz``; the gate and the averages are the
    digitiser's), and ``input_noise_uv``, its noise referred to its input (µV rms, one sample),
    from which the declared gain predicts the records' noise (``ucal.echo.by_hand``)."""

    panel: PulserSettings
    input_noise_uv: float = DEFAULT_INPUT_NOISE_UV


#: ``[pulser] timing``: the instrument's gate, or ucal on the A-scan.
PULSER_TIMINGS = ("gate", "ascan")

#: Largest ``[pulser] timeout_s`` a profile may state (s).
MAX_PULSER_TIMEOUT_S = 60.0

#: Largest value of each ``[controller]`` timeout a profile may state (s).
MAX_CONTROLLER_TIMEOUT_S = {
    "connect_timeout_s": 60.0,
    "first_state_timeout_s": 120.0,
    "state_timeout_s": 60.0,
    "reply_timeout_s": 60.0,
    "halt_timeout_s": 60.0,
    "settle_timeout_s": 3600.0,
}


@dataclass(frozen=True)
class CellProfile:
    """A robot cell as the profile describes it (nominal values + calibration results)."""

    model: RobotModel
    tool_position_mm: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, 80.0]))
    tool_rotation_deg: np.ndarray = field(default_factory=lambda: np.zeros(3))
    sample_position_mm: np.ndarray = field(default_factory=lambda: np.zeros(3))
    sample_rotation_deg: np.ndarray = field(default_factory=lambda: np.zeros(3))
    sample_face_size_mm: float = 500.0
    reflector_points_mm: np.ndarray | None = None  # (n, 3), n >= 3
    reflector_points_std_mm: float = 1.0  # one sigma of a touched point (an uncalibrated robot)
    step: Step | None = None  # a step of known height on the block's XY face (``[step]``)
    water_temperature_c: float = 20.0
    # One-sigma tolerances of what the profile states (SPEC.md defaults: a tool from its drawing,
    # a hand-placed block, a tank thermometer); solvers carry them as priors.
    tool_position_std_mm: np.ndarray = field(default_factory=lambda: np.full(3, 1.0))
    tool_rotation_std_deg: np.ndarray = field(default_factory=lambda: np.full(3, 0.5))
    sample_position_std_mm: np.ndarray = field(default_factory=lambda: np.full(3, 5.0))
    sample_rotation_std_deg: np.ndarray = field(default_factory=lambda: np.full(3, 0.5))
    water_temperature_std_c: float = 2.0
    dh_length_std_mm: float = 0.2  # how well the DH lengths and twists match this robot
    dh_angle_std_deg: float = 0.02
    #: How fast the tank may warm or cool during a run (°C/min, one sigma; ``[water]``).
    drift_std_c_per_min: float = 0.05
    #: How well the tank's thermometer follows a change of the water the beam crosses (°C, one
    #: sigma; ``[water] thermometer_std_c``): what its log leaves of the drift
    #: (``ucal.thermometer``).
    thermometer_std_c: float = 0.02
    #: Not a profile key: set for a run whose water paths a thermometer's log has corrected
    #: (``ucal.thermometer``), whose drift then turns no more than ``thermometer_std_c`` allows.
    tank_logged: bool = False
    #: Not a profile key: the tank's drift over the run as its thermometer's log measured it
    #: (°C/min; ``ucal.thermometer``), the drift's prior mean; 0 without a log.
    logged_drift_c_per_min: float = 0.0
    #: Lost motion each joint may have (deg, one sigma, (6,); ``[robot] backlash_std_deg``).
    backlash_std_deg: np.ndarray = field(default_factory=lambda: np.full(6, 0.01))
    #: The arm under its load (``ucal.profile.arm_load``): each joint's nominal stiffness
    #: (N·m/rad, (6,), 0 = rigid) and the one sigma of its compliance (% of the nominal, (6,):
    #: a full level's where it identified the joint, ``[calibration] stiffness_nm_per_rad``), the
    #: links' masses (kg, (6,)) and centres of mass at the zero pose (mm, base frame, (6, 3);
    #: None: nothing weighs), the tool's mass (kg) and centre of mass (mm, flange frame), and
    #: the readings at whose load the written offsets hold (None: not calibrated).
    stiffness_nm_per_rad: np.ndarray = field(default_factory=lambda: np.zeros(6))
    stiffness_std_pct: np.ndarray = field(default_factory=lambda: np.full(6, 50.0))
    link_mass_kg: np.ndarray | None = None
    link_centre_of_mass_mm: np.ndarray | None = None
    tool_mass_kg: float = 0.0
    tool_centre_of_mass_mm: np.ndarray = field(default_factory=lambda: np.zeros(3))
    load_posture_deg: np.ndarray | None = None
    frequency_mhz: float = 25.0
    element_diameter_mm: float = 6.0
    joint_offsets_deg: np.ndarray = field(default_factory=lambda: np.zeros(6))
    #: ``[calibration] std_deg`` as written with the offsets (NaN: not determined); None: never
    #: calibrated.
    joint_offsets_std_deg: np.ndarray | None = None
    #: ``[calibration] dh_std`` as written with the identified table: one sigma of each row's
    #: ``d_mm, a_mm, alpha_deg, beta_deg`` (6, 4), NaN where not determined (the [robot]
    #: tolerance stands); None: no table identified.
    dh_std: np.ndarray | None = None
    unobservable_joints: tuple[int, ...] = ()
    procedure: Procedure = field(default_factory=Procedure)
    controller: ControllerTimeouts = field(default_factory=ControllerTimeouts)
    pulser: PulserConfig = field(default_factory=PulserConfig)
    path: Path | None = None
    #: The cell as described, where ucal wrote a measurement over the description
    #: (``ucal.profile.described``): the ``[robot]`` table's model where ``[calibration] dh``
    #: replaced it, the tool as drawn, the block as placed; None: as the fields above.
    described_model: RobotModel | None = None
    described_tool: tuple[np.ndarray, np.ndarray] | None = None
    described_sample: tuple[np.ndarray, np.ndarray] | None = None

    def as_described(self) -> CellProfile:
        """The cell as its technician described it, not as ucal measured it: the ``[robot]``
        table's model, the tool as drawn, the block as placed (what a simulated cell is
        built from, ``ucal.sim.demo``); tolerances and everything else as they are."""
        tool = self.described_tool or (self.tool_position_mm, self.tool_rotation_deg)
        sample = self.described_sample or (self.sample_position_mm, self.sample_rotation_deg)
        return self.replace(
            model=self.described_model or self.model,
            tool_position_mm=tool[0],
            tool_rotation_deg=tool[1],
            sample_position_mm=sample[0],
            sample_rotation_deg=sample[1],
            described_model=None,
            described_tool=None,
            described_sample=None,
        )

    @property
    def tool_matrix(self) -> np.ndarray:
        """Tool frame relative to the flange (4, 4)."""
        return transform(self.tool_position_mm, rpy_to_matrix(self.tool_rotation_deg))

    @property
    def sample_matrix(self) -> np.ndarray:
        """Calibration-block frame in the base frame (4, 4); faces are its coordinate planes."""
        return transform(self.sample_position_mm, rpy_to_matrix(self.sample_rotation_deg))

    def replace(self, **changes: Any) -> CellProfile:
        return replace(self, **changes)


@dataclass(frozen=True)
class Reflector:
    """A finite flat plate: a point on it, its unit normal (towards the water side), its extent.

    The plate is the rectangle ``point + u·e1 + v·e2`` with |u| <= size[0]/2, |v| <= size[1]/2,
    ``e1`` = ``edge_direction`` projected into the plane, ``e2 = normal × e1``.
    """

    point_mm: np.ndarray
    normal: np.ndarray
    size_mm: np.ndarray = field(default_factory=lambda: np.array([200.0, 200.0]))
    edge_direction: np.ndarray = field(default_factory=lambda: np.array([1.0, 0.0, 0.0]))
    #: Radius of the rounded edges (mm): the flat part ends this far inside ``size_mm``; the
    #: rounded band turns its normal away from a beam aimed at the plate and echoes nothing.
    edge_radius_mm: float = 0.0
    #: Peak-to-valley flatness error (mm): a bow ``f·((2u/w)² + (2v/h)²)/2 − f/2`` along the
    #: normal, so the water path and the local normal change across the plate.
    flatness_mm: float = 0.0


@dataclass(frozen=True)
class Step:
    """A step of known height standing on the block's XY face (a ground step block, or a gauge
    block wrung to the face): its flat square top, ``height_mm`` above the face, is a reflector
    whose distance from the face no sound speed enters — the length standard of
    ``calibrate --level full``. Block frame: the top's centre at ``centre_mm`` (x, y), side
    ``size_mm``.

    A profile states how well the height is known (``height_std_mm``, one sigma: the block's
    certificate); a world may tilt the top (``tilt_deg`` about the block's x and y axes: not
    quite parallel to the face, as a gauge block not wrung flat).
    """

    height_mm: float
    centre_mm: np.ndarray
    size_mm: float
    height_std_mm: float = 0.0
    tilt_deg: np.ndarray = field(default_factory=lambda: np.zeros(2))


@dataclass(frozen=True)
class Noise:
    """Random errors of single readings (``[noise]``); every random source is seeded by ``seed``."""

    tof_ns: float = 0.0  # one-sigma TOF jitter of a single reading
    amplitude: float = 0.0  # one-sigma relative amplitude noise of a single reading
    seed: int = 0


@dataclass(frozen=True)
class CellTiming:
    """The real cell's time (world ``[timing]``; s here, ms in the file), seeded by ``Noise.seed``.

    Defaults are the released VAL3 server's state stream (JOINT_POSITION every 20 ms, no time
    stamp in the frame) over a cell network, and a Modbus TCP instrument on a LAN: the
    simulated cell applies them on both clocks, so every ``--sim`` run and every test meets a
    stream whose frames arrive late and unevenly, and readings whose acquisition instant the
    client does not know exactly.

    * ``state_period_s``: the stream's period; ``state_latency_s`` + a half-normal jitter of
      one-sigma ``state_jitter_s``: how old the position a frame carries is when it arrives;
      ``missing_state_frames``: the share of frames lost.
    * ``pulser_latency_s`` + jitter ``pulser_jitter_s`` (one sigma, half-normal): the
      instrument transport's round trip, beyond its turnaround (``ucal.timing``), half before
      the acquisition and half after; ``acquisition_delay_s``: from the acquisition to the
      reply that carries it (an instrument that answers with its last completed acquisition).
    """

    state_period_s: float | None = None  # None: the server's own (20 ms for the VAL3 server)
    state_latency_s: float = 0.002
    state_jitter_s: float = 0.001
    missing_state_frames: float = 0.0
    pulser_latency_s: float = 0.001
    pulser_jitter_s: float = 0.0005
    acquisition_delay_s: float = 0.0


#: Fixed delay (ns) between the instrument's time zero and the pulse leaving the element, that
#: every TOF reading carries: ~0.8 m of coaxial cable each way (≈ 5 ns/m) left after the
#: instrument's own zero. Real probes and cables add 10–60 ns; 8 ns keeps the uncorrected
#: reading of a 50 mm path at 20 °C at 67.46 µs to 0.01 µs.
DEFAULT_PULSER_DELAY_NS = 8.0


@dataclass(frozen=True)
class PulserTruth:
    """How the pulser-receiver reports what it receives (``[pulser]`` of a world file).

    ``amplitude_bits``: amplitude quantised to 2^bits levels of full screen height, truncated
    (a reading below one level reads 0); 0 = not quantised. ``gain_error_db``: one-sigma error
    of the gain actually applied, drawn anew at each gain change. ``delay_ns``: fixed
    electronic delay added to every time of flight (round trip, ns). ``register_map``: the
    Modbus register map the simulated pulser serves, read from ``register_map_path`` (None:
    the profile's). ``kind``: the back-end the simulated cell speaks, ``"modbus"`` (a pulser
    that gates) or ``"ascii-scpi"`` (an ASCII serial pulser and a SCPI oscilloscope that
    digitises at ``sample_rate_mhz`` with a ``bits`` ADC; ucal times the echoes). ``scope``:
    the family of that oscilloscope, ``"keysight"`` or ``"rigol"``
    (``drivers.digitizer.simulated_scopes.FAMILIES``; a Rigol DS1000Z's ADC has 8 bits, whatever
    ``bits`` says). ``"manual"``: a pulser-receiver set by hand, the same oscilloscope alone
    beside it; ``gain_db`` its front panel's gain (the world's default: the profile's
    declaration, else 20 dB, where the block's echo at 50 mm is 0.8 of full screen), which a
    run reads only through the records. ``baseline_offset``: the receiver's output at rest, a
    constant in every A-scan sample (fraction of full screen height, −0.5…0.5; 0 = none), in
    the averages and in the reference echo a run captures.
    """

    amplitude_bits: int = 0
    gain_error_db: float = 0.0
    delay_ns: float = DEFAULT_PULSER_DELAY_NS
    register_map_path: Path | None = None
    register_map: RegisterMap | None = None
    kind: str = "modbus"
    sample_rate_mhz: float = 200.0
    bits: int = 12
    scope: str = "keysight"
    gain_db: float = 20.0
    baseline_offset: float = 0.0


#: Standard gravity (m/s², ISO 80000-3), along −z of the robot base by default.
STANDARD_GRAVITY_M_S2 = 9.80665
#: Linear thermal expansion of aluminium (per K): the TX90 family's arm castings.
ALUMINIUM_EXPANSION_PER_K = 23e-6


@dataclass(frozen=True)
class ArmTruth:
    """How the simulated arm bends under gravity and grows as it warms (``ucal.sim.arm``).

    ``stiffness_nm_per_rad`` (6,): each joint's torsional stiffness, 0 = rigid (the joint does
    not give); ``link_mass_kg`` (6,) and ``link_centre_of_mass_mm`` (6, 3): each link's mass
    and its centre of mass at the zero pose (every DH angle at its θ offset), base frame;
    ``tool_mass_kg`` and ``tool_centre_of_mass_mm`` (3,, flange frame): the tool's;
    ``gravity_m_s2`` (3,, base frame). The arm's temperature above the one its DH table holds
    at ``t_s`` seconds of the cell's clock is ``offset_k + warmup_k·(1 − exp(−t_s/τ))``, τ =
    ``warmup_time_constant_min``; every link's d and a grow by ``expansion_per_k`` per K.
    The defaults bend and grow nothing.
    """

    stiffness_nm_per_rad: np.ndarray = field(default_factory=lambda: np.zeros(6))
    link_mass_kg: np.ndarray = field(default_factory=lambda: np.zeros(6))
    link_centre_of_mass_mm: np.ndarray = field(default_factory=lambda: np.zeros((6, 3)))
    tool_mass_kg: float = 0.0
    tool_centre_of_mass_mm: np.ndarray = field(default_factory=lambda: np.zeros(3))
    gravity_m_s2: np.ndarray = field(
        default_factory=lambda: np.array([0.0, 0.0, -STANDARD_GRAVITY_M_S2])
    )
    offset_k: float = 0.0
    warmup_k: float = 0.0
    warmup_time_constant_min: float = 30.0
    expansion_per_k: float = ALUMINIUM_EXPANSION_PER_K

    @property
    def bends(self) -> bool:
        """Whether a joint gives under a load: a stiffness given and a weight to bend it."""
        loaded = np.any(self.link_mass_kg > 0.0) or self.tool_mass_kg > 0.0
        return bool(np.any(self.stiffness_nm_per_rad > 0.0) and loaded)

    @property
    def warms(self) -> bool:
        """Whether the links' lengths ever differ from the DH table's."""
        return self.expansion_per_k != 0.0 and (self.offset_k != 0.0 or self.warmup_k != 0.0)

    def temperature_k(self, t_s: float) -> float:
        """The arm's temperature above its DH table's (K) ``t_s`` seconds after the start."""
        if self.warmup_k == 0.0:
            return self.offset_k
        tau_s = 60.0 * self.warmup_time_constant_min
        return self.offset_k + self.warmup_k * -math.expm1(-max(t_s, 0.0) / tau_s)


@dataclass(frozen=True)
class WorldTruth:
    """The truth a real cell hides (world file of SPEC.md, missing keys = as the profile says)."""

    model: RobotModel  # true DH table (nominal or with DH errors)
    joint_offsets_deg: np.ndarray  # actual = reading + offset
    tool_position_mm: np.ndarray
    tool_rotation_deg: np.ndarray
    sample_position_mm: np.ndarray
    sample_rotation_deg: np.ndarray
    sample_face_size_mm: float
    reflector: Reflector | None
    water_temperature_c: float
    frequency_mhz: float
    element_diameter_mm: float
    noise: Noise = field(default_factory=Noise)
    initial_joints_deg: np.ndarray = field(default_factory=lambda: np.zeros(6))
    #: Hayati twist of each link about its y axis (deg): A_i = Rz(θ)·Tz(d)·Tx(a)·Rx(α)·Ry(β).
    dh_beta_deg: np.ndarray = field(default_factory=lambda: np.zeros(6))
    step: Step | None = None  # the step on the block's XY face, as it really is
    #: Lost motion per joint (deg): the link lags the encoder by half of it, against the
    #: direction of the joint's last motion.
    backlash_deg: np.ndarray = field(default_factory=lambda: np.zeros(6))
    #: Where each link settles after a move of its joint, about where the encoder says (deg,
    #: one sigma, (6,)): drawn anew for every move, hidden from the readings (the gears'
    #: and the servo's scatter: a TX90's ±0.03 mm pose repeatability).
    repeatability_deg: np.ndarray = field(default_factory=lambda: np.zeros(6))
    #: Linear drift of the water temperature with simulated time (°C per minute).
    water_drift_c_per_min: float = 0.0
    #: The thermometer's log: the water's temperature over simulated time, in place of
    #: ``water_temperature_c`` (then its value at the start) and the linear drift.
    water_temperature_log: TemperatureLog | None = None
    pulser: PulserTruth = field(default_factory=PulserTruth)
    #: Beam squint (deg): the acoustic axis leaves the tool centre tilted this much from the
    #: housing's z axis (the tool frame of a drawing), towards ``beam_squint_azimuth_deg`` from
    #: the housing's x axis about its z.
    beam_squint_deg: float = 0.0
    beam_squint_azimuth_deg: float = 0.0
    #: Near-field directivity: the echo of a tilted plane returns displaced by 2L·tan 2θ and,
    #: inside the near field, about as wide as the element (``ucal.sim.receiver``).
    near_field: bool = False
    #: Water's absorption in the A-scans: every echo's spectrum through α₀(T)·f² over its own
    #: water path, both ways (``ucal.sim.rf``); False: every echo of one shape.
    water_absorption: bool = False
    #: The Simple Message server the controller behaves as
    #: (``drivers.controller.simulator.SERVERS``) and its start-up silence (s; None: the
    #: server's own).
    controller_server: str = "simple"
    controller_silence_s: float | None = None
    timing: CellTiming = field(default_factory=CellTiming)
    #: The arm's compliance under gravity and its growth with temperature (none by default).
    arm: ArmTruth = field(default_factory=ArmTruth)

    @property
    def tool_matrix(self) -> np.ndarray:
        return transform(self.tool_position_mm, rpy_to_matrix(self.tool_rotation_deg))

    @property
    def beam_matrix(self) -> np.ndarray:
        """The frame whose +z is the acoustic axis (4, 4, flange frame): the tool frame turned
        by the squint; what a tool-frame calibration measures."""
        az = np.radians(self.beam_squint_azimuth_deg)
        axis = np.array([-np.sin(az), np.cos(az), 0.0])  # tilts z towards the azimuth
        k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
        t = np.radians(self.beam_squint_deg)
        squint = np.eye(3) + np.sin(t) * k + (1 - np.cos(t)) * k @ k
        return np.asarray(self.tool_matrix @ transform(np.zeros(3), squint))

    @property
    def sample_matrix(self) -> np.ndarray:
        return transform(self.sample_position_mm, rpy_to_matrix(self.sample_rotation_deg))

    def replace(self, **changes: Any) -> WorldTruth:
        return replace(self, **changes)

    @classmethod
    def nominal(cls, profile: CellProfile) -> WorldTruth:
        """A world equal to what the profile says: no hidden error, no noise."""
        refl = None
        if profile.reflector_points_mm is not None and len(profile.reflector_points_mm) >= 3:
            p = np.asarray(profile.reflector_points_mm, float)
            n = np.cross(p[1] - p[0], p[2] - p[0])
            n = n / np.linalg.norm(n)
            refl = Reflector(point_mm=p.mean(0), normal=n if n[2] >= 0 else -n)
        return cls(
            model=profile.model,
            joint_offsets_deg=np.zeros(6),
            tool_position_mm=np.array(profile.tool_position_mm, float),
            tool_rotation_deg=np.array(profile.tool_rotation_deg, float),
            sample_position_mm=np.array(profile.sample_position_mm, float),
            sample_rotation_deg=np.array(profile.sample_rotation_deg, float),
            sample_face_size_mm=profile.sample_face_size_mm,
            reflector=refl,
            step=profile.step,
            water_temperature_c=profile.water_temperature_c,
            frequency_mhz=profile.frequency_mhz,
            element_diameter_mm=profile.element_diameter_mm,
            dh_beta_deg=np.array(profile.model.beta_deg, float),
            pulser=PulserTruth()
            if profile.pulser.by_hand is None
            else PulserTruth(kind="manual", gain_db=profile.pulser.by_hand.panel.gain_db),
        )
