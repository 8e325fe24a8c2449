"""The command line's side of a measuring procedure (``ucal.procedure``).

``ConsolePresenter`` shows the plan on stderr (not with ``-q``, unless it asks), asks before
the first motion naming the cell, and displays progress (``ucal.cli.progress``); ``run_job``
runs a command's job through the procedure's steps; ``finish`` prints the outcome: the
command's tables on stdout, or the one JSON object with ``--json``, both drawn from the
command's typed result, and exit 1 when out of tolerance; with ``--publish`` the final result
is published too (``ucal.cli.publishing``: checked before the run, sent once the result is
final, never changing the exit code). ``recorded_run`` checks
``--record``/``--replay``/``--remeasure`` and loads the run a replay solves again;
``replay_job`` runs it. ``run_command`` is all of it for a moving command: the replay or the
run on the cell its options name, then the outcome printed.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, TypeVar

import click
from click.core import ParameterSource

from ucal import interrupt
from ucal.cell import CellProfile
from ucal.cell_choice import CellChoice
from ucal.cli.options import (
    MovingCall,
    ask_to_move,
    cell_options_typed,
    check_can_confirm,
    check_output,
    emit_json,
    info,
)
from ucal.cli.progress import StepProgress
from ucal.cli.publishing import prepare_publication, publish_outcome
from ucal.devices.record import Record, read_record
from ucal.errors import InputError, InterruptedAfterResult, OutOfToleranceError
from ucal.procedure import CommandResult, Job, MeasuringProcedure, Outcome, RunOptions, Step
from ucal.profile import load_profile, profile_from_text
from ucal.progress import Progress
from ucal.thermometer import read_log

R = TypeVar("R", bound=CommandResult)
#: The job a moving command runs, made from the profile and, on a replay, the record.
JobFor = Callable[[CellProfile, Record | None], Job[Any, Any, Any, R]]


class ConsolePresenter:
    """Plan and progress on stderr, the question on the terminal. ``asks``: the run will ask
    before the first motion, so the plan is shown even with ``-q`` (the operator cannot
    confirm what they have not seen)."""

    def __init__(self, asks: bool = False) -> None:
        self.asks = asks

    def show_plan(self, text: str) -> None:
        if self.asks:
            click.echo(text, err=True)
        else:
            info(text)

    def confirm(self, cell: CellChoice) -> None:
        ask_to_move(cell)

    def notice(self, text: str) -> None:
        info(text)

    @contextlib.contextmanager
    def progress(self, title: str) -> Iterator[Callable[[Progress], None]]:
        with StepProgress(title) as display:
            yield display.show


def run_job(
    job: Job[Any, Any, Any, R],
    options: RunOptions,
    on_step: Callable[[Step], None] | None = None,
) -> Outcome[R]:
    """Run ``job`` through the procedure's steps with the console presenter; first refuse a
    run that would have to ask before moving with no terminal to ask on (exit 2, no plan)."""
    if options.cell is not None:
        check_can_confirm(options.cell, options.yes)
    prepare_publication(job, options)
    asks = options.cell is not None and options.replay is None and not options.yes
    return MeasuringProcedure(job, options, ConsolePresenter(asks), on_step).run()


def finish(outcome: Outcome[R], as_json: bool, show: Callable[[Outcome[R]], None]) -> None:
    """Print the outcome: ``show`` draws the command's tables (without ``--json``); out of
    tolerance, exit 1, and after a signal that came once the robot had stopped, exit 130 (with
    ``--json`` the CLI prints the result with the error fields). With ``--publish`` the result
    is published once shown, before the exit."""
    if not as_json:
        show(outcome)
    ended: InterruptedAfterResult | OutOfToleranceError | None = None
    if interrupt.received:  # a signal once the robot had stopped: the result stands, reported
        ended = InterruptedAfterResult(outcome.to_json())
    elif outcome.out_of_tolerance:
        ended = OutOfToleranceError(outcome.message, outcome.to_json())
    publish_outcome(outcome, None if ended is None else str(ended))
    if ended is not None:
        raise ended
    if as_json:
        emit_json(outcome.to_json())


def run_command(
    call: MovingCall,
    command: str,
    fixed: dict[str, str],
    job_for: JobFor[R],
    show: Callable[[Outcome[R]], None],
    thermometer: Path | None = None,
) -> None:
    """Run a moving command and print its outcome (``finish``): with ``--replay``, the job
    ``job_for`` makes of the recorded profile and the record solves it again
    (``recorded_run``, ``fixed`` as there; the record holds the thermometer's log the run
    was solved with); else the job of PROFILE on the cell the options name (with the tank
    thermometer's log ``thermometer``)."""
    outcome = replay_outcome(call, command, fixed, job_for)
    if outcome is None:
        cell = call.cell()
        job = job_for(load_profile(call.profile_path), None)
        outcome = run_job(job, run_options(call, cell, thermometer))
    finish(outcome, call.as_json, show)


def run_options(call: MovingCall, cell: CellChoice, thermometer: Path | None = None) -> RunOptions:
    """How a run on ``cell`` goes, as the command line says (``thermometer``: the tank
    thermometer's log, read and checked now: ``ProfileError``, exit 2)."""
    log_ = None if thermometer is None else read_log(thermometer, "--thermometer")
    return RunOptions(cell, call.yes, call.dry_run, call.record_path, thermometer=log_)


def replay_outcome(
    call: MovingCall, command: str, fixed: dict[str, str], job_for: JobFor[R]
) -> Outcome[R] | None:
    """With ``--replay``, the outcome of solving the record again (``recorded_run``, ``fixed``
    as there); None without."""
    replayed = recorded_run(
        command, call.profile_path, call.record_path, call.replay_path, call.remeasure, fixed
    )
    if replayed is None:
        return None
    record, profile = replayed
    return replay_job(job_for(profile, record), record, call.remeasure)


def recorded_run(
    command: str,
    profile_path: Path,
    record_path: Path | None,
    replay_path: Path | None,
    remeasure: bool,
    fixed: dict[str, str],
) -> tuple[Record, CellProfile] | None:
    """The record a ``--replay`` solves again and its profile (None without ``--replay``, the
    ``--record`` file's directory checked). Exit 2 (``InputError``) for a replay given a cell or
    ``--record``, ``--remeasure`` without ``--replay``, a record of another command, and an
    option typed on the command line that would measure something else than was recorded:
    ``fixed`` maps each such option's key in the record's ``options`` to its parameter."""
    if replay_path is None:
        if remeasure:
            raise InputError("--remeasure replays a record's device traffic: give --replay FILE")
        if record_path is not None:
            check_output(record_path)
        return None
    ctx = click.get_current_context()
    if cell_options_typed(ctx) or record_path is not None:
        raise InputError(
            "--replay solves a recorded run: it takes no --sim, --controller, --pulser or --record"
        )
    record = read_record(replay_path)
    if record.command != command:
        raise InputError(
            f"{replay_path}: a record of `ucal {record.command}`; `ucal {command}` cannot replay it"
        )
    options = record.options
    flags = {p.name: p.opts[0] for p in ctx.command.params}
    for key, name in fixed.items():
        typed = ctx.get_parameter_source(name) == ParameterSource.COMMANDLINE
        if typed and ctx.params[name] != options.get(key):
            flag = flags[name]
            raise InputError(
                f"{replay_path}: recorded with {flag} {_shown(options.get(key))}; it cannot be "
                f"replayed with {flag} {_shown(ctx.params[name])}: a replay solves what was "
                f"measured (leave {flag} out)"
            )
    profile = profile_from_text(
        record.profile_text, f"{replay_path} (recorded profile)", base_dir=profile_path.parent
    )
    return record, profile


def _shown(value: Any) -> str:
    return "(not given)" if value is None else str(value)


def replay_job(job: Job[Any, Any, Any, R], record: Record, remeasure: bool) -> Outcome[R]:
    """Run ``job`` on a record (``recorded_run``): nothing moves, nothing is asked or written."""
    options = RunOptions(None, yes=True, dry_run=True, replay=record, remeasure=remeasure)
    outcome = run_job(job, options)
    outcome.replayed = Path(record.path)
    return outcome
