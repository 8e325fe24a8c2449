"""Progress of a moving command, on stderr (stdout stays for the result and ``--json``).

On a terminal a live bar; otherwise (a script, a log file, a pipe) one plain line per step, so
a scripted run shows it is alive; nothing with ``-q``. A step of a measuring procedure
(``ucal.progress.Progress``) shows what is measured (configuration and face, posture or point),
the moves and pulser reads so far and the estimated time left::

    calibrate [1/12] face base/YZ (45 moves, 515 reads, about 30 s left)
"""

from __future__ import annotations

import sys
from types import TracebackType
from typing import Any, Self

import click
from rich.console import Console
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

from ucal import progress
from ucal.cli.options import quiet


class StepProgress:
    """``with StepProgress("calibrate") as p: p.step("face XY", done, total, "12 moves")``."""

    def __init__(self, title: str) -> None:
        self.title = title
        self._bar: Any = None
        self._task: Any = None
        self._silent = quiet()

    def __enter__(self) -> Self:
        if not self._silent and sys.stderr.isatty():
            self._bar = Progress(
                TextColumn("{task.description}"),
                BarColumn(),
                TextColumn("{task.completed}/{task.total}"),
                TextColumn("{task.fields[detail]}"),
                TimeElapsedColumn(),
                console=Console(stderr=True),
                transient=False,
            )
            self._bar.start()
            self._task = self._bar.add_task(self.title, total=None, detail="")
        return self

    def step(self, what: str, done: int, total: int, detail: str = "") -> None:
        """Report that ``done`` of ``total`` steps are finished and ``what`` is under way."""
        if self._silent:
            return
        if self._bar is not None:
            self._bar.update(
                self._task,
                description=f"{self.title}: {what}",
                completed=done,
                total=total,
                detail=detail,
            )
            return
        click.echo(
            f"{self.title} [{done}/{total}] {what}" + (f" ({detail})" if detail else ""), err=True
        )

    def show(self, p: progress.Progress) -> None:
        """Show a step of a measuring procedure with its counters and the time left."""
        self.step(p.step.what, p.step.done, p.step.total, p.detail)

    def __exit__(
        self,
        kind: type[BaseException] | None,
        error: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        if self._bar is not None:
            self._bar.stop()
