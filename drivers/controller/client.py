"""Robot controller over ROS-Industrial Simple Message (the Staubli VAL3 server's protocol).

Two TCP connections, as the VAL3 server expects them (``val3/ros_server``):

* motion port (default 11000): the client sends JOINT_TRAJ_PT as SERVICE_REQUEST, one request
  at a time, and reads the SERVICE_REPLY that acknowledges *enqueueing* the point (not its
  execution; REP-I0006).
* state port (default 11002): the server streams joint state (JOINT_POSITION, or JOINT_FEEDBACK
  on current VAL3 servers) and STATUS. A background thread keeps the latest of each and a
  bounded history of timestamped joint samples.

Units at the interface are degrees and seconds; radians exist only on the wire.
"""

from __future__ import annotations

import collections
import logging
import math
import socket
import threading
import time

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


def _velocity_on_wire(speed: float) -> float:
    """The velocity fraction to send for ``speed``.

    The VAL3 server rounds the received velocity to four decimals and, when the result is
    exactly 0.1 and the sequence is not 0, replaces it by a linear extrapolation of the two
    previous points' velocities (``val3/ros_server/decTrajPt.pgx``, "Smooth last point in
    traj"). After a fast point that extrapolation can exceed what was asked for, so a request
    for 10 % is sent as 10.01 %.
    """
    if round(speed, 4) == 0.1:
        return 0.1001
    return speed


