"""A pulser-receiver whose echoes a digitiser records and the host times.

``DigitisedPulser`` is what the ASCII serial pulser (``drivers.pulser.ascii``) and the pulser
set by hand (``drivers.pulser.manual``) share: the digitiser that records the receiver's RF
output (``visa://RESOURCE``, or any digitiser whose URL scheme the registry knows,
``drivers.registry.open_digitizer``), the record rescaled from volts to fractions of full
screen height (``full_screen_v`` volts of RF output = 1.0, times the back-end's own factor,
``record_scale``), and the injected ``echo_timer`` (``drivers.digitizer.base.EchoTimer``; ucal
gives ``ucal.echo.host``'s) that returns the strongest echo in the gate; below the gate
threshold there is no time of flight.

A reading is always a new acquisition, so ``fresh`` costs nothing; ``counter`` is the
digitiser's acquisition count since the connection opened. The digitiser, triggered by the
pulser's sync output, completes an acquisition once it has averaged ``averages`` of them at the
pulser's PRF: that (``drivers.pulser.base.ReadingWait``, ``reading_wait``) plus ``timeout_s``,
the link's margin.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any

import numpy as np

from drivers.digitizer.base import AScanRecord, Digitizer, EchoTimer, EchoTiming
from drivers.pulser.base import GateReading, PulserReceiver, PulserSettings, ReadingWait
from drivers.registry import open_digitizer

#: Default time a reading may wait beyond its acquisition (the link's margin), s.
DEFAULT_TIMEOUT_S = 1.0
#: Gate threshold of the host's gate, fraction of full screen height: weaker echoes give no
#: time of flight (the Modbus pulser's power-on threshold).
DEFAULT_THRESHOLD = 0.02


class DigitisedPulser(PulserReceiver):
    """The digitiser side of a pulser-receiver timed on the host (module docstring).

    ``digitizer`` is the digitiser's URL (opened by the back-end of its scheme with
    ``digitizer_options``) or a ``Digitizer``; ``full_screen_v`` the RF output (V) that is full
    screen height; ``echo_timer`` times the echo in a record (ucal injects it; without one
    ``read_gate`` refuses). A subclass keeps the settings in effect in ``_settings`` (None:
    the defaults) and may scale the record further (``record_scale``). No I/O here.
    """

    def _attach(
        self,
        digitizer: str | Digitizer,
        timeout_s: float,
        full_screen_v: float,
        echo_timer: EchoTimer | None,
        digitizer_options: dict[str, Any] | None,
    ) -> None:
        """Set up the digitiser side (called by the subclass's ``__init__``)."""
        if not (math.isfinite(full_screen_v) and full_screen_v > 0):
            raise ValueError(f"full_screen_v must be a positive voltage, got {full_screen_v!r}")
        if isinstance(digitizer, str):
            digitizer = open_digitizer(
                digitizer,
                timeout_s=max(timeout_s, 2.0),
                full_scale_v=full_screen_v,
                **(digitizer_options or {}),
            )
        self.digitizer = digitizer
        self.full_screen_v = float(full_screen_v)
        self.echo_timer: EchoTimer | None = echo_timer
        self._timeout_s = float(timeout_s)
        self._threshold = DEFAULT_THRESHOLD
        self._settings: PulserSettings | None = None
        #: The echo of the last ``read_gate`` as the host timed it, and its record.
        self.last_echo: EchoTiming | None = None
        self.last_record: AScanRecord | None = None

    def record_scale(self) -> float:
        """What a record in fractions of full screen is multiplied by (1: as recorded)."""
        return 1.0

    def timing_label(self) -> str:
        """How echoes are timed, for ``identity``."""
        if self.echo_timer is None:
            return "host (no echo timer given yet)"
        timer = self.echo_timer
        return str(getattr(timer, "label", getattr(timer, "__name__", type(timer).__name__)))

    def reading_wait(self, timeout_s: float | None = None) -> ReadingWait:
        """How long one acquisition may take to complete (``ReadingWait``): the digitiser's
        averages at the pulser's PRF as last configured (the defaults, 1 at 1 kHz, before
        any), and ``timeout_s`` for the link (None: this back-end's)."""
        return ReadingWait.of(
            self._settings or PulserSettings(),
            self._timeout_s if timeout_s is None else float(timeout_s),
        )

    def read_gate(self, fresh: bool = True, timeout_s: float | None = None) -> GateReading:
        """One acquisition, timed on the host: the strongest echo in the gate; no time of
        flight below the gate threshold. The digitiser's completion may take the acquisition
        and ``timeout_s`` (``reading_wait``), its preamble and data ``timeout_s`` each (None:
        this back-end's ``timeout_s``). Every reading is a new acquisition (``fresh``)."""
        if self.echo_timer is None:
            raise RuntimeError(
                f"pulser at {self.endpoint}: no echo timer: this back-end only digitises, "
                "the application must give it one (echo_timer)"
            )
        record = self.read_ascan_record(timeout_s)
        echo = self.echo_timer(record, (self._settings or PulserSettings()).gate_ns)
        self.last_echo, self.last_record = echo, record
        amplitude = float(echo.amplitude) if math.isfinite(echo.amplitude) else 0.0
        tof_ns = float(echo.tof_ns)
        if not (amplitude >= self._threshold and math.isfinite(tof_ns)):
            tof_ns = float("nan")
        return GateReading(
            amplitude=max(amplitude, 0.0),
            tof_ns=tof_ns,
            counter=record.counter,
            device_time_s=record.host_time_s,
            host_time_s=record.host_time_s,
            tof_std_ns=float(echo.tof_std_ns) if math.isfinite(tof_ns) else math.nan,
        )

    def read_ascan(self, timeout_s: float = 2.0) -> tuple[np.ndarray, float] | None:
        """One acquisition: samples (fraction of full screen height) and sample rate (Hz)."""
        record = self.read_ascan_record(timeout_s)
        return np.asarray(record.samples, float), record.sample_rate_hz

    def read_ascan_record(self, timeout_s: float | None = None) -> AScanRecord:
        """One acquisition with its time base, rails, step, clipping and counter, in fractions
        of full screen height (times ``record_scale``), stamped with ``self.clock`` on
        arrival; waits as ``read_gate`` says."""
        self.connect()
        wait = self.reading_wait(timeout_s)
        record = self.digitizer.acquire(wait.link_s, acquisition_s=wait.acquisition_s)
        scale = self.record_scale() / self.full_screen_v
        return replace(record.scaled(scale), host_time_s=self.clock.now())

    def gate_threshold(self) -> float:
        """The host gate's threshold, fraction of full screen height."""
        return self._threshold

    def set_gate_threshold(self, fraction: float) -> None:
        """Set the host gate's threshold (fraction of full screen height, 0 … 1)."""
        if not (math.isfinite(fraction) and 0.0 <= fraction <= 1.0):
            raise ValueError(f"gate threshold must be 0 … 1 of full screen, got {fraction!r}")
        self._threshold = float(fraction)
