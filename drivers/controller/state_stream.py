"""The state side of the Simple Message client: the reader of the state port and what it keeps.

A background thread reads the state port (``_state_loop``) and keeps the latest joints and
STATUS and a bounded history of timestamped joint samples; messages of other types are skipped
(REP-I0006). Every call that needs state waits on it (``_wait_for``) and, while it waits,
checks the stream: closed, broken or silent (``first_state_timeout_s``, ``state_timeout_s``),
and a point the controller halted short of its target (``halt_timeout_s``; what the controller
says of it is a STATUS received after the point was accepted: one from before says nothing of
the motion, so a halt waits up to a second ``halt_timeout_s`` for a fresh one). The motion side,
``drivers.controller.client.SimpleMessageController``, derives from it.
"""

from __future__ import annotations

import collections
import itertools
import logging
import math
import select
import threading
import time
from collections.abc import Callable
from typing import Any, TypeVar

import numpy as np

from drivers.clock import Clock, HostClock
from drivers.controller.base import ControllerStatus, JointSample, RobotController
from drivers.controller.link import (
    N_JOINTS,
    POLL_S,
    RECV_SIZE,
    STAMP_SPACE,
    Connection,
    enable_receive_stamps,
    receive_stamp_s,
    timeout_error,
)
from drivers.controller.simple_message import (
    CommType,
    FrameReader,
    JointFeedback,
    JointPosition,
    Message,
    MsgType,
    OtherMessage,
    Status,
)
from drivers.controller.val3 import describe_status, status_from_message
from drivers.errors import ConnectionLost, DeviceError, DeviceTimeout, DriverError, ProtocolError
from drivers.urls import ControllerAddress

# The client logs both ports (its READ/WRITE lines) under one name.
log = logging.getLogger("drivers.controller.client")
_T = TypeVar("_T")

#: A move in progress gets at least this much closer to its target (deg, the largest joint
#: distance) every ``halt_timeout_s``; otherwise the controller has halted it.
PROGRESS_DEG = 1e-3


