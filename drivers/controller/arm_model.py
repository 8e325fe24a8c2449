"""The simulated arm behind the simulated controller: how it moves, what it reports, and the
points it queues.

Motion model: ``drivers.controller.motion``, the one a plan's estimate takes too: every point a
joint-interpolated trapezoid, the joints starting and ending together, points queued and not
blended (the arm rests on each and the next begins at once), the servo settling after the last
(``Segment``, ``settling``); the queued segments and where the arm rests before them are a
``Plan``, replaced whole so that it can be read without a lock. ``SimulatedArm`` holds the
plan, the faults (e-stop, drives, error, hold), the STATUS they give, and what a trajectory
point does (``_enqueue``); ``drivers.controller.simulator.SimulatedController`` derives from it
and serves it over Simple Message.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from drivers.clock import HOST_CLOCK, Clock
from drivers.controller.motion import DEFAULT_MAX_ACCEL_DEG_S2, JointMove, joint_move
from drivers.controller.server_variants import ServerVariant
from drivers.controller.simple_message import JointTrajPt, RobotMode, Status

# The simulated controller logs what its arm does under its own name.
log = logging.getLogger("drivers.controller.simulator")

N_JOINTS = 6
# Nominal maximum joint speeds of a TX90-class arm (deg/s), J1..J6.
DEFAULT_MAX_SPEED_DEG_S = (250.0, 200.0, 250.0, 400.0, 400.0, 600.0)
# Targets this far beyond a joint limit are clamped onto it instead of refused: a target that
# sits exactly on the limit comes back a few 1e-5 deg beyond it after deg → float32 rad → deg.
RANGE_EPS_DEG = 1e-4


@dataclass(frozen=True)
class Segment:
    """One joint-interpolated move (``move``, in the arm's own time) played at ``time_scale``;
    times on the controller's clock (s); ``settle_s``: the servo settling after it, when it is
    the last (clock s)."""

    seq: int
    t_start: float
    t_end: float
    start_deg: np.ndarray
    target_deg: np.ndarray
    move: JointMove | None = None
    settle_s: float = 0.0

    def _own_time(self, t: float) -> float:
        """``t`` of the clock as the move's own time since its start (s)."""
        span = self.t_end - self.t_start
        assert self.move is not None
        return (t - self.t_start) / span * self.move.duration_s

    def at(self, t: float) -> np.ndarray:
        if t >= self.t_end:
            return self.target_deg.copy()
        if t <= self.t_start:
            return self.start_deg.copy()
        if self.move is None:
            f = (t - self.t_start) / (self.t_end - self.t_start)
            return np.asarray(self.start_deg + f * (self.target_deg - self.start_deg))
        return self.move.at(self._own_time(t))

    def velocity(self, t: float) -> np.ndarray:
        """Joint velocities (deg/s of the clock) at ``t``."""
        span = self.t_end - self.t_start
        if not self.t_start <= t < self.t_end or span <= 0.0:
            return np.zeros(N_JOINTS)
        if self.move is None:
            return np.asarray((self.target_deg - self.start_deg) / span)
        return self.move.velocity(self._own_time(t)) * (self.move.duration_s / span)


@dataclass(frozen=True)
class Plan:
    """Position at rest before the first segment, then the queued segments (immutable)."""

    rest_deg: np.ndarray
    segments: tuple[Segment, ...] = ()
    rest_sign: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(N_JOINTS))
    settle_s: float = 0.0
    #: how many moves have turned each joint before the first segment
    rest_moves: np.ndarray = dataclasses.field(
        default_factory=lambda: np.zeros(N_JOINTS, dtype=np.int64)
    )

    def at(self, t: float) -> np.ndarray:
        for seg in reversed(self.segments):
            if t >= seg.t_start:
                return seg.at(t)
        return self.rest_deg.copy()

    def velocity_at(self, t: float) -> np.ndarray:
        """Joint velocities (deg/s) at ``t``: the moving segment's, else zero."""
        for seg in self.segments:
            if seg.t_start <= t < seg.t_end:
                return seg.velocity(t)
        return np.zeros(N_JOINTS)

    @property
    def settles_until(self) -> float:
        """When the last segment has settled (clock s); -inf without one."""
        if not self.segments:
            return -math.inf
        last = self.segments[-1]
        return last.t_end + last.settle_s + self.settle_s

    def in_motion(self, t: float) -> bool:
        return t < self.settles_until

    def sign_at(self, t: float) -> np.ndarray:
        """Direction (-1, 0, +1) of each joint's last motion begun by ``t``."""
        sign = self.rest_sign.copy()
        for seg in self.segments:
            if seg.t_start >= t:
                break
            step = np.sign(seg.target_deg - seg.start_deg)
            sign = np.where(step != 0, step, sign)
        return sign

    def moves_at(self, t: float) -> np.ndarray:
        """How many moves begun by ``t`` have turned each joint (int, (6,)): a simulated
        link settles anew, a little off, after each move of its joint."""
        moves = self.rest_moves.copy()
        for seg in self.segments:
            if seg.t_start >= t:
                break
            moves += seg.target_deg != seg.start_deg
        return moves

    def rest(self, t: float) -> Plan:
        """The plan of an arm stopped where it is at ``t``."""
        return Plan(self.at(t), (), self.sign_at(t), self.settle_s, self.moves_at(t))


