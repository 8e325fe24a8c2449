"""The procedure every command that moves the robot follows, in one order.

``calibrate``, ``tool-frame`` and ``verify`` differ in what they plan, measure and solve; the
order is the same and lives here (``MeasuringProcedure.run``):

1. **check** usage and files: the profile lock and room to write (``Job.check``);
2. **plan** every target, checked before any motion (``Job.plan``: ``SafetyError``, exit 4);
3. **show** the plan with its estimated duration on a real cell;
4. **confirm**, naming the cell ("the simulated cell" or the controller's address); ``--yes``
   skips the question, a replayed run moves nothing and asks nothing;
5. **open** the cell (``ucal.devices.session``: simulated, real or replayed; recorded with
   ``--record``) and check the controller's status;
6. **measure**, reporting each step with moves, reads and the time left (``ucal.progress``);
   the cell is closed (the robot told to STOP) as soon as the measurement ends, however it
   ends; with ``--record`` the measurements are written as the record's measurement lines
   (``Job.measurement_lines``) when the step ends;
7. **solve** the measurements (``Job.solve``);
8. **write** the result (the profile, or a picture), unless this is a dry run or the result
   may not be written;
9. **result**: one ``Outcome``: the command's typed result (the tables and ``--json`` are
   drawn from it), written or not, out of tolerance or not.

A replay (``--replay FILE``) solves the record's measurement lines: steps 5 and 6 are skipped
(``Job.measured_from`` rebuilds what the measure step handed on), nothing moves and nothing is
asked. With ``--remeasure``, or a record that has no measurement lines (version 1, or a run
cut off before its measure step ended: a one-line warning says so), the recorded device
traffic answers steps 5 and 6 instead, and the search runs again. Either way the plan is the
recorded one (the header's ``planned``), so that a change to the planners since leaves the
record replayable; a record whose plan this ucal cannot rebuild is planned again (a warning
says so), and then a header key the job writes besides ``options`` and ``plan`` (check's
reference, say) that differs is refused (``RecordError``, exit 2).

A ``Job`` is what one command contributes to these steps; ``Presenter`` is how the command
line shows the plan, asks and displays progress (``ucal.cli.procedure``). ``on_step`` hears
each step as it starts, which is how a test holds the three commands to the same order.

A signal is acted on at every step boundary and every measuring step (``ucal.interrupt.check``):
one whose ``KeyboardInterrupt`` was swallowed where it struck still stops the run before the
cell is opened, before the first motion, before the next face and before anything is written.
From the write step on the robot has stopped and a signal is only recorded
(``ucal.interrupt.hold``): the result is written and reported whole, and the command line ends
the run as interrupted (exit 130) with that result.
"""

from __future__ import annotations

import contextlib
import logging
from collections.abc import Callable, Iterable, Iterator
from contextlib import AbstractContextManager
from dataclasses import dataclass, field, replace
from enum import StrEnum
from pathlib import Path
from typing import Any, Generic, Protocol, TypeVar

import numpy as np

from ucal import __version__, interrupt
from ucal.cell import CellProfile, TemperatureLog, WorldTruth
from ucal.cell_choice import CellChoice
from ucal.devices.record import (
    SESSION,
    Record,
    Recorder,
    RecordError,
    decode,
    encode,
    measured_from_lines,
    measurement_lines,
    plain_json,
    sha256_text,
)
from ucal.devices.session import CellSession, check_status, open_cell, replay_cell
from ucal.profile import check_writable, profile_lock
from ucal.progress import MeasureStep, Progress, Report, time_left_s
from ucal.thermometer import (
    Thermometer,
    awaited,
    check_time_base,
    last_reading_min,
    on_run,
    reading_span_min,
)
from ucal.timing import DurationEstimate

log = logging.getLogger(__name__)

PlanT = TypeVar("PlanT")
MeasuredT = TypeVar("MeasuredT")
SolvedT = TypeVar("SolvedT")


class CommandResult(Protocol):
    """What a command's typed result gives besides its fields: its ``--json`` object."""

    def to_json(self) -> dict[str, Any]:
        """The command's ``--json`` object of SPEC.md (and more)."""
        ...


ResultT = TypeVar("ResultT", bound=CommandResult)
ResultT_co = TypeVar("ResultT_co", bound=CommandResult, covariant=True)


class Step(StrEnum):
    """The steps of a measuring procedure, in their order."""

    CHECK = "check"
    PLAN = "plan"
    SHOW = "show"
    CONFIRM = "confirm"
    OPEN = "open"
    MEASURE = "measure"
    SOLVE = "solve"
    WRITE = "write"
    RESULT = "result"


