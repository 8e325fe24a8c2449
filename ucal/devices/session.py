"""Open a cell for a command that moves the robot: the simulated cell or real instruments.

``open_cell`` is a context manager yielding a ``CellSession``: the ``Rig`` (controller + pulser
through the same drivers a real cell uses) and, in simulation, the hidden truth for reporting.
On exit — normal, error or Ctrl-C — the controller is told to STOP before anything closes.

The simulated cell is served in this process on simulated time (``drivers.clock.SimClock``)
shared with the drivers: a run goes as fast as it computes, gives the same readings for the
same world whatever the machine's load, and its clock at the end is the run's duration on a
real cell. The controller's timeouts come from the profile's ``[controller]`` table; on the
simulated cell those on the state stream (first state, silence, halt, settle) run in simulated
time and the real-time ones (connect, reply) are only guards against a hung simulator.
"""

from __future__ import annotations

import contextlib
import logging
from collections.abc import Iterator
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from drivers.clock import HOST_CLOCK, Clock, SimClock
from drivers.digitizer.base import HostTimed
from drivers.errors import DriverError
from drivers.pulser.ascii import AsciiScpiPulser
from drivers.pulser.ascii_commands import KNOBS, Letter
from drivers.pulser.digitised import DigitisedPulser
from drivers.pulser.manual import SCHEME as MANUAL
from drivers.pulser.manual import ManualPulser
from drivers.pulser.modbus import ModbusPulser
from drivers.registry import open_controller, open_pulser
from ucal.cell import CellProfile, WorldTruth
from ucal.devices.record import (
    Record,
    Recorder,
    RecordingController,
    RecordingPulser,
    Replay,
    ReplayController,
    ReplayPulser,
)
from ucal.devices.rig import Rig
from ucal.errors import HardwareError, InputError, ProfileError, SafetyError
from ucal.profile.models import joint_speeds_deg_s
from ucal.sim.demo import demo_world
from ucal.sim.serve import SimulatedCellServer
from ucal.world import load_world

if TYPE_CHECKING:
    from ucal.echo.capture import Capture

log = logging.getLogger(__name__)

#: The ASCII pulser's pulse width knob.
WIDTH = KNOBS[Letter.WIDTH]
#: Real-time guard on every request to the in-process simulated cell (s): it answers at once
#: in simulated time, so only a hung simulator could make a request take this long.
SIM_GUARD_TIMEOUT_S = 60.0


@dataclass
class CellSession:
    rig: Rig
    truth: WorldTruth | None  # the simulator's hidden truth; None on a real cell
    simulated: bool
    clock: Clock = HOST_CLOCK  # simulated time on the simulated cell
    echo_timing: TimingMode = field(default_factory=lambda: TimingMode())

    @property
    def elapsed_s(self) -> float:
        """Time since the cell was opened (simulated time on the simulated cell)."""
        return self.clock.now() - self._t0

    @property
    def started_s(self) -> float:
        """The clock when the cell was opened: a simulated cell's clock starts there."""
        return self._t0

    def __post_init__(self) -> None:
        self._t0 = self.clock.now()


def check_status(rig: Rig) -> None:
    """Preflight: drives powered, no e-stop, no error (``SafetyError`` names the controller)."""
    st = rig.controller.status()
    where = rig.controller.endpoint
    if st.e_stopped:
        raise SafetyError(f"controller at {where}: emergency stop is engaged")
    if st.drives_powered is False:
        raise SafetyError(f"controller at {where}: drives are not powered")
    if st.in_error:
        raise SafetyError(f"controller at {where}: in error (code {st.error_code})")


def make_rig(profile: CellProfile, controller: Any, pulser: Any) -> Rig:
    """The rig of a cell: the profile's joint ranges and speed, the pulser configured."""
    rig = Rig(
        controller,
        pulser,
        profile.model.joint_min_deg,
        profile.model.joint_max_deg,
        speed=profile.procedure.speed,
        move_timeout_s=profile.controller.settle_timeout_s,
        speeds_deg_s=joint_speeds_deg_s(profile.model),
    )
    check_averages(profile, rig)
    rig.pulser.configure(rig.settings)
    return rig


def check_averages(profile: CellProfile, rig: Rig) -> None:
    """``[procedure] tof_averages`` against what the connected pulser (its register map, or
    its digitiser) takes, before the first motion: ``ProfileError`` (exit 2) naming the key,
    the device and its range, where the run would otherwise stop at its first distance."""
    check = getattr(rig.pulser, "check_settings", None)  # a replayed pulser has none
    if check is None:
        return
    try:
        check(rig.settings)
    except ValueError as e:  # not the averages: the gate and settings the procedures read at
        endpoint = getattr(rig.pulser, "endpoint", "the pulser")
        raise ProfileError(
            profile.path or "the profile",
            "pulser.prf_hz" if profile.pulser.set_by_hand else None,
            f"the pulser at {endpoint} cannot take the procedures' settings: {e}",
        ) from None
    averages = max(profile.procedure.tof_averages, 1)
    try:
        check(replace(rig.settings, averages=averages))
    except ValueError as e:
        endpoint = getattr(rig.pulser, "endpoint", "the pulser")
        raise ProfileError(
            profile.path or "the profile",
            "procedure.tof_averages",
            f"{averages} averages per distance reading: the pulser at {endpoint} refuses it "
            f"({e}); set a count it takes",
        ) from None


