"""The rig: the robot and the pulser-receiver as the procedures use them.

``Rig`` counts moves and reads, keeps the pulser's settings (gain, averages) and the noise
floor, sweeps a joint-space line while reading the pulser (each reading paired with the
streamed joint positions), and checks every reading for values no instrument gives (exit 3).
The rig keeps what a reading needs to be modelled later: the sign of each joint's last motion
(``approach``) and the time since the run's first reading (``minutes``).
The measuring library (``ucal.measure``) and every procedure measure through a rig; the cell
session (``ucal.devices.session``) builds it from the profile.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np

from drivers.controller.base import RobotController
from drivers.pulser.base import GateReading, PulserReceiver, PulserSettings
from ucal import interrupt, timing
from ucal.errors import HardwareError
from ucal.profile.models import joint_speeds_deg_s

if TYPE_CHECKING:
    from ucal.echo.capture import Capture

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class SweepSpacing:
    """How far apart a sweep's readings may come (deg of joint travel), by purpose.

    ``acquire_deg``: acquisition lines, at most (and at most 0.4 × the spacing of the lines) —
    at acquisition gain the echo shows over a few degrees, as wide as the lines are apart, so
    a few readings land on it even this far apart. Centring sweeps: their length over
    ``centre_reads_per_half`` per half-width, at least ``centre_min_deg`` — a long sweep only
    needs to locate the echo's span. ``main_lobe_deg``: main-lobe crosses — the −6 dB lobe is
    ~0.4° wide and its half-maximum crossings are interpolated between readings. A sweep aims
    at ``aim`` × its allowed spacing, from the measured time between readings.
    """

    acquire_deg: float = 1.0
    centre_reads_per_half: float = 10.0
    centre_min_deg: float = 0.04
    main_lobe_deg: float = 0.06
    aim: float = 0.9

    def centre_deg(self, half_width_deg: float) -> float:
        """Allowed spacing on a centring sweep of ± ``half_width_deg`` joint travel."""
        return max(self.centre_min_deg, half_width_deg / self.centre_reads_per_half)


#: The first build's spacing (every sweep read about as densely as the pulser answered): the
#: baseline that benchmarks/paper_protocol.py compares the reads and accuracy against.
DENSE_SPACING = SweepSpacing(
    acquire_deg=0.08,
    centre_reads_per_half=math.inf,
    centre_min_deg=0.04,
    main_lobe_deg=0.01,
    aim=0.5,
)
#: Slowest sweep (fraction of maximum speed): the VAL3 server takes a wire velocity of 0.001
#: (0.1 %) for "extrapolate from the previous points", so sweeps stay clear of it.
MIN_SPEED = 0.002
#: The arm's measured rate over the commanded one is taken as 1 while within this band: a
#: sweep's spacing tolerates 1.5x, and a run on a cell that moves as commanded keeps the
#: speeds it always had.
RATE_BAND = (0.8, 1.25)
#: Joint samples inside a sweep's motion needed to fit the arm's rate; with fewer the motion
#: lasted at most the time between the samples that bracket it (a lower bound on the rate).
MIN_RATE_SAMPLES = 3
#: A sweep's reading during which the arm travelled farther than this many of the sweep's
#: allowed spacings (``max_step_deg``) is tied to no posture and left out (``Rig._tied``):
#: paired at the middle of its stretch it could be off by more than the spacing.
READ_TRAVEL_STEPS = 2.0
#: Time per reading assumed before the first sweep has measured it (s): Modbus TCP.
_FIRST_READ_S = timing.read_s("tcp")
#: Noise floor taken when an empty gate reads exactly 0 and no reading is above 0 (fraction of
#: full screen height): one level of an 8-bit amplitude. A quantised instrument reports 0 below
#: one level, so the true floor is under it; the threshold (four floors) stays above the noise.
ZERO_FLOOR_FSH = 1.0 / 256
#: The pulser's settings a rig starts with: the gate every procedure reads in, 5–405 µs.
DEFAULT_SETTINGS = PulserSettings(gain_db=40.0, gate_start_us=5.0, gate_width_us=400.0, averages=1)
#: Gain step (dB) while an empty gate reads 0 (``Rig.measure_floor``).
FLOOR_GAIN_STEP_DB = 12.0


def check_reading(endpoint: str, amplitude: float, tof_ns: float) -> None:
    """Raise ``HardwareError`` (exit 3) naming the pulser for a reading no instrument gives:
    an amplitude that is NaN, infinite or negative, or a time of flight that is negative or
    infinite (an echo without a finite time). NaN time of flight is "no echo" and fine."""
    if not math.isfinite(amplitude) or amplitude < 0.0:
        raise HardwareError(
            f"pulser at {endpoint}: impossible reading: amplitude {amplitude!r} "
            "(expected a fraction of full screen height, 0 or more)"
        )
    if math.isinf(tof_ns) or tof_ns < 0.0:
        raise HardwareError(
            f"pulser at {endpoint}: impossible reading: time of flight "
            f"{tof_ns!r} ns with amplitude {amplitude!r} (expected a positive "
            "round-trip time, or none without an echo)"
        )


def check_readings(endpoint: str, amplitudes: np.ndarray, tofs_ns: np.ndarray) -> None:
    """:func:`check_reading` over the readings of a sweep; the first bad one is reported."""
    amplitudes, tofs_ns = np.asarray(amplitudes, float), np.asarray(tofs_ns, float)
    bad = ~np.isfinite(amplitudes) | (amplitudes < 0.0) | np.isinf(tofs_ns) | (tofs_ns < 0.0)
    if np.any(bad):
        i = int(np.argmax(bad))
        check_reading(endpoint, float(amplitudes[i]), float(tofs_ns[i]))


class Sweep(NamedTuple):
    """The readings of one line swept (or stepped): the joints at each reading (n, 6, deg),
    its amplitude (n,, fraction of full screen) and its time of flight (n,, ns)."""

    joints_deg: np.ndarray
    amplitudes: np.ndarray
    tofs_ns: np.ndarray


@dataclass
class RigCounters:
    moves: int = 0
    reads: int = 0


class Rig:
    """The robot and the pulser as the procedures use them: counted moves and reads, gain."""

    def __init__(
        self,
        controller: RobotController,
        pulser: PulserReceiver,
        joint_min_deg: np.ndarray,
        joint_max_deg: np.ndarray,
        speed: float = 0.3,
        move_timeout_s: float = 60.0,
        settings: PulserSettings | None = None,
        speeds_deg_s: np.ndarray | None = None,
    ):
        self.controller = controller
        self.pulser = pulser
        self.joint_min_deg = np.asarray(joint_min_deg, float)
        self.joint_max_deg = np.asarray(joint_max_deg, float)
        self.speed = speed
        self.sweep_speed = speed
        # The joints' speeds at speed 1.0 (deg/s): the robot model's (``joint_speeds_deg_s``;
        # without one, the lowest of the shipped models')
        self.speeds_deg_s = (
            joint_speeds_deg_s(None) if speeds_deg_s is None else np.asarray(speeds_deg_s, float)
        )
        # Time between readings during a sweep (s), measured by every sweep: sets the speed
        # that spaces the readings as a sweep asks.
        self.read_interval_s = _FIRST_READ_S
        self.read_period_s = 0.0  # wait between a sweep's reads (s); 0: read back to back
        self.spacing = SweepSpacing()
        self.move_timeout_s = move_timeout_s
        self.counters = RigCounters()
        self.settings = settings or DEFAULT_SETTINGS
        self.floor_per_gain: float | None = None  # noise-floor amplitude at 0 dB gain
        # One level of a quantised amplitude register (fraction of full screen height), seen
        # when an empty gate reads exactly 0; 0 while no quantisation has shown.
        self.amplitude_step_fsh = 0.0
        # Called with every commanded target before the motion (a progress display's hook)
        self.on_move: Callable[[np.ndarray], None] | None = None
        # Captures the reference echo of a host-timed pulser at the first distance reading
        # (``ucal.echo.capture``); None: nothing to capture.
        self.reference_capture: Capture | None = None
        self.last_sweep_step_deg = 0.0
        # The arm's joint rate over the commanded one, measured by the sweeps: a pendant's
        # speed override, a controller's own limits or a simulated cell's time scale make the
        # arm slower or faster than commanded, and the sweep speed that spaces the readings
        # must come from the motion as measured, not as commanded.
        self.rate_factor = 1.0
        self.stepped_lines = 0  # lines read as settled steps (the arm too fast to sweep)
        self._streamed = False  # whether the last sweep had streamed joints to tie its readings
        # The sign (+1/-1) of each joint's last motion (``approach``), from the last target
        # commanded; +1 for a joint not yet moved in the run (its motion before is unknown).
        self.approach = np.ones(6)
        self._last_target: np.ndarray | None = None
        # Pulser clock (s) at the run's first reading and at the last one (``minutes``).
        self._first_read_s: float | None = None
        self._last_read_s: float | None = None
        # The host's wall clock (s since the epoch) when the first reading was stamped: where
        # a real cell's thermometer log (wall-clock times) meets the run's clock.
        self.first_read_wall_s: float | None = None

    def clip(self, q: np.ndarray) -> np.ndarray:
        return np.asarray(np.clip(q, self.joint_min_deg, self.joint_max_deg))

    def configure(self, **changes: Any) -> None:
        new = replace(self.settings, **changes)
        if new != self.settings:
            self.pulser.configure(new)
            self.settings = new

    def moved_to(self, target: np.ndarray, start: np.ndarray | None = None) -> None:
        """Note a motion to ``target`` (from ``start``, else the last target): each joint that
        moves sets its sign in ``approach``."""
        target = np.asarray(target, float)
        start = self._last_target if start is None else np.asarray(start, float)
        if start is not None:
            delta = target - start
            self.approach = np.where(np.abs(delta) > 1e-9, np.sign(delta), self.approach)
        self._last_target = target.copy()

    def _stamp(self, reading: GateReading) -> None:
        """Note the pulser clock of a reading (``minutes``)."""
        if self._first_read_s is None:
            self._first_read_s = reading.host_time_s
            clock = getattr(self.controller, "clock", None)
            age_s = 0.0 if clock is None else clock.now() - reading.host_time_s
            self.first_read_wall_s = time.time() - max(age_s, 0.0)
        self._last_read_s = reading.host_time_s

    @property
    def first_read_s(self) -> float | None:
        """The pulser clock (s) at the run's first reading; None before it."""
        return self._first_read_s

    def minutes(self) -> float:
        """Minutes from the run's first reading to the last one, on the pulser's clock (the
        clock that stamps a reading's arrival and pairs it with the streamed joints)."""
        if self._first_read_s is None or self._last_read_s is None:
            return 0.0
        return (self._last_read_s - self._first_read_s) / 60.0

    def move(self, q: np.ndarray, speed: float | None = None) -> np.ndarray:
        interrupt.check()  # an interrupt swallowed since the last motion starts none
        q = np.asarray(q, float)
        self.moved_to(q)
        self.counters.moves += 1
        if self.on_move:
            self.on_move(q)
        return self.controller.move_joints(q, speed or self.speed, self.move_timeout_s)

    def read(self, averages: int = 1) -> GateReading:
        """One fresh reading, checked (:func:`check_reading`: exit 3 for an impossible one)."""
        self.configure(averages=int(averages))
        self.counters.reads += 1
        reading = self.pulser.read_gate(fresh=True)
        check_reading(self.pulser.endpoint, reading.amplitude, reading.tof_ns)
        self._stamp(reading)
        return reading

    def normalised_amplitude(self, averages: int = 1) -> float:
        """Amplitude normalised to 0 dB gain; a saturated reading is repeated 10 dB lower."""
        for _ in range(8):
            a = self.read(averages).amplitude
            g = self.settings.gain_db
            if a < 0.98 or g <= 0.0:
                return a / 10 ** (g / 20)
            self.configure(gain_db=max(g - 10.0, 0.0))
        raise HardwareError(f"{self.pulser.endpoint}: echo saturates at every gain")

    def level_gain(self, averages: int = 1) -> None:
        """Lower (or raise) the gain until the echo here sits at 40–85 % of full screen."""
        for _ in range(8):
            a = self.read(averages).amplitude
            if 0.4 <= a <= 0.85:
                return
            g = self.settings.gain_db
            new = g - 12.0 if a >= 0.999 else g + 20 * np.log10(0.6 / max(a, 1e-4))
            new = float(np.clip(new, 0.0, 80.0))
            if abs(new - g) < 0.05:
                return
            self.configure(gain_db=new)

    def threshold(self) -> float:
        """Detection level at the current gain: four times the measured noise floor."""
        floor = (self.floor_per_gain or 1e-4) * 10 ** (self.settings.gain_db / 20)
        return max(4.0 * floor, 0.02)

    def measure_floor(self, n: int = 8) -> None:
        """Noise floor from readings without an echo (call with the beam in open water).

        The median of ``n`` readings; never 0, which the acquisition gain divides by. An empty
        gate that reads exactly 0 is a quantised amplitude below one level: the smallest
        reading above 0 bounds that level (``amplitude_step_fsh``), and the floor is measured
        again ``FLOOR_GAIN_STEP_DB`` higher until it shows (up to 80 dB; then one level,
        at most :data:`ZERO_FLOOR_FSH`, is taken). A floor taken as one level would be
        overestimated tenfold, and the acquisition gain set too low to show the side lobes.
        """
        while True:
            vals = [self.read().amplitude for _ in range(n)]
            floor = float(np.median(vals))
            if floor > 0.0:
                break
            positive = [v for v in vals if v > 0.0]
            step = min(positive) if positive else ZERO_FLOOR_FSH
            if self.amplitude_step_fsh == 0.0 or step < self.amplitude_step_fsh:
                self.amplitude_step_fsh = step
            gain = self.settings.gain_db
            log.info("the empty gate reads 0 at %.1f dB (quantised amplitude)", gain)
            if gain >= 80.0:
                floor = step
                break
            self.configure(gain_db=min(gain + FLOOR_GAIN_STEP_DB, 80.0))
        self.floor_per_gain = floor / 10 ** (self.settings.gain_db / 20)
        log.info("noise floor %.2e FSH at %.1f dB", floor, self.settings.gain_db)

    def sweep(self, target: np.ndarray, max_step_deg: float = 0.08) -> Sweep:
        """Move to ``target`` reading the pulser all the way.

        Returns the joint positions at each reading (n, 6), the amplitudes (n,) and the TOFs
        (n,), readings paired with the streamed joints by interpolation at arrival time (a
        reading the stream does not tie to a posture within the spacing is left out: ``_tied``).
        The speed is chosen from the measured time between readings so that they come
        ``spacing.aim`` × ``max_step_deg`` apart; reading stops when the joints reach the target
        (none is taken while the servo settles).
        """
        target = np.asarray(target, float)
        start = self.controller.read_joints()
        self.configure(averages=1)
        self.moved_to(target, start)
        self.counters.moves += 1
        if self.on_move:
            self.on_move(target)
        speed = self._sweep_speed_for(start, target, max_step_deg)
        clock = self.controller.clock
        t0 = clock.now()
        interrupt.check()
        self.controller.start_move(target, speed)
        readings: list[GateReading] = []
        sent: list[float] = []
        busy_s = 0.0  # time spent reading (without the waits), for the next sweep's speed
        deadline = t0 + self.move_timeout_s
        while True:
            if sent and self.read_period_s > 0.0:
                # At full speed the readings would come closer than needed: wait for the
                # joints to travel the spacing (fewer pulser reads, the same motion).
                idle = self.read_period_s - (clock.now() - sent[-1])
                if idle > 0.0:
                    clock.sleep(idle)
            sent.append(clock.now())
            readings.append(self.pulser.read_gate(fresh=True))
            self._stamp(readings[-1])
            self.counters.reads += 1
            here = self.controller.read_joints()
            busy_s += clock.now() - sent[-1]
            if np.max(np.abs(here - target)) < 1e-3:
                break
            if clock.now() > deadline:
                raise HardwareError(
                    f"{self.controller.endpoint}: sweep did not settle "
                    f"within {self.move_timeout_s:.0f} s"
                )
        if len(readings) > 1:
            self.read_interval_s = busy_s / len(readings)
        self.controller.wait_settled(target, self.move_timeout_s)
        samples = self.controller.joint_samples(t0 - 0.1)
        ts = np.array([s.t_s for s in samples])
        js = np.array([s.joints_deg for s in samples])
        after = ts >= t0  # this motion's frames (the history holds the move before it too)
        self._streamed = len(ts) >= 2
        self._measure_rate(start, target, speed, ts[after], js[after])
        amps = np.array([r.amplitude for r in readings])
        tofs = np.array([r.tof_ns for r in readings])
        check_readings(self.pulser.endpoint, amps, tofs)
        # The acquisition happens between request and answer: pair at the midpoint.
        asked = np.array(sent)
        answered = np.array([r.host_time_s for r in readings])
        tr = 0.5 * (asked + answered)
        if len(ts) >= 2:
            q = np.column_stack([np.interp(tr, ts, js[:, j]) for j in range(6)])
            tied = self._tied(start, target, ts, js, asked, answered, max_step_deg)
            q, amps, tofs, tr = q[tied], amps[tied], tofs[tied], tr[tied]
        else:
            q = np.tile(target, (len(tr), 1))
        self.last_sweep_step_deg = self._covered_step(start, target, ts[after], js[after], tr)
        return Sweep(q, amps, tofs)

    def _tied(
        self,
        start: np.ndarray,
        target: np.ndarray,
        ts: np.ndarray,
        js: np.ndarray,
        asked: np.ndarray,
        answered: np.ndarray,
        max_step_deg: float,
    ) -> np.ndarray:
        """Which of a sweep's readings the stream ties to a posture within the spacing asked.

        A reading's acquisition happened between its request and its answer; the streamed
        joints say how far the arm went in between. A reading whose answer came late (a
        loaded host, a slow link: its thread was not scheduled while the arm went on) may
        have been acquired anywhere on that stretch, and a stretch longer than
        ``READ_TRAVEL_STEPS`` spacings is no posture: such a reading is left out (the sweep
        counts the readings it kept, ``_covered_step``, and is swept again slower when they
        are too few)."""
        j = int(np.argmax(np.abs(target - start) / self.speeds_deg_s))
        travel = np.abs(np.interp(answered, ts, js[:, j]) - np.interp(asked, ts, js[:, j]))
        return np.asarray(travel <= READ_TRAVEL_STEPS * max_step_deg)

    def _covered_step(
        self, start: np.ndarray, target: np.ndarray, ts: np.ndarray, js: np.ndarray, tr: np.ndarray
    ) -> float:
        """Joint travel per reading that the state stream ties to a posture on a sweep.

        A reading is tied by interpolating the streamed joints at its time; between two frames
        of the moving arm that is exact for a joint-interpolated move, within a frame of the
        motion's start or end it is not. Readings are counted within a frame period of the
        frames that show the arm between start and target; an arm faster than the stream
        resolves (a simulated cell without time) shows no such frame, and a sweep of it
        covers nothing, whatever it read.
        """
        j = int(np.argmax(np.abs(target - start) / self.speeds_deg_s))
        travel = float(np.max(np.abs(target - start)))
        if len(ts) < 2:
            # No stream to tie them (a controller double): the readings as if spread evenly.
            return travel / max(len(tr), 1)
        lo, hi = sorted((float(start[j]), float(target[j])))
        margin = 1e-6 * max(travel, 1.0)
        moving = ts[(js[:, j] > lo + margin) & (js[:, j] < hi - margin)]
        if moving.size == 0:
            return travel
        period = float(np.median(np.diff(ts)))
        tied = np.count_nonzero((tr >= moving[0] - period) & (tr <= moving[-1] + period))
        return travel / max(int(tied), 1)

    def _sweep_speed_for(self, start: np.ndarray, target: np.ndarray, max_step_deg: float) -> float:
        """Speed fraction that spaces readings ``spacing.aim · max_step_deg`` apart on this move.

        The move's rate is set by its slowest joint relative to its maximum speed (the
        controller's joint-interpolated motion): travel per reading = speed · rate_max ·
        interval, with rate_max = |Δ|_max over the move's duration at full speed.
        """
        delta = np.abs(np.asarray(target, float) - np.asarray(start, float))
        full_speed_s = float(np.max(delta / self.speeds_deg_s))
        if full_speed_s <= 0.0:
            return self.speed
        rate_deg_s = float(np.max(delta)) / full_speed_s * self.rate_factor
        speed = self.spacing.aim * max_step_deg / (rate_deg_s * self.read_interval_s)
        self.sweep_speed = float(np.clip(speed, MIN_SPEED, self.speed))
        # Capped at the profile's speed: read no more often than the spacing needs.
        self.read_period_s = (
            self.spacing.aim * max_step_deg / (rate_deg_s * self.sweep_speed)
            if speed > self.speed
            else 0.0
        )
        return self.sweep_speed

    def _measure_rate(
        self, start: np.ndarray, target: np.ndarray, speed: float, ts: np.ndarray, js: np.ndarray
    ) -> None:
        """Update ``rate_factor`` from a sweep's streamed joints: the arm's rate over the rate
        commanded (``speed`` of the nominal maximum), on the joint that sets the move's
        duration.

        The samples strictly between start and target are fitted with a line in time; with
        fewer than ``MIN_RATE_SAMPLES`` of them the motion lasted at most the time between the
        last sample at the start and the first at the target, which bounds the rate from
        below (an instantaneous arm shows no sample inside its motion at all).
        """
        delta = np.asarray(target, float) - np.asarray(start, float)
        # the joint that sets the move's duration (joint-interpolated: all arrive together)
        j = int(np.argmax(np.abs(delta) / self.speeds_deg_s))
        travel = abs(float(delta[j]))
        if travel < 1e-3 or len(ts) < 2:
            return
        commanded = speed * float(self.speeds_deg_s[j])  # deg/s on joint j
        u = (js[:, j] - start[j]) / delta[j]  # 0 at the start, 1 at the target
        tol = 1e-4 / travel
        inside = (u > tol) & (u < 1.0 - tol)
        if np.count_nonzero(inside) >= MIN_RATE_SAMPLES:
            slope = np.polyfit(ts[inside], u[inside], 1)[0]  # travel fractions per s
            rate = abs(float(slope)) * travel
        else:
            at_start = np.flatnonzero(u <= tol)
            at_end = np.flatnonzero(u >= 1.0 - tol)
            if at_start.size == 0 or at_end.size == 0 or at_end[0] <= at_start[-1]:
                return
            lasted = max(float(ts[at_end[0]] - ts[at_start[-1]]), 1e-6)
            rate = max(travel / lasted, commanded * self.rate_factor)
        factor = rate / commanded
        if RATE_BAND[0] <= factor <= RATE_BAND[1]:
            factor = 1.0
        if factor != self.rate_factor:
            log.info(
                "the arm moves at %.3g x the commanded speed (%.3g deg/s on J%d for %.3g): "
                "sweep speeds follow the measured motion",
                factor,
                rate,
                j + 1,
                commanded,
            )
        self.rate_factor = factor

    def line(self, start: np.ndarray, end: np.ndarray, max_step_deg: float = 0.08) -> Sweep:
        """Sweep from ``start`` to ``end`` (moving to ``start`` first if needed); a sweep whose
        readings came too far apart (or that kept none, ``_tied``) is swept again, back, at the
        speed the measured motion allows. An arm too fast to sweep even at ``MIN_SPEED`` (its
        speed overridden upwards, or a simulated cell without time) is read in settled steps
        along the line instead: slower, but every reading tied to a posture the robot stood at.
        """
        here = self.controller.read_joints()
        if np.max(np.abs(here - start)) > 1e-3:
            self.move(start)
        a, b = np.asarray(start, float), np.asarray(end, float)
        for _ in range(4):
            out = self.sweep(b, max_step_deg)
            if len(out.amplitudes) and self.last_sweep_step_deg <= 1.5 * max_step_deg:
                return out
            a, b = b, a  # the arm stands at the new ``a``
            if self.sweep_speed <= MIN_SPEED:
                break  # no slower sweep to try
        if not self._streamed:
            return out  # no stream to say how the arm moved (a controller double)
        return self.stepped_line(a, b, max_step_deg)

    def stepped_line(self, start: np.ndarray, end: np.ndarray, max_step_deg: float) -> Sweep:
        """Read the line from ``start`` to ``end`` in settled steps ``spacing.aim`` ×
        ``max_step_deg`` apart: the postures, amplitudes and times of flight."""
        a, b = np.asarray(start, float), np.asarray(end, float)
        travel = float(np.max(np.abs(b - a)))
        n = max(int(np.ceil(travel / (self.spacing.aim * max_step_deg))), 1) + 1
        if self.stepped_lines == 0:
            log.warning(
                "the arm outruns the pulser even at %.1f %% speed (measured %.3g x the "
                "commanded rate): lines are read in settled steps",
                100 * MIN_SPEED,
                self.rate_factor,
            )
        self.stepped_lines += 1
        self.configure(averages=1)
        qs, amps, tofs = [], [], []
        for f in np.linspace(0.0, 1.0, n):
            q = a + f * (b - a)
            qs.append(self.move(q))
            reading = self.read()
            amps.append(reading.amplitude)
            tofs.append(reading.tof_ns)
        self.last_sweep_step_deg = travel / max(n - 1, 1)
        return Sweep(np.asarray(qs, float), np.asarray(amps, float), np.asarray(tofs, float))
