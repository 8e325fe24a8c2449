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

This module holds the connections and the motion port; the state port is read by its base,
``drivers.controller.state_stream``; the links' timeouts are in ``drivers.controller.link``
and what the VAL3 server makes of velocities and STATUS in ``drivers.controller.val3``, whose
public names it re-exports.
"""

from __future__ import annotations

import contextlib
import logging
import math
import socket
import threading
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from drivers.clock import HOST_CLOCK, Clock
from drivers.controller.link import (
    DEFAULT_TIMEOUTS,
    N_JOINTS,
    RECV_SIZE,
    Connection,
    tcp_connect,
)
from drivers.controller.simple_message import (
    CommType,
    FrameReader,
    JointTrajPt,
    JointTrajPtReply,
    Message,
    SpecialSeq,
)
from drivers.controller.state_stream import PROGRESS_DEG, StateStreamController
from drivers.controller.val3 import (
    MIN_VELOCITY,
    VAL3_SMOOTHING_DODGE,
    VAL3_SMOOTHING_PERCENT,
    describe_status,
    val3_percent,
    velocity_on_wire,
)
from drivers.errors import (
    ConnectionLost,
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

__all__ = [
    "DEFAULT_TIMEOUTS",
    "MIN_VELOCITY",
    "N_JOINTS",
    "PROGRESS_DEG",
    "VAL3_SMOOTHING_DODGE",
    "VAL3_SMOOTHING_PERCENT",
    "Connection",
    "SimpleMessageController",
    "tcp_connect",
    "val3_percent",
    "velocity_on_wire",
]

log = logging.getLogger(__name__)


class SimpleMessageController(StateStreamController):
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
        super().__init__(
            first_state_timeout_s=first_state_timeout_s,
            state_timeout_s=state_timeout_s,
            halt_timeout_s=halt_timeout_s,
            history_size=history_size,
            clock=clock,
        )
        self._address = ControllerAddress(host, int(motion_port), int(state_port))
        self.connect_timeout_s = connect_timeout_s
        self.reply_timeout_s = reply_timeout_s
        self._connect = connect

        self._motion_sock: Connection | None = None
        self._motion_reader: FrameReader | None = None
        self._motion_lock = threading.Lock()
        self._motion_error: DriverError | None = None
        self._next_seq = 0
        # Sequences of requests whose reply timed out: their replies may still come.
        self._late: list[int] = []

    @classmethod
    def from_url(cls, url: str, **kwargs: Any) -> SimpleMessageController:
        """Build from ``tcp://HOST:PORT[?state=PORT]``; keyword arguments as the constructor."""
        address = parse_controller_url(url)
        return cls(address.host, address.motion_port, address.state_port, **kwargs)

    @property
    def endpoint(self) -> str:
        return self._address.url

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
        self._motion_sock = motion
        self._motion_reader = FrameReader(self.device, self.endpoint)
        self._motion_error = None
        self._next_seq = 0
        self._late = []
        self._start_stream(state)
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
                data = sock.recv(RECV_SIZE)
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
        log.debug("motion link failed: %s", error)  # raised: the caller reports it, once
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
                detail = f"; it reports {describe_status(st)}"
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
        except DeviceTimeout as e:
            with self._cond:
                last = None if self._joints_deg is None else np.round(self._joints_deg, 4)
            if last is None:
                raise
            detail = str(e).removeprefix(f"{self.device} at {self.endpoint}: ")
            raise DeviceTimeout(
                self.device, self.endpoint, f"{detail}; last readings {last.tolist()} deg"
            ) from None

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
                log.warning("controller at %s answered FAILURE to STOP", self.endpoint)
        except DriverError as e:
            log.warning("STOP not confirmed: %s", e)
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
            log.warning("STOP could not be sent to %s: %s (%s)", self.endpoint, e, why)
