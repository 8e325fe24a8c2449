"""Serve the simulated cell on 127.0.0.1: the simulated controller and pulser, one truth.

The controller (ROS-Industrial Simple Message, ``drivers.controller.simulator``) moves the
simulated robot; the pulser (Modbus, ``drivers.pulser.simulator``) answers every acquisition
with ``SimulatedCell.echo`` at the controller's joint readings of that instant, so a reading
taken while the robot moves sees the robot where it is. Both listen on free ports.

With ``pulser_kind="ascii-scpi"`` (world ``[pulser] kind``) the pulser is the ASCII serial one
(``drivers.pulser.ascii_simulator``: it holds the knobs) and a SCPI oscilloscope
(``drivers.digitizer.scpi_simulator``) records its RF output: every acquisition of the scope
takes the same echo at that instant and returns it as a waveform (``ucal.sim.rf``), which ucal
times on the host. The oscilloscope speaks the dialect of one family (world ``[pulser] scope``:
a Keysight InfiniiVision X-Series or a Rigol DS1000Z, ``drivers.digitizer.scpi_simulator``),
its trigger wired to the pulser's sync output where that family's is (EXT; CH2 on a DS1000Z).
With ``pulser_kind="manual"`` the same oscilloscope is served alone, beside a pulser-receiver
set by hand (``manual://``): its front panel is the profile's declaration with the world's
gain (``panel``), and its echoes have the world's centre frequency.

Time (``drivers.clock``): with a ``SimClock`` (a client in the same process, ``ucal calibrate
--sim``) both devices run on simulated time in lock step with the client — an acquisition
takes its real-cell duration (``ucal.timing``: transport, pulses averaged) of simulated time,
half before the echo is taken and half after, and moves and settling take theirs. On the host
clock (``ucal sim serve``) the same durations pass in real time multiplied by ``time_scale``;
the water's time (``SimulatedCell.water_temperature_c``) is the host's seconds since the cell
started, not scaled: the time scale speeds the arm and the pulser, not the tank.
"""

from __future__ import annotations

import contextlib
import json
import logging
import math
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any, Self

import numpy as np

from drivers.clock import HOST_CLOCK, Clock, SimClock
from drivers.controller.simulator import SimulatedController
from drivers.digitizer.scpi_simulator import AcquisitionRequest, SimulatedScope
from drivers.digitizer.simulated_scopes import FAMILIES as SCOPE_FAMILIES
from drivers.loopback import Served
from drivers.pulser.ascii_simulator import SimulatedAsciiPulser
from drivers.pulser.base import PulserSettings
from drivers.pulser.manual import URL as MANUAL_URL
from drivers.pulser.registers import RegisterMap
from drivers.pulser.simulator import AScanRequest as PulserAScanRequest
from drivers.pulser.simulator import SimulatedPulser
from ucal import timing
from ucal.cell import CellProfile, WorldTruth
from ucal.files import jsonable
from ucal.kinematics.rotations import matrix_to_pose
from ucal.profile.models import joint_accelerations_deg_s2, joint_speeds_deg_s
from ucal.sim.cell import SimulatedCell
from ucal.sim.demo import demo_world
from ucal.world import PULSER_KINDS

if TYPE_CHECKING:
    from ucal.sim.rf import RfOutput

log = logging.getLogger(__name__)

HOST = "127.0.0.1"


