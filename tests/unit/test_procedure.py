"""The procedure's order, dry run and result shape, with a job that measures nothing, and the
progress display's plain lines (stderr not a terminal) with the estimated time left."""

from __future__ import annotations

import contextlib
import signal
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

import ucal.procedure as procedure_module
from ucal import interrupt
from ucal.cell_choice import CellChoice
from ucal.cli.progress import StepProgress
from ucal.devices.record import read_record
from ucal.devices.session import TimingMode
from ucal.procedure import Measured, MeasuringProcedure, Outcome, RunOptions, Step
from ucal.progress import MeasureStep, Progress, time_left_s
from ucal.timing import DurationEstimate


class FakeRig:
    class counters:
        moves = 3
        reads = 7


class FakeSession:
    rig = FakeRig()
    truth = None
    elapsed_s = 10.0
    echo_timing = TimingMode()


class Job:
    """Records what the procedure asks of it."""

    command = "fake"
    profile = SimpleNamespace(path="cell.toml")
    profile_path = Path("cell.toml")

    def __init__(self, log: list[str], ok: bool = True) -> None:
        self.log = log
        self.ok = ok

    def profile_text(self) -> str:
        return ""

    def check(self, options: RunOptions) -> contextlib.AbstractContextManager[object]:
        self.log.append("job.check")
        return contextlib.nullcontext()

    def plan(self) -> str:
        return "the plan"

    def summary(self, plan: str) -> str:
        return f"summary of {plan}"

    def estimate(self, plan: str) -> DurationEstimate:
        return DurationEstimate(10, 100, 20.0, 30.0, 60.0)

    def record_header(self, plan: str) -> dict[str, Any]:
        return {}

    def measure(self, plan: str, session: Any, report: Callable[[MeasureStep], None]) -> str:
        report(MeasureStep("face base/XY", 0, 2, "base", "XY"))
        report(MeasureStep("face base/YZ", 1, 2, "base", "YZ"))
        return "measured"

    def measurement_lines(self, data: str) -> list[dict[str, Any]]:
        return [{"of": "run", "data": data}]

    def measured_from(self, lines: list[dict[str, Any]], plan: str, source: str) -> str:
        self.log.append("job.measured_from")
        return str(lines[0]["data"])

    def solve(self, plan: str, measured: Measured[str]) -> str:
        assert measured.data == "measured" and measured.duration_s == 10.0
        return "solved"

    def may_write(self, solved: str) -> bool:
        return self.ok

    def write(self, solved: str) -> None:
        self.log.append("job.write")

    def result(
        self, plan: str, measured: Measured[str], solved: str, written: bool
    ) -> Outcome[Written]:
        return Outcome(self.command, Written(written), written, not self.ok, "")


@dataclass(frozen=True)
class Written:
    """The fake job's result."""

    written: bool

    def to_json(self) -> dict[str, Any]:
        return {"written": self.written}


class Presenter:
    def __init__(self, log: list[str]) -> None:
        self.log = log
        self.shown: list[Progress] = []

    def show_plan(self, text: str) -> None:
        self.log.append(f"show: {text.splitlines()[0]}")

    def confirm(self, cell: CellChoice) -> None:
        self.log.append(f"confirm {cell.name}")

    def notice(self, text: str) -> None:
        self.log.append(f"notice: {text}")

    @contextlib.contextmanager
    def progress(self, title: str) -> Iterator[Callable[[Progress], None]]:
        yield self.shown.append


@pytest.fixture
def fake_cell(monkeypatch: pytest.MonkeyPatch) -> None:
    @contextlib.contextmanager
    def open_cell(*args: Any, **kwargs: Any) -> Iterator[FakeSession]:
        yield FakeSession()

    monkeypatch.setattr(procedure_module, "open_cell", open_cell)
    monkeypatch.setattr(procedure_module, "check_status", lambda rig: None)


def run(log: list[str], options: RunOptions, ok: bool = True) -> tuple[Outcome[Written], Presenter]:
    presenter = Presenter(log)
    outcome = MeasuringProcedure(Job(log, ok), options, presenter, on_step=log.append).run()
    return outcome, presenter


def test_steps_in_order_and_the_cell_named_before_any_motion(fake_cell: None) -> None:
    log: list[Any] = []
    outcome, presenter = run(log, RunOptions(CellChoice("", None, None)))
    assert log == [
        Step.CHECK,
        "job.check",
        Step.PLAN,
        Step.SHOW,
        "show: summary of the plan",
        Step.CONFIRM,
        "confirm the simulated cell",
        Step.OPEN,
        Step.MEASURE,
        Step.SOLVE,
        Step.WRITE,
        "job.write",
        Step.RESULT,
    ]
    assert outcome.written and outcome.to_json() == {
        "written": True,
        "timing": "gate",
        "reference_echo": None,
    }
    # each reported step with the rig's counters and the time left on the cell's clock
    assert [(p.step.what, p.moves, p.reads, p.left_s) for p in presenter.shown] == [
        ("face base/XY", 3, 7, 20.0),
        ("face base/YZ", 3, 7, 20.0),
    ]


def test_yes_asks_nothing_and_a_dry_run_writes_nothing(fake_cell: None) -> None:
    log: list[Any] = []
    outcome, _ = run(log, RunOptions(CellChoice("", None, None), yes=True, dry_run=True))
    assert "confirm the simulated cell" not in log and "job.write" not in log
    assert [e for e in log if isinstance(e, Step)] == list(Step)  # the same steps
    assert outcome.written is False


