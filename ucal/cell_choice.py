"""The cell a command that moves the robot will open, as its options name it.

Light on purpose: the command line checks the cell options (``ucal.cli.options``) before it
loads anything heavy, so that usage errors come at once.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class CellChoice:
    """The cell a moving command will open: the simulated cell (``sim_world`` not None; ""
    = demo truth) or the controller and pulser at their URLs (and the pulser's digitiser,
    for one that does not digitise)."""

    sim_world: str | None
    controller_url: str | None
    pulser_url: str | None
    digitizer_url: str | None = None

    @property
    def name(self) -> str:
        """The cell in words, for the confirmation prompt."""
        if self.sim_world is not None:
            return "the simulated cell"
        return f"the robot at {self.controller_url}"

    @property
    def address(self) -> str | None:
        """The cell as a record names it: "simulated cell" or the controller's URL."""
        return "simulated cell" if self.sim_world is not None else self.controller_url
