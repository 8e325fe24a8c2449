"""The Simple Message client's two TCP links: how a connection is opened, what the client
needs of it, and the timeouts that bound it (``drivers.controller.client``).

Timeouts are seconds, named as the client's constructor keywords; ``timeout_error`` is the
error of one of them running out, naming it.
"""

from __future__ import annotations

import socket
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
