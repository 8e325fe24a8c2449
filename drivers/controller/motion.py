"""How a TX90-class arm moves one trajectory point: the one motion model of the simulated
controller, of a plan's time estimate (``ucal.timing``) and of the physical bound a benchmark
prints.

The VAL3 server (``staubli_val3_driver``, ``val3/ros_server/motionControl.pgx``) hands every
trajectory point to ``movej``: a joint-interpolated move, every joint on one straight line in
joint space, starting and ending together. Its motion descriptor sets only ``vel`` (the
point's velocity, % of the joints' speeds, ``pushMotion.pgx``); ``accel`` and ``decel`` stay at
100 % of the arm's, whatever the velocity. The descriptor's ``leave`` and ``reach`` are 0 and
``blend`` is left at VAL3's default, ``off`` (``ros_server.dtx``): consecutive points do not
blend, the arm comes to rest on each, and ``movej`` returns at once, so the controller starts
the next queued point as soon as the last one is reached, with no settling between them.

Profile (``JointMove``): the path parameter s goes 0 → 1 along a trapezoid, accelerating at the
largest rate no joint exceeds (joint i moves s·Δᵢ, so its acceleration is s̈·|Δᵢ| ≤ aᵢ), cruising
at the largest rate no joint exceeds at ``speed`` of its speed limit, decelerating as it
accelerated. The slowest joint sets the time; a move too short to reach the speed is
triangular. Closed form: with v = min vᵢ·speed/|Δᵢ| and a = min aᵢ/|Δᵢ|, T = 1/v + v/a when
v²/a ≤ 1, else 2·√(1/a).

Settling (``settle_s``): a servo loop tracks a commanded acceleration with a following error
proportional to it (e = a/ω² for a loop of natural frequency ω), which it takes out after the
last deceleration as exp(−ω·t). The controller calls the move done once every joint is within
``SETTLE_TOLERANCE_DEG``: settle = ln(e/ε)/ω, with e the joint's following error at its own
deceleration (``FOLLOWING_ERROR_DEG`` at its limit, less in proportion), never more than the
joint moved. ω = 2π · ``SERVO_BANDWIDTH_HZ``; the error at full deceleration is set so that a
stop at the limits settles in 50 ms, the figure the controller's settling was modelled with
before. A long move settles in about 50 ms; a 0.05° approach leg, whose following error is at
most the 0.05° it moves, in about 40 ms; a joint that decelerates gently, sooner.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

#: Joint accelerations of a TX90-class arm (deg/s²) where a model states none: the figure the
#: TX90 family's data files give (``profiles/tx90*.toml`` ``max_acceleration_deg_s2``).
DEFAULT_MAX_ACCEL_DEG_S2 = (1000.0, 1000.0, 1000.0, 2000.0, 2000.0, 2000.0)
#: Natural frequency of the joints' position loops (Hz).
SERVO_BANDWIDTH_HZ = 15.0
#: The controller calls a move done when every joint is this close to its target (deg).
SETTLE_TOLERANCE_DEG = 1e-3
#: Following error of a joint decelerating at its limit (deg): settles in 50 ms at 15 Hz.
FOLLOWING_ERROR_DEG = SETTLE_TOLERANCE_DEG * math.exp(0.05 * 2.0 * math.pi * SERVO_BANDWIDTH_HZ)


@dataclass(frozen=True)
class JointMove:
    """One joint-interpolated point from ``start_deg`` to ``target_deg`` (deg, (6,)): a
    trapezoid of the path parameter, accelerating for ``accel_time_s``, lasting ``duration_s``
    (s, from its start); ``settle_s``: the servo settling after it (s), when it ends a motion."""

    start_deg: np.ndarray
    target_deg: np.ndarray
    duration_s: float
    accel_time_s: float
    settle_s: float

    @property
    def _peak_rate(self) -> float:
        """The path parameter's cruise rate (1/s)."""
        return 1.0 / (self.duration_s - self.accel_time_s)

    def fraction(self, t: float) -> float:
        """How far along the path (0 … 1) the move is ``t`` s after its start."""
        total, ta = self.duration_s, self.accel_time_s
        if t >= total:
            return 1.0
        if t <= 0.0:
            return 0.0
        rate = self._peak_rate
        accel = rate / ta
        if t < ta:
            return 0.5 * accel * t * t
        if t <= total - ta:
            return 0.5 * rate * ta + rate * (t - ta)
        left = total - t
        return 1.0 - 0.5 * accel * left * left

    def rate(self, t: float) -> float:
        """The path parameter's rate (1/s) ``t`` s after the start."""
        total, ta = self.duration_s, self.accel_time_s
        if t <= 0.0 or t >= total:
            return 0.0
        peak = self._peak_rate
        return peak * min(t / ta, 1.0, (total - t) / ta)

    def at(self, t: float) -> np.ndarray:
        """Joint positions (deg, (6,)) ``t`` s after the start."""
        return np.asarray(self.start_deg + self.fraction(t) * (self.target_deg - self.start_deg))

    def velocity(self, t: float) -> np.ndarray:
        """Joint velocities (deg/s, (6,)) ``t`` s after the start."""
        return np.asarray(self.rate(t) * (self.target_deg - self.start_deg))