class SimulatedCellServer(Served):
    """The simulated controller and pulser of one world, served on 127.0.0.1 (context manager).

    ``world`` None means the demo truth of ``profile``. ``log_path`` receives one JSON line per
    executed motion; ``time_scale`` multiplies every duration on the host clock (0 =
    instantaneous); ``pulser_framing`` is ``"tcp"`` (Modbus TCP) or ``"rtu"`` (Modbus RTU over a
    TCP socket); ``clock`` is the devices' clock (a ``SimClock`` for lock-step simulated time,
    which ignores ``time_scale``); ``server`` overrides the world's ``controller_server`` (the
    Simple Message server the controller behaves as, ``drivers.controller.simulator.SERVERS``);
    ``pulser_kind`` overrides the world's ``[pulser] kind`` (``"modbus"`` or ``"ascii-scpi"``),
    ``scope`` its ``[pulser] scope`` (the ascii-scpi cell's oscilloscope family,
    ``drivers.digitizer.simulated_scopes.FAMILIES``).
    """

    def __init__(
        self,
        world: WorldTruth | None,
        profile: CellProfile,
        log_path: str | Path | None = None,
        time_scale: float = 1.0,
        pulser_framing: str = "tcp",
        host: str = HOST,
        clock: Clock | None = None,
        server: str | None = None,
        pulser_kind: str | None = None,
        scope: str | None = None,
    ):
        if pulser_framing not in ("tcp", "rtu"):
            raise ValueError(f"pulser_framing must be 'tcp' or 'rtu', got {pulser_framing!r}")
        if pulser_kind is not None and pulser_kind not in PULSER_KINDS:
            raise ValueError(f"pulser_kind must be one of {PULSER_KINDS}, got {pulser_kind!r}")
        if scope is not None and scope not in SCOPE_FAMILIES:
            raise ValueError(f"scope must be one of {tuple(SCOPE_FAMILIES)}, got {scope!r}")
        self.profile = profile
        self.world = world if world is not None else demo_world(profile)
        # the simulated pulser applies its own gate and threshold (holding registers)
        self.cell = SimulatedCell(self.world, threshold=0.0)
        self.log_path = Path(log_path) if log_path is not None else None
        self.time_scale = float(time_scale)
        self.pulser_framing = pulser_framing
        self.host = host
        self.server = server if server is not None else self.world.controller_server
        self.clock: Clock = clock if clock is not None else HOST_CLOCK
        self.simulated_time = isinstance(self.clock, SimClock)
        self._t0 = 0.0
        self.pulser_kind = pulser_kind if pulser_kind is not None else self.world.pulser.kind
        self.scope = scope if scope is not None else self.world.pulser.scope
        self.controller: Any = None
        self.pulser: Any = None
        self.digitizer: Any = None  # the oscilloscope of an ascii-scpi or a manual cell
        self.rf: RfOutput | None = None  # made with the first A-scan
        self._log_file: IO[str] | None = None
        self._log_lock = threading.Lock()
        self._motions = 0
        # (joint readings, gain dB, simulated time s, motion sign) of the latest acquisition
        self._posture: tuple[np.ndarray, float, float, np.ndarray | None] | None = None
        # the pulser transport's jitter, seeded by the world (its own stream of numbers)
        self._transport_rng = np.random.default_rng([int(self.world.noise.seed), 0x9017])

    # --- lifecycle ----------------------------------------------------------------------------
    def start(self) -> Self:
        """Start both simulators (idempotent); returns self."""
        if self.controller is not None:
            return self
        if self.log_path is not None:
            # open for the server's lifetime, closed by stop()
            self._log_file = open(self.log_path, "a", encoding="utf-8")  # noqa: SIM115
        model = self.world.model
        period_s = self.world.timing.state_period_s
        try:
            self.controller = SimulatedController(
                np.asarray(model.joint_min_deg, float),
                np.asarray(model.joint_max_deg, float),
                np.asarray(self.world.initial_joints_deg, float),
                self.host,
                motion_port=0,
                state_port=0,
                time_scale=1.0 if self.simulated_time else self.time_scale,
                on_motion=self._on_motion,
                clock=self.clock,
                settling=True,
                max_speed_deg_s=joint_speeds_deg_s(model).tolist(),
                max_accel_deg_s2=joint_accelerations_deg_s2(model).tolist(),
                server=self.server,
                startup_silence_s=self.world.controller_silence_s,
                state_rate_hz=None if period_s is None else 1.0 / period_s,
                state_latency_s=self.world.timing.state_latency_s,
                state_jitter_s=self.world.timing.state_jitter_s,
                missing_state_frames=self.world.timing.missing_state_frames,
                seed=self.world.noise.seed,
            )
            self.controller.start()
            if self.pulser_kind == "ascii-scpi":
                self._start_ascii_scpi()
            elif self.pulser_kind == "manual":
                self._start_scope()
            else:
                self.pulser = SimulatedPulser(
                    self._acquire,
                    framing=self.pulser_framing,
                    host=self.host,
                    port=0,
                    unit=1,
                    center_frequency_hz=self.world.frequency_mhz * 1e6,
                    sample_rate_hz=self.world.pulser.sample_rate_mhz * 1e6,
                    register_map=self.register_map,
                    bits=self.world.pulser.bits,
                    ascan=self._modbus_ascan,
                    on_ascan_read=self._ascan_transfer,
                )
                self.pulser.start()
            self._t0 = self.clock.now()
        except BaseException:
            self.stop()
            raise
        log.info("simulated cell: %s", self.urls)
        return self

    def _start_ascii_scpi(self) -> None:
        """Start the ASCII serial pulser and the oscilloscope that records its RF output."""
        self.pulser = SimulatedAsciiPulser(self.host, 0).start()
        self._start_scope()

    def _start_scope(self) -> None:
        """Start the oscilloscope that records the pulser's RF output."""
        self.rf = self._rf_output()
        family = SCOPE_FAMILIES[self.scope]
        self.digitizer = SimulatedScope(
            self._ascan,
            self.host,
            0,
            sample_rate_hz=self.world.pulser.sample_rate_mhz * 1e6,
            bits=None if family.fixed_bits else self.world.pulser.bits,
            seed=self.world.noise.seed,
            family=family.name,
            on_transfer=self._scope_transfer,
        ).start()

    def stop(self) -> None:
        """Stop the simulators and close the motion log. Idempotent."""
        for name in ("digitizer", "pulser", "controller"):
            dev = getattr(self, name)
            if dev is not None:
                try:
                    dev.stop()
                except Exception:  # stopping one device must not hide the other
                    log.exception("stopping the simulated %s failed", name)
                setattr(self, name, None)
        if self._log_file is not None:
            with self._log_lock:
                self._log_file.close()
                self._log_file = None

    @property
    def register_map(self) -> RegisterMap | None:
        """The register map the simulated pulser serves: the world's, else the profile's (None:
        ucal's own)."""
        world = self.world.pulser.register_map
        return world if world is not None else self.profile.pulser.register_map

    @property
    def panel(self) -> PulserSettings:
        """The front panel of a pulser set by hand: the profile's declaration (the defaults
        where it has none) with the world's gain."""
        by_hand = self.profile.pulser.by_hand
        declared = PulserSettings() if by_hand is None else by_hand.panel
        return replace(declared, gain_db=self.world.pulser.gain_db)

    @property
    def urls(self) -> dict[str, str]:
        """``{"controller": URL, "pulser": URL}`` of the running simulators, and
        ``"digitizer": URL`` for an ascii-scpi or a manual cell (whose pulser is
        ``manual://``)."""
        if self.controller is None or (self.pulser is None and self.digitizer is None):
            raise RuntimeError("the simulated cell is not running")
        pulser = MANUAL_URL if self.pulser is None else self.pulser.url
        urls = {"controller": self.controller.url, "pulser": pulser}
        if self.digitizer is not None:
            urls["digitizer"] = self.digitizer.url
        return urls

    @property
    def motions(self) -> int:
        """Number of motions the controller reported as executed."""
        return self._motions

    # --- callbacks (server threads) -----------------------------------------------------------
    def _acquire(self, settings: PulserSettings) -> tuple[float, float]:
        """Pulser model: the raw echo at the controller's joint readings of the acquisition.

        The request's half of the transport (the instrument's own part, ``ucal.timing``, and
        the world's network latency with its jitter) passes, then the pulses averaged; the echo
        is that of the arm ``acquisition_delay`` before the reply leaves, and the reply's half
        of the transport passes after.
        """
        world = self.world.timing
        rng = self._transport_rng
        pulses_s = settings.acquisition_s
        transport_s = timing.device_transport_s(self.pulser_framing) + world.pulser_latency_s
        jitter = world.pulser_jitter_s * np.abs(rng.standard_normal(2))
        self._let_pass(0.5 * transport_s + float(jitter[0]) + pulses_s)
        t = self.clock.now()
        delay = min(world.acquisition_delay_s, max(t - self._t0, 0.0))
        joints = self.controller.joints_at(t - delay) + self._settled_off_deg(t - delay)
        t_s = t - delay - self._t0
        motion_sign = self.controller.motion_sign_at(t - delay)
        echo = self.cell.echo(
            joints,
            averages=settings.averages,
            gain_db=settings.gain_db,
            t_s=t_s,
            motion_sign=motion_sign,
        )
        # where the arm was: the A-scan of this acquisition holds its other echoes too
        self._posture = (joints, float(settings.gain_db), t_s, motion_sign)
        self._let_pass(0.5 * transport_s + float(jitter[1]) + delay)
        return echo

    def _settled_off_deg(self, t: float) -> np.ndarray:
        """Where each link has settled off its reading at instant ``t`` (deg, (6,)): the
        world's ``repeatability_deg`` drawn anew for each move of the joint (zero for a rigid
        world), the same draw for a joint as long as it stays still."""
        sigma = np.asarray(self.world.repeatability_deg, float)
        if not np.any(sigma > 0.0):
            return np.zeros(6)
        moves = self.controller.moves_at(t)
        seed = int(self.world.noise.seed)
        return np.array(
            [
                sigma[j] * np.random.default_rng([seed, 0x5E771E, j, int(moves[j])]).normal()
                if sigma[j] > 0.0
                else 0.0
                for j in range(6)
            ]
        )

    def _ascan(self, request: AcquisitionRequest) -> np.ndarray:
        """Scope model (scope server thread): the receiver's RF output (V) over the record
        asked, holding the echo of this instant (``_acquire`` with the pulser's knobs and the
        scope's window and averages); the time the scope takes to hand it over passes when it
        is read (``_scope_transfer``)."""
        assert self.rf is not None
        knobs = self.panel if self.pulser is None else self.pulser.settings
        settings = replace(
            knobs,
            gate_start_us=max(request.t0_ns, 0.0) * 1e-3,
            gate_width_us=max(request.n - 1, 1) * request.dt_ns * 1e-3,
            averages=request.averages,
        )
        amplitude, tof_ns = self._acquire(settings)
        if self.pulser is not None and not self.pulser.pulsing:
            amplitude, tof_ns = 0.0, float("nan")
        return self._rf_record(request.t0_ns, request.dt_ns, request.n, amplitude, tof_ns, settings)

    def _scope_transfer(self, points: int, size: int) -> None:
        """Let the time the scope takes to hand over ``points`` samples in ``size`` bytes pass
        (scope server thread): what is read, not what it acquired."""
        from ucal.sim.rf import transfer_s

        self._let_pass(transfer_s(points, max(size // max(points, 1), 1)))

    def _modbus_ascan(self, request: PulserAScanRequest) -> np.ndarray:
        """The Modbus pulser's A-scan model (pulser server thread): the receiver's RF output
        (fractions of full screen) of the acquisition just made, which its ADC digitises."""
        return self._rf_record(
            request.t0_ns,
            request.dt_ns,
            request.n,
            request.amplitude,
            request.tof_ns,
            request.settings,
        )

    def _rf_output(self) -> RfOutput:
        # The RF model (scipy.signal) loads with the first A-scan: a run that reads only the
        # instrument's gate never needs it.
        from ucal.sim.rf import RfOutput

        return RfOutput(
            self.world.frequency_mhz,
            self.cell.noise_floor,
            self.world.noise.seed,
            water_absorption=self.world.water_absorption,
            baseline_offset=self.world.pulser.baseline_offset,
        )

    def _rf_record(
        self,
        t0_ns: float,
        dt_ns: float,
        n: int,
        amplitude: float,
        tof_ns: float,
        settings: PulserSettings,
    ) -> np.ndarray:
        """The receiver's RF output over a record (``ucal.sim.rf``): the echoes of this
        acquisition (``SimulatedCell.echoes_along`` where the arm was, each through its own
        water), the receiver's noise at its gain and averages and its baseline offset."""
        from ucal.sim.rf import later_echoes

        if self.rf is None:
            self.rf = self._rf_output()
        noise = self.rf.noise_rms_fsh(settings.gain_db, settings.averages)
        later: list[tuple[float, float]] = []
        water_mm: list[float] = []
        temperature_c = self.world.water_temperature_c
        posture = self._posture
        if posture is not None and math.isfinite(tof_ns):
            joints, gain_db, t_s, motion_sign = posture
            beam = self.cell.true_beam(joints, motion_sign, t_s)
            echoes = self.cell.echoes_along(beam, gain_db, t_s)
            later = later_echoes([(e.tof_ns, e.amplitude) for e in echoes])
            water_mm = [e.water_path_mm for e in echoes]
            temperature_c = self.cell.water_temperature_c(t_s)
            if self.pulser_kind == "manual" and echoes and amplitude >= 1.0:
                # the receiver's output beyond full screen, not the gate's saturated reading:
                # the scope clips it (a panel's gain too high for the echo)
                amplitude = max(amplitude, echoes[0].amplitude)
        return self.rf.record(
            t0_ns,
            dt_ns,
            n,
            amplitude,
            tof_ns,
            noise,
            later,
            water_mm=water_mm,
            temperature_c=temperature_c,
        )

    def _ascan_transfer(self, words: int) -> None:
        """Let the time of one A-scan request of ``words`` registers pass (pulser server
        thread): the instrument's part and the network's latency, as a measurement read."""
        self._let_pass(
            timing.device_transport_s(self.pulser_framing, registers=words)
            + self.world.timing.pulser_latency_s
        )

    def _let_pass(self, seconds: float) -> None:
        """Let an acquisition's duration pass: simulated time, or host time × time_scale."""
        if self.simulated_time:
            self.clock.sleep(seconds)
        elif self.time_scale > 0:
            time.sleep(seconds * self.time_scale)

    def _on_motion(self, record: dict[str, Any]) -> None:
        """Controller callback at the end of each executed move: write one JSON line.

        The controller's record (``seq``, ``t_start``, ``start_deg``, ``target_deg``,
        ``end_deg``, ``duration_s``, ``stopped``) plus the wall-clock time ``t_wall_s``, the
        move's number ``motion``, the cell's time ``t_cell_s`` (s since it started: the time
        of the water's drift and the arm's warm-up) and the true TCP pose ``true_tcp_pose``
        (X, Y, Z, RX, RY, RZ; mm, deg) at ``end_deg`` then.
        """
        with self._log_lock:
            self._motions += 1
            number = self._motions
        if self._log_file is None:
            return
        line_record: dict[str, Any] = {"motion": number, "t_wall_s": time.time(), **record}
        try:
            now = self.clock.now()
            end = np.asarray(record["end_deg"], float) + self._settled_off_deg(now)
            line_record["t_cell_s"] = now - self._t0
            line_record["true_tcp_pose"] = matrix_to_pose(
                self.cell.true_tcp(end, self.controller.motion_sign_at(now), now - self._t0)
            )
        except Exception:  # the log must never break the controller thread
            log.debug("motion log: no end position in %r", record, exc_info=True)
        line = json.dumps(line_record, default=jsonable)
        with self._log_lock:
            if self._log_file is not None:
                self._log_file.write(line + "\n")
                self._log_file.flush()


@contextlib.contextmanager
def serving(*args: str, cwd: str | Path | None = None) -> Iterator[dict[str, str]]:
    """``ucal sim serve ARGS`` in a process of its own, as a script beside a real command line
    starts it: its URLs (the first line it prints) while the block runs, then SIGTERM and its
    end awaited (its stderr is discarded)."""
    served = subprocess.Popen(
        [sys.executable, "-m", "ucal", "sim", "serve", *args],
        cwd=cwd,
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
    )
    try:
        assert served.stdout is not None
        yield json.loads(served.stdout.readline())
    finally:
        served.send_signal(signal.SIGTERM)
        served.communicate(timeout=30)
