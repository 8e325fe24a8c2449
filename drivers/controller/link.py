"""The Simple Message client's two TCP links: how a connection is opened, what the client
needs of it, and the timeouts that bound it (``drivers.controller.client``).

Timeouts are seconds, named as the client's constructor keywords; ``timeout_error`` is the
error of one of them running out, naming it.
"""

from __future__ import annotations

import socket
import struct
import sys
from typing import Protocol

from drivers.errors import DeviceTimeout

N_JOINTS = 6
RECV_SIZE = 4096
#: The state reader wakes at least this often (s) to notice close().
POLL_S = 0.1

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
TIMEOUT_LABELS = {
    "connect_timeout_s": "connect timeout",
    "first_state_timeout_s": "first-state timeout",
    "state_timeout_s": "state timeout",
    "reply_timeout_s": "reply timeout",
    "halt_timeout_s": "halt timeout",
    "settle_timeout_s": "settle timeout",
}


class Connection(Protocol):
    """What the client needs of a connected socket (``socket.socket`` has all of it)."""

    def settimeout(self, value: float | None) -> None: ...
    def recv(self, size: int) -> bytes: ...
    def sendall(self, data: bytes) -> None: ...
    def shutdown(self, how: int) -> None: ...
    def close(self) -> None: ...


#: Linux's ``SO_TIMESTAMPNS`` (and its control message ``SCM_TIMESTAMPNS``), which Python's
#: ``socket`` module does not name: the kernel stamps every segment it receives (realtime
#: clock, a ``struct timespec``), and ``recvmsg`` hands the stamp of the last one read over.
_SO_TIMESTAMPNS = 35
_TIMESPEC = struct.Struct("qq")
#: Control-message buffer of one stamp.
STAMP_SPACE = socket.CMSG_SPACE(_TIMESPEC.size) if hasattr(socket, "CMSG_SPACE") else 0


def enable_receive_stamps(sock: object) -> bool:
    """Ask the kernel to stamp what ``sock`` receives (Linux, a real socket); whether it does.

    A frame's arrival is then the kernel's, not the moment a thread of a loaded host got round
    to reading it: a reader scheduled late reads a frame that waited in the socket, and stamps
    it with the time it arrived, not the time it was read (``receive_stamp_s``)."""
    if not (sys.platform.startswith("linux") and isinstance(sock, socket.socket)):
        return False
    if not hasattr(sock, "recvmsg") or not STAMP_SPACE:
        return False
    try:
        sock.setsockopt(socket.SOL_SOCKET, _SO_TIMESTAMPNS, 1)
    except OSError:
        return False
    return True


def receive_stamp_s(ancillary: list[tuple[int, int, bytes]]) -> float | None:
    """When the kernel received the last segment of a ``recvmsg`` whose control messages are
    ``ancillary`` (s since the epoch, the host's realtime clock); None without a stamp."""
    for level, kind, data in ancillary:
        if level == socket.SOL_SOCKET and kind == _SO_TIMESTAMPNS and len(data) >= _TIMESPEC.size:
            sec, nsec = _TIMESPEC.unpack_from(data)
            return float(sec + 1e-9 * nsec)
    return None


def tcp_connect(host: str, port: int, timeout_s: float) -> socket.socket:
    """Open a TCP connection with Nagle's algorithm off (each frame goes out at once)."""
    sock = socket.create_connection((host, port), timeout=timeout_s)
    sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    return sock


def timeout_error(
    device: str, endpoint: str, name: str, value: float, detail: str
) -> DeviceTimeout:
    """The error of timeout ``name`` (a key of ``TIMEOUT_LABELS``), ``value`` s, running out."""
    return DeviceTimeout(
        device, endpoint, f"{TIMEOUT_LABELS[name]} ran out ({name} = {value:g} s): {detail}"
    )
