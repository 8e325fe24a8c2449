"""The transport of an oscilloscope over PyVISA: bytes to and from a message-based resource.

:class:`ScpiTransport` is what ``drivers.digitizer.visa.ScpiScope`` needs of a link (write a
program message, read an answer line, read n bytes, close); :class:`PyVisaTransport` gives it
over a PyVISA resource, which :func:`open_visa_resource` opens with the VISA library named
(``"@py"``: pyvisa-py) and LF as its read termination, Nagle's delay off. :func:`is_timeout`
tells a VISA or socket timeout from another failure.
"""

from __future__ import annotations

import socket
from typing import Any, Protocol

from drivers.digitizer import scpi


class ScpiTransport(Protocol):
    """Bytes to and from a message-based instrument."""

    def write(self, message: str) -> None:
        """Send one program message (the terminator is added)."""
        ...

    def read_line(self, timeout_s: float) -> str:
        """One answer line, its terminator stripped."""
        ...

    def read_exact(self, n: int, timeout_s: float) -> bytes:
        """Exactly ``n`` bytes."""
        ...

    def close(self) -> None:
        """Close. Idempotent."""
        ...


class PyVisaTransport:
    """:class:`ScpiTransport` over a PyVISA message-based resource (``write_raw``,
    ``read_raw``, ``read_bytes``, ``timeout`` in ms); the resource is opened with LF as its
    read termination."""

    def __init__(self, resource: Any):
        self.resource = resource
        self._timeout_ms: float | None = None

    def _timeout(self, timeout_s: float) -> None:
        ms = max(1.0, timeout_s * 1e3)
        if ms != self._timeout_ms:
            self.resource.timeout = ms
            self._timeout_ms = ms

    def write(self, message: str) -> None:
        self.resource.write_raw(message.encode("ascii") + scpi.TERMINATOR)

    def read_line(self, timeout_s: float) -> str:
        self._timeout(timeout_s)
        raw = bytes(self.resource.read_raw())
        if not raw.endswith(scpi.TERMINATOR):
            raise scpi.ScpiError(f"answer not terminated by LF: {raw[:64]!r}")
        return raw[:-1].decode("ascii", errors="replace").rstrip("\r")

    def read_exact(self, n: int, timeout_s: float) -> bytes:
        self._timeout(timeout_s)
        data = bytes(self.resource.read_bytes(n, break_on_termchar=False))
        if len(data) != n:
            raise scpi.ScpiError(f"expected {n} bytes, got {len(data)}")
        return data

    def close(self) -> None:
        self.resource.close()


def open_visa_resource(resource: str, backend: str, timeout_s: float) -> Any:
    """Open ``resource`` with PyVISA's ``backend`` (``"@py"``: pyvisa-py), LF read termination."""
    import pyvisa  # the VISA library is loaded when a scope is opened, not at import

    manager = pyvisa.ResourceManager(backend)
    handle = manager.open_resource(
        resource, read_termination="\n", write_termination="", timeout=timeout_s * 1e3
    )
    _no_delay(handle)
    return handle


def _no_delay(handle: Any) -> None:
    """Request/reply traffic: no Nagle delay on a small command written before the next (a
    family that takes one command a message writes several in a row; the second would wait for
    the scope's delayed acknowledgement of the first, 40 ms). ``VI_ATTR_TCPIP_NODELAY`` where
    the VISA library takes it; pyvisa-py's raw socket sessions refuse the attribute, so their
    socket is set directly. Nothing for a resource that is no TCP/IP one."""
    from pyvisa import constants

    try:
        handle.set_visa_attribute(constants.ResourceAttribute.tcpip_nodelay, True)
        return
    except Exception:  # not a TCP/IP resource, or a library without the attribute
        pass
    try:
        interface = handle.visalib.sessions[handle.session].interface
    except Exception:  # not pyvisa-py, or not a socket session
        return
    if isinstance(interface, socket.socket):
        interface.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)


def is_timeout(exc: Exception) -> bool:
    """Whether ``exc`` is a VISA timeout (``VI_ERROR_TMO``) or a socket timeout."""
    if isinstance(exc, TimeoutError):
        return True
    try:
        from pyvisa import constants, errors
    except ImportError:  # pragma: no cover - pyvisa is a dependency
        return False
    return (
        isinstance(exc, errors.VisaIOError) and exc.error_code == constants.StatusCode.error_timeout
    )