@dataclass(frozen=True)
class TimingMode:
    """How a session's echoes are timed: ``mode`` ``"gate"`` (the instrument's gate) or
    ``"ascan"`` (on the host, from the A-scan), and for the latter the reference capture
    (``ucal.echo.capture``) that holds the timer."""

    mode: str = "gate"
    capture: Capture | None = None

    def as_json(self) -> dict[str, Any]:
        """``"timing"`` and ``"reference_echo"`` (None with the gate) of a run's result."""
        return {
            "timing": self.mode,
            "reference_echo": None if self.capture is None else self.capture.as_json(),
        }


def fit_back_end(pulser: Any, profile: CellProfile) -> TimingMode:
    """What ucal gives a pulser back-end before its first reading: an echo timer
    (``ucal.echo.host``, with the profile's reference echo if it names one) to one that only
    digitises, and to one that can transfer its A-scans when the profile says ``[pulser]
    timing = "ascan"`` (``drivers.digitizer.base.HostTimed``); and to the ASCII pulser the
    pulse width of the profile's transducer (a half cycle of its centre frequency). Returns
    how the session's echoes are timed."""
    endpoint = pulser.endpoint
    timing = TimingMode()
    host_timed = isinstance(pulser, DigitisedPulser) or profile.pulser.timing == "ascan"
    if host_timed:
        if not isinstance(pulser, HostTimed) or (
            isinstance(pulser, ModbusPulser) and "ascan_samples" not in pulser.register_map
        ):
            raise InputError(
                f'{profile.path}: [pulser] timing = "ascan", but the pulser at {endpoint} '
                'gives no A-scan to time (its register map has no ascan_samples): use "gate"'
            )
        # the host's echo timing (scipy.signal) loads only for a session that uses it
        from ucal.echo.capture import ReferenceCapture
        from ucal.echo.host import HostEchoTimer

        timer = HostEchoTimer(profile.pulser.reference_echo)
        pulser.echo_timer = timer
        path = profile.pulser.reference_echo_path
        capture = ReferenceCapture(timer, profile_path=None if path is None else str(path))
        timing = TimingMode("ascan", capture)
        if timer.reference is None:
            log.warning(
                "pulser %s: no reference echo: echoes are timed on the host by their envelope "
                "(coarse) until the cell's own is captured on the block",
                endpoint,
            )
    if isinstance(pulser, AsciiScpiPulser):
        width_ns = 500.0 / profile.frequency_mhz
        try:
            WIDTH.code(width_ns)
        except ValueError as e:
            raise InputError(
                f"{profile.path}: transducer.frequency_mhz = {profile.frequency_mhz:g} MHz needs "
                f"a pulse of {width_ns:g} ns, which the pulser at {endpoint} cannot give ({e})"
            ) from None
        pulser.pulse_width_ns = width_ns
    return timing


def by_hand_options(profile: CellProfile, pulser_url: str) -> dict[str, Any]:
    """The options of a pulser set by hand (``manual://``): its front panel as the profile
    declares it; ``InputError`` (exit 2) where the profile and the URL disagree on whether the
    pulser is set by hand."""
    by_hand = profile.pulser.by_hand
    manual = pulser_url.split("://", 1)[0].strip().lower() == MANUAL
    if manual and by_hand is None:
        raise ProfileError(
            profile.path or "the profile",
            "pulser.kind",
            f'the pulser at {pulser_url} is set by hand: declare its front panel, kind = "manual" '
            "and gain_db (docs/protocols/manual_pulser.md)",
        )
    if by_hand is not None and not manual:
        raise ProfileError(
            profile.path or "the profile",
            "pulser.kind",
            f"'manual': the cell's pulser is set by hand, not at {pulser_url}: give --pulser "
            "manual:// and its digitiser (--digitizer), or remove kind and the panel's keys",
        )
    return {} if by_hand is None else {"declared": by_hand.panel}


def check_set_by_hand(pulser: Any, rig: Rig, profile: CellProfile) -> None:
    """Before the first motion: a pulser set by hand (``drivers.pulser.manual``) checked
    against a few A-scans where the arm stands (``ucal.echo.by_hand``: ``ProfileError``, exit
    2, naming the key the records disagree with); where they show no echo, its first timed echo
    is checked before it is used. Other pulsers: nothing."""
    by_hand = profile.pulser.by_hand
    if by_hand is None or not isinstance(pulser, ManualPulser):
        return
    from ucal.echo.by_hand import FirstEchoCheck, judge, look, records_at_the_panel
    from ucal.profile.by_hand import declared_of

    declared = declared_of(profile, pulser.full_screen_v)
    try:
        records, gate_ns = records_at_the_panel(pulser, declared, rig.settings)
        pulser.configure(rig.settings)
    except DriverError as e:
        raise HardwareError(str(e)) from e
    found = look(records, declared, gate_ns)
    log.info("pulser set by hand, where the arm stands: %s", found.as_json())
    judge(found, declared)
    if found.echo is None and pulser.echo_timer is not None:
        pulser.echo_timer = FirstEchoCheck(pulser.echo_timer, declared)