class SimpleMessageController(RobotController):
    """Six-axis controller driven through a Simple Message server (motion + state ports).

    ``connect_timeout_s`` bounds each TCP connect; ``reply_timeout_s`` the wait for the reply to
    a JOINT_TRAJ_PT request; ``state_timeout_s`` how long the state stream may stay silent
    before the link is declared dead (the VAL3 server streams every few milliseconds).
    ``history_size`` bounds the joint-sample history kept for ``joint_samples``. ``clock``
    stamps the state frames and times the waits on them (``drivers.clock``: the host's
    monotonic clock on a real cell, simulated time against an in-process simulated cell).
    """

    def __init__(self, host: str = "127.0.0.1", motion_port: int = DEFAULT_MOTION_PORT,
                 state_port: int = DEFAULT_STATE_PORT, *, connect_timeout_s: float = 2.0,
                 reply_timeout_s: float = 2.0, state_timeout_s: float = 1.0,
                 history_size: int = 65536, clock: Clock = HOST_CLOCK):
        for name, value in (("connect_timeout_s", connect_timeout_s),
                            ("reply_timeout_s", reply_timeout_s),
                            ("state_timeout_s", state_timeout_s)):
            if not (value > 0 and math.isfinite(value)):
                raise ValueError(f"{name} must be a positive number of seconds, got {value}")
        if history_size < 1:
            raise ValueError(f"history_size must be at least 1, got {history_size}")
        self._address = ControllerAddress(host, int(motion_port), int(state_port))
        self.connect_timeout_s = connect_timeout_s
        self.reply_timeout_s = reply_timeout_s
        self.state_timeout_s = state_timeout_s
        self._history_size = history_size
        self.clock = clock

        self._motion_sock: socket.socket | None = None
        self._motion_reader: FrameReader | None = None
        self._motion_lock = threading.Lock()
        self._motion_error: DriverError | None = None
        self._next_seq = 0

        self._state_sock: socket.socket | None = None
        self._state_thread: threading.Thread | None = None
        self._closing = threading.Event()
        # Guards everything below; notified on every state frame and when the link dies.
        self._cond = threading.Condition()
        self._joints_deg: np.ndarray | None = None
        self._joints_t = 0.0
        self._status: ControllerStatus | None = None
        self._status_t = 0.0
        self._last_frame_t = 0.0
        self._accepted_t = 0.0
        self._state_error: DriverError | None = None
        self._samples: collections.deque[JointSample] = collections.deque(maxlen=history_size)

    @classmethod
    def from_url(cls, url: str, **kwargs: float) -> SimpleMessageController:
        """Build from ``tcp://HOST:PORT[?state=PORT]``; keyword arguments as the constructor."""
        address = parse_controller_url(url)
        return cls(address.host, address.motion_port, address.state_port, **kwargs)

    @property
    def endpoint(self) -> str:
        return self._address.url

    # -- connection -------------------------------------------------------------------------

    def _open(self, port: int, what: str) -> socket.socket:
        try:
            sock = socket.create_connection((self._address.host, port),
                                            timeout=self.connect_timeout_s)
        except TimeoutError:
            raise DeviceTimeout(self.device, self.endpoint,
                                f"no answer connecting to the {what} port {port} within "
                                f"{self.connect_timeout_s:g} s") from None
        except OSError as e:
            raise ConnectionLost(self.device, self.endpoint,
                                 f"cannot connect to the {what} port {port}: "
                                 f"{e.strerror or e}") from None
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        return sock

    def connect(self) -> None:
        """Open the motion and state connections and start the state reader thread."""
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
            self._last_frame_t = self.clock.now()
        self._motion_sock, self._state_sock = motion, state
        self._motion_reader = FrameReader(self.device, self.endpoint)
        self._motion_error = None
        self._next_seq = 0
        self._state_thread = threading.Thread(
            target=self._state_loop, args=(state, FrameReader(self.device, self.endpoint)),
            name=f"controller-state {self.endpoint}", daemon=True)
        self._state_thread.start()
        log.info("connected to controller at %s", self.endpoint)

    def close(self) -> None:
        """Close both connections and stop the reader thread. Idempotent."""
        self._closing.set()
        for sock in (self._motion_sock, self._state_sock):
            if sock is not None:
                try:
                    sock.shutdown(socket.SHUT_RDWR)
                except OSError:
                    pass  # already reset by the peer
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

    def _state_loop(self, sock: socket.socket, reader: FrameReader) -> None:
        debug = log.isEnabledFor(logging.DEBUG)
        while not self._closing.is_set():
            try:
                data = sock.recv(_RECV_SIZE)
            except TimeoutError:
                continue
            except OSError as e:
                if not self._closing.is_set():
                    self._state_failed(ConnectionLost(
                        self.device, self.endpoint, f"state connection failed: {e}"))
                return
            if not data:
                if not self._closing.is_set():
                    self._state_failed(ConnectionLost(
                        self.device, self.endpoint, "state connection closed by the controller"))
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

    def _on_state_messages(self, messages: list[Message], now: float) -> int:
        """Keep the latest joints and status; return how many joint frames there were."""
        joint_frames = 0
        with self._cond:
            self._last_frame_t = now
            for msg in messages:
                if isinstance(msg, (JointPosition, JointFeedback)):
                    rad = msg.joints_rad if isinstance(msg, JointPosition) else msg.positions_rad
                    joints = np.degrees(np.asarray(rad[:N_JOINTS], dtype=float))
                    self._joints_deg, self._joints_t = joints, now
                    self._samples.append(JointSample(now, joints))
                    joint_frames += 1
                elif isinstance(msg, Status):
                    self._status, self._status_t = _status_from_message(msg), now
                else:
                    # REP-I0006: receivers ignore topic messages they do not use.
                    log.warning("controller at %s: ignoring %s on the state port",
                                self.endpoint, type(msg).__name__)
            self._cond.notify_all()
        return joint_frames

    def _state_failed(self, error: DriverError) -> None:
        log.error("%s", error)
        with self._cond:
            self._state_error = error
            self._cond.notify_all()

    def _check_state_locked(self, now: float) -> None:
        """Raise if the state link is closed, broken or silent (caller holds ``_cond``)."""
        if self._state_error is not None:
            raise self._state_error
        if self._state_sock is None:
            raise ConnectionLost(self.device, self.endpoint, "not connected")
        silent = now - self._last_frame_t
        if silent > self.state_timeout_s:
            raise DeviceTimeout(self.device, self.endpoint,
                                f"no state message for {silent:.2f} s "
                                f"(limit {self.state_timeout_s:g} s)")

    def _wait_for(self, predicate, timeout_s: float, what: str):
        """Wait until ``predicate()`` (called with ``_cond`` held) returns non-None."""
        deadline = self.clock.now() + timeout_s
        with self._cond:
            while True:
                now = self.clock.now()
                self._check_state_locked(now)
                value = predicate()
                if value is not None:
                    return value
                remaining = deadline - now
                if remaining <= 0:
                    raise DeviceTimeout(self.device, self.endpoint,
                                        f"no {what} within {timeout_s:g} s")
                # Wake in time to notice a silent stream as well as the deadline.
                self.clock.wait(self._cond, min(remaining, self.state_timeout_s / 2))

    def read_joints(self, timeout_s: float = 2.0) -> np.ndarray:
        """Latest joint readings (deg, (6,)), waiting at most ``timeout_s`` for a first one."""
        joints = self._wait_for(lambda: self._joints_deg, timeout_s, "joint position")
        return joints.copy()

    def status(self, timeout_s: float = 2.0) -> ControllerStatus:
        """Latest STATUS, waiting at most ``timeout_s`` for a first one."""
        return self._wait_for(lambda: self._status, timeout_s, "status message")

    def joint_samples(self, since_t_s: float = 0.0) -> list[JointSample]:
        """Streamed joint positions received at or after ``since_t_s`` (``clock`` time, s)."""
        with self._cond:
            return [s for s in self._samples if s.t_s >= since_t_s]

    # -- motion -----------------------------------------------------------------------------

    def _send(self, sock: socket.socket, frame: bytes) -> None:
        if log.isEnabledFor(logging.DEBUG):
            log.debug("WRITE: motion %s", frame.hex())
        sock.sendall(frame)

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
                    raise self._motion_failed(ConnectionLost(
                        self.device, self.endpoint, "motion connection closed by the controller"))
                if log.isEnabledFor(logging.DEBUG):
                    log.debug("READ: motion %s", data.hex())
                for reply in reader.feed(data):
                    if isinstance(reply, JointTrajPtReply) and (
                            reply.sequence is None or reply.sequence == msg.sequence):
                        return reply
                    # REP-I0006: ignore replies with no outstanding request (e.g. the late
                    # answer to a request that timed out) and topics we do not use.
                    log.warning("controller at %s: ignoring %s on the motion port while "
                                "waiting for the reply to sequence %d", self.endpoint, reply,
                                msg.sequence)
        except TimeoutError:
            raise DeviceTimeout(self.device, self.endpoint,
                                f"no reply to trajectory point {msg.sequence} within "
                                f"{timeout_s:g} s") from None
        except ProtocolError as e:
            raise self._motion_failed(e) from None
        except OSError as e:
            raise self._motion_failed(ConnectionLost(
                self.device, self.endpoint, f"motion connection failed: {e}")) from None

    def _motion_failed(self, error: DriverError) -> DriverError:
        log.error("%s", error)
        self._motion_error = error
        return error

    def start_move(self, target_deg: np.ndarray, speed: float = 0.5) -> None:
        """Send a joint target (deg, (6,)) at ``speed`` (fraction of maximum, (0, 1]).

        Returns once the controller accepted the point. Raises ``MotionRejected`` when it
        answers FAILURE, ``ConnectionLost``/``DeviceTimeout``/``ProtocolError`` on link faults,
        ``ValueError`` for a malformed target or speed.
        """
        target = np.asarray(target_deg, dtype=float).reshape(-1)
        if target.shape != (N_JOINTS,) or not np.all(np.isfinite(target)):
            raise ValueError(f"target_deg must be {N_JOINTS} finite numbers, got {target_deg!r}")
        if not (0.0 < speed <= 1.0):
            raise ValueError(f"speed must be in (0, 1], got {speed}")
        with self._cond:
            self._check_state_locked(self.clock.now())
        with self._motion_lock:
            seq = self._next_seq
            msg = JointTrajPt(seq, tuple(np.radians(target)), _velocity_on_wire(speed), 0.0)
            reply = self._request(msg, self.reply_timeout_s)
            self._next_seq = seq + 1
        accepted_t = self.clock.now()
        if not reply.success:
            detail = ""
            with self._cond:
                st = self._status
            if st is not None:
                detail = (f"; status: powered={st.drives_powered}, e-stopped={st.e_stopped}, "
                          f"in error={st.in_error} (code {st.error_code})")
            raise MotionRejected(self.device, self.endpoint,
                                 f"trajectory point {seq} to {np.round(target, 4).tolist()} deg "
                                 f"at speed {speed:g} refused (reply code {reply.reply_code})"
                                 f"{detail}")
        with self._cond:
            self._accepted_t = accepted_t
        log.info("controller accepted point %d: %s deg at speed %g", seq,
                 np.round(target, 4).tolist(), speed)

    def wait_settled(self, target_deg: np.ndarray, timeout_s: float,
                     tol_deg: float = 1e-3) -> np.ndarray:
        """Block until STATUS says not in motion and every joint is within ``tol_deg`` of target.

        Only STATUS and joint messages received after the last accepted point count. Returns
        the settled readings (deg). Raises ``DeviceTimeout`` after ``timeout_s``,
        ``ConnectionLost`` as soon as the state stream dies, ``DeviceError`` as soon as the
        controller reports an e-stop, an error or unpowered drives.
        """
        target = np.asarray(target_deg, dtype=float).reshape(-1)
        if target.shape != (N_JOINTS,):
            raise ValueError(f"target_deg must have {N_JOINTS} elements, got {target_deg!r}")

        def settled() -> np.ndarray | None:
            st, joints = self._status, self._joints_deg
            if st is None or joints is None:
                return None
            if self._status_t <= self._accepted_t or self._joints_t <= self._accepted_t:
                return None
            if st.e_stopped or st.in_error or st.drives_powered is False:
                raise DeviceError(self.device, self.endpoint,
                                  f"controller stopped the motion: e-stopped={st.e_stopped}, "
                                  f"in error={st.in_error} (code {st.error_code}), "
                                  f"powered={st.drives_powered}")
            if st.in_motion is False and np.max(np.abs(joints - target)) <= tol_deg:
                return joints.copy()
            return None

        try:
            return self._wait_for(settled, timeout_s, f"settling within {tol_deg:g} deg of "
                                                      f"{np.round(target, 4).tolist()} deg")
        except DeviceTimeout:
            with self._cond:
                last = None if self._joints_deg is None else np.round(self._joints_deg, 4)
            if last is not None:
                log.error("controller at %s did not settle; last readings %s deg",
                          self.endpoint, last.tolist())
            raise

    def stop(self) -> None:
        """Send STOP_TRAJECTORY (sequence -4). Never raises; failures are logged."""
        sock = self._motion_sock
        if sock is None:
            log.debug("stop: not connected to %s", self.endpoint)
            return
        msg = JointTrajPt(SpecialSeq.STOP_TRAJECTORY, (), 0.0, 0.0, CommType.SERVICE_REQUEST)
        if not self._motion_lock.acquire(timeout=self.reply_timeout_s):
            # Another thread is stuck waiting for a reply: send anyway, do not read its answer.
            try:
                self._send(sock, msg.pack())
                log.warning("stop sent to %s without waiting for its reply", self.endpoint)
            except OSError as e:
                log.error("stop could not be sent to %s: %s", self.endpoint, e)
            return
        try:
            reply = self._request(msg, min(self.reply_timeout_s, 1.0))
            # REP-I0006: a new trajectory starts at sequence 0.
            self._next_seq = 0
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