class SimulatedArm:
    """The arm a simulated controller moves (see the module docstring).

    Joint limits and positions in degrees, speeds in deg/s, accelerations in deg/s²
    (``max_accel_deg_s2``); ``time_scale``, ``settle_s``, ``settling``, ``on_motion``,
    ``on_point`` and ``clock`` as in ``SimulatedController``; ``variant`` says
    what the server does with a point it cannot execute. ``_history_s``: how long finished
    moves are kept for frames that describe the arm a little in the past (the server sets it).
    """

    def __init__(
        self,
        joint_min_deg: Sequence[float] | np.ndarray,
        joint_max_deg: Sequence[float] | np.ndarray,
        initial_deg: Sequence[float] | np.ndarray | None,
        max_speed_deg_s: Sequence[float],
        *,
        variant: ServerVariant,
        time_scale: float,
        settle_s: float,
        on_motion: Callable[[dict[str, Any]], None] | None,
        on_point: Callable[[int], None] | None,
        clock: Clock | None,
        max_accel_deg_s2: Sequence[float] = DEFAULT_MAX_ACCEL_DEG_S2,
        settling: bool = False,
    ):
        self.joint_min_deg = np.asarray(joint_min_deg, dtype=float)
        self.joint_max_deg = np.asarray(joint_max_deg, dtype=float)
        self.max_speed_deg_s = np.asarray(max_speed_deg_s, dtype=float)
        self.max_accel_deg_s2 = np.asarray(max_accel_deg_s2, dtype=float)
        for name, arr in (
            ("joint_min_deg", self.joint_min_deg),
            ("joint_max_deg", self.joint_max_deg),
            ("max_speed_deg_s", self.max_speed_deg_s),
            ("max_accel_deg_s2", self.max_accel_deg_s2),
        ):
            if arr.shape != (N_JOINTS,) or not np.all(np.isfinite(arr)):
                raise ValueError(f"{name} must be {N_JOINTS} finite numbers, got {arr.tolist()}")
        if np.any(self.joint_min_deg >= self.joint_max_deg):
            raise ValueError("every joint_min_deg must be below its joint_max_deg")
        if np.any(self.max_speed_deg_s <= 0) or np.any(self.max_accel_deg_s2 <= 0):
            raise ValueError("max_speed_deg_s and max_accel_deg_s2 must be positive")
        if initial_deg is None:
            initial = np.clip(np.zeros(N_JOINTS), self.joint_min_deg, self.joint_max_deg)
        else:
            initial = np.asarray(initial_deg, dtype=float)
            if initial.shape != (N_JOINTS,) or not self._in_range(initial):
                raise ValueError(
                    f"initial_deg {initial.tolist()} is not {N_JOINTS} values "
                    "inside the joint ranges"
                )
        if not (time_scale >= 0 and math.isfinite(time_scale)):
            raise ValueError(f"time_scale must be >= 0, got {time_scale}")
        if not (settle_s >= 0 and math.isfinite(settle_s)):
            raise ValueError(f"settle_s must be >= 0, got {settle_s}")
        self.variant = variant
        self.time_scale = float(time_scale)
        self.settling = bool(settling)
        self.on_motion = on_motion
        self.on_point = on_point
        self.clock: Clock = clock if clock is not None else HOST_CLOCK
        self._history_s = 0.0
        self._lock = threading.Lock()  # guards plan changes, faults, counters (and the server's)
        # replaced whole, read without the lock
        self._plan = Plan(initial.copy(), settle_s=float(settle_s))
        self._drives_powered = True
        self._e_stopped = False
        self._in_error = False
        self._error_code = 0
        self.moves_executed = 0
        self.points_received = 0  # valid trajectory points received (on_point counts these)
        self.stops_received = 0  # STOP_TRAJECTORY requests seen (tests check that STOP was sent)
        self._hold_in_motion: bool | None = None  # set by hold(): the arm is held

    def joints_deg(self) -> np.ndarray:
        """Joint readings (deg, (6,)) at this instant. Thread-safe, lock-free."""
        return self._plan.at(self.clock.now())

    def motion_sign(self) -> np.ndarray:
        """Direction (-1, 0, +1) of each joint's last motion, at this instant."""
        return self._plan.sign_at(self.clock.now())

    def joints_at(self, t: float) -> np.ndarray:
        """Joint readings (deg, (6,)) at instant ``t`` of the clock, a little in the past at
        most (finished moves are kept for the stream's latency)."""
        return self._plan.at(t)

    def motion_sign_at(self, t: float) -> np.ndarray:
        """Direction (-1, 0, +1) of each joint's last motion begun by instant ``t``."""
        return self._plan.sign_at(t)

    def moves_at(self, t: float) -> np.ndarray:
        """How many moves begun by instant ``t`` have turned each joint (int, (6,))."""
        return self._plan.moves_at(t)

    def in_motion(self) -> bool:
        """Whether a move is executing (or settling) at this instant."""
        return self._plan.in_motion(self.clock.now())

    def set_fault(
        self,
        *,
        e_stopped: bool | None = None,
        drives_powered: bool | None = None,
        in_error: bool | None = None,
        error_code: int | None = None,
    ) -> None:
        """Change the reported fault state; an e-stop, power loss or error freezes motion."""
        with self._lock:
            if e_stopped is not None:
                self._e_stopped = bool(e_stopped)
            if drives_powered is not None:
                self._drives_powered = bool(drives_powered)
            if in_error is not None:
                self._in_error = bool(in_error)
            if error_code is not None:
                self._error_code = int(error_code)
            halt = self._e_stopped or not self._drives_powered or self._in_error
        if halt:
            self._freeze(self.clock.now(), "fault")

    def hold(self, in_motion: bool | None = False) -> None:
        """Stop the arm where it is and execute no more points (they are still acknowledged),
        the stream going on, STATUS reporting ``in_motion``: a halt the controller makes
        without a fault (``False``) or an arm held while reporting motion (``True``).
        ``None`` releases the hold."""
        with self._lock:
            self._hold_in_motion = in_motion
        if in_motion is not None:
            self._freeze(self.clock.now(), "held")

    def _in_range(self, joints: np.ndarray) -> bool:
        return bool(
            np.all(joints >= self.joint_min_deg - RANGE_EPS_DEG)
            and np.all(joints <= self.joint_max_deg + RANGE_EPS_DEG)
        )

    def _status(self, now: float) -> Status:
        with self._lock:
            powered, estop, err, code = (
                self._drives_powered,
                self._e_stopped,
                self._in_error,
                self._error_code,
            )
            held = self._hold_in_motion
        possible = powered and not estop and not err
        moving = self._plan.in_motion(now) if held is None else held
        return Status(
            drives_powered=int(powered),
            e_stopped=int(estop),
            error_code=code,
            in_error=int(err),
            in_motion=int(moving),
            mode=RobotMode.AUTO,
            motion_possible=int(possible),
        )

    def _record(self, seg: Segment, end_deg: np.ndarray, stopped: bool) -> dict[str, Any]:
        wall_start = time.time() - (self.clock.now() - seg.t_start)
        return {
            "seq": seg.seq,
            "t_start": seg.t_start,
            "t_wall_start": wall_start,
            "start_deg": [float(v) for v in seg.start_deg],
            "target_deg": [float(v) for v in seg.target_deg],
            "end_deg": [float(v) for v in end_deg],
            "duration_s": seg.t_end - seg.t_start,
            "stopped": stopped,
        }

    def _notify(self, records: list[dict[str, Any]]) -> None:
        callback = self.on_motion
        if callback is None:
            return
        for record in records:
            try:
                callback(record)
            except Exception:  # a faulty observer must not kill the simulator
                log.exception("on_motion callback failed")

    def _retire(self, now: float) -> None:
        """Drop finished segments from the plan and report them."""
        with self._lock:
            plan = self._plan
            # a move is done once it has settled (the last one is reported in motion until
            # then) and no frame still to be sent describes it
            keep_s = plan.settle_s + self._history_s
            done = [s for s in plan.segments if s.t_end + s.settle_s + keep_s <= now]
            if not done:
                return
            self._plan = Plan(
                done[-1].target_deg.copy(),
                plan.segments[len(done) :],
                plan.sign_at(done[-1].t_end),
                plan.settle_s,
                plan.moves_at(done[-1].t_end),
            )
        self._notify([self._record(s, s.target_deg, False) for s in done])

    def _freeze(self, now: float, why: str) -> None:
        """Stop where the arm is now: report finished and interrupted moves, drop queued ones."""
        with self._lock:
            plan = self._plan
            if not plan.segments:
                return
            here = plan.at(now)
            records = [
                self._record(s, s.target_deg, False) for s in plan.segments if s.t_end <= now
            ]
            active = [s for s in plan.segments if s.t_start <= now < s.t_end]
            records += [self._record(s, here, True) for s in active]
            dropped = sum(1 for s in plan.segments if s.t_start > now)
            self._plan = plan.rest(now)
        if active or dropped:
            log.info(
                "simulated controller stopped motion (%s) at %s deg; %d queued point(s) dropped",
                why,
                np.round(here, 4).tolist(),
                dropped,
            )
        self._notify(records)

    def _enqueue(self, msg: JointTrajPt) -> bool:
        """Queue one trajectory point; False when it must be refused."""
        target = np.degrees(np.asarray(msg.joints_rad[:N_JOINTS], dtype=float))
        velocity = min(float(msg.velocity), 1.0)  # VAL3: limit(velocity * 100, 0, 100) %
        if not (np.all(np.isfinite(target)) and math.isfinite(velocity) and velocity > 0):
            log.warning(
                "simulated controller refuses point %d: bad target or velocity %r",
                msg.sequence,
                msg.velocity,
            )
            return False
        if not self._in_range(target):
            log.warning(
                "simulated controller refuses point %d: %s deg outside the joint ranges",
                msg.sequence,
                np.round(target, 4).tolist(),
            )
            return False
        target = np.clip(target, self.joint_min_deg, self.joint_max_deg)
        with self._lock:
            self.points_received += 1
            count = self.points_received
        if self.on_point is not None:
            self.on_point(count)  # a fault hook strikes before the point is executed
        now = self.clock.now()
        self._retire(now)
        with self._lock:
            if self._e_stopped or not self._drives_powered or self._in_error:
                refuse = self.variant.refuse_when_halted
                log.warning(
                    "simulated controller %s point %d: e-stopped=%s powered=%s in error=%s",
                    "refuses" if refuse else "drops",
                    msg.sequence,
                    self._e_stopped,
                    self._drives_powered,
                    self._in_error,
                )
                return not refuse
            if self._hold_in_motion is not None or (
                self.variant.needs_state_stream and not self._streaming(now)
            ):
                log.warning(
                    "simulated controller drops point %d: %s",
                    msg.sequence,
                    "the arm is held"
                    if self._hold_in_motion is not None
                    else "the state stream is not running",
                )
                return True
            plan = self._plan
            if plan.segments:
                start_t, start = plan.segments[-1].t_end, plan.segments[-1].target_deg
            else:
                start_t, start = now, plan.rest_deg
            # points queued, not blended: this one starts when the last is reached
            t0 = max(now, start_t)
            move = joint_move(start, target, velocity, self.max_speed_deg_s, self.max_accel_deg_s2)
            scale = self.time_scale
            settle = move.settle_s * scale if self.settling else 0.0
            seg = Segment(
                msg.sequence, t0, t0 + move.duration_s * scale, start.copy(), target, move, settle
            )
            self._plan = dataclasses.replace(plan, segments=plan.segments + (seg,))
            self.moves_executed += 1
        log.debug(
            "simulated controller queued point %d: %s deg in %.3f s",
            msg.sequence,
            np.round(target, 4).tolist(),
            seg.t_end - seg.t_start,
        )
        return True

    def _streaming(self, now: float) -> bool:
        """Whether the state stream runs at ``now``; the server, which streams, says."""
        return True
