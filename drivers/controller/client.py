"""Robot controller over ROS-Industrial Simple Message (the Staubli VAL3 server's protocol).

Two TCP connections, as the VAL3 server expects them (``val3/ros_server``):

* motion port (default 11000): the client sends JOINT_TRAJ_PT as SERVICE_REQUEST, one request
  at a time, and reads the SERVICE_REPLY that acknowledges *enqueueing* the point (not its
  execution; REP-I0006).
* state port (default 11002): the server streams joint state and STATUS. The released
  ``master`` branch sends JOINT_POSITION at 50 Hz and a STATUS every 5th pass; the unmerged pull
  request #36 sends JOINT_FEEDBACK at 250 Hz and a STATUS every 20th. Both servers stay silent
  for 1 s after a client connects (``recvHeartbeat.pgx``: ``delay(1.0)``). A background thread
  keeps the latest joints and STATUS and a bounded history of timestamped joint samples;
  messages of other types are skipped (REP-I0006).

Timeouts (seconds, constructor keywords; ``docs/protocols/simple_message.md``): each TCP
connect (``connect_timeout_s``), the first state message after connecting
(``first_state_timeout_s``, well above the server's 1 s of silence), the longest silence of the
stream once it runs (``state_timeout_s``), the reply to a request (``reply_timeout_s``), and how
long the arm may stand short of its target before the motion counts as halted by the controller
(``halt_timeout_s``); the settle deadline is the caller's (``wait_settled``). Every timeout error
names the timeout that ran out.

Units at the interface are degrees and seconds; radians exist only on the wire.
"""

from __future__ import annotations

import collections
import contextlib
import logging
import math
import select
import socket
import struct
import threading
import time
from collections.abc import Callable
from typing import Any, Protocol

import numpy as np

from drivers.clock import HOST_CLOCK, Clock
from drivers.controller.base import ControllerStatus, JointSample, RobotController
from drivers.controller.simple_message import (
    CommType,
    FrameReader,
    JointFeedback,
    JointPosition,
    JointTrajPt,
    JointTrajPtReply,
    Message,
    MsgType,
    OtherMessage,
    SpecialSeq,
    Status,
)
from drivers.errors import (
    ConnectionLost,
    DeviceError,
    DeviceTimeout,
    DriverError,
    MotionRejected,
    ProtocolError,
)
from drivers.urls import (
    DEFAULT_MOTION_PORT,
    DEFAULT_STATE_PORT,
    ControllerAddress,
    parse_controller_url,
)

log = logging.getLogger(__name__)

N_JOINTS = 6
_RECV_SIZE = 4096
# The reader thread wakes at least this often (s) to notice close().
_POLL_S = 0.1

#: Default timeouts (s). The VAL3 server sends nothing for 1 s after a client connects to its
#: state port, so the first state message may take well over that.
DEFAULT_TIMEOUTS: dict[str, float] = {
    "connect_timeout_s": 2.0,
    "first_state_timeout_s": 5.0,
    "state_timeout_s": 1.0,
    "reply_timeout_s": 2.0,
    "halt_timeout_s": 1.5,
}
#: What each timeout bounds, for the message when it runs out.
_TIMEOUT_LABELS = {
    "connect_timeout_s": "connect timeout",
    "first_state_timeout_s": "first-state timeout",
    "state_timeout_s": "state timeout",
    "reply_timeout_s": "reply timeout",
    "halt_timeout_s": "halt timeout",
    "settle_timeout_s": "settle timeout",
}

#: Slowest velocity sent (fraction of maximum speed). The VAL3 server turns the wire velocity
#: into a percentage and rounds it to four decimals (``interpolateVel.pgx``): below 5e-7 that is
#: 0, which ``movej`` refuses, and below 1e-4 the rounding alone changes the speed by more than
#: 1 %. 1e-4 also keeps the slowest joint of a TX90 moving at 0.02 deg/s, which the halt
#: detection (``PROGRESS_DEG`` per ``halt_timeout_s``) sees as progress.
MIN_VELOCITY = 1e-4
#: The rounded percentage that the master server's "smooth last point in traj" rule replaces by
#: an extrapolation of the previous points' wire velocities (``interpolateVel.pgx``).
VAL3_SMOOTHING_PERCENT = 0.1
#: What is sent instead of a velocity that rounds to ``VAL3_SMOOTHING_PERCENT`` (0.101 %).
VAL3_SMOOTHING_DODGE = 0.00101
#: A move in progress gets at least this much closer to its target (deg, the largest joint
#: distance) every ``halt_timeout_s``; otherwise the controller has halted it.
PROGRESS_DEG = 1e-3


