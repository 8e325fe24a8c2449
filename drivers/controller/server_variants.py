"""The Simple Message servers a Staubli controller may run, as a client sees them.

``SERVERS`` names each variant ``drivers.controller.simulator.SimulatedController`` plays
(``ucal sim serve --server``): how its state port streams, how many clients each port serves,
and what it does with a point it cannot execute (the simulator's module docstring tells each
one's sources).
"""

from __future__ import annotations

from dataclasses import dataclass

from drivers.controller.simple_message import MsgType


@dataclass(frozen=True)
class ServerVariant:
    """What a Simple Message server on a Staubli controller does that a client can see."""

    name: str
    joint_message: int  # MsgType.JOINT_POSITION or JOINT_FEEDBACK
    state_rate_hz: float  # state passes per second
    status_first: int  # first STATUS after this pass (1-based)
    status_every: int  # then after every this many passes
    startup_silence_s: float  # nothing on the state port this long after a client connects
    one_client_per_port: bool  # a second connection to a port is closed at once
    refuse_when_halted: bool  # FAILURE (else SUCCESS, point dropped) while e-stopped etc.
    needs_state_stream: bool  # no motion while the state stream is not running


#: The server variants of ``SimulatedController(server=...)`` and ``ucal sim serve --server``.
SERVERS: dict[str, ServerVariant] = {
    "simple": ServerVariant("simple", MsgType.JOINT_POSITION, 50.0, 1, 1, 0.0, False, True, False),
    "val3": ServerVariant("val3", MsgType.JOINT_POSITION, 50.0, 6, 5, 1.0, True, False, True),
    "val3-feedback": ServerVariant(
        "val3-feedback", MsgType.JOINT_FEEDBACK, 250.0, 21, 20, 1.0, True, True, True
    ),
}