@contextlib.contextmanager
def open_cell(
    profile: CellProfile,
    sim_world: str | None,
    controller_url: str | None,
    pulser_url: str | None,
    recorder: Recorder | None = None,
    digitizer_url: str | None = None,
) -> Iterator[CellSession]:
    """Connect to the simulated cell (``sim_world`` not None; "" = demo truth) or to the URLs
    (``digitizer_url``: the digitiser of a pulser that does not digitise itself).

    With a ``recorder`` every call the procedure makes to the devices is recorded as it happens
    (``ucal.devices.record``).
    """
    if sim_world is None and not (controller_url and pulser_url):
        raise InputError("give either --sim [WORLD] or both --controller URL and --pulser URL")
    if sim_world is not None and (controller_url or pulser_url):
        raise InputError("--sim cannot be combined with --controller/--pulser")
    with contextlib.ExitStack() as stack:
        truth = None
        clock: Clock = HOST_CLOCK
        controller_options = profile.controller.driver_options()
        pulser_options: dict[str, Any] = {
            "timeout_s": profile.pulser.timeout_s,
            "retries": profile.pulser.retries,
        }
        if profile.pulser.register_map is not None:
            pulser_options["register_map"] = profile.pulser.register_map
        if sim_world is not None:
            truth = load_world(Path(sim_world), profile) if sim_world else demo_world(profile)
            clock = SimClock()
            server = stack.enter_context(SimulatedCellServer(truth, profile, clock=clock))
            stack.callback(clock.close)  # after the drivers have closed, before the server stops
            controller_url, pulser_url = server.urls["controller"], server.urls["pulser"]
            digitizer_url = server.urls.get("digitizer")
            controller_options.update(
                reply_timeout_s=SIM_GUARD_TIMEOUT_S, connect_timeout_s=SIM_GUARD_TIMEOUT_S
            )
            pulser_options["timeout_s"] = SIM_GUARD_TIMEOUT_S
        assert controller_url and pulser_url
        if digitizer_url:
            pulser_options["digitizer"] = digitizer_url
        pulser_options.update(by_hand_options(profile, pulser_url))
        controller: Any
        pulser: Any
        try:
            controller = open_controller(controller_url, **controller_options)
            pulser = open_pulser(pulser_url, **pulser_options)
        except ValueError as e:
            raise InputError(str(e)) from e
        except TypeError as e:  # a back-end whose from_url takes no register map / digitiser
            if "register_map" in pulser_options and "register_map" in str(e):
                raise InputError(
                    f"[pulser] register_map ({profile.pulser.register_map_path}) is for Modbus "
                    f"pulsers; the back-end of {pulser_url} takes none ({e})"
                ) from e
            if "digitizer" in pulser_options and "digitizer" in str(e):
                raise InputError(
                    f"--digitizer {digitizer_url}: the pulser at {pulser_url} digitises "
                    f"itself; a digitiser is for pulsers that do not (ascii://, manual://) ({e})"
                ) from e
            raise
        echo_timing = fit_back_end(pulser, profile)
        controller.clock = pulser.clock = clock
        device = pulser
        if recorder is not None:
            controller = RecordingController(controller, recorder)
            pulser = RecordingPulser(pulser, recorder)
        try:
            stack.enter_context(pulser)
            stack.enter_context(controller)  # exits first: STOP, then close
        except DriverError as e:
            raise HardwareError(str(e)) from e
        rig = make_rig(profile, controller, pulser)
        check_set_by_hand(device, rig, profile)
        rig.reference_capture = echo_timing.capture
        yield CellSession(rig, truth, sim_world is not None, clock, echo_timing)


@contextlib.contextmanager
def replay_cell(profile: CellProfile, record: Record) -> Iterator[CellSession]:
    """A cell that answers with a recorded run's device traffic (``ucal.devices.record``): no
    motion."""
    replay = Replay(record)
    controller = ReplayController(replay, str(record.header.get("cell", "recorded cell")))
    pulser = ReplayPulser(replay, "recorded pulser")
    # the session's own clock stays the host's: the procedure's clock readings are the replay's
    # how the recorded run timed its echoes is in its readings; a reference it captured on the
    # block is replayed as the calls it made (ucal.echo.capture.ReplayedCapture)
    rig = make_rig(profile, controller, pulser)
    result = record.result or {}
    recorded = result.get("reference_echo")
    timing = TimingMode(str(result.get("timing", profile.pulser.timing)))
    if isinstance(recorded, dict) and recorded.get("source") == "captured":
        from ucal.echo.capture import ReplayedCapture

        capture = ReplayedCapture(recorded)
        rig.reference_capture = capture
        timing = TimingMode(timing.mode, capture)
    yield CellSession(rig, None, False, echo_timing=timing)
