"""What a measuring run reports while it runs, and how much of it is left.

A measurement (``run_calibration``, ``run_tool_frame``, ``run_verify``) reports each step it
starts as a ``MeasureStep``; the procedure (``ucal.procedure``) adds the rig's counters and the
time left and hands a ``Progress`` to the display (``ucal.cli.progress``).

The time left comes from the plan's estimate of the run on a real cell (``ucal.timing``), set
against the cell's own clock: simulated time on the simulated cell (so the same world gives the
same figures on any machine), the host's on a real one. While the run is within its estimate
the rest of the estimate is left; past it, the steps still to come at the pace of those done.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass


@dataclass(frozen=True)
class MeasureStep:
    """One step of a measuring run, reported when it starts (``done`` steps are finished)."""

    what: str  # e.g. "face j3/XY", "peak 2", "edge +e1", "before point 3", "solving"
    done: int
    total: int
    configuration: str | None = None  # the arm configuration or posture being measured
    face: str | None = None  # the block face ("XY", "YZ", "XZ") or the plate


#: How a measurement reports its steps.
Report = Callable[[MeasureStep], None]


@dataclass(frozen=True)
class Progress:
    """A step with the rig's counters and the time left, as a display shows it."""

    step: MeasureStep
    moves: int
    reads: int
    elapsed_s: float  # on the cell's clock
    left_s: float  # estimated time left (s)

    @property
    def detail(self) -> str:
        """Counters and time left in words: ``45 moves, 515 reads, about 30 s left``."""
        return f"{self.moves} moves, {self.reads} reads, about {_duration(self.left_s)} left"


def time_left_s(estimate_s: float, elapsed_s: float, done: int, total: int) -> float:
    """Time left (s) of a run estimated at ``estimate_s`` after ``elapsed_s`` with ``done`` of
    ``total`` steps finished (module docstring)."""
    if done >= total:
        return 0.0
    if elapsed_s < estimate_s:
        return estimate_s - elapsed_s
    return elapsed_s / max(done, 1) * (total - done)


def _duration(seconds: float) -> str:
    seconds = max(seconds, 0.0)
    if seconds >= 90:
        return f"{seconds / 60:.1f} min"
    return f"{seconds:.0f} s"