class Connection(Protocol):
    """What the client needs of a connected socket (``socket.socket`` has all of it)."""

    def settimeout(self, value: float | None) -> None: ...
    def recv(self, size: int) -> bytes: ...
    def sendall(self, data: bytes) -> None: ...
    def shutdown(self, how: int) -> None: ...
    def close(self) -> None: ...


def tcp_connect(host: str, port: int, timeout_s: float) -> socket.socket:
    """Open a TCP connection with Nagle's algorithm off (each frame goes out at once)."""
    sock = socket.create_connection((host, port), timeout=timeout_s)
    sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    return sock


def _tri(value: int) -> bool | None:
    """Map a REP-I0006 tri-state (-1 unknown, 0 off, 1 on) to ``None``/``False``/``True``."""
    return None if value < 0 else bool(value)


def _status_from_message(msg: Status) -> ControllerStatus:
    return ControllerStatus(
        drives_powered=_tri(msg.drives_powered),
        e_stopped=_tri(msg.e_stopped),
        in_motion=_tri(msg.in_motion),
        in_error=_tri(msg.in_error),
        error_code=msg.error_code,
        mode=msg.mode if msg.mode in (1, 2) else 0,
        motion_possible=_tri(msg.motion_possible),
    )


def val3_percent(velocity: float) -> float:
    """The percentage the VAL3 master server compares for a wire ``velocity``.

    ``pushMotion.pgx`` multiplies the float32 it received by 100; ``interpolateVel.pgx`` rounds
    the result to four decimals.
    """
    received = struct.unpack("<f", struct.pack("<f", velocity))[0]
    return math.floor(received * 100.0 * 10000.0 + 0.5) / 10000.0


def velocity_on_wire(speed: float) -> float:
    """The velocity fraction to send for ``speed`` (fraction of maximum, (0, 1]).

    Raised to ``MIN_VELOCITY``, the slowest the server runs as asked. And the released VAL3
    server replaces a velocity whose rounded percentage is exactly 0.1 (wire 0.001, not 0.1)
    by ``2·v[0] − v[1]`` of the last two wire velocities it received ("smooth last point in
    traj", ``interpolateVel.pgx``): a fraction, not a percentage, so 100 times too slow or
    negative. Such a velocity is sent as 0.00101 (0.101 %).
    """
    velocity = max(float(speed), MIN_VELOCITY)
    if val3_percent(velocity) == VAL3_SMOOTHING_PERCENT:
        return VAL3_SMOOTHING_DODGE
    return velocity


