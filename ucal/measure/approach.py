"""The approach discipline: every static posture reached with each joint moving up.

A joint with backlash (lost motion) leaves its link behind the encoder by half the lost
motion, against the direction of its last motion. If every posture a command measures at is
reached the same way, the lag is the same everywhere: in the calibration it becomes part of
the offset instead of a configuration-dependent error, and a command measuring later (verify,
check, tool-frame) sees the arm as the calibration did (``[calibration] approach =
"positive"``). ``FinalApproachRig`` is that discipline, for every command's static postures:
the face searches' probes and water paths, the plate's, the edge scans' probes.

What a rig reads while it moves (acquisition lines, centring sweeps) only finds an echo; the
rig's ``approach`` still gives the sign of each joint's last motion at any reading, and every
measurement carries it, so a solver can model the lost motion.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from ucal import interrupt
from ucal.rig import Rig

#: Final approach of every move (deg below the target on each joint), larger than any backlash.
APPROACH_DEG = 0.05


if TYPE_CHECKING:
    _RigProxy = Rig  # a FinalApproachRig stands wherever a Rig does
else:
    _RigProxy = object


class FinalApproachRig(_RigProxy):
    """A ``Rig`` whose moves finish with a short approach from the negative side of each joint.

    A joint with backlash leaves its link behind the encoder by half the lost motion, against
    the direction of its last motion. If a move would bring any joint down onto its target, the
    robot first goes ``APPROACH_DEG`` below the target on every joint, then up to it: all
    static postures are then reached from below. The two segments are one move in the counters.
    Everything else is the wrapped rig's.
    """

    _rig: Rig
    _approach_deg: float

    def __init__(self, rig: Rig, approach_deg: float = APPROACH_DEG):
        object.__setattr__(self, "_rig", rig)
        object.__setattr__(self, "_approach_deg", approach_deg)

    def __getattr__(self, name: str) -> object:
        return getattr(self._rig, name)

    def __setattr__(self, name: str, value: object) -> None:
        setattr(self._rig, name, value)

    def move(self, q: np.ndarray, speed: float | None = None) -> np.ndarray:
        """Move to ``q`` (deg), arriving from below on every joint; return the settled readings."""
        rig = self._rig
        q = np.asarray(q, float)
        here = rig.controller.read_joints()
        if np.any(q < here - 1e-6):
            below = np.maximum(q - self._approach_deg, rig.joint_min_deg)
            interrupt.check()
            rig.controller.move_joints(below, speed or rig.speed, rig.move_timeout_s)
            rig.moved_to(below, here)
        return rig.move(q, speed)
