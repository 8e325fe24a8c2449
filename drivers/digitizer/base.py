"""What a digitiser gives, and how a host times the echo in it.

``AScanRecord`` is one record: sample k at ``t0_ns + k·dt_ns``, with what the instrument says
about it (its rails and quantisation step, whether a sample was clipped, how many acquisitions
it averages, its place in the acquisition count, when it arrived). A digitiser returns it in
volts; a pulser back-end that digitises (``drivers.pulser.ascii.AsciiScpiPulser``) rescales it
to fractions of full screen height, the unit of ``GateReading.amplitude``.

``EchoTimer`` is the contract of the echo estimator a back-end that only digitises needs: the
maths lives in the application (``ucal.echo``), which ``drivers`` never imports, so the
application injects it (``HostTimed.echo_timer``): a callable ``(record, gate_ns) ->
EchoTiming``. A timer may say how much of a record it reads around the echo (a method
``window_ns(dt_ns)``: the half width, ns); a back-end that transfers records by parts
(``drivers.pulser.modbus``) transfers no more than that.
"""

from __future__ import annotations

import abc
import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Protocol, runtime_checkable

import numpy as np

from drivers.device import Device


@dataclass(frozen=True)
class AScanRecord:
    """One digitised record: ``samples[k]`` taken ``t0_ns + k·dt_ns`` after the trigger.

    ``rails``: the lowest and highest value a sample can take (a sample on one is clipped);
    ``lsb``: the quantisation step; both in the samples' unit. ``clipped``: some sample sits on
    a rail. ``averages``: acquisitions averaged into it. ``counter``: acquisitions made since
    the connection opened (this one included). ``host_time_s``: the host clock when it arrived.
    """

    t0_ns: float
    dt_ns: float
    samples: np.ndarray = field(repr=False)
    rails: tuple[float, float]
    lsb: float
    clipped: bool
    averages: int
    counter: int
    host_time_s: float

    def __post_init__(self) -> None:
        if not (math.isfinite(self.dt_ns) and self.dt_ns > 0.0):
            raise ValueError(f"sample interval must be positive, got {self.dt_ns} ns")

    @property
    def n(self) -> int:
        """Number of samples."""
        return int(np.size(self.samples))

    @property
    def sample_rate_hz(self) -> float:
        """Samples per second."""
        return 1e9 / self.dt_ns

    def scaled(self, factor: float) -> AScanRecord:
        """The same record with samples, rails and step multiplied by ``factor`` (> 0)."""
        return replace(
            self,
            samples=np.asarray(self.samples, float) * factor,
            rails=(self.rails[0] * factor, self.rails[1] * factor),
            lsb=self.lsb * factor,
        )


@dataclass(frozen=True)
class EchoTiming:
    """The echo a host found in a record: its amplitude (the record's unit), its round-trip
    time of flight and one sigma (ns; NaN when there is no echo to time), how it was timed,
    and whether samples of it were clipped."""

    amplitude: float
    tof_ns: float
    tof_std_ns: float
    method: str
    clipped: bool = False


#: ``(record, (gate start, gate end) ns) -> EchoTiming``: the strongest echo in the gate.
EchoTimer = Callable[[AScanRecord, tuple[float, float]], EchoTiming]


def left_aligned_step(codes: np.ndarray) -> int:
    """The ADC's step in ``codes`` (integers, 0 = the ADC's zero): the largest power of two
    that divides every one, as an ADC of fewer bits left-aligned in wider words gives them;
    1 when every code is 0 (nothing shows)."""
    # two's complement keeps a number's trailing zeros: the OR of the codes has the lowest
    # set bit of the smallest step
    codes = np.asarray(codes, np.int64)
    bits = int(np.bitwise_or.reduce(codes)) if codes.size else 0
    return bits & -bits if bits else 1


def timer_window_ns(timer: EchoTimer, dt_ns: float, default_ns: float) -> float:
    """Half width (ns) of the record ``timer`` reads around an echo (its ``window_ns``), else
    ``default_ns``."""
    window = getattr(timer, "window_ns", None)
    return float(window(dt_ns)) if callable(window) else float(default_ns)


@runtime_checkable
class HostTimed(Protocol):
    """A back-end whose time of flight is computed on the host from its A-scan: the
    application gives it an ``EchoTimer`` before the first reading."""

    echo_timer: EchoTimer | None


class Digitizer(Device):
    """An instrument that records the receiver's RF output (endpoint e.g.
    ``visa://TCPIP::127.0.0.1::5025::SOCKET``). Use as a context manager; ``connect`` also sets
    the instrument up for single acquisitions. ``clock`` stamps ``AScanRecord.host_time_s``.
    """

    device = "digitizer"

    @abc.abstractmethod
    def configure(self, start_ns: float, width_ns: float, averages: int) -> None:
        """Record ``width_ns`` from ``start_ns`` after the trigger, averaging ``averages``
        acquisitions (1 = none); ``ValueError`` for what the instrument cannot do."""

    def check(self, start_ns: float, width_ns: float, averages: int) -> None:
        """Raise ``ValueError``, as ``configure`` would, for a window or average count the
        instrument cannot take, sending nothing (the base takes any)."""

    @abc.abstractmethod
    def acquire(self, timeout_s: float | None = None, acquisition_s: float = 0.0) -> AScanRecord:
        """Make one acquisition (averaged as configured) and return its record in volts.

        ``timeout_s`` is the link's margin of each answer (None: the instrument's own);
        ``acquisition_s`` (s) what the acquisition itself takes beyond it, its averages at
        the trigger's rate (the pulser's PRF, which the instrument is not told)."""

    def identity(self) -> dict[str, object]:
        """What the instrument tells about itself."""
        return {}
