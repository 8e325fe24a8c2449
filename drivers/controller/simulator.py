"""A simulated Staubli controller that speaks Simple Message on 127.0.0.1.

It behaves like the VAL3 server (ros-industrial/staubli_val3_driver, ``val3/ros_server``) as
far as a client can tell: a motion port that acknowledges every JOINT_TRAJ_PT request with a
52-byte SERVICE_REPLY echoing the sequence (FAILURE for a target outside the joint ranges, a
non-positive velocity, or — unlike VAL3, which queues the point and lets the arm controller
refuse it — while e-stopped, unpowered or in error), points executed one after the other as
joint-interpolated moves at ``velocity`` times each joint's maximum speed, STOP_TRAJECTORY
(sequence -4) freezing the arm where it is and dropping queued points, motion stopped when the
motion client disconnects (``motionControl.pgx`` resets motion when a connection drops), and a
state port that streams joint state and STATUS to every connected client.

Motion model: every joint moves linearly in time from start to target, all joints arriving
together; duration = max over joints of |Δ| / (max_speed · velocity) · ``time_scale``
(``time_scale`` 0 makes moves instantaneous), and STATUS reports the arm in motion for
``settle_s`` more (the servo settling before the controller calls a move done).
``joints_deg()`` evaluates that model at the current instant without locking, so other
simulated devices may call it at a high rate; ``motion_sign()`` gives the direction of each
joint's last motion (for lost motion in the joints).

Server variants (``server``, ``SERVERS``): ``"simple"`` (the default) streams joint state and
STATUS in every frame to any number of clients as soon as they connect. ``"val3"`` behaves as
the released VAL3 server (``staubli_val3_driver`` branch ``master``): JOINT_POSITION at 50 Hz and
a STATUS every 5th pass (first after the 6th), nothing for 1 s after a client connects to the
state port (``recvHeartbeat.pgx``: ``delay(1.0)``), one client per port (a second connection is
closed at once and the first is served on), points acknowledged SUCCESS but dropped while the
state stream is not running or the arm is e-stopped, unpowered or in error, and motion stopped
when either connection drops (``motionControl.pgx``). ``"val3-feedback"`` is the unmerged pull
request #36: JOINT_FEEDBACK at 250 Hz, a STATUS every 20th pass (first after the 21st), FAILURE
while motion is not possible (its ``pushMotion.pgx``), otherwise as ``"val3"``. Every variant
answers a request it does not execute (PING, JOINT_TRAJ_PT_FULL, any other type) with a FAILURE
reply of the request's type and body, and ignores topics it does not use.

Fault hooks for tests: ``set_fault`` (e-stop, drives, error), ``hold`` (the arm stops and
points are acknowledged but not executed, STATUS reporting in motion or not), ``on_point``
(called with the count of accepted points), ``inject_reply`` / ``inject_state`` (raw bytes in
place of the next reply / before the next state frame).

Time: ``clock`` (``drivers.clock``). On the host clock the state port streams at
``state_rate_hz`` from a thread of its own. On a ``SimClock`` the stream is a ticker of that
clock: a frame per period of simulated time, handed to the client in lock step; the start-up
silence then passes in simulated time.
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import math
import socket
import struct
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Self

import numpy as np

from drivers.clock import HOST_CLOCK, Clock, SimClock
from drivers.controller.simple_message import (
    CommType,
    FrameReader,
    JointFeedback,
    JointPosition,
    JointTrajPt,
    JointTrajPtReply,
    Message,
    MsgType,
    ReplyCode,
    RobotMode,
    SpecialSeq,
    Status,
)
from drivers.errors import ProtocolError
from drivers.loopback import Served, accept_clients


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

log = logging.getLogger(__name__)

N_JOINTS = 6
# Nominal maximum joint speeds of a TX90-class arm (deg/s), J1..J6.
DEFAULT_MAX_SPEED_DEG_S = (250.0, 200.0, 250.0, 400.0, 400.0, 600.0)
# Targets this far beyond a joint limit are clamped onto it instead of refused: a target that
# sits exactly on the limit comes back a few 1e-5 deg beyond it after deg → float32 rad → deg.
RANGE_EPS_DEG = 1e-4
_POLL_S = 0.1  # how often blocking loops look at the stop flag (s)
_SEND_TIMEOUT_S = 0.5  # a state client that cannot take a frame within this is dropped
_LOOPBACK = ("127.0.0.1", "localhost")


@dataclass(eq=False)
class _StateClient:
    """A connected state client: served from ``serve_from_t`` (after the start-up silence)."""

    sock: socket.socket
    peer: str
    serve_from_t: float
    passes: int = 0


@dataclass(frozen=True)
class _Segment:
    """One joint-interpolated move; times on the host monotonic clock (s)."""

    seq: int
    t_start: float
    t_end: float
    start_deg: np.ndarray
    target_deg: np.ndarray

    def at(self, t: float) -> np.ndarray:
        if t >= self.t_end:
            return self.target_deg.copy()
        if t <= self.t_start:
            return self.start_deg.copy()
        f = (t - self.t_start) / (self.t_end - self.t_start)
        return self.start_deg + f * (self.target_deg - self.start_deg)


@dataclass(frozen=True)
class _Plan:
    """Position at rest before the first segment, then the queued segments (immutable)."""

    rest_deg: np.ndarray
    segments: tuple[_Segment, ...] = ()
    rest_sign: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(N_JOINTS))
    settle_s: float = 0.0

    def at(self, t: float) -> np.ndarray:
        for seg in reversed(self.segments):
            if t >= seg.t_start:
                return seg.at(t)
        return self.rest_deg.copy()

    def velocity_at(self, t: float) -> np.ndarray:
        """Joint velocities (deg/s) at ``t``: the moving segment's, else zero."""
        for seg in self.segments:
            if seg.t_start <= t < seg.t_end:
                return (seg.target_deg - seg.start_deg) / (seg.t_end - seg.t_start)
        return np.zeros(N_JOINTS)

    def in_motion(self, t: float) -> bool:
        return bool(self.segments) and t < self.segments[-1].t_end + self.settle_s

    def sign_at(self, t: float) -> np.ndarray:
        """Direction (-1, 0, +1) of each joint's last motion begun by ``t``."""
        sign = self.rest_sign.copy()
        for seg in self.segments:
            if seg.t_start >= t:
                break
            step = np.sign(seg.target_deg - seg.start_deg)
            sign = np.where(step != 0, step, sign)
        return sign

    def rest(self, t: float) -> _Plan:
        """The plan of an arm stopped where it is at ``t``."""
        return _Plan(self.at(t), (), self.sign_at(t), self.settle_s)


