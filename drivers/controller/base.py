"""The robot-controller interface that procedures depend on.

Units: joint readings in degrees (encoder readings as the controller reports them),
speed as a fraction of the controller's maximum in (0, 1], times in seconds.
"""

from __future__ import annotations

import abc
from dataclasses import dataclass

import numpy as np

from drivers.device import Device


@dataclass(frozen=True)
class ControllerStatus:
    """Robot status; tri-state fields are ``None`` when the controller says 'unknown'."""

    drives_powered: bool | None
    e_stopped: bool | None
    in_motion: bool | None
    in_error: bool | None
    error_code: int = 0
    mode: int = 0  # 1 manual, 2 auto, 0 unknown (REP-I0006 RobotMode)
    motion_possible: bool | None = None


@dataclass(frozen=True)
class JointSample:
    """One streamed joint position: host monotonic receive time (s) and readings (deg, (6,))."""

    t_s: float
    joints_deg: np.ndarray


class RobotController(Device):
    """A six-axis robot controller (endpoint e.g. ``tcp://127.0.0.1:11000?state=11002``).

    Use as a context manager: exit sends STOP, then closes. ``clock`` timestamps and waits on
    the streamed state.
    """

    device = "controller"

    @abc.abstractmethod
    def read_joints(self, timeout_s: float = 2.0) -> np.ndarray:
        """Latest joint readings (deg, (6,)), waiting at most ``timeout_s`` for a first one."""

    @abc.abstractmethod
    def status(self, timeout_s: float = 2.0) -> ControllerStatus:
        """Latest robot status."""

    @abc.abstractmethod
    def start_move(self, target_deg: np.ndarray, speed: float = 0.5) -> None:
        """Send a joint-space target and return once the controller accepted it.

        Raises ``MotionRejected`` if the controller answers FAILURE.
        """

    @abc.abstractmethod
    def wait_settled(
        self, target_deg: np.ndarray, timeout_s: float, tol_deg: float = 1e-3
    ) -> np.ndarray:
        """Block until not in motion and the readings are within ``tol_deg`` of the target.

        Returns the settled readings; raises ``DeviceTimeout`` after ``timeout_s``.
        """

    def move_joints(
        self,
        target_deg: np.ndarray,
        speed: float = 0.5,
        timeout_s: float = 60.0,
        tol_deg: float = 1e-3,
    ) -> np.ndarray:
        """Move in joint space and wait until settled; returns the settled readings (deg)."""
        self.start_move(target_deg, speed)
        return self.wait_settled(target_deg, timeout_s, tol_deg)

    @abc.abstractmethod
    def stop(self) -> None:
        """Stop any motion now (STOP_TRAJECTORY). Never raises on a dead link; logs instead."""

    @abc.abstractmethod
    def joint_samples(self, since_t_s: float = 0.0) -> list[JointSample]:
        """Streamed joint positions received at or after ``since_t_s`` (host monotonic clock)."""

    def __exit__(self, *exc: object) -> None:
        try:
            self.stop()
        finally:
            self.close()