class StateStreamController(RobotController):
    """A controller whose state comes from a Simple Message state port (see the module).

    ``first_state_timeout_s``, ``state_timeout_s`` and ``halt_timeout_s`` (s) as in
    ``SimpleMessageController``; ``history_size`` bounds the joint-sample history kept for
    ``joint_samples``; ``clock`` stamps the state frames and times the waits on them.
    """

    _address: ControllerAddress

    def __init__(
        self,
        *,
        first_state_timeout_s: float,
        state_timeout_s: float,
        halt_timeout_s: float,
        history_size: int,
        clock: Clock,
    ):
        self.first_state_timeout_s = first_state_timeout_s
        self.state_timeout_s = state_timeout_s
        self.halt_timeout_s = halt_timeout_s
        self._history_size = history_size
        self.clock = clock
        self._state_sock: Connection | None = None
        self._reader_waiting = True  # the state reader is blocked in recv, nothing in hand
        self._kernel_stamps = False  # frames stamped with their arrival in the kernel
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
        # (joint frames so far, time) at each STATUS: the stream's rate and STATUS cadence, over
        # the 0.2 s ``stream_info`` measures even with a STATUS every millisecond
        self._status_marks: collections.deque[tuple[int, float]] = collections.deque(maxlen=1024)
        self._samples: collections.deque[JointSample] = collections.deque(maxlen=history_size)
        # The point being executed: its target, when it was accepted, and its progress.
        self._target: np.ndarray | None = None
        self._target_tol_deg = 1e-3
        self._accepted_t = 0.0
        self._best_distance = math.inf
        self._best_t = 0.0
        self._idle_since: float | None = None  # STATUS "not in motion" since then

    def _ran_out(self, name: str, detail: str, value: float | None = None) -> DeviceTimeout:
        """The error of timeout ``name`` (a key of ``DEFAULT_TIMEOUTS``) running out."""
        value = getattr(self, name) if value is None else value
        return timeout_error(self.device, self.endpoint, name, value, detail)

    def _start_stream(self, sock: Connection) -> None:
        """Forget the last connection's state and start reading ``sock``, the state port."""
        sock.settimeout(POLL_S)
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
        self._state_sock = sock
        # On the host's clock every frame is stamped with its arrival in the kernel, not when
        # the reader thread got round to it (``_state_loop``); a simulated clock stamps frames
        # with the instants they describe already.
        self._kernel_stamps = isinstance(self.clock, HostClock) and enable_receive_stamps(sock)
        self._state_thread = threading.Thread(
            target=self._state_loop,
            args=(sock, FrameReader(self.device, self.endpoint)),
            name=f"controller-state {self.endpoint}",
            daemon=True,
        )
        self._state_thread.start()

    def _state_loop(self, sock: Connection, reader: FrameReader) -> None:
        """Read the state port until closed. With the kernel's receive stamps a frame at a time
        (a stamp is the last segment's of a read): a frame is stamped with when it arrived,
        however late a loaded host schedules this thread to read it, so that the arm's
        position it gives is paired with the instant the controller sent it for (a frame read
        20 ms late and stamped on reading puts every reading of those 20 ms at the arm's
        position before them)."""
        debug = log.isEnabledFor(logging.DEBUG)
        stamped = self._kernel_stamps
        ancillary: list[tuple[int, int, bytes]] = []
        last_arrived: float | None = None
        while not self._closing.is_set():
            self._reader_waiting = True
            try:
                if stamped:
                    data, ancillary, _, _ = sock.recvmsg(reader.wanted, STAMP_SPACE)  # type: ignore[attr-defined]
                else:
                    data = sock.recv(RECV_SIZE)
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
                now = self.clock.now()
                arrived = receive_stamp_s(ancillary) if stamped else None
                if arrived is not None and arrived == last_arrived:
                    now = self._last_frame_t  # the same segment as the frame before
                elif arrived is not None:
                    # in arrival order, and never before the connection: a realtime clock
                    # stepped forward cannot date a frame before the one read before it
                    age_s = max(time.time() - arrived, 0.0)
                    now = max(now - age_s, self._last_frame_t, self._connected_t)
                last_arrived = arrived
                taken = self._on_state_messages(messages, now)
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
                    sample = JointSample(now, joints)
                    if self._samples and self._samples[-1].t_s >= now:
                        # Frames that came with one stamp (one read of a reader that fell
                        # behind, or segments the kernel merged while they waited for it,
                        # stamped with the last one's arrival): the stamp is the newest
                        # frame's arrival only, and the older frames' postures are kept at no
                        # instant (a posture paired with a later instant than it was sent at
                        # puts every reading in between behind the arm).
                        self._samples[-1] = sample
                    else:
                        self._samples.append(sample)
                    joint_frames += 1
                    self._joint_count += 1
                    self._joint_type = MsgType(msg.msg_type).name
                    if self._target is not None:
                        distance = float(np.max(np.abs(joints - self._target)))
                        if distance < self._best_distance - PROGRESS_DEG:
                            self._best_distance, self._best_t = distance, now
                elif isinstance(msg, Status):
                    self._status, self._status_t = status_from_message(msg), now
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
        log.debug("state link failed: %s", error)  # raised by the next wait: reported once
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
                f"{describe_status(st)}",
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
            fresh = st is not None and self._status_t > self._accepted_t
            if st is not None and not fresh and stalled_s < 2.0 * self.halt_timeout_s:
                return  # a STATUS from before the point says nothing of it: wait for one
            if st is None:
                said = "no status yet"
            elif fresh:
                said = describe_status(st)
            else:
                said = f"no status since the point was accepted (before it: {describe_status(st)})"
            raise DeviceError(
                self.device,
                self.endpoint,
                f"controller halted the motion {distance:.4g} deg short of "
                f"{np.round(target, 4).tolist()} deg: the joints have not "
                f"moved towards it for {stalled_s:.1f} s; it reports {said}",
            )

    def _wait_for(
        self,
        predicate: Callable[[], _T | None],
        timeout_s: float,
        what: str,
        timeout_name: str | None = None,
    ) -> _T:
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
            # stamped in arrival order on a monotonic clock: the samples asked for are the
            # newest ones, found from the end of a history of thousands
            out = list(itertools.takewhile(lambda s: s.t_s >= since_t_s, reversed(self._samples)))
        out.reverse()
        return out
