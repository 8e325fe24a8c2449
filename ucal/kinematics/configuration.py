"""The arm configuration of joint readings, in the words of the Staubli controller.

A VAL3 ``point`` carries, besides its pose, the ``config`` the arm reaches it in: which of the
eight inverse-kinematic solutions of a TX90-family pose (``ucal.kinematics.ik``) it is. The
controller names each part from the joint readings::

    shoulder  lefty      the wrist centre W in front of axis 1: (W_x, W_y) · x_1 >= 0, x_1 the
                         direction joint 1 faces (the x axis of DH frame 1, towards axis 2)
              righty     W behind axis 1: the arm reaches back over its base
    elbow     epositive  J3 >= 0
              enegative  J3 < 0
    wrist     wpositive  J5 >= 0
              wnegative  J5 < 0

The shoulder's words are those of the public VAL3 post-processors (a rear-reaching arm is
``righty``); the elbow's and wrist's are the signs of the readings, as the controller's
``epositive``/``wpositive`` say. At zero (arm straight up) a TX90 is ``lefty, epositive,
wpositive``. The boundaries are the arm's singularities: W on the vertical plane through axis 1
across the arm (shoulder), the stretched elbow (J3 = 0) and the aligned wrist (J5 = 0). The
readings are the controller's (joint offsets taken out), through the DH table given: the
controller's own for the configuration it will report.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ucal.kinematics.dh import RobotModel, fk_frames

#: The words of each part of a VAL3 ``config``, indexed by its bit of ``configuration_codes``.
SHOULDER = ("lefty", "righty")
ELBOW = ("epositive", "enegative")
WRIST = ("wpositive", "wnegative")
#: The parts of a configuration, as a VAL3 ``config`` names its fields.
PARTS = ("shoulder", "elbow", "wrist")


@dataclass(frozen=True)
class ArmConfig:
    """A VAL3 ``config``: ``shoulder`` lefty/righty, ``elbow`` epositive/enegative, ``wrist``
    wpositive/wnegative."""

    shoulder: str
    elbow: str
    wrist: str

    @classmethod
    def from_code(cls, code: int) -> ArmConfig:
        """The configuration of a ``configuration_codes`` value (0…7)."""
        if not 0 <= code < 8:
            raise ValueError(f"a configuration code is 0…7, got {code}")
        return cls(SHOULDER[(code >> 2) & 1], ELBOW[(code >> 1) & 1], WRIST[code & 1])

    def words(self) -> tuple[str, str, str]:
        """``(shoulder, elbow, wrist)``, as a CSV row or a VAL3 ``config`` literal lists them."""
        return (self.shoulder, self.elbow, self.wrist)

    def changed(self, other: ArmConfig) -> tuple[str, ...]:
        """The parts (``PARTS``) in which ``other`` differs from this configuration."""
        return tuple(
            p for p, a, b in zip(PARTS, self.words(), other.words(), strict=True) if a != b
        )

    def to_json(self) -> dict[str, str]:
        return dict(zip(PARTS, self.words(), strict=True))

    def __str__(self) -> str:
        return ", ".join(self.words())


def configuration_codes(model: RobotModel, joints_deg: np.ndarray) -> np.ndarray:
    """The configuration of joint readings (…, 6) in degrees as ints (…,): ``4·shoulder +
    2·elbow + wrist``, each bit 0 for lefty / epositive / wpositive (``ArmConfig.from_code``).

    The readings are the controller's: ``model``'s DH table without joint offsets. Rows with a
    NaN reading get -1.
    """
    q = np.asarray(joints_deg, dtype=float)
    frames = fk_frames(model, np.nan_to_num(q))
    facing = frames[..., 1, :2, 0]  # x axis of frame 1: where joint 1 points the arm
    wrist = frames[..., 4, :2, 3]  # the wrist centre, seen from above (axis 1 at the origin)
    rear = np.sum(facing * wrist, -1) < 0.0
    codes = 4 * rear.astype(int) + 2 * (q[..., 2] < 0.0) + (q[..., 4] < 0.0)
    return np.where(np.any(np.isnan(q), -1), -1, codes)


def arm_configs(model: RobotModel, joints_deg: np.ndarray) -> tuple[ArmConfig, ...]:
    """The configuration of each row of joint readings (n, 6) in degrees
    (``configuration_codes``)."""
    codes = configuration_codes(model, np.atleast_2d(joints_deg))
    return tuple(ArmConfig.from_code(int(c)) for c in codes)
