"""The pulser-receiver interface that procedures depend on.

Units: gain in dB, PRF in Hz, gate start/width in µs of round-trip time, time of flight in
nanoseconds (round trip, transmit to echo peak), amplitude as a fraction of full screen height
(0…1, may saturate at 1 with high gain).
"""

from __future__ import annotations

import abc
import math
from dataclasses import dataclass

import numpy as np

from drivers.device import Device


@dataclass(frozen=True)
class PulserSettings:
    """Acquisition settings of the pulser-receiver.

    Receiver: ``gain_db`` (dB), gate start and width (µs of round-trip time), ``averages``
    (acquisitions per reading), band-pass filter ``high_pass_mhz`` … ``low_pass_mhz`` (MHz;
    a high-pass of 0 lets DC through). Pulser: ``prf_hz`` (Hz), ``pulse_voltage_v`` (V, the
    spike or square-pulse amplitude that sets the pulse energy), ``damping_ohm`` (Ω across the
    transducer: lower damps the ringing and shortens the pulse).

    Construction checks what is physically meaningless (not a finite number, a negative or zero
    rate, voltage or damping, a filter band that is empty) and raises ``ValueError`` naming the
    field; a device's own ranges are checked by its driver before anything is written. Nothing
    is clipped.
    """

    gain_db: float = 20.0
    prf_hz: float = 1000.0
    gate_start_us: float = 5.0
    gate_width_us: float = 200.0
    averages: int = 1
    pulse_voltage_v: float = 100.0
    damping_ohm: float = 50.0
    high_pass_mhz: float = 1.0
    low_pass_mhz: float = 50.0

    def __post_init__(self) -> None:
        for name in (
            "gain_db",
            "prf_hz",
            "gate_start_us",
            "gate_width_us",
            "pulse_voltage_v",
            "damping_ohm",
            "high_pass_mhz",
            "low_pass_mhz",
        ):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(
                value, (int, float, np.integer, np.floating)
            ):
                raise ValueError(f"{name} must be a number, got {value!r}")
            if not math.isfinite(value):
                raise ValueError(f"{name} must be finite, got {value!r}")
        for name in ("prf_hz", "gate_width_us", "pulse_voltage_v", "damping_ohm"):
            if getattr(self, name) <= 0:
                raise ValueError(f"{name} must be positive, got {getattr(self, name)!r}")
        for name in ("gate_start_us", "high_pass_mhz"):
            if getattr(self, name) < 0:
                raise ValueError(f"{name} must not be negative, got {getattr(self, name)!r}")
        averages = self.averages
        if (
            isinstance(averages, bool)
            or not isinstance(averages, (int, float, np.integer, np.floating))
            or not math.isfinite(averages)
            or averages != round(averages)
            or averages < 1
        ):
            raise ValueError(f"averages must be an integer >= 1, got {averages!r}")
        if self.low_pass_mhz <= self.high_pass_mhz:
            raise ValueError(
                f"low_pass_mhz = {self.low_pass_mhz!r} MHz must be above "
                f"high_pass_mhz = {self.high_pass_mhz!r} MHz (empty filter band)"
            )

    @property
    def gate_ns(self) -> tuple[float, float]:
        """The gate's start and end, ns of round-trip time."""
        start_ns = self.gate_start_us * 1e3
        return start_ns, start_ns + self.gate_width_us * 1e3

    @property
    def acquisition_s(self) -> float:
        """The time one reading's acquisition takes, s: ``averages`` pulses at ``prf_hz``
        (1 s for 1,000 averages at 1 kHz)."""
        return int(self.averages) / float(self.prf_hz)