@dataclass(frozen=True)
class RunOptions:
    """How a procedure runs: on which cell, asking or not, writing or not, recorded or not."""

    cell: CellChoice | None  # None with ``replay``
    yes: bool = False
    dry_run: bool = False  # nothing is written
    record_path: Path | None = None
    replay: Record | None = None  # a recorded run answers instead of a cell; nothing moves
    remeasure: bool = False  # replay the recorded device traffic, not the measurements
    #: The tank's thermometer log (``--thermometer``), read when the run is solved.
    thermometer: TemperatureLog | None = None

    @property
    def writes(self) -> bool:
        return not self.dry_run and self.replay is None

    def replays_measurements(self) -> bool:
        """Whether the run solves a record's measurement lines (no cell, no measure step); a
        warning when it would, but the record has none."""
        if self.replay is None or self.remeasure:
            return False
        if not self.replay.measured:
            log.warning(
                "%s has no measurement lines (%s): replaying its device traffic",
                self.replay.path,
                "a version 1 record"
                if self.replay.version == 1
                else "the run was cut off before its measure step ended",
            )
            return False
        return True


@dataclass
class Measured(Generic[MeasuredT]):
    """What the measure step hands on: the job's measurements and what the cell said."""

    data: MeasuredT
    duration_s: float  # the run on the cell's clock (simulated time on the simulated cell)
    truth: WorldTruth | None  # the simulator's hidden truth, for reporting
    #: How the echoes were timed: ``"timing"`` and ``"reference_echo"`` of the result.
    echo_timing: dict[str, Any] = field(default_factory=dict)
    #: The tank's thermometer on the run's clock (``ucal.thermometer``), if one was given.
    thermometer: Thermometer | None = None

    def for_solving(self, profile: CellProfile) -> tuple[CellProfile, Measured[MeasuredT]]:
        """The profile and the measurements the solve step takes: with a thermometer, every
        water path with the tank's turns taken out and the drift's prior the log's
        (``Thermometer.corrected``, ``Thermometer.profile``); without, both unchanged. New
        objects: the measurements as measured stay what the record holds."""
        if self.thermometer is None:
            return profile, self
        return self.thermometer.profile(profile, self.data), replace(
            self, data=self.thermometer.corrected(self.data)
        )

    def thermometer_summary(self) -> dict[str, Any] | None:
        """What the tank's thermometer said of the run (``--json``'s ``thermometer``); None
        without one."""
        return None if self.thermometer is None else self.thermometer.summary(self.data)


class Counted(Protocol):
    """What every measure step counts: the robot's moves and the pulser's readings."""

    @property
    def moves(self) -> int: ...

    @property
    def reads(self) -> int: ...


CountedT = TypeVar("CountedT", bound=Counted)


@dataclass(frozen=True)
class RunFacts:
    """What every command's result says of its run besides what it found."""

    profile_path: Path
    written: bool  # the result (the profile, the picture, the history entry) was written
    moves: int
    reads: int
    duration_s: float  # on the cell's clock: simulated time on the simulated cell
    truth: WorldTruth | None = None  # the simulator's hidden truth, for reporting

    @classmethod
    def of(cls, measured: Measured[CountedT], profile_path: Path, written: bool) -> RunFacts:
        """The facts of the run ``measured`` came from."""
        data = measured.data
        return cls(
            profile_path, written, data.moves, data.reads, measured.duration_s, measured.truth
        )


@dataclass
class Outcome(Generic[ResultT_co]):
    """The one result shape of every command: its typed result and what became of it."""

    command: str
    result: ResultT_co  # what the command's tables and ``--json`` object are drawn from
    written: bool
    out_of_tolerance: bool = False
    message: str = ""  # why it is out of tolerance (the one-line error)
    #: How the echoes were timed (``Measured.echo_timing``), set by the procedure.
    echo_timing: dict[str, object] = field(default_factory=dict)
    created: bool | None = None  # the profile was created for the run (``calibrate``)
    replayed: Path | None = None  # the record a replay solved again
    #: What the tank's thermometer said of the run (``ucal.thermometer.summary``), if given.
    thermometer: dict[str, Any] | None = None

    def to_json(self) -> dict[str, Any]:
        """The ``--json`` object of SPEC.md (and more): the result's, then how the run went."""
        out = {**self.result.to_json(), **self.echo_timing}
        if self.created is not None:
            out["created"] = self.created
        if self.replayed is not None:
            out["replayed"] = str(self.replayed)
        if self.thermometer is not None:
            out["thermometer"] = self.thermometer
        return out


