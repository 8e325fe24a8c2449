"""Typed driver faults; every message names the device and its endpoint."""

from __future__ import annotations


class DriverError(Exception):
    """Base of every hardware or communication fault raised by a driver."""

    def __init__(self, device: str, endpoint: str, message: str):
        self.device = device
        self.endpoint = endpoint
        super().__init__(f"{device} at {endpoint}: {message}")


class DeviceTimeout(DriverError):
    """A blocking call did not complete within its timeout."""


class ConnectionLost(DriverError):
    """The connection could not be opened or closed unexpectedly."""


class ProtocolError(DriverError):
    """Bytes that do not follow the protocol (bad length, bad frame, bad CRC, bad type)."""


class DeviceError(DriverError):
    """The device answered with an error (Modbus exception, controller in error, e-stop)."""


class MotionRejected(DriverError):
    """The controller refused a motion (target outside joint range, not powered, e-stopped)."""