@dataclass(frozen=True)
class ReadingWait:
    """How long one reading may take, s: what the instrument was asked to do, then the link's
    own margin.

    The rule of every back-end: a reading's deadline (``total_s``) is its acquisition
    (``acquisition_s``: ``averages`` pulses at ``prf_hz``), plus ``transfer_s``, the time its
    bytes take on the link where the back-end knows it (a Modbus RTU line at its baud; 0 where
    it is negligible), plus ``link_s``, the back-end's ``timeout_s``: the answer's latency and
    a busy host, no longer the whole wait. 1,000 averages at 1 kHz with ``timeout_s = 1`` wait
    2 s; 16 averages at 1 kHz wait 1.016 s.
    """

    averages: int
    prf_hz: float
    link_s: float
    transfer_s: float = 0.0

    @classmethod
    def of(cls, settings: PulserSettings, link_s: float, transfer_s: float = 0.0) -> ReadingWait:
        """The wait of a reading taken with ``settings``."""
        return cls(int(settings.averages), float(settings.prf_hz), float(link_s), transfer_s)

    @property
    def acquisition_s(self) -> float:
        """The pulses averaged, s."""
        return self.averages / self.prf_hz

    @property
    def total_s(self) -> float:
        """The reading's deadline from its start, s."""
        return self.acquisition_s + self.transfer_s + self.link_s

    def describe(self) -> str:
        """What the wait is made of, for a timeout's message: ``1 s averaging 1000 pulses at
        1000 Hz, then timeout_s = 1 s for the link``."""
        pulses = "pulse" if self.averages == 1 else "pulses"
        line = f", {self.transfer_s:.2g} s on the line" if self.transfer_s > 0 else ""
        return (
            f"{self.acquisition_s:.3g} s averaging {self.averages} {pulses} at "
            f"{self.prf_hz:g} Hz{line}, then timeout_s = {self.link_s:g} s for the link"
        )


@dataclass(frozen=True)
class GateReading:
    """One gated reading: peak amplitude, time of flight at the peak, counter, device time.

    ``tof_ns`` is NaN when no echo crossed the gate threshold. ``counter`` increments with each
    new acquisition; ``device_time_s`` is the device clock at acquisition; ``host_time_s`` the
    host monotonic clock when the reading arrived (for pairing with streamed joint positions).
    ``tof_std_ns`` is one sigma of ``tof_ns`` when the one who timed the echo knows it (an
    echo timed on the host from the A-scan: its SNR and bandwidth); NaN for a device's gate,
    which does not say.
    """

    amplitude: float
    tof_ns: float
    counter: int
    device_time_s: float
    host_time_s: float
    tof_std_ns: float = math.nan

    @property
    def has_echo(self) -> bool:
        return bool(np.isfinite(self.tof_ns))


class PulserReceiver(Device):
    """An ultrasonic pulser-receiver (endpoint e.g. ``modbus-tcp://127.0.0.1:5020?unit=1``).

    Use as a context manager. ``clock`` stamps ``GateReading.host_time_s``.
    """

    device = "pulser"

    @abc.abstractmethod
    def configure(self, settings: PulserSettings) -> dict[str, dict[str, float]] | None:
        """Write the settings; validators raise ``ValueError`` for out-of-range values.

        A device that takes its own steps of a setting (an indexed damping, a gain in 0.1 dB)
        returns what was asked and what it set, ``{name: {"asked": x, "set": y}}``, so that a
        run's record holds both; None: every setting is set as asked."""

    def check_settings(self, settings: PulserSettings) -> None:
        """Raise ``ValueError``, as ``configure`` would, for a setting the device cannot take,
        writing nothing: what a run checks before its first motion. The base checks what
        ``PulserSettings`` itself holds (done when it is built); a back-end with its own
        ranges (a register map, a digitiser's average counts) checks those."""

    @abc.abstractmethod
    def settings(self) -> PulserSettings:
        """Read the settings back from the device."""

    @abc.abstractmethod
    def read_gate(self, fresh: bool = True, timeout_s: float | None = None) -> GateReading:
        """One gated reading. With ``fresh`` wait for a counter newer than the last one read.
        The wait is bounded by what the reading asks of the instrument and the link's margin
        (``ReadingWait``): ``timeout_s`` is that margin (None: the back-end's own)."""

    def identity(self) -> dict[str, object]:
        """Optional: what the device tells about itself (model, firmware, serial, …)."""
        return {}

    def read_ascan(self, timeout_s: float = 2.0) -> tuple[np.ndarray, float] | None:
        """Optional: A-scan samples (normalised, (n,)) and sample rate (Hz); None if unsupported."""
        return None