class SimpleMessageController(RobotController):
    """Six-axis controller driven through a Simple Message server (motion + state ports).

    Timeouts (s; defaults in ``DEFAULT_TIMEOUTS``): ``connect_timeout_s`` bounds each TCP
    connect; ``first_state_timeout_s`` the wait for the first state message after connecting
    (every call that needs state waits that long for it); ``state_timeout_s`` how long the
    running stream may stay silent before the link is declared dead; ``reply_timeout_s`` the
    wait for the reply to a request; ``halt_timeout_s`` how long the arm may stand short of the
    target of an accepted point (no progress of ``PROGRESS_DEG``, or STATUS "not in motion")
    before the motion counts as halted by the controller. ``history_size`` bounds the
    joint-sample history kept for ``joint_samples``. ``clock`` stamps the state frames and
    times the waits on them (``drivers.clock``: the host's monotonic clock on a real cell,
    simulated time against an in-process simulated cell). ``connect`` opens one connection
    (``tcp_connect`` by default; tests pass scripted ones).
    """

    def __init__(
        self,
        host: str = "127.0.0.1",
        motion_port: int = DEFAULT_MOTION_PORT,
        state_port: int = DEFAULT_STATE_PORT,
        *,
        connect_timeout_s: float = DEFAULT_TIMEOUTS["connect_timeout_s"],
        first_state_timeout_s: float = DEFAULT_TIMEOUTS["first_state_timeout_s"],
        state_timeout_s: float = DEFAULT_TIMEOUTS["state_timeout_s"],
        reply_timeout_s: float = DEFAULT_TIMEOUTS["reply_timeout_s"],
        halt_timeout_s: float = DEFAULT_TIMEOUTS["halt_timeout_s"],
        history_size: int = 65536,
        clock: Clock = HOST_CLOCK,
        connect: Callable[[str, int, float], Connection] = tcp_connect,
    ):
        for name, value in (
            ("connect_timeout_s", connect_timeout_s),
            ("first_state_timeout_s", first_state_timeout_s),
            ("state_timeout_s", state_timeout_s),
            ("reply_timeout_s", reply_timeout_s),
            ("halt_timeout_s", halt_timeout_s),
        ):
            if not (value > 0 and math.isfinite(value)):
                raise ValueError(f"{name} must be a positive number of seconds, got {value}")
        if history_size < 1:
            raise ValueError(f"history_size must be at least 1, got {history_size}")
        self._address = ControllerAddress(host, int(motion_port), int(state_port))
        self.connect_timeout_s = connect_timeout_s
        self.first_state_timeout_s = first_state_timeout_s
        self.state_timeout_s = state_timeout_s
        self.reply_timeout_s = reply_timeout_s
        self.halt_timeout_s = halt_timeout_s
        self._history_size = history_size
        self.clock = clock
        self._connect = connect

        self._motion_sock: Connection | None = None
        self._motion_reader: FrameReader | None = None
        self._motion_lock = threading.Lock()
        self._motion_error: DriverError | None = None
        self._next_seq = 0
        # Sequences of requests whose reply timed out: their replies may still come.
        self._late: list[int] = []

        self._state_sock: Connection | None = None
        self._reader_waiting = True  # the state reader is blocked in recv, nothing in hand
        self._state_thread: threading.Thread | None = None
        self._closing = threading.Event()
        # Guards everything below; notified on every state frame and when the link dies.
        self._cond = threading.Condition()
        self._joints_deg: np.ndarray | None = None
        self._joints_t = 0.0
        self._status: ControllerStatus | None = None
        self._status_t = 0.0
        self._connected_t = 0.0
        self._first_frame_t: float | None = None
        self._last_frame_t = 0.0
        self._state_error: DriverError | None = None
        self._skipped_types: set[int] = set()
        self._joint_type = ""  # the joint message the stream carries
        self._joint_count = 0  # joint frames since connecting
        # (joint frames so far, time) at each STATUS: the stream's rate and STATUS cadence
        self._status_marks: collections.deque[tuple[int, float]] = collections.deque(maxlen=64)
        self._samples: collections.deque[JointSample] = collections.deque(maxlen=history_size)
        # The point being executed: its target, when it was accepted, and its progress.
        self._target: np.ndarray | None = None
        self._target_tol_deg = 1e-3
        self._accepted_t = 0.0
        self._best_distance = math.inf
        self._best_t = 0.0
        self._idle_since: float | None = None  # STATUS "not in motion" since then

    @classmethod
    def from_url(cls, url: str, **kwargs: Any) -> SimpleMessageController:
        """Build from ``tcp://HOST:PORT[?state=PORT]``; keyword arguments as the constructor."""
        address = parse_controller_url(url)
        return cls(address.host, address.motion_port, address.state_port, **kwargs)

    @property
    def endpoint(self) -> str:
        return self._address.url

    def _ran_out(self, name: str, detail: str, value: float | None = None) -> DeviceTimeout:
        """The error of timeout ``name`` (a key of ``DEFAULT_TIMEOUTS``) running out."""
        value = getattr(self, name) if value is None else value
        return DeviceTimeout(
            self.device,
            self.endpoint,
            f"{_TIMEOUT_LABELS[name]} ran out ({name} = {value:g} s): {detail}",
        )

    # -- connection -------------------------------------------------------------------------

    def _open(self, port: int, what: str) -> Connection:
        try:
            return self._connect(self._address.host, port, self.connect_timeout_s)
        except TimeoutError:
            raise self._ran_out(
                "connect_timeout_s", f"no answer connecting to the {what} port {port}"
            ) from None
        except OSError as e:
            raise ConnectionLost(
                self.device,
                self.endpoint,
                f"cannot connect to the {what} port {port}: {e.strerror or e}",
            ) from None

    def connect(self) -> None:
        """Open the motion and state connections and start the state reader thread.

        Returns once both are open; the first state message may come later (the VAL3 server
        waits 1 s): every call that needs state waits up to ``first_state_timeout_s`` for it.
        """
        if self._motion_sock is not None:
            return
        motion = self._open(self._address.motion_port, "motion")
        try:
            state = self._open(self._address.state_port, "state")
        except DriverError:
            motion.close()
            raise
        state.settimeout(_POLL_S)
        self._closing.clear()
        with self._cond:
            self._joints_deg = None
            self._status = None
            self._state_error = None
            self._samples.clear()
            self._connected_t = self.clock.now()
            self._first_frame_t = None
            self._target = None
            self._joint_count = 0
            self._status_marks.clear()
        self._motion_sock, self._state_sock = motion, state
        self._motion_reader = FrameReader(self.device, self.endpoint)
        self._motion_error = None
        self._next_seq = 0
        self._late = []
        self._state_thread = threading.Thread(
            target=self._state_loop,
            args=(state, FrameReader(self.device, self.endpoint)),
            name=f"controller-state {self.endpoint}",
            daemon=True,
        )
        self._state_thread.start()
        log.info("connected to controller at %s", self.endpoint)

    def close(self) -> None:
        """Close both connections and stop the reader thread. Idempotent."""
        self._closing.set()
        for sock in (self._motion_sock, self._state_sock):
            if sock is not None:
                with contextlib.suppress(OSError):  # already reset by the peer
                    sock.shutdown(socket.SHUT_RDWR)
                sock.close()
        thread = self._state_thread
        if thread is not None and thread is not threading.current_thread():
            thread.join(timeout=2.0)
        was_open = self._motion_sock is not None
        self._motion_sock = self._state_sock = None
        self._state_thread = None
        with self._cond:
            self._cond.notify_all()
        if was_open:
            log.info("closed connection to controller at %s", self.endpoint)

    # -- state stream -----------------------------------------------------------------------

    def _state_loop(self, sock: Connection, reader: FrameReader) -> None:
        debug = log.isEnabledFor(logging.DEBUG)
        while not self._closing.is_set():
            self._reader_waiting = True
            try:
                data = sock.recv(_RECV_SIZE)
            except TimeoutError:
                continue
            except OSError as e:
                self._reader_waiting = False
                if not self._closing.is_set():
                    self._state_failed(
                        ConnectionLost(self.device, self.endpoint, f"state connection failed: {e}")
                    )
                return
            self._reader_waiting = False
            if not data:
                if not self._closing.is_set():
                    self._state_failed(
                        ConnectionLost(self.device, self.endpoint, self._closed_detail())
                    )
                return
            if debug:
                log.debug("READ: state %s", data.hex())
            try:
                messages = reader.feed(data)
            except ProtocolError as e:
                self._state_failed(e)
                return
            if messages:
                taken = self._on_state_messages(messages, self.clock.now())
                self.clock.frames_taken(taken)

    def _closed_detail(self) -> str:
        if self._first_frame_t is None:
            return (
                "state connection closed by the controller before it sent anything (a "
                "VAL3 server serves one client per port: is another client connected?)"
            )
        return "state connection closed by the controller"

    def _on_state_messages(self, messages: list[Message], now: float) -> int:
        """Keep the latest joints and status; return how many joint frames there were."""
        joint_frames = 0
        with self._cond:
            if self._first_frame_t is None:
                self._first_frame_t = now
            self._last_frame_t = now
            for msg in messages:
                if isinstance(msg, (JointPosition, JointFeedback)):
                    rad = msg.joints_rad if isinstance(msg, JointPosition) else msg.positions_rad
                    joints = np.degrees(np.asarray(rad[:N_JOINTS], dtype=float))
                    self._joints_deg, self._joints_t = joints, now
                    self._samples.append(JointSample(now, joints))
                    joint_frames += 1
                    self._joint_count += 1
                    self._joint_type = MsgType(msg.msg_type).name
                    if self._target is not None:
                        distance = float(np.max(np.abs(joints - self._target)))
                        if distance < self._best_distance - PROGRESS_DEG:
                            self._best_distance, self._best_t = distance, now
                elif isinstance(msg, Status):
                    self._status, self._status_t = _status_from_message(msg), now
                    self._status_marks.append((self._joint_count, now))
                    if msg.in_motion != 0:
                        self._idle_since = None
                    elif self._idle_since is None:
                        self._idle_since = now
                else:
                    # REP-I0006: receivers ignore messages they do not use.
                    self._skip(msg, "state")
            self._cond.notify_all()
        return joint_frames

    def _skip(self, msg: Message, port: str) -> None:
        """Log a message that is not used (once per type for topics, which repeat)."""
        msg_type = int(getattr(msg, "msg_type", -1))
        if isinstance(msg, OtherMessage) and msg.comm_type == CommType.TOPIC:
            if msg_type in self._skipped_types:
                return
            self._skipped_types.add(msg_type)
        log.warning(
            "controller at %s: ignoring %s (type %d) on the %s port",
            self.endpoint,
            type(msg).__name__,
            msg_type,
            port,
        )

    def _state_failed(self, error: DriverError) -> None:
        log.error("%s", error)
        with self._cond:
            self._state_error = error
            self._cond.notify_all()

    def _stream_behind(self) -> bool:
        """Whether the state reader has frames it has not taken yet: bytes wait in the socket,
        or the reader is not back in ``recv`` (busy with what came, or not yet scheduled by a
        loaded host). Then a silence is the host's, not the controller's: the stream's
        timeouts and the halt detection judge the controller only on a reader that waits
        with nothing to read."""
        if not self._reader_waiting:
            return True
        fileno = getattr(self._state_sock, "fileno", None)
        if fileno is None:
            return False
        try:
            ready, _, _ = select.select([fileno()], [], [], 0)
        except (OSError, ValueError, TypeError):
            return False
        return bool(ready)

    def _check_state_locked(self, now: float) -> None:
        """Raise if the state link is closed, broken or silent, or the motion was halted.

        The caller holds ``_cond``.
        """
        if self._state_error is not None:
            raise self._state_error
        if self._state_sock is None:
            raise ConnectionLost(self.device, self.endpoint, "not connected")
        if self._first_frame_t is None:
            if now - self._connected_t > self.first_state_timeout_s and not self._stream_behind():
                raise self._ran_out(
                    "first_state_timeout_s",
                    f"no state message since connecting to the state port "
                    f"{self._address.state_port} (a VAL3 server streams 1 s after a client "
                    f"connects: is ros_server running?)",
                )
        elif now - self._last_frame_t > self.state_timeout_s and not self._stream_behind():
            raise self._ran_out(
                "state_timeout_s", f"no state message for {now - self._last_frame_t:.2f} s"
            )
        if self._target is not None:
            self._check_halt_locked(now)

    def _check_halt_locked(self, now: float) -> None:
        """Raise ``DeviceError`` if the controller halted the accepted point (see the class)."""
        target, st = self._target, self._status
        assert target is not None
        if (
            st is not None
            and self._status_t > self._accepted_t
            and (st.e_stopped or st.in_error or st.drives_powered is False)
        ):
            raise DeviceError(
                self.device,
                self.endpoint,
                f"controller stopped the motion to "
                f"{np.round(target, 4).tolist()} deg: it reports "
                f"{_describe(st)}",
            )
        joints = self._joints_deg
        if joints is None or now - self._accepted_t < self.halt_timeout_s:
            return
        distance = float(np.max(np.abs(joints - target)))
        if distance <= self._target_tol_deg:
            return
        stalled_s = now - self._best_t
        idle_s = 0.0 if self._idle_since is None else now - max(self._idle_since, self._accepted_t)
        if (
            stalled_s >= self.halt_timeout_s or idle_s >= self.halt_timeout_s
        ) and not self._stream_behind():
            said = "no status yet" if st is None else _describe(st)
            raise DeviceError(
                self.device,
                self.endpoint,
                f"controller halted the motion {distance:.4g} deg short of "
                f"{np.round(target, 4).tolist()} deg: the joints have not "
                f"moved towards it for {stalled_s:.1f} s; it reports {said}",
            )

    def _wait_for(self, predicate, timeout_s: float, what: str, timeout_name: str | None = None):
        """Wait until ``predicate()`` (called with ``_cond`` held) returns non-None.

        Before the first state message the wait lasts at least until ``first_state_timeout_s``
        after connecting. ``timeout_name`` names the timeout in the error (else the plain
        ``timeout_s``).
        """
        start = self.clock.now()
        deadline = start + timeout_s
        with self._cond:
            if self._first_frame_t is None:
                deadline = max(deadline, self._connected_t + self.first_state_timeout_s)
            while True:
                now = self.clock.now()
                self._check_state_locked(now)
                value = predicate()
                if value is not None:
                    return value
                remaining = deadline - now
                if remaining <= 0:
                    if timeout_name is not None:
                        raise self._ran_out(timeout_name, f"no {what}", timeout_s)
                    raise DeviceTimeout(
                        self.device, self.endpoint, f"no {what} within {now - start:.3g} s"
                    )
                # Wake in time to notice a silent stream and a halt as well as the deadline.
                self.clock.wait(
                    self._cond, min(remaining, self.state_timeout_s / 2, self.halt_timeout_s / 2)
                )

    def read_joints(self, timeout_s: float = 2.0) -> np.ndarray:
        """Latest joint readings (deg, (6,)), waiting at most ``timeout_s`` for a first one.

        While a point is being executed this also raises ``DeviceError`` as soon as the
        controller has halted it (``halt_timeout_s``).
        """
        joints = self._wait_for(lambda: self._joints_deg, timeout_s, "joint position")
        return joints.copy()

    def status(self, timeout_s: float = 2.0) -> ControllerStatus:
        """Latest STATUS, waiting at most ``timeout_s`` for a first one."""
        return self._wait_for(lambda: self._status, timeout_s, "status message")

    def stream_info(self, timeout_s: float = 3.0) -> dict[str, Any]:
        """What the state port streams, measured: ``joint_message`` (JOINT_POSITION or
        JOINT_FEEDBACK), ``joint_rate_hz``, ``status_every`` (joint frames per STATUS) and
        ``first_state_s`` (how long the first message took after connecting).

        Waits for STATUS messages spanning 0.2 s at least (the released VAL3 server sends one
        every 5th pass at 50 Hz, pull request #36 every 20th at 250 Hz).
        """

        def measured() -> dict[str, Any] | None:
            marks = self._status_marks
            if len(marks) < 3 or marks[-1][1] - marks[0][1] < 0.2:
                return None
            (c0, t0), (c1, _), (c2, t2) = marks[0], marks[-2], marks[-1]
            return {
                "joint_message": self._joint_type,
                "joint_rate_hz": round((c2 - c0) / (t2 - t0), 1),
                "status_every": c2 - c1,
                "first_state_s": round((self._first_frame_t or 0.0) - self._connected_t, 3),
            }

        return self._wait_for(measured, timeout_s, "STATUS messages spanning 0.2 s")

    def joint_samples(self, since_t_s: float = 0.0) -> list[JointSample]:
        """Streamed joint positions received at or after ``since_t_s`` (``clock`` time, s)."""
        with self._cond:
            return [s for s in self._samples if s.t_s >= since_t_s]

    # -- motion -----------------------------------------------------------------------------

    def _send(self, sock: Connection, frame: bytes) -> None:
        if log.isEnabledFor(logging.DEBUG):
            log.debug("WRITE: motion %s", frame.hex())
        sock.sendall(frame)

    def _is_reply(self, reply: Message, seq: int) -> bool:
        """Whether ``reply`` answers the request ``seq``; stale and other messages are logged.

        REP-I0006: a reply with no outstanding request (the late answer to a request that
        timed out) is ignored. A reply without a sequence is taken as the oldest late one
        while any is due, so a late reply is never taken for a new point.
        """
        if not isinstance(reply, JointTrajPtReply):
            self._skip(reply, "motion")
            return False
        if reply.sequence == seq:
            return True
        if reply.sequence is None:
            if not self._late:
                return True
            late = self._late.pop(0)
            why = f"taken as the late reply to point {late}"
        elif reply.sequence in self._late:
            self._late.remove(reply.sequence)
            why = "the late reply to a request that timed out"
        else:
            why = "no such request outstanding"
        log.warning(
            "controller at %s: ignoring a reply (sequence %s) while waiting for the "
            "reply to point %d: %s",
            self.endpoint,
            reply.sequence,
            seq,
            why,
        )
        return False

    def _request(self, msg: JointTrajPt, timeout_s: float) -> JointTrajPtReply:
        """Send one JOINT_TRAJ_PT request and return its reply (caller holds the motion lock)."""
        if self._motion_error is not None:
            raise self._motion_error
        sock, reader = self._motion_sock, self._motion_reader
        if sock is None or reader is None:
            raise ConnectionLost(self.device, self.endpoint, "not connected")
        deadline = time.monotonic() + timeout_s
        try:
            sock.settimeout(timeout_s)
            self._send(sock, msg.pack())
            while True:
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    raise TimeoutError
                sock.settimeout(remaining)
                data = sock.recv(_RECV_SIZE)
                if not data:
                    raise self._motion_failed(
                        ConnectionLost(
                            self.device, self.endpoint, "motion connection closed by the controller"
                        )
                    )
                if log.isEnabledFor(logging.DEBUG):
                    log.debug("READ: motion %s", data.hex())
                for reply in reader.feed(data):
                    if self._is_reply(reply, msg.sequence):
                        assert isinstance(reply, JointTrajPtReply)
                        return reply
        except TimeoutError:
            self._late = [*self._late, msg.sequence][-16:]
            raise self._ran_out(
                "reply_timeout_s", f"no reply to trajectory point {msg.sequence}", timeout_s
            ) from None
        except ProtocolError as e:
            raise self._motion_failed(e) from None
        except OSError as e:
            raise self._motion_failed(
                ConnectionLost(self.device, self.endpoint, f"motion connection failed: {e}")
            ) from None

    def _motion_failed(self, error: DriverError) -> DriverError:
        log.error("%s", error)
        self._motion_error = error
        return error

    def start_move(self, target_deg: np.ndarray, speed: float = 0.5) -> None:
        """Send a joint target (deg, (6,)) at ``speed`` (fraction of maximum, (0, 1]).

        Waits for the state stream first (the VAL3 server drops points received before it
        streams). Returns once the controller accepted the point. Raises ``MotionRejected``
        when it answers FAILURE, ``ConnectionLost``/``DeviceTimeout``/``ProtocolError`` on link
        faults, ``ValueError`` for a malformed target or speed. The velocity sent is
        ``velocity_on_wire(speed)``.
        """
        target = np.asarray(target_deg, dtype=float).reshape(-1)
        if target.shape != (N_JOINTS,) or not np.all(np.isfinite(target)):
            raise ValueError(f"target_deg must be {N_JOINTS} finite numbers, got {target_deg!r}")
        if not (0.0 < speed <= 1.0):
            raise ValueError(f"speed must be in (0, 1], got {speed}")
        with self._cond:
            self._target = None  # a new point replaces the one being executed
        self.read_joints()
        with self._motion_lock:
            # A sequence number is used once: the late reply to a request that timed out must
            # not match the next one.
            seq = self._next_seq
            self._next_seq = seq + 1
            msg = JointTrajPt(seq, tuple(np.radians(target)), velocity_on_wire(speed), 0.0)
            reply = self._request(msg, self.reply_timeout_s)
        accepted_t = self.clock.now()
        if not reply.success:
            detail = ""
            with self._cond:
                st = self._status
            if st is not None:
                detail = f"; it reports {_describe(st)}"
            raise MotionRejected(
                self.device,
                self.endpoint,
                f"trajectory point {seq} to {np.round(target, 4).tolist()} deg "
                f"at speed {speed:g} refused (reply code {reply.reply_code})"
                f"{detail}",
            )
        with self._cond:
            self._accepted_t = accepted_t
            self._target = target.copy()
            self._target_tol_deg = 1e-3
            joints = self._joints_deg
            self._best_distance = (
                math.inf if joints is None else float(np.max(np.abs(joints - target)))
            )
            self._best_t = accepted_t
        log.info(
            "controller accepted point %d: %s deg at speed %g",
            seq,
            np.round(target, 4).tolist(),
            speed,
        )

    def wait_settled(
        self, target_deg: np.ndarray, timeout_s: float, tol_deg: float = 1e-3
    ) -> np.ndarray:
        """Block until STATUS says not in motion and every joint is within ``tol_deg`` of target.

        Only STATUS and joint messages received after the last accepted point count. Returns
        the settled readings (deg). Raises ``DeviceTimeout`` after ``timeout_s`` (the settle
        timeout), ``ConnectionLost`` as soon as the state stream dies, ``DeviceError`` as soon
        as the controller reports an e-stop, an error or unpowered drives, or has left the arm
        short of the target for ``halt_timeout_s``.
        """
        target = np.asarray(target_deg, dtype=float).reshape(-1)
        if target.shape != (N_JOINTS,):
            raise ValueError(f"target_deg must have {N_JOINTS} elements, got {target_deg!r}")
        with self._cond:
            if self._target is not None:
                self._target_tol_deg = tol_deg

        def settled() -> np.ndarray | None:
            st, joints = self._status, self._joints_deg
            if st is None or joints is None:
                return None
            if self._status_t <= self._accepted_t or self._joints_t <= self._accepted_t:
                return None
            if st.in_motion is not True and np.max(np.abs(joints - target)) <= tol_deg:
                self._target = None
                return joints.copy()
            return None

        try:
            return self._wait_for(
                settled,
                timeout_s,
                f"settling within {tol_deg:g} deg of {np.round(target, 4).tolist()} deg",
                "settle_timeout_s",
            )
        except DeviceTimeout:
            with self._cond:
                last = None if self._joints_deg is None else np.round(self._joints_deg, 4)
            if last is not None:
                log.error(
                    "controller at %s did not settle; last readings %s deg",
                    self.endpoint,
                    last.tolist(),
                )
            raise

    def stop(self) -> None:
        """Send STOP_TRAJECTORY (sequence -4). Never raises; failures are logged.

        STOP goes out even when the motion link has failed before (a bad frame, a reset): its
        reply is then not read, and the earlier fault is logged with it.
        """
        sock = self._motion_sock
        if sock is None:
            log.debug("stop: not connected to %s", self.endpoint)
            return
        with self._cond:
            self._target = None
        msg = JointTrajPt(SpecialSeq.STOP_TRAJECTORY, (), 0.0, 0.0, CommType.SERVICE_REQUEST)
        if not self._motion_lock.acquire(timeout=self.reply_timeout_s):
            # Another thread is stuck waiting for a reply: send anyway, do not read its answer.
            self._send_unanswered(sock, msg, "another request is waiting for its reply")
            return
        try:
            if self._motion_error is not None:
                self._send_unanswered(sock, msg, f"the motion link failed: {self._motion_error}")
                return
            reply = self._request(msg, min(self.reply_timeout_s, 1.0))
            # REP-I0006: a new trajectory starts at sequence 0 (after any late reply's).
            self._next_seq = max((s for s in self._late if s >= 0), default=-1) + 1
            if reply.success:
                log.info("controller at %s acknowledged STOP", self.endpoint)
            else:
                log.error("controller at %s answered FAILURE to STOP", self.endpoint)
        except DriverError as e:
            log.error("stop not confirmed: %s", e)
        except Exception:  # stop() runs on error paths and must not raise
            log.exception("stop failed at %s", self.endpoint)
        finally:
            self._motion_lock.release()

    def _send_unanswered(self, sock: Connection, msg: JointTrajPt, why: str) -> None:
        """Send ``msg`` without reading a reply (``why`` says why); log, never raise."""
        try:
            self._send(sock, msg.pack())
            log.warning("STOP sent to %s without reading its reply: %s", self.endpoint, why)
        except OSError as e:
            log.error("STOP could not be sent to %s: %s (%s)", self.endpoint, e, why)


def _describe(st: ControllerStatus) -> str:
    """A STATUS in words, for messages."""

    def tri(value: bool | None, yes: str, no: str) -> str:
        return "unknown" if value is None else yes if value else no

    return (
        f"{tri(st.in_motion, 'in motion', 'not in motion')}, drives "
        f"{tri(st.drives_powered, 'powered', 'off')}, e-stop "
        f"{tri(st.e_stopped, 'engaged', 'released')}, "
        f"{tri(st.in_error, f'in error (code {st.error_code})', 'no error')}, motion "
        f"{tri(st.motion_possible, 'possible', 'not possible')}"
    )
