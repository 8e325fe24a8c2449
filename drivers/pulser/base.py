"""The pulser-receiver interface that procedures depend on.

Units: gain in dB, PRF in Hz, gate start/width in µs of round-trip time, time of flight in
nanoseconds (round trip, transmit to echo peak), amplitude as a fraction of full screen height
(0…1, may saturate at 1 with high gain).
"""

from __future__ import annotations

import abc
from dataclasses import dataclass
from typing import Self

import numpy as np


@dataclass(frozen=True)
class PulserSettings:
    """Acquisition settings of the pulser-receiver."""

    gain_db: float = 20.0
    prf_hz: float = 1000.0
    gate_start_us: float = 5.0
    gate_width_us: float = 200.0
    averages: int = 1


@dataclass(frozen=True)
class GateReading:
    """One gated reading: peak amplitude, time of flight at the peak, counter, device time.

    ``tof_ns`` is NaN when no echo crossed the gate threshold. ``counter`` increments with each
    new acquisition; ``device_time_s`` is the device clock at acquisition; ``host_time_s`` the
    host monotonic clock when the reading arrived (for pairing with streamed joint positions).
    """

    amplitude: float
    tof_ns: float
    counter: int
    device_time_s: float
    host_time_s: float

    @property
    def has_echo(self) -> bool:
        return bool(np.isfinite(self.tof_ns))


class PulserReceiver(abc.ABC):
    """An ultrasonic pulser-receiver. Use as a context manager."""

    device = "pulser"

    @property
    @abc.abstractmethod
    def endpoint(self) -> str:
        """Where the pulser is (e.g. ``modbus-tcp://127.0.0.1:5020?unit=1``)."""

    @abc.abstractmethod
    def connect(self) -> None:
        """Open the connection; raise ``ConnectionLost`` or ``DeviceTimeout`` on failure."""

    @abc.abstractmethod
    def close(self) -> None:
        """Close the connection. Idempotent."""

    @abc.abstractmethod
    def configure(self, settings: PulserSettings) -> None:
        """Write the settings; validators raise ``ValueError`` for out-of-range values."""

    @abc.abstractmethod
    def settings(self) -> PulserSettings:
        """Read the settings back from the device."""

    @abc.abstractmethod
    def read_gate(self, fresh: bool = True, timeout_s: float = 1.0) -> GateReading:
        """One gated reading. With ``fresh`` wait for a counter newer than the last one read."""

    def read_ascan(self, timeout_s: float = 2.0) -> tuple[np.ndarray, float] | None:
        """Optional: A-scan samples (normalised, (n,)) and sample rate (Hz); None if unsupported."""
        return None

    def __enter__(self) -> Self:
        self.connect()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