def joint_move(
    start_deg: Sequence[float] | np.ndarray,
    target_deg: Sequence[float] | np.ndarray,
    speed: float,
    speed_deg_s: Sequence[float] | np.ndarray,
    accel_deg_s2: Sequence[float] | np.ndarray = DEFAULT_MAX_ACCEL_DEG_S2,
) -> JointMove:
    """The move from ``start_deg`` to ``target_deg`` at ``speed`` (fraction of the joints'
    ``speed_deg_s``), the joints accelerating at most at ``accel_deg_s2`` (see the module
    docstring)."""
    start = np.asarray(start_deg, float)
    target = np.asarray(target_deg, float)
    delta = np.abs(target - start)
    moving = delta > 0.0
    if not np.any(moving):
        return JointMove(start.copy(), target.copy(), 0.0, 0.0, 0.0)
    v = float(np.min(np.asarray(speed_deg_s, float)[moving] * speed / delta[moving]))
    a_max = np.asarray(accel_deg_s2, float)
    a = float(np.min(a_max[moving] / delta[moving]))
    if v * v / a <= 1.0:
        ta, total = v / a, 1.0 / v + v / a
    else:
        ta = math.sqrt(1.0 / a)
        total = 2.0 * ta
    return JointMove(start.copy(), target.copy(), total, ta, settle_time_s(delta, a, a_max))


def settle_time_s(delta_deg: np.ndarray, path_accel: float, accel_deg_s2: np.ndarray) -> float:
    """Servo settling after a stop (s): each joint's following error at its deceleration
    (``path_accel`` · |Δ|, against its limit ``accel_deg_s2``), at most what it moved, taken
    out at the loop's rate until within the tolerance (module docstring)."""
    error = np.minimum(FOLLOWING_ERROR_DEG * path_accel * delta_deg / accel_deg_s2, delta_deg)
    worst = float(np.max(error))
    if worst <= SETTLE_TOLERANCE_DEG:
        return 0.0
    return math.log(worst / SETTLE_TOLERANCE_DEG) / (2.0 * math.pi * SERVO_BANDWIDTH_HZ)


def trajectory_s(
    points_deg: Sequence[np.ndarray],
    speed: float,
    speed_deg_s: Sequence[float] | np.ndarray,
    accel_deg_s2: Sequence[float] | np.ndarray = DEFAULT_MAX_ACCEL_DEG_S2,
) -> float:
    """Time (s) of a trajectory through ``points_deg`` (the first is where the arm is) sent as
    queued points: each reached at rest and the next begun at once, the servo settling after
    the last (the VAL3 server's semantics, module docstring)."""
    total, settle = 0.0, 0.0
    for a, b in itertools.pairwise(points_deg):
        move = joint_move(a, b, speed, speed_deg_s, accel_deg_s2)
        total += move.duration_s
        if move.duration_s > 0.0:
            settle = move.settle_s
    return total + settle
