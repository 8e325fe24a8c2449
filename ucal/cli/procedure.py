"""The command line's side of a measuring procedure (``ucal.procedure``).

``ConsolePresenter`` shows the plan on stderr (not with ``-q``, unless it asks), asks before
the first motion naming the cell, and displays progress (``ucal.cli.progress``); ``run_job``
runs a command's job through the procedure's steps; ``finish`` prints the outcome: the
command's tables on stdout, or the one JSON object with ``--json``, and exit 1 when out of
tolerance.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator
from typing import Any

import click

from ucal.cell_choice import CellChoice
from ucal.cli.options import ask_to_move, check_can_confirm, emit_json, info
from ucal.cli.progress import StepProgress
from ucal.errors import OutOfToleranceError
from ucal.procedure import Job, MeasuringProcedure, Outcome, RunOptions, Step
from ucal.progress import Progress


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

    @contextlib.contextmanager
    def progress(self, title: str) -> Iterator[Callable[[Progress], None]]:
        with StepProgress(title) as display:
            yield display.show


def run_job(
    job: Job[Any, Any, Any],
    options: RunOptions,
    on_step: Callable[[Step], None] | None = None,
) -> Outcome:
    """Run ``job`` through the procedure's steps with the console presenter; first refuse a
    run that would have to ask before moving with no terminal to ask on (exit 2, no plan)."""
    if options.cell is not None:
        check_can_confirm(options.cell, options.yes)
    asks = options.cell is not None and options.replay is None and not options.yes
    return MeasuringProcedure(job, options, ConsolePresenter(asks), on_step).run()


def finish(outcome: Outcome, as_json: bool, show: Callable[[Outcome], None]) -> None:
    """Print the outcome: ``show`` draws the command's tables (without ``--json``); out of
    tolerance, exit 1 (with ``--json`` the CLI prints the result with the error fields)."""
    if not as_json:
        show(outcome)
    if outcome.out_of_tolerance:
        raise OutOfToleranceError(outcome.message, outcome.result)
    if as_json:
        emit_json(outcome.result)