class SimulatedController(Served):
    """Simple Message controller simulator (see the module docstring for its behaviour).

    Joint limits and positions in degrees, speeds in deg/s, ``state_rate_hz`` in Hz.
    ``on_motion(record)`` is called once per executed move, when it ends, with the JSON-able
    record ``{"seq", "t_start" (host monotonic s), "t_wall_start" (Unix time s), "start_deg",
    "target_deg", "end_deg", "duration_s", "stopped"}``; it runs on a simulator thread and must
    not block. ``moves_executed`` counts accepted trajectory points (STOP and the other special
    sequences excluded).
    ``server`` names the server variant (``SERVERS``: ``"simple"``, ``"val3"``,
    ``"val3-feedback"``); ``joint_message`` (``MsgType.JOINT_POSITION`` (10) or
    ``MsgType.JOINT_FEEDBACK`` (15)), ``state_rate_hz`` and ``startup_silence_s`` override the
    variant's. ``on_point(count)`` is called as each valid trajectory point is received, before
    it is executed, with the number received so far (a fault hook; it runs on the motion
    thread).
    """

    device = "controller"

    def __init__(
        self,
        joint_min_deg: Sequence[float] | np.ndarray,
        joint_max_deg: Sequence[float] | np.ndarray,
        initial_deg: Sequence[float] | np.ndarray | None = None,
        host: str = "127.0.0.1",
        motion_port: int = 0,
        state_port: int = 0,
        max_speed_deg_s: Sequence[float] = DEFAULT_MAX_SPEED_DEG_S,
        time_scale: float = 1.0,
        state_rate_hz: float | None = None,
        on_motion: Callable[[dict], None] | None = None,
        joint_message: int | None = None,
        clock: Clock | None = None,
        settle_s: float = 0.0,
        server: str = "simple",
        startup_silence_s: float | None = None,
        on_point: Callable[[int], None] | None = None,
        state_latency_s: float = 0.0,
        state_jitter_s: float = 0.0,
        missing_state_frames: float = 0.0,
        seed: int = 0,
    ):
        self.joint_min_deg = np.asarray(joint_min_deg, dtype=float)
        self.joint_max_deg = np.asarray(joint_max_deg, dtype=float)
        self.max_speed_deg_s = np.asarray(max_speed_deg_s, dtype=float)
        for name, arr in (
            ("joint_min_deg", self.joint_min_deg),
            ("joint_max_deg", self.joint_max_deg),
            ("max_speed_deg_s", self.max_speed_deg_s),
        ):
            if arr.shape != (N_JOINTS,) or not np.all(np.isfinite(arr)):
                raise ValueError(f"{name} must be {N_JOINTS} finite numbers, got {arr.tolist()}")
        if np.any(self.joint_min_deg >= self.joint_max_deg):
            raise ValueError("every joint_min_deg must be below its joint_max_deg")
        if np.any(self.max_speed_deg_s <= 0):
            raise ValueError("max_speed_deg_s must be positive")
        if initial_deg is None:
            initial = np.clip(np.zeros(N_JOINTS), self.joint_min_deg, self.joint_max_deg)
        else:
            initial = np.asarray(initial_deg, dtype=float)
            if initial.shape != (N_JOINTS,) or not self._in_range(initial):
                raise ValueError(
                    f"initial_deg {initial.tolist()} is not {N_JOINTS} values "
                    "inside the joint ranges"
                )
        if host not in _LOOPBACK:
            raise ValueError(f"the simulator serves on 127.0.0.1 only, not {host!r}")
        if not (time_scale >= 0 and math.isfinite(time_scale)):
            raise ValueError(f"time_scale must be >= 0, got {time_scale}")
        if not (settle_s >= 0 and math.isfinite(settle_s)):
            raise ValueError(f"settle_s must be >= 0, got {settle_s}")
        if server not in SERVERS:
            raise ValueError(f"server must be one of {', '.join(SERVERS)}, got {server!r}")
        self.variant = SERVERS[server]
        if state_rate_hz is None:
            state_rate_hz = self.variant.state_rate_hz
        if joint_message is None:
            joint_message = self.variant.joint_message
        if startup_silence_s is None:
            startup_silence_s = self.variant.startup_silence_s
        if not (startup_silence_s >= 0 and math.isfinite(startup_silence_s)):
            raise ValueError(f"startup_silence_s must be >= 0, got {startup_silence_s}")
        if not (state_rate_hz > 0 and math.isfinite(state_rate_hz)):
            raise ValueError(f"state_rate_hz must be > 0, got {state_rate_hz}")
        if joint_message not in (MsgType.JOINT_POSITION, MsgType.JOINT_FEEDBACK):
            raise ValueError(f"joint_message must be 10 or 15, got {joint_message}")
        for name, value in (
            ("state_latency_s", state_latency_s),
            ("state_jitter_s", state_jitter_s),
        ):
            if not (value >= 0 and math.isfinite(value)):
                raise ValueError(f"{name} must be >= 0, got {value}")
        if not 0.0 <= missing_state_frames < 1.0:
            raise ValueError(f"missing_state_frames must be in [0, 1), got {missing_state_frames}")
        self.host = "127.0.0.1"
        self._requested_ports = (int(motion_port), int(state_port))
        self.time_scale = float(time_scale)
        self.state_rate_hz = float(state_rate_hz)
        self.on_motion = on_motion
        self.joint_message = int(joint_message)
        self.startup_silence_s = float(startup_silence_s)
        self.on_point = on_point
        self.clock: Clock = clock if clock is not None else HOST_CLOCK
        # The stream's own time: each frame carries the arm as it was latency + jitter before
        # it is sent (frames have no time stamp: the client sees only when they arrive), some
        # frames are lost. One seeded generator, drawn once per pass, so that the same world
        # gives the same stream.
        self.state_latency_s = float(state_latency_s)
        self.state_jitter_s = float(state_jitter_s)
        self.missing_state_frames = float(missing_state_frames)
        self._stream_rng = np.random.default_rng([int(seed), 0x57A7E])
        self._last_frame_t = -math.inf  # the instant the last frame described
        # How far back frames may describe the arm: finished moves are kept this much longer.
        self._history_s = self.state_latency_s + 6.0 * self.state_jitter_s

        self._lock = threading.Lock()  # guards plan changes, faults, client lists, counters
        # replaced whole, read without the lock
        self._plan = _Plan(initial.copy(), settle_s=float(settle_s))
        self._drives_powered = True
        self._e_stopped = False
        self._in_error = False
        self._error_code = 0
        self.moves_executed = 0
        self.points_received = 0  # valid trajectory points received (on_point counts these)
        self.stops_received = 0  # STOP_TRAJECTORY requests seen (tests check that STOP was sent)
        self.motion_port: int | None = None
        self.state_port: int | None = None

        self._stop_evt = threading.Event()
        self._listeners: list[socket.socket] = []
        self._motion_clients: set[socket.socket] = set()
        self._state_clients: list[_StateClient] = []
        self._hold_in_motion: bool | None = None  # set by hold(): the arm is held
        self._replies: list[bytes] = []  # inject_reply()
        self._state_garbage = b""  # inject_state()
        self._threads: list[threading.Thread] = []
        self._started = False

    # -- lifecycle --------------------------------------------------------------------------

    @property
    def url(self) -> str:
        """``tcp://127.0.0.1:<motion>?state=<state>`` (after ``start()``)."""
        if self.motion_port is None:
            raise RuntimeError("simulated controller not started")
        return f"tcp://{self.host}:{self.motion_port}?state={self.state_port}"

    def start(self) -> Self:
        """Bind both ports on 127.0.0.1 and start serving; returns ``self``."""
        if self._started:
            return self
        self._stop_evt.clear()
        try:
            motion = self._listen(self._requested_ports[0])
            self._listeners.append(motion)
            state = self._listen(self._requested_ports[1])
            self._listeners.append(state)
        except OSError:
            self._close_all(abort=False)
            raise
        self.motion_port = motion.getsockname()[1]
        self.state_port = state.getsockname()[1]
        self._started = True
        self._spawn(self._accept_loop, (motion, self._serve_motion), "accept-motion")
        self._spawn(self._accept_loop, (state, self._add_state_client), "accept-state")
        if isinstance(self.clock, SimClock):
            self.clock.add_ticker(1.0 / self.state_rate_hz, self._tick, self._has_state_clients)
        else:
            self._spawn(self._stream_loop, (), "stream")
        log.info("simulated controller serving at %s", self.url)
        return self

    def stop(self) -> None:
        """Stop serving, close every connection, end any motion (reported stopped)."""
        self._shutdown(abort=False)

    def kill(self) -> None:
        """Simulate a crash: reset every connection at once and stop serving."""
        self._shutdown(abort=True)

    def _shutdown(self, abort: bool) -> None:
        if not self._started:
            return
        self._started = False
        self._stop_evt.set()
        if isinstance(self.clock, SimClock):
            self.clock.remove_ticker(self._tick)
        self._freeze(self.clock.now(), "simulator killed" if abort else "simulator stopped")
        self._close_all(abort)
        # Two passes: the accept threads may spawn a connection thread while they wind down.
        for _ in range(2):
            with self._lock:
                threads = list(self._threads)
            for thread in threads:
                if thread is not threading.current_thread():
                    thread.join(timeout=2.0)
        with self._lock:
            self._threads.clear()
        log.info("simulated controller %s", "killed" if abort else "stopped")

    def _listen(self, port: int) -> socket.socket:
        sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        sock.bind((self.host, port))
        sock.listen(8)
        sock.settimeout(_POLL_S)
        return sock

    def _spawn(self, target: Callable, args: tuple, name: str) -> None:
        thread = threading.Thread(
            target=target, args=args, daemon=True, name=f"sim-controller-{name}"
        )
        with self._lock:
            self._threads.append(thread)
        thread.start()

    def _close_all(self, abort: bool) -> None:
        with self._lock:
            socks = [
                *self._listeners,
                *self._motion_clients,
                *(c.sock for c in self._state_clients),
            ]
            self._listeners.clear()
            self._motion_clients.clear()
            self._state_clients.clear()
        for sock in socks:
            if abort:
                # SO_LINGER with zero timeout: close() sends RST, as a crashed controller would.
                with contextlib.suppress(OSError):
                    sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
            else:
                with contextlib.suppress(OSError):  # listener, or peer already gone
                    sock.shutdown(socket.SHUT_RDWR)
            sock.close()

    def _accept_loop(
        self, listener: socket.socket, handler: Callable[[socket.socket, str], None]
    ) -> None:
        # listener closed by stop()/kill(): the loop ends
        accept_clients(
            listener, self._stop_evt, lambda conn, addr: handler(conn, f"{addr[0]}:{addr[1]}")
        )

    # -- model ------------------------------------------------------------------------------

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

    def inject_reply(self, raw: bytes) -> None:
        """Send ``raw`` instead of the next reply on the motion port."""
        with self._lock:
            self._replies.append(bytes(raw))

    def inject_state(self, raw: bytes) -> None:
        """Send ``raw`` to the state clients before the next state frame."""
        with self._lock:
            self._state_garbage += bytes(raw)

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

    def _record(self, seg: _Segment, end_deg: np.ndarray, stopped: bool) -> dict:
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

    def _notify(self, records: list[dict]) -> None:
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
            done = [s for s in plan.segments if s.t_end + keep_s <= now]
            if not done:
                return
            self._plan = _Plan(
                done[-1].target_deg.copy(),
                plan.segments[len(done) :],
                plan.sign_at(done[-1].t_end),
                plan.settle_s,
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
            t0 = max(now, start_t)
            duration = float(np.max(np.abs(target - start) / (self.max_speed_deg_s * velocity)))
            seg = _Segment(msg.sequence, t0, t0 + duration * self.time_scale, start.copy(), target)
            self._plan = dataclasses.replace(plan, segments=plan.segments + (seg,))
            self.moves_executed += 1
        log.debug(
            "simulated controller queued point %d: %s deg in %.3f s",
            msg.sequence,
            np.round(target, 4).tolist(),
            seg.t_end - seg.t_start,
        )
        return True

    # -- motion port ------------------------------------------------------------------------

    def _refuse_second(self, conn: socket.socket, peer: str, port: str, served: bool) -> bool:
        """Close ``conn`` at once if the variant serves one client per port and one is served."""
        if not (served and self.variant.one_client_per_port):
            return False
        log.warning(
            "simulated controller: %s client %s not served: another client is "
            "connected (one client per port)",
            port,
            peer,
        )
        conn.close()
        return True

    def _serve_motion(self, conn: socket.socket, peer: str) -> None:
        with self._lock:
            if self._stop_evt.is_set():
                conn.close()
                return
            if self._refuse_second(conn, peer, "motion", bool(self._motion_clients)):
                return
            self._motion_clients.add(conn)
        self._spawn(self._motion_loop, (conn, peer), f"motion {peer}")

    def _motion_loop(self, conn: socket.socket, peer: str) -> None:
        log.info("simulated controller: motion client %s connected", peer)
        reader = FrameReader("simulated controller", f"motion client {peer}")
        try:
            # Inside the try: stop() may already have closed this socket.
            conn.settimeout(_POLL_S)
            while not self._stop_evt.is_set():
                try:
                    data = conn.recv(4096)
                except TimeoutError:
                    continue
                if not data:
                    break
                for msg in reader.feed(data):
                    reply = self._handle(msg)
                    if reply is not None:
                        with self._lock:
                            if self._replies:
                                reply = self._replies.pop(0)
                        conn.sendall(reply)
        except ProtocolError as e:
            log.warning("%s; dropping the connection", e)
        except OSError as e:
            if not self._stop_evt.is_set():
                log.info("simulated controller: motion client %s: %s", peer, e)
        finally:
            with self._lock:
                known = conn in self._motion_clients
                self._motion_clients.discard(conn)
            if known:
                conn.close()
            if not self._stop_evt.is_set():
                # motionControl.pgx: no motion while the motion connection is down.
                self._freeze(self.clock.now(), "motion client disconnected")
                log.info("simulated controller: motion client %s disconnected", peer)

    def _handle(self, msg: Message) -> bytes | None:
        """Act on one message from the motion port; return the reply frame, if any."""
        if not isinstance(msg, JointTrajPt):
            # REP-I0006: unsupported service requests get a FAILURE reply, topics are ignored.
            if msg.comm_type == CommType.SERVICE_REQUEST:
                return dataclasses.replace(
                    msg, comm_type=CommType.SERVICE_REPLY, reply_code=ReplyCode.FAILURE
                ).pack()
            log.info("simulated controller ignores %s on the motion port", type(msg).__name__)
            return None
        if msg.sequence == SpecialSeq.STOP_TRAJECTORY:
            with self._lock:
                self.stops_received += 1
            self._freeze(self.clock.now(), "STOP_TRAJECTORY")
            ok = True
        elif msg.sequence < 0:
            ok = True  # trajectory start/end markers: nothing to execute
        else:
            ok = self._enqueue(msg)
        if msg.comm_type != CommType.SERVICE_REQUEST:
            return None
        code = ReplyCode.SUCCESS if ok else ReplyCode.FAILURE
        return JointTrajPtReply(code, msg.sequence).pack()

    # -- state port -------------------------------------------------------------------------

    def _add_state_client(self, conn: socket.socket, peer: str) -> None:
        conn.settimeout(_SEND_TIMEOUT_S)
        with self._lock:
            if self._stop_evt.is_set():
                conn.close()
                return
            if self._refuse_second(conn, peer, "state", bool(self._state_clients)):
                return
            client = _StateClient(conn, peer, self.clock.now() + self.startup_silence_s)
            self._state_clients.append(client)
        log.info("simulated controller: state client %s connected", peer)
        self._spawn(self._heartbeat_loop, (client,), f"state {peer}")

    def _heartbeat_loop(self, client: _StateClient) -> None:
        """Read (and ignore) what the state client sends, to notice it leave at once, as the
        VAL3 server's heartbeat task does (``recvHeartbeat.pgx``)."""
        while not self._stop_evt.is_set() and client in self._state_clients:
            try:
                if not client.sock.recv(64):
                    break
            except TimeoutError:
                continue
            except OSError:
                break
        if not self._stop_evt.is_set():
            self._drop_state_client(client, "disconnected")

    def _streaming(self, now: float) -> bool:
        """Whether a state client is connected and past the start-up silence."""
        return any(c.serve_from_t <= now for c in self._state_clients)

    def _joint_frame(self, now: float) -> bytes:
        rad = tuple(np.radians(self._plan.at(now)))
        if self.joint_message == MsgType.JOINT_FEEDBACK:
            # PR #36 encodeJFeedback.pgx: valid time | positions | velocities; the time is
            # VAL3's clock() written as an int32.
            velocity = tuple(np.radians(self._plan.velocity_at(now)))
            return JointFeedback(
                rad, velocity, robot_id=0, valid_fields=0x07, time_raw=struct.pack("<i", int(now))
            ).pack()
        return JointPosition(rad).pack()

    def _has_state_clients(self) -> bool:
        return bool(self._state_clients)

    def _frame_instant(self, now: float) -> float | None:
        """The instant the frame sent at ``now`` describes, or None for a lost frame.

        ``now`` less the latency and a half-normal jitter, never earlier than the last frame's
        (the stream keeps its order, as TCP does).
        """
        rng = self._stream_rng
        lost = self.missing_state_frames > 0 and rng.random() < self.missing_state_frames
        delay = self.state_latency_s + self.state_jitter_s * abs(float(rng.standard_normal()))
        if lost:
            return None
        t = min(max(now - delay, self._last_frame_t), now)
        self._last_frame_t = t
        return t

    def _send_state(self, now: float) -> int:
        """Send the state frames of instant ``now`` to every state client; return how many."""
        self._retire(now)
        with self._lock:
            clients = [c for c in self._state_clients if c.serve_from_t <= now]
            garbage, self._state_garbage = self._state_garbage, b""
        if not clients:
            return 0
        described = self._frame_instant(now)
        if described is None:
            return 0
        joints = self._joint_frame(described)
        status = self._status(described).pack()
        variant = self.variant
        sent = 0
        for client in clients:
            client.passes += 1
            n = client.passes - variant.status_first
            frames = garbage + joints
            if n >= 0 and n % variant.status_every == 0:
                frames += status
            try:
                client.sock.sendall(frames)
                sent += 1
            except OSError as e:
                self._drop_state_client(client, str(e))
        return sent

    def _drop_state_client(self, client: _StateClient, why: str) -> None:
        with self._lock:
            if client not in self._state_clients:
                return
            self._state_clients.remove(client)
        log.info("simulated controller: state client %s gone: %s", client.peer, why)
        client.sock.close()
        if self.variant.needs_state_stream:
            # motionControl.pgx: no motion while the state connection is down.
            self._freeze(self.clock.now(), "state client disconnected")

    def _tick(self, t: float) -> int:
        """SimClock ticker: the state frames of simulated instant ``t``."""
        if self._stop_evt.is_set():
            return 0
        return self._send_state(t)

    def _stream_loop(self) -> None:
        period = 1.0 / self.state_rate_hz
        next_t = time.monotonic()
        while not self._stop_evt.is_set():
            self._send_state(self.clock.now())
            next_t = max(next_t + period, time.monotonic())
            self._stop_evt.wait(next_t - time.monotonic())
