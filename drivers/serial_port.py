"""Serial ports for the drivers: a device path, or a pyserial URL such as ``socket://HOST:PORT``
(a serial-to-Ethernet converter, or a simulated device on 127.0.0.1).

``SocketPort`` is pyserial's ``socket://`` port with two corrections a request/reply protocol
needs; ``open_port`` opens any DEVICE with it where it applies.
"""

from __future__ import annotations

import contextlib
import select
import socket
from typing import Any

import serial
from serial.urlhandler.protocol_socket import Serial as _PyserialSocket


# pyserial has no type information, so its class is Any here: subclassing it is reported only
# under --strict (disallow_subclassing_any), hence the second code for the project's own config.
class SocketPort(_PyserialSocket):  # type: ignore[misc, unused-ignore]
    """pyserial's ``socket://`` port with an exact ``in_waiting``, a close without delay and
    no Nagle delay.

    pyserial reports at most 1 byte waiting on a socket, so a receiver that reads what is
    waiting would read a frame one byte per poll (~1 ms each); peeking gives the real count.
    pyserial also sleeps 0.3 s in ``close()``; a closed TCP stream needs no such pause. A
    command written just after another would wait for the first one's acknowledgement (Nagle's
    algorithm against the peer's delayed ACK: up to 40 ms); a serial line sends at once.
    """

    # Set by pyserial's ``open()``/``close()``; declared for the overrides below.
    is_open: bool
    _socket: socket.socket | None

    def open(self) -> None:
        """Connect, with TCP_NODELAY."""
        super().open()
        if self._socket is not None:
            self._socket.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)

    @property
    def in_waiting(self) -> int:
        """Return the number of bytes received and not yet read."""
        if not self.is_open or self._socket is None:
            return int(super().in_waiting)
        ready, _, _ = select.select([self._socket], [], [], 0)
        if not ready:
            return 0
        try:
            peeked = self._socket.recv(65536, socket.MSG_PEEK)
        except BlockingIOError:
            return 0
        return max(len(peeked), 1)  # 1 at EOF, so that read() reports the disconnect

    def close(self) -> None:
        """Close the TCP stream."""
        if self.is_open and self._socket is not None:
            with contextlib.suppress(OSError):
                self._socket.shutdown(socket.SHUT_RDWR)
            self._socket.close()
            self._socket = None
        self.is_open = False


def open_port(device: str, baud: int, timeout_s: float, **line: Any) -> Any:
    """Open ``device`` (a path or a pyserial URL) at ``baud`` with ``timeout_s`` reads;
    ``line`` adds pyserial settings (``parity``, ``bytesize``, ``stopbits``). Raises
    ``serial.SerialException`` or ``OSError`` when it cannot."""
    if device.startswith("socket://"):
        port = SocketPort(None, timeout=timeout_s)
        port.port = device
        port.open()
        return port
    return serial.serial_for_url(device, baudrate=baud, timeout=timeout_s, **line)
