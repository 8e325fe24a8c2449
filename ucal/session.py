"""Open a cell for a command that moves the robot: the simulated cell or real instruments.

``open_cell`` is a context manager yielding a ``CellSession``: the ``Rig`` (controller + pulser
through the same drivers a real cell uses) and, in simulation, the hidden truth for reporting.
On exit — normal, error or Ctrl-C — the controller is told to STOP before anything closes.
"""

from __future__ import annotations

import contextlib
import logging
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

from drivers.controller.client import SimpleMessageController
from drivers.errors import DriverError
from drivers.pulser.modbus import ModbusPulser
from ucal.calibration.search import Rig
from ucal.cell import CellProfile, WorldTruth
from ucal.errors import HardwareError, InputError, SafetyError

log = logging.getLogger(__name__)

#: Motion-time multiplier of the simulated controller (1 = real time).
SIM_TIME_SCALE = 1.0


@dataclass
class CellSession:
    rig: Rig
    truth: WorldTruth | None      # the simulator's hidden truth; None on a real cell
    simulated: bool


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


@contextlib.contextmanager
def open_cell(profile: CellProfile, sim_world: str | None, controller_url: str | None,
              pulser_url: str | None, time_scale: float = SIM_TIME_SCALE) -> Iterator[CellSession]:
    """Connect to the simulated cell (``sim_world`` not None; "" = demo truth) or to the URLs."""
    if sim_world is None and not (controller_url and pulser_url):
        raise InputError("give either --sim [WORLD] or both --controller URL and --pulser URL")
    if sim_world is not None and (controller_url or pulser_url):
        raise InputError("--sim cannot be combined with --controller/--pulser")
    with contextlib.ExitStack() as stack:
        truth = None
        if sim_world is not None:
            from ucal.sim.demo import demo_world
            from ucal.sim.serve import SimulatedCellServer
            from ucal.world import load_world

            truth = load_world(Path(sim_world), profile) if sim_world else demo_world(profile)
            server = stack.enter_context(SimulatedCellServer(truth, profile,
                                                             time_scale=time_scale))
            controller_url, pulser_url = server.urls["controller"], server.urls["pulser"]
        try:
            controller = SimpleMessageController.from_url(controller_url)
            pulser = ModbusPulser.from_url(pulser_url)
        except ValueError as e:
            raise InputError(str(e)) from e
        try:
            stack.enter_context(pulser)
            stack.enter_context(controller)  # exits first: STOP, then close
        except DriverError as e:
            raise HardwareError(str(e)) from e
        rig = Rig(controller, pulser, profile.model.joint_min_deg, profile.model.joint_max_deg,
                  speed=profile.procedure.speed)
        rig.pulser.configure(rig.settings)
        yield CellSession(rig, truth, sim_world is not None)