def test_out_of_tolerance_is_not_written(fake_cell: None) -> None:
    log: list[Any] = []
    outcome, _ = run(log, RunOptions(CellChoice(None, "tcp://h:1", "modbus-tcp://h:2")), ok=False)
    assert "confirm the robot at tcp://h:1" in log and "job.write" not in log
    assert outcome.out_of_tolerance and not outcome.written


class InterruptedJob(Job):
    """A signal arrives during the first face and its ``KeyboardInterrupt`` is lost there."""

    def measure(self, plan: str, session: Any, report: Callable[[MeasureStep], None]) -> str:
        report(MeasureStep("face base/XY", 0, 2, "base", "XY"))
        interrupt.received.append(signal.SIGTERM)  # what the handler recorded
        report(MeasureStep("face base/YZ", 1, 2, "base", "YZ"))
        self.log.append("second face measured")
        return "measured"


def test_a_lost_interrupt_stops_the_measurement_at_the_next_step(
    fake_cell: None, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(interrupt, "received", [])
    log: list[Any] = []
    presenter = Presenter(log)
    procedure = MeasuringProcedure(
        InterruptedJob(log), RunOptions(CellChoice("", None, None), yes=True), presenter, log.append
    )
    with pytest.raises(KeyboardInterrupt, match="signal 15"):
        procedure.run()
    assert log[-1] == Step.MEASURE and "job.write" not in log
    assert [p.step.what for p in presenter.shown] == ["face base/XY"]


def test_time_left_from_the_estimate_then_from_the_pace() -> None:
    assert time_left_s(37.0, 8.0, 1, 12) == 29.0  # within the estimate: the rest of it
    assert time_left_s(37.0, 40.0, 10, 12) == pytest.approx(8.0)  # past it: 4 s per step
    assert time_left_s(37.0, 40.0, 12, 12) == 0.0


def test_plain_progress_lines_on_a_non_terminal(capsys: pytest.CaptureFixture[str]) -> None:
    steps = [
        Progress(MeasureStep("face base/YZ", 1, 12, "base", "YZ"), 45, 515, 8.0, 29.0),
        Progress(MeasureStep("solving", 12, 12), 190, 1344, 37.2, 0.0),
        Progress(MeasureStep("peak 2", 1, 11), 45, 491, 100.0, 125.0),
    ]
    with StepProgress("calibrate") as display:
        for p in steps:
            display.show(p)
    assert capsys.readouterr().err.splitlines() == [
        "calibrate [1/12] face base/YZ (45 moves, 515 reads, about 29 s left)",
        "calibrate [12/12] solving (190 moves, 1344 reads, about 0 s left)",
        "calibrate [1/11] peak 2 (45 moves, 491 reads, about 2.1 min left)",
    ]


def test_faces_and_configurations_serialise_as_before() -> None:
    import json

    from ucal.model.geometry import FACE_NAMES, FACE_ORDER, Configuration, Face

    assert json.dumps([Face.XY, Configuration.J3]) == '[2, "j3"]'
    assert FACE_ORDER == (2, 0, 1) and FACE_NAMES == ("YZ", "XZ", "XY")
    assert f"{Configuration.BASE}/{FACE_NAMES[Face.XZ]}" == "base/XZ"
    assert np.eye(3)[:, Face.XZ].tolist() == [0.0, 1.0, 0.0]


def test_a_replay_solves_the_recorded_measurements_without_opening_a_cell(
    fake_cell: None, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    path = tmp_path / "run.jsonl"
    run([], RunOptions(CellChoice("", None, None), yes=True, dry_run=True, record_path=path))
    record = read_record(path)
    assert [line["of"] for line in record.measurements] == ["run", "session"]
    assert record.session()["duration_s"] == 10.0
    record.header["planned"] = "the recorded plan"  # as the planner had it then
    log: list[Any] = []
    outcome, _ = run(log, RunOptions(None, replay=record))
    assert "show: summary of the recorded plan" in log
    assert [e for e in log if isinstance(e, Step)] == [
        s for s in Step if s not in (Step.OPEN, Step.MEASURE)
    ]
    assert "job.measured_from" in log and "job.write" not in log and not outcome.written
    assert outcome.to_json()["timing"] == "gate"  # as the recorded session timed its echoes
    # with --remeasure the recorded traffic answers (faked here: the fake cell made no calls)
    monkeypatch.setattr(
        procedure_module,
        "replay_cell",
        lambda profile, record: contextlib.nullcontext(FakeSession()),
    )
    log.clear()
    run(log, RunOptions(None, replay=record, remeasure=True))
    assert Step.MEASURE in log and "job.measured_from" not in log


def test_measurements_a_record_cannot_hold_leave_the_run_and_its_traffic(
    fake_cell: None, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    class Unrecordable(Job):
        def measurement_lines(self, data: str) -> list[dict[str, Any]]:
            raise TypeError("cannot record a Thing")

    path = tmp_path / "run.jsonl"
    options = RunOptions(CellChoice("", None, None), yes=True, dry_run=True, record_path=path)
    outcome = MeasuringProcedure(Unrecordable([]), options, Presenter([])).run()
    assert outcome.to_json()["timing"] == "gate"  # the run went on to its result
    record = read_record(path)
    assert record.result is not None and not record.measured
    assert "cannot record a Thing" in caplog.text