class Job(Protocol[PlanT, MeasuredT, SolvedT, ResultT_co]):
    """What one command contributes to the procedure's steps."""

    command: str  # "calibrate", "tool-frame", "verify": the progress display's title
    profile: CellProfile
    profile_path: Path

    def profile_text(self) -> str:
        """The profile as the run reads it, for a ``--record`` file."""
        ...

    def check(self, options: RunOptions) -> AbstractContextManager[object]:
        """Check the files (the lock held for the run, room to write); usage was checked
        before the job was made."""
        ...

    def plan(self) -> PlanT: ...

    def summary(self, plan: PlanT) -> str:
        """The plan in words, for the technician before the first motion."""
        ...

    def estimate(self, plan: PlanT) -> DurationEstimate: ...

    def record_header(self, plan: PlanT) -> dict[str, Any]:
        """``options`` and ``plan`` of a ``--record`` file's header."""
        ...

    def measure(self, plan: PlanT, session: CellSession, report: Report) -> MeasuredT: ...

    def measurement_lines(self, data: MeasuredT) -> list[dict[str, Any]]:
        """The measure step's data as a record's measurement lines (``ucal.devices.record``)."""
        ...

    def measured_from(self, lines: list[dict[str, Any]], plan: PlanT, source: str) -> MeasuredT:
        """The measure step's data again, from the lines ``measurement_lines`` wrote."""
        ...

    def solve(self, plan: PlanT, measured: Measured[MeasuredT]) -> SolvedT: ...

    def may_write(self, solved: SolvedT) -> bool:
        """Whether the result may be written (in tolerance, or forced)."""
        ...

    def write(self, solved: SolvedT) -> None: ...

    def result(
        self, plan: PlanT, measured: Measured[MeasuredT], solved: SolvedT, written: bool
    ) -> Outcome[ResultT_co]: ...


class Presenter(Protocol):
    """How the procedure talks to the technician (the command line's is
    ``ucal.cli.procedure.ConsolePresenter``)."""

    def show_plan(self, text: str) -> None: ...

    def confirm(self, cell: CellChoice) -> None:
        """Ask before the first motion, naming the cell; raise to refuse."""
        ...

    def progress(self, title: str) -> AbstractContextManager[Callable[[Progress], None]]: ...

    def notice(self, text: str) -> None:
        """A line the technician should see while nothing else shows (not an error)."""
        ...


def hold_profile(profile_path: Path, options: RunOptions) -> AbstractContextManager[object]:
    """The profile held for the run (one run per profile) with room checked for the result,
    when the run may write it; nothing otherwise."""
    if not options.writes:
        return contextlib.nullcontext()
    stack = contextlib.ExitStack()
    stack.enter_context(profile_lock(profile_path))
    try:
        check_writable(profile_path)
    except BaseException:
        stack.close()
        raise
    return stack


class ProfileJob:
    """What every job that writes into its profile shares: the profile held for the run, and its
    text for a ``--record`` file."""

    def __init__(self, profile: CellProfile, profile_path: Path) -> None:
        self.profile = profile
        self.profile_path = profile_path

    def profile_text(self) -> str:
        assert self.profile.path is not None
        return Path(self.profile.path).read_text(encoding="utf-8")

    def check(self, options: RunOptions) -> AbstractContextManager[object]:
        return hold_profile(self.profile_path, options)

    def measurement_lines(self, data: Any) -> list[dict[str, Any]]:
        """One line per measurement of the measure step's dataclass (``ucal.devices.record``)."""
        return measurement_lines(data)

    def measured_from(self, lines: list[dict[str, Any]], plan: Any, source: str) -> Any:
        return measured_from_lines(lines, source)


class CheckingJob(ProfileJob):
    """What the jobs that check the cell against its profile share (``verify`` and its region
    check): the tolerance they judge by, and nothing held for the run (the profile is read,
    never written)."""

    command = "verify"

    def __init__(
        self, profile: CellProfile, profile_path: Path, tolerance_mm: float | None = None
    ) -> None:
        super().__init__(profile, profile_path)
        self.tolerance_mm = (
            profile.procedure.verify_tolerance_mm if tolerance_mm is None else tolerance_mm
        )

    def check(self, options: RunOptions) -> AbstractContextManager[object]:
        return contextlib.nullcontext()


