"""The approach discipline: every static posture reached with each joint moving one way.

A joint with backlash (lost motion) leaves its link behind the encoder by half the lost
motion, against the direction of its last motion. If every posture a command measures at is
reached the same way, the lag is the same everywhere: in the calibration it becomes part of
the offset instead of a configuration-dependent error, and a command measuring later (verify,
check, tool-frame) sees the arm as the calibration did (``[calibration] approach =
"positive"``). ``FinalApproachRig`` is that discipline, for every command's static postures:
the face searches' probes and water paths, the plate's, the edge scans' probes. A plan that
measures the lost motion reaches some postures from above (``direction = -1``): the same
readings, each joint's link on the other side of its lost motion.

What a rig reads while it moves (acquisition lines, centring sweeps) only finds an echo; the
rig's ``approach`` still gives the sign of each joint's last motion at any reading, and every
measurement carries it, so a solver can model the lost motion. A sweep that ends moving a
joint the other way leaves that joint's sign wrong until the next move turns it: a static
move therefore approaches afresh whenever any joint's last motion was the other way, even a
joint the move leaves where it is. Verify's points (``keep_still``) move only the joints that
need it: the arm's joints stay still while the wrist turns the beam onto each face, their
links where they settled at the point (a real link settles a little off each time it moves,
the arm's pose repeatability: ``verify --iso9283`` measures it, and one arrival's scatter is
in all three faces' water paths, as the standard's one attained pose).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from ucal import interrupt
from ucal.devices.rig import Rig
from ucal.timing import APPROACH_DEG

__all__ = ["APPROACH", "APPROACH_DEG", "FinalApproachRig", "approaching"]

#: The approach direction the offsets belong to: every static posture is reached with each joint
#: moving in its positive direction (``FinalApproachRig``), the link lagging its encoder
#: by half the lost motion; SPEC.md ``approach`` ("centre": the middle of the lost motion).
APPROACH = "positive"


if TYPE_CHECKING:
    _RigProxy = Rig  # a FinalApproachRig stands wherever a Rig does
else:
    _RigProxy = object


class FinalApproachRig(_RigProxy):
    """A ``Rig`` whose moves finish with a short approach in ``direction`` on every joint.

    ``direction`` +1 (the default): from below. A joint with backlash leaves its link behind
    the encoder by half the lost motion, against the direction of its last motion. If a move
    would bring any joint against ``direction`` onto its target, or any joint last moved
    against it (a sweep that ended the other way), the robot goes through a pre-point
    ``APPROACH_DEG`` short of the target on every joint, then onto it: all static postures are
    then reached the same way. The pre-point and the target are one trajectory, two queued
    points: the controller (the VAL3 server's ``movej``, blend off) reaches the pre-point and
    starts the last leg at once, without settling there or waiting for a state frame; it
    settles once, at the target. With ``keep_still`` only the joints that need it go short
    (the others straight to their target: a joint that is there stays, its link where it
    settled). The two segments are one move in the counters. Everything else is the wrapped
    rig's.
    """

    _rig: Rig
    _approach_deg: float
    _direction: float

    def __init__(
        self,
        rig: Rig,
        approach_deg: float = APPROACH_DEG,
        direction: int = 1,
        keep_still: bool = False,
    ):
        if direction not in (1, -1):
            raise ValueError(f"direction must be +1 or -1, got {direction!r}")
        object.__setattr__(self, "_rig", rig)
        object.__setattr__(self, "_approach_deg", approach_deg)
        object.__setattr__(self, "_direction", float(direction))
        object.__setattr__(self, "_keep_still", bool(keep_still))

    def __getattr__(self, name: str) -> object:
        return getattr(self._rig, name)

    def __setattr__(self, name: str, value: object) -> None:
        setattr(self._rig, name, value)

    @property
    def direction(self) -> int:
        """+1: every posture reached from below; −1: from above."""
        return int(self._direction)

    def move(self, q: np.ndarray, speed: float | None = None) -> np.ndarray:
        """Move to ``q`` (deg), arriving in ``direction`` on every joint; return the settled
        readings."""
        rig, sign = self._rig, self._direction
        q = np.asarray(q, float)
        here = rig.controller.read_joints()
        if self._keep_still:
            # only a joint that would arrive against the direction by any amount (a millionth
            # of a degree turns its link to the other side of its lost motion), or last moved
            # against it, goes short; the others go straight to their target
            need = (sign * (q - here) < 0.0) | (np.asarray(rig.approach) != sign)
        else:
            need = np.full(
                6, bool(np.any(sign * (q - here) < -1e-6) or np.any(rig.approach != sign))
            )
        if np.any(need):
            short = np.clip(q - sign * self._approach_deg, rig.joint_min_deg, rig.joint_max_deg)
            short = np.where(need, short, q)
            interrupt.check()
            rig.controller.start_move(short, speed or rig.speed)  # queued: no stop there
            rig.moved_to(short, here)
        return rig.move(q, speed)


def approaching(rig: Rig, direction: int) -> Rig:
    """``rig`` reaching every static posture in ``direction`` (+1 from below, −1 from above):
    a ``FinalApproachRig`` of the rig ``rig`` wraps, if it wraps one."""
    inner = rig._rig if isinstance(rig, FinalApproachRig) else rig
    return FinalApproachRig(inner, direction=direction)
