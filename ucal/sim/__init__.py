"""The simulated cell: acoustics, beam–reflector geometry, echo model, demo truth, loopback servers.

``SimulatedCell(world)`` is the physics of a ``WorldTruth``; ``demo_world(profile)`` is the
built-in truth of ``--sim``; ``SimulatedCellServer`` serves the simulated controller and
pulser on 127.0.0.1 (imported from ``ucal.sim.serve`` so that the physics needs no drivers).
"""

from ucal.sim.cell import SimulatedCell, ideal_echo
from ucal.sim.demo import demo_world

__all__ = ["SimulatedCell", "demo_world", "ideal_echo"]