class MeasuringProcedure(Generic[PlanT, MeasuredT, SolvedT, ResultT]):
    """Run a ``Job`` through the steps of the module docstring."""

    def __init__(
        self,
        job: Job[PlanT, MeasuredT, SolvedT, ResultT],
        options: RunOptions,
        presenter: Presenter,
        on_step: Callable[[Step], None] | None = None,
    ) -> None:
        self.job = job
        self.options = options
        self.presenter = presenter
        self.on_step = on_step

    def _enter(self, step: Step) -> None:
        interrupt.check()
        log.debug("%s: %s", self.job.command, step)
        if self.on_step is not None:
            self.on_step(step)

    def run(self) -> Outcome[ResultT]:
        """Check, plan, show, confirm, open, measure, solve, write; the outcome."""
        job, options = self.job, self.options
        self._enter(Step.CHECK)
        if options.thermometer is not None and options.cell is not None:
            check_time_base(options.thermometer, options.cell.sim_world is not None)
        with job.check(options):
            self._enter(Step.PLAN)
            plan = self._plan()
            estimate = job.estimate(plan)
            self._enter(Step.SHOW)
            self.presenter.show_plan(job.summary(plan) + "\n" + estimate.describe())
            self._enter(Step.CONFIRM)
            if options.replay is None and not options.yes:
                assert options.cell is not None
                self.presenter.confirm(options.cell)
            with self._recorder(plan) as recorder:
                if options.replay is not None and options.replays_measurements():
                    measured = self._measured(plan, options.replay)
                else:
                    measured = self._measure(plan, estimate, recorder)
                self._enter(Step.SOLVE)
                job.profile, measured = measured.for_solving(job.profile)
                solved = job.solve(plan, measured)
                self._enter(Step.WRITE)
                # the robot has stopped: a signal from here on cuts neither the write nor
                # the report of what was written (the run still ends as interrupted)
                interrupt.hold()
                written = options.writes and job.may_write(solved)
                if written:
                    job.write(solved)
                self._enter(Step.RESULT)
                outcome = job.result(plan, measured, solved, written)
                outcome.echo_timing = measured.echo_timing
                outcome.thermometer = measured.thermometer_summary()
                if recorder is not None:
                    recorder.end(outcome.to_json())
        return outcome

    @contextlib.contextmanager
    def _recorder(self, plan: PlanT) -> Iterator[Recorder | None]:
        path = self.options.record_path
        if path is None:
            yield None
            return
        profile = self.job.profile
        assert self.options.cell is not None
        text = self.job.profile_text()
        with Recorder(path).open(
            {
                "command": self.job.command,
                "ucal": __version__,
                "profile_path": str(profile.path),
                "profile_sha256": sha256_text(text),
                "profile_text": text,
                "cell": self.options.cell.address,
                **self.job.record_header(plan),
                **self._planned(plan),
            }
        ) as recorder:
            yield recorder

    def _planned(self, plan: PlanT) -> dict[str, Any]:
        """The header's ``planned``: the whole plan, tagged (none, with a warning, for a plan
        a record cannot hold: a replay then plans again)."""
        try:
            return {"planned": encode(plan)}
        except TypeError as e:
            log.warning("the plan is not recorded (%s): a replay plans again", e)
            return {}

    def _plan(self) -> PlanT:
        """The job's plan; a replay's is the recorded one (the header's ``planned``), so that a
        change to the planner since leaves the record replayable."""
        record = self.options.replay
        if record is None or "planned" not in record.header:
            return self.job.plan()
        try:
            plan: PlanT = decode(record.header["planned"])
        except RecordError as e:
            log.warning("%s: its plan is not this ucal's (%s): planning again", record.path, e)
            return self.job.plan()
        return plan

    def _measured(self, plan: PlanT, record: Record) -> Measured[MeasuredT]:
        """What the measure step handed on, from the record's measurement lines."""
        self._check_plan(plan, record)
        session = record.session()
        data = self.job.measured_from(record.measurements, plan, str(record.path))
        echo_timing = dict(session.get("echo_timing", {}))
        water = session.get("thermometer")
        return Measured(
            data,
            float(session.get("duration_s", 0.0)),
            None,
            echo_timing,
            None if water is None else Thermometer.from_json(water),
        )

    def _check_plan(self, plan: PlanT, record: Record) -> None:
        """Refuse a replay whose plan the recorded run did not measure: a header key the job
        writes besides ``options`` and ``plan`` that differs (``RecordError``, exit 2)."""
        for key, value in plain_json(self.job.record_header(plan)).items():
            if key not in ("options", "plan") and record.header.get(key) != value:
                raise RecordError(
                    f"{record.path}: the run was recorded with another {key} than this replay "
                    f"reads from {self.job.profile_path}'s history: it cannot solve those "
                    "measurements"
                )

    def _open(self, recorder: Recorder | None) -> AbstractContextManager[CellSession]:
        profile, options = self.job.profile, self.options
        if options.replay is not None:
            return replay_cell(profile, options.replay)
        assert options.cell is not None
        cell = options.cell
        return open_cell(
            profile,
            cell.sim_world,
            cell.controller_url,
            cell.pulser_url,
            recorder,
            digitizer_url=cell.digitizer_url,
        )

    def _measure(
        self, plan: PlanT, estimate: DurationEstimate, recorder: Recorder | None
    ) -> Measured[MeasuredT]:
        self._enter(Step.OPEN)
        with self._open(recorder) as session:
            check_status(session.rig)
            self._enter(Step.MEASURE)
            with self.presenter.progress(self.job.command) as show:

                def report(step: MeasureStep) -> None:
                    interrupt.check()
                    counters = session.rig.counters
                    elapsed = session.elapsed_s
                    show(
                        Progress(
                            step,
                            counters.moves,
                            counters.reads,
                            elapsed,
                            time_left_s(estimate.tcp_s, elapsed, step.done, step.total),
                        )
                    )

                data = self.job.measure(plan, session, report)
            measured = Measured(
                data, session.elapsed_s, session.truth, session.echo_timing.as_json()
            )
            first_min = self._first_read_min(session)
        # the cell closed (the robot stopped): a live log may be waited for
        measured.thermometer = self._thermometer(first_min, data)
        if recorder is not None:
            self._record_measurements(recorder, measured)
        return measured

    def _first_read_min(self, session: CellSession) -> float | None:
        """The run's first reading in the time base of the thermometer's log, if one was given
        and the run read: a logger's wall-clock times meet the run at the first reading's wall
        time, a simulated cell's minutes at its clock (``check_time_base``)."""
        log_ = self.options.thermometer
        rig = session.rig
        if log_ is None or rig.first_read_s is None:
            return None
        if log_.wall_clock:
            assert rig.first_read_wall_s is not None
            return rig.first_read_wall_s / 60.0
        return (rig.first_read_s - session.started_s) / 60.0

    def _thermometer(self, first_min: float | None, data: Any) -> Thermometer | None:
        """The thermometer's log on the run's clock (``ucal.thermometer.on_run``), read again
        now that the run has measured, a live logger's once it has logged past the run's last
        reading (``ucal.thermometer.awaited``); None without a log or a reading."""
        log_ = self.options.thermometer
        if log_ is None or first_min is None:
            return None
        # the logger wrote on
        log_ = awaited(log_, first_min + last_reading_min(data), waiting=self.presenter.notice)
        return on_run(log_, self.job.profile.thermometer_std_c, first_min, reading_span_min(data))

    def _record_measurements(self, recorder: Recorder, measured: Measured[MeasuredT]) -> None:
        """Write the measurement lines; measurements a record cannot hold (a value of a type it
        does not know) are left out with a warning, not the run: its traffic is recorded."""
        try:
            lines = self.job.measurement_lines(measured.data)
            lines.append(
                {
                    "of": SESSION,
                    "duration_s": measured.duration_s,
                    "echo_timing": plain_json(measured.echo_timing),
                    "thermometer": None
                    if measured.thermometer is None
                    else measured.thermometer.as_json(),
                }
            )
        except (TypeError, ValueError) as e:
            log.warning(
                "%s: the measurements are not recorded (%s): a replay replays the traffic",
                recorder.path,
                e,
            )
            return
        recorder.measurements(lines)


class PlannedPosture(Protocol):
    """What a record's plan rows read of a planned target or posture."""

    @property
    def label(self) -> str: ...

    @property
    def joints_deg(self) -> np.ndarray: ...

    @property
    def water_path_mm(self) -> float: ...


#: The plans' last line: how every planned posture is measured.
WRIST_SEARCH = (
    "The wrist searches around each planned posture for the echo (joints 4-6 only); every "
    "move ends approaching from below on each joint (backlash), unless said above."
)


def plan_line(name: str, planned: PlannedPosture) -> str:
    """One planned posture in a plan's table: its name, joints (deg) and water path."""
    joints = "".join(f"{v:9.2f}" for v in planned.joints_deg)
    return f"  {name}{joints}   {planned.water_path_mm:6.1f} mm"


def plan_rows(planned: Iterable[PlannedPosture]) -> list[dict[str, Any]]:
    """The ``plan`` of a ``--record`` file's header: every planned posture."""
    return [
        {"label": p.label, "joints_deg": p.joints_deg.tolist(), "water_path_mm": p.water_path_mm}
        for p in planned
    ]
