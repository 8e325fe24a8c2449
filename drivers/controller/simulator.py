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

Motion model (``drivers.controller.motion``, the one a plan's time estimate takes): each point a
joint-interpolated trapezoid, every joint starting and ending together, at ``velocity`` times
each joint's maximum speed and at most each joint's maximum acceleration (``max_accel_deg_s2``),
its duration multiplied by ``time_scale`` (0 makes moves instantaneous). Points are queued and
not blended, as the VAL3 server's ``movej`` with its descriptor's ``blend`` off: the arm rests on
each and starts the next at once. With ``settling`` STATUS reports the arm in motion after the
last point for the servo settling the model gives that move (scaled likewise), and for a fixed
``settle_s`` more.
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

The arm itself (its motion model, faults and queue of points) is ``drivers.controller.arm_model``;
the server variants are ``drivers.controller.server_variants``; this module serves them on
the two ports, and re-exports ``SERVERS``, ``DEFAULT_MAX_SPEED_DEG_S`` and
``DEFAULT_MAX_ACCEL_DEG_S2``.

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
from typing import Any, Self

import numpy as np

from drivers.clock import Clock, SimClock
from drivers.controller.arm_model import (
    DEFAULT_MAX_SPEED_DEG_S,
    N_JOINTS,
    RANGE_EPS_DEG,
    SimulatedArm,
)
from drivers.controller.motion import DEFAULT_MAX_ACCEL_DEG_S2
from drivers.controller.server_variants import SERVERS, ServerVariant
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
    SpecialSeq,
)
from drivers.errors import ProtocolError
from drivers.loopback import Served, accept_clients

__all__ = [
    "DEFAULT_MAX_ACCEL_DEG_S2",
    "DEFAULT_MAX_SPEED_DEG_S",
    "N_JOINTS",
    "RANGE_EPS_DEG",
    "SERVERS",
    "ServerVariant",
    "SimulatedController",
]

log = logging.getLogger(__name__)

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


class SimulatedController(SimulatedArm, Served):
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
        on_motion: Callable[[dict[str, Any]], None] | None = None,
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
        max_accel_deg_s2: Sequence[float] = DEFAULT_MAX_ACCEL_DEG_S2,
        settling: bool = False,
    ):
        if server not in SERVERS:
            raise ValueError(f"server must be one of {', '.join(SERVERS)}, got {server!r}")
        super().__init__(
            joint_min_deg,
            joint_max_deg,
            initial_deg,
            max_speed_deg_s,
            variant=SERVERS[server],
            time_scale=time_scale,
            settle_s=settle_s,
            on_motion=on_motion,
            on_point=on_point,
            clock=clock,
            max_accel_deg_s2=max_accel_deg_s2,
            settling=settling,
        )
        if host not in _LOOPBACK:
            raise ValueError(f"the simulator serves on 127.0.0.1 only, not {host!r}")
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
        self.state_rate_hz = float(state_rate_hz)
        self.joint_message = int(joint_message)
        self.startup_silence_s = float(startup_silence_s)
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

        self.motion_port: int | None = None
        self.state_port: int | None = None

        self._stop_evt = threading.Event()
        self._listeners: list[socket.socket] = []
        self._motion_clients: set[socket.socket] = set()
        self._state_clients: list[_StateClient] = []
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

    def _spawn(self, target: Callable[..., object], args: tuple[Any, ...], name: str) -> None:
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

    def inject_reply(self, raw: bytes) -> None:
        """Send ``raw`` instead of the next reply on the motion port."""
        with self._lock:
            self._replies.append(bytes(raw))

    def inject_state(self, raw: bytes) -> None:
        """Send ``raw`` to the state clients before the next state frame."""
        with self._lock:
            self._state_garbage += bytes(raw)

    # -- motion port ------------------------------------------------------------------------

    def _refuse(self, conn: socket.socket, peer: str, port: str, served: bool) -> bool:
        """Close ``conn`` at once if the simulator is stopping, or if the variant serves one
        client per port and one is ``served``; the caller holds ``_lock``."""
        if self._stop_evt.is_set():
            conn.close()
            return True
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
            if self._refuse(conn, peer, "motion", bool(self._motion_clients)):
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
            if self._refuse(conn, peer, "state", bool(self._state_clients)):
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
