"""Modbus client for the pulser-receiver: RTU over a serial line or pyserial URL, and Modbus TCP.

The register map (a data file, ``drivers.pulser.map_file``; ucal's own by default) and its
encodings are in ``drivers.pulser.registers``; the transport (a pymodbus synchronous client),
timeouts, the mapping of Modbus faults to ``drivers.errors`` and the DEBUG log of every frame
(``WRITE:``/``READ:`` in hex) in ``drivers.pulser.modbus_link``; this module gives the
registers their meaning: identity, settings, readings, the A-scan.

Fault mapping (every message names the device ``pulser`` and its URL):

- Modbus exception response → ``DeviceError`` ("illegal data address (0x02)" …);
- no byte back within the timeout → ``DeviceTimeout``;
- bytes back that never form a valid frame (bad CRC, wrong unit, truncated) → ``ProtocolError``;
- connection refused, serial device missing, peer closed → ``ConnectionLost``.

Timeouts. A reading's deadline is what it asks of the device plus the link's margin
(``drivers.pulser.base.ReadingWait``, ``reading_wait``): the acquisition, ``averages`` pulses
at ``prf_hz`` as last configured (1 s for 1,000 averages at 1 kHz), the measurement block's
time on the line (Modbus RTU at the URL's baud: 22.9 ms at 19,200 baud; nothing over TCP), and
``timeout_s``. An A-scan's transfer adds its samples' time on the line once its header has
said how many there are. ``timeout_s`` is thus the link's margin, not the whole wait.

Host timing. With an ``echo_timer`` (``drivers.digitizer.base.EchoTimer``; ucal injects its
estimator when the profile says ``[pulser] timing = "ascan"``) every reading is timed on the
host: the measurement block is read as always (the acquisition, its counter, and the device's
peak-mode gate, which says whether and roughly where there is an echo), then the A-scan of that
acquisition around the device's peak — as much of it as the timer reads (its ``window_ns``),
a few requests rather than the whole gate — and the timer gives the amplitude, the time of
flight and its std. Below the device's gate threshold there is nothing to time: the reading is
the device's amplitude without a time of flight, and nothing is transferred. The A-scan's
int16 samples carry the device's ADC codes left-aligned; its step and rails follow from them
(``left_aligned_step``).
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from drivers.digitizer.base import (
    AScanRecord,
    EchoTimer,
    EchoTiming,
    left_aligned_step,
    timer_window_ns,
)
from drivers.errors import DeviceError, DeviceTimeout, ProtocolError
from drivers.pulser import registers as reg
from drivers.pulser.base import GateReading, PulserReceiver, PulserSettings, ReadingWait
from drivers.pulser.map_file import register_map_of
from drivers.pulser.modbus_link import (
    DEFAULT_RETRIES,
    DEFAULT_TIMEOUT_S,
    MIN_REQUEST_TIMEOUT_S,
    READ_FUNCTION,
    ModbusLink,
)
from drivers.pulser.urls import PulserUrl, parse_pulser_url

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class AScan:
    """One A-scan: normalised samples (1.0 = full screen), sample rate (Hz), time of sample 0."""

    samples: np.ndarray
    sample_rate_hz: float
    start_ns: float
    counter: int

    @property
    def time_ns(self) -> np.ndarray:
        """Round-trip time of each sample, ns."""
        return self.start_ns + np.arange(self.samples.size) * (1e9 / self.sample_rate_hz)


#: Pause between two polls of the measurement block while waiting for a new counter, s.
POLL_INTERVAL_S = 0.002
#: Half width (ns) of the A-scan transferred around the device's peak for a timer that does
#: not say how much it reads.
DEFAULT_WINDOW_NS = 2000.0


class ModbusPulser(ModbusLink, PulserReceiver):
    """The pulser-receiver over Modbus RTU or Modbus TCP.

    Build it with :meth:`from_url`. No I/O happens before :meth:`connect` (or the first call
    that needs the device, which connects lazily). ``timeout_s`` is the link's margin of every
    request and reading beyond what it asks of the device (module docstring).
    ``register_map`` is the device's map (a ``RegisterMap`` or the path of a map file; None:
    ucal's own). ``port`` (RTU only) injects an already-open pyserial-compatible port instead
    of opening ``DEVICE``, e.g. a test double; it is closed by :meth:`close`.
    """

    def __init__(
        self,
        url: str | PulserUrl,
        timeout_s: float = DEFAULT_TIMEOUT_S,
        *,
        port: Any = None,
        register_map: reg.RegisterMap | str | Path | None = None,
        retries: int = DEFAULT_RETRIES,
    ):
        parsed = parse_pulser_url(url) if isinstance(url, str) else url
        super().__init__(parsed, timeout_s, retries=retries, port=port)
        self._map = register_map_of(register_map)
        self._last_counter: int | None = None
        self._map_version: int | None = None
        self._front_end_written: list[list[int]] | None = None  # last front-end block written
        self.last_status = reg.Status(0)  #: status bits of the last gate reading
        #: Times echoes on the host from the A-scan (module docstring); None: the device's gate.
        self.echo_timer: EchoTimer | None = None
        #: The echo of the last host-timed ``read_gate`` as the host timed it, and its record.
        self.last_echo: EchoTiming | None = None
        self.last_record: AScanRecord | None = None
        self._settings: PulserSettings | None = None  # as last configured

    @classmethod
    def from_url(
        cls,
        url: str,
        timeout_s: float = DEFAULT_TIMEOUT_S,
        register_map: reg.RegisterMap | str | Path | None = None,
        retries: int = DEFAULT_RETRIES,
    ) -> ModbusPulser:
        """Build a pulser from its URL; ``timeout_s`` (s) is the link's margin of every
        request beyond what it asks of the device (a reading: its acquisition), one asked
        again ``retries`` times when nothing at all came back; ``register_map`` is the
        device's map (None: ucal's own).

        ``url`` is ``modbus-tcp://HOST:PORT[?unit=N]`` or
        ``modbus-rtu://DEVICE[?baud=N&unit=N&parity=E]``. Raises ``ValueError`` for a
        malformed URL or an invalid map file. Does not connect.
        """
        return cls(url, timeout_s, register_map=register_map, retries=retries)

    # --- PulserReceiver ---------------------------------------------------------------------
    @property
    def register_map(self) -> reg.RegisterMap:
        """The register map this client speaks."""
        return self._map

    def connect(self) -> None:
        """Open the connection and check the device identity (magic and map version, where
        the map has them).

        Raises ``ConnectionLost`` (cannot open), ``DeviceTimeout`` (no answer),
        ``ProtocolError`` (not this register map) or ``DeviceError`` (exception response).
        """
        with self._lock:
            if self._connected:
                return
            log.debug("pulser %s: connecting", self._endpoint)
            self._open()
            identity = self._map.present(("magic", "map_version"))
            try:
                words = self._read_values(identity, "identify", autoconnect=False)
            except BaseException:
                self._close_client()
                raise
            got = {r.name: r.decode(words[r.name]) for r in identity}
            if any(r.values is not None and got[r.name] not in r.values for r in identity):
                self._close_client()
                answer = " ".join(_identity_text(r.name, [got[r.name]]) for r in identity)
                expected = " ".join(_identity_text(r.name, r.values or ()) for r in identity)
                raise ProtocolError(
                    self.device,
                    self._endpoint,
                    f"unexpected identity {answer} (expected {expected}): not the register "
                    f"map {self._map}",
                )
            version = got.get("map_version")
            self._map_version = None if version is None else int(version)
            self._front_end_written = None
            self._connected = True
            log.debug("pulser %s: connected, map version %s", self._endpoint, version)

    def close(self) -> None:
        """Close the connection. Idempotent."""
        with self._lock:
            self._connected = False
            self._close_client()

    @property
    def map_version(self) -> int | None:
        """The register-map version the device reported (connects first if needed); None when
        the map has no version register."""
        self.connect()
        return self._map_version

    def check_settings(self, settings: PulserSettings) -> None:
        """Validate the settings against the register map's ranges, writing nothing."""
        self._map.encode_settings(settings, reg.SETTINGS)
        self._map.encode_settings(settings, reg.FRONT_END)

    def configure(self, settings: PulserSettings) -> None:
        """Validate and write the settings: gain, PRF, gate and averages in one request (FC 16),
        then pulse voltage, damping and filters in a second one (map version 2) when they differ
        from what this connection last wrote.

        Raises ``ValueError`` naming the setting for an out-of-range value (nothing is
        written then), or for settings other than the defaults that the device has no register
        for (not in the map, or a map-version-1 device and the front end); values are rounded
        to the register resolution (0.1 dB, 1 Hz, 1 ns, 1 V, 1 Ω, 0.01 MHz in ucal's map).
        """
        registers = self._map.encode_settings(settings, reg.SETTINGS)
        front_end = self._map.encode_settings(settings, reg.FRONT_END)
        map_version = self.map_version
        default = PulserSettings()
        absent = [r for r, _ in registers + front_end if not self._on_device(r)]
        refused = [
            r for r in absent if getattr(settings, r.ucal_name) != getattr(default, r.ucal_name)
        ]
        if refused:
            raise ValueError(
                f"pulser at {self._endpoint}: {', '.join(r.ucal_name for r in refused)} cannot "
                f"be set: the device's register map is version {map_version} (the register "
                f"needs version {max(r.min_version or 0 for r in refused)})"
            )
        registers = [e for e in registers if e[0] not in absent]
        front_end = [e for e in front_end if e[0] not in absent]
        self._write_values(registers, "configure")
        written = [words for _, words in front_end]
        if front_end and written != self._front_end_written:
            self._write_values(front_end, "configure front end")
            self._front_end_written = written
        self._settings = settings
        log.debug("pulser %s: configured %s", self._endpoint, settings)

    def settings(self) -> PulserSettings:
        """Read the settings back from the device (one FC 03 in ucal's map).

        A setting the device has no register for (a map-version-1 device: the front end)
        reads as its default.
        """
        version = self.map_version
        present = self._map.present(reg.SETTINGS + reg.FRONT_END, version)
        return self._map.decode_settings(self._read_values(present, "read settings"))

    def identity(self) -> dict[str, object]:
        """Map version, and model, firmware and serial number where the map has them (v2)."""
        version = self.map_version
        out: dict[str, object] = {}
        if version is not None:
            out["register_map_version"] = version
        present = self._map.present(reg.DEVICE_INFO, version)
        if present:
            info = self._map.decode_device_info(
                self._read_values(present, "read device information")
            )
            if info.model is not None:
                out["model"] = info.model
            if info.firmware is not None:
                out["firmware"] = info.firmware_version
            if info.serial is not None:
                out["serial"] = info.serial
        if self.echo_timer is not None:
            label = getattr(self.echo_timer, "label", type(self.echo_timer).__name__)
            out["timing"] = str(label)
        return out

    def reading_wait(self, timeout_s: float | None = None) -> ReadingWait:
        """How long one reading may take (``ReadingWait``): the acquisition as last configured
        (the device's power-on 1 average at 1 kHz before any ``configure``), the measurement
        block's time on the line, and ``timeout_s`` for the link (None: the pulser's)."""
        return ReadingWait.of(
            self._settings or PulserSettings(),
            self._timeout_s if timeout_s is None else float(timeout_s),
            self._values_line_s(self._map.present(reg.MEASUREMENT)),
        )

    def read_gate(self, fresh: bool = True, timeout_s: float | None = None) -> GateReading:
        """Read the gated peak amplitude and time of flight (ns, round trip).

        With ``fresh`` poll the measurement block until its counter differs from the last one
        this object returned (the first call accepts any reading), each read allowed the
        acquisition beyond the link's timeout (the device may answer once it has averaged).
        The whole wait is bounded by ``reading_wait(timeout_s)``: the acquisition, the block's
        time on the line and ``timeout_s`` (s; None: the pulser's, so that a simulated cell's
        generous guard is not cut short by a busy machine), then ``DeviceTimeout`` saying how
        long it waited and what of it was averaging. ``host_time_s`` is ``self.clock.now()``
        when the answer arrived. A gate ending after the pulse period raises ``DeviceError``.
        """
        wait = self.reading_wait(timeout_s)
        started = time.monotonic()
        deadline = started + wait.total_s
        measurement = self._map.present(reg.MEASUREMENT)
        while True:
            try:
                words = self._read_values(
                    measurement, "read gate", deadline, busy_s=wait.acquisition_s
                )
            except DeviceTimeout as exc:
                raise self._late_reading("no answer", wait, started) from exc
            host_time_s = self.clock.now()
            m = self._map.decode_measurement(words)
            counter = m.counter
            if counter is None:  # a map without a counter: every read is a new reading
                counter = 0 if self._last_counter is None else self._last_counter + 1
            if not fresh or self._last_counter is None or counter != self._last_counter:
                break
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                raise self._late_reading(
                    "no new reading", wait, started, f"counter stays at {counter}"
                )
            time.sleep(min(POLL_INTERVAL_S, remaining))
        self._last_counter = counter
        self.last_status = m.status
        if reg.Status.GATE_ERROR in m.status:
            raise DeviceError(
                self.device,
                self._endpoint,
                "gate error: the gate ends after the pulse repetition period",
            )
        tof_ns = float("nan")
        if reg.Status.ECHO in m.status:
            if not math.isfinite(m.tof_ns):
                raise ProtocolError(
                    self.device, self._endpoint, f"echo flagged but time of flight is {m.tof_ns}"
                )
            tof_ns = m.tof_ns
        reading = GateReading(
            amplitude=m.amplitude,
            tof_ns=tof_ns,
            counter=counter,
            device_time_s=host_time_s if m.device_time_ms is None else m.device_time_ms / 1000.0,
            host_time_s=host_time_s,
        )
        if self.echo_timer is None or not math.isfinite(tof_ns):
            return reading
        return self._timed_on_host(reading, self.echo_timer, deadline)

    def _late_reading(
        self, what: str, wait: ReadingWait, started: float, note: str = ""
    ) -> DeviceTimeout:
        """The timeout of a reading: ``what`` did not come, how long that was, ``note``, and
        what the wait was made of."""
        waited_s = time.monotonic() - started
        why = f"{note}; {wait.describe()}" if note else wait.describe()
        return DeviceTimeout(
            self.device, self._endpoint, f"read gate: {what} within {waited_s:.3g} s ({why})"
        )

    def _timed_on_host(
        self, reading: GateReading, timer: EchoTimer, deadline: float
    ) -> GateReading:
        """``reading`` with the amplitude, time of flight and std ``timer`` finds in the
        A-scan around the device's peak."""
        record = self.read_ascan_record(
            reading.tof_ns, timeout_s=max(deadline - time.monotonic(), MIN_REQUEST_TIMEOUT_S)
        )
        echo = timer(record, (self._settings or PulserSettings()).gate_ns)
        self.last_echo, self.last_record = echo, record
        if not (math.isfinite(echo.tof_ns) and echo.amplitude > 0.0):
            return replace(reading, tof_ns=float("nan"))
        return replace(
            reading,
            amplitude=min(float(echo.amplitude), 1.0),
            tof_ns=float(echo.tof_ns),
            tof_std_ns=float(echo.tof_std_ns),
            host_time_s=record.host_time_s,
        )

    def read_ascan(self, timeout_s: float = 2.0) -> tuple[np.ndarray, float] | None:
        """Read the A-scan over the gate: normalised samples (n,) and sample rate (Hz); None
        when the register map has no A-scan."""
        if "ascan_samples" not in self._map:
            return None
        scan = self.read_ascan_trace(timeout_s)
        return scan.samples, scan.sample_rate_hz

    # --- beyond the interface ---------------------------------------------------------------
    def read_ascan_trace(self, timeout_s: float = 2.0) -> AScan:
        """Read the A-scan with its time base; the whole transfer may take its samples' time
        on the line and ``timeout_s`` (s) for the link.

        Reading the header makes the device freeze the A-scan of its latest acquisition; the
        samples are then read in blocks of at most 125 registers.
        """
        deadline = time.monotonic() + float(timeout_s)
        sample_register, header = self._ascan_header(deadline)
        if header.length > sample_register.words:
            raise ProtocolError(
                self.device,
                self._endpoint,
                f"A-scan length {header.length} exceeds {sample_register.words}",
            )
        if header.length and not (
            math.isfinite(header.sample_rate_hz) and header.sample_rate_hz > 0
        ):
            raise ProtocolError(
                self.device, self._endpoint, f"A-scan sample rate {header.sample_rate_hz} Hz"
            )
        samples = self._ascan_words(sample_register, 0, header.length, deadline, timeout_s)
        return AScan(
            samples=reg.decode_samples(samples, sample_register.full_scale),
            sample_rate_hz=header.sample_rate_hz,
            start_ns=float(header.start_ns),
            counter=-1 if header.counter is None else header.counter,
        )

    def read_ascan_record(
        self,
        centre_ns: float | None = None,
        half_width_ns: float | None = None,
        timeout_s: float = 2.0,
    ) -> AScanRecord:
        """The A-scan of the latest acquisition as a record (fractions of full screen height,
        the ADC's step and rails, stamped with ``self.clock`` on arrival): the samples within
        ``half_width_ns`` (None: the echo timer's window, else ``DEFAULT_WINDOW_NS``) of
        ``centre_ns``, or the whole A-scan when ``centre_ns`` is None. The transfer may take
        the samples' time on the line and ``timeout_s`` for the link."""
        deadline = time.monotonic() + float(timeout_s)
        sample_register, header = self._ascan_header(deadline)
        if not (0 < header.length <= sample_register.words):
            raise ProtocolError(
                self.device,
                self._endpoint,
                f"A-scan length {header.length} (expected 1 … {sample_register.words})",
            )
        if not (math.isfinite(header.sample_rate_hz) and header.sample_rate_hz > 0):
            raise ProtocolError(
                self.device, self._endpoint, f"A-scan sample rate {header.sample_rate_hz} Hz"
            )
        dt_ns = 1e9 / header.sample_rate_hz
        first, stop = 0, header.length
        if centre_ns is not None:
            if half_width_ns is None:
                timer = self.echo_timer
                half_width_ns = (
                    DEFAULT_WINDOW_NS
                    if timer is None
                    else timer_window_ns(timer, dt_ns, DEFAULT_WINDOW_NS)
                )
            k = round((centre_ns - header.start_ns) / dt_ns)
            half = math.ceil(half_width_ns / dt_ns)
            first, stop = max(0, k - half), min(header.length, k + half + 1)
            if stop - first < 8:  # the peak at the A-scan's end: its last samples
                first, stop = max(0, min(first, header.length - 8)), header.length
        words = self._ascan_words(sample_register, first, stop, deadline, timeout_s)
        host_time_s = self.clock.now()
        codes = np.asarray(words, dtype=np.uint16).view(np.int16).astype(np.int64)
        step = left_aligned_step(codes)
        fs = float(sample_register.full_scale)
        low, high = -32768, 32768 - step  # the lowest and highest multiples of the step
        settings = self._settings or PulserSettings()
        return AScanRecord(
            t0_ns=float(header.start_ns) + first * dt_ns,
            dt_ns=dt_ns,
            samples=codes / fs,
            rails=(low / fs, high / fs),
            lsb=step / fs,
            clipped=bool(np.any((codes <= low) | (codes >= high))),
            averages=int(settings.averages),
            counter=-1 if header.counter is None else int(header.counter),
            host_time_s=host_time_s,
        )

    def _ascan_header(self, deadline: float) -> tuple[reg.Register, reg.AScanHeader]:
        """The samples' register and the A-scan header; reading it freezes the A-scan of the
        latest acquisition."""
        sample_register = self._register("ascan_samples")
        header = self._map.decode_ascan_header(
            self._read_values(self._map.present(reg.ASCAN_HEADER), "read A-scan header", deadline)
        )
        return sample_register, header

    def _ascan_words(
        self, r: reg.Register, first: int, stop: int, deadline: float, timeout_s: float
    ) -> list[int]:
        """Samples ``first`` … ``stop - 1`` of the frozen A-scan, in blocks of at most 125
        registers; ``DeviceTimeout`` past ``deadline`` (``timeout_s`` after the transfer began)
        and the samples' time on the line."""
        line_s = self._line_s(stop - first)
        deadline += line_s
        words: list[int] = []
        while first + len(words) < stop:
            if time.monotonic() >= deadline:
                on_line = f", {line_s:.2g} s of it their time on the line" if line_s else ""
                raise DeviceTimeout(
                    self.device,
                    self._endpoint,
                    f"A-scan of {stop - first} samples not read within "
                    f"{timeout_s + line_s:.3g} s ({len(words)} read{on_line})",
                )
            count = min(reg.MAX_READ_REGISTERS, stop - first - len(words))
            words += self._read(
                READ_FUNCTION[r.table],
                r.address + first + len(words),
                count,
                "read A-scan samples",
                deadline,
            )
        return words

    def set_gate_threshold(self, fraction: float) -> None:
        """Set the gate threshold, fraction of full screen height (0 … 1, 0.001 resolution in
        ucal's map)."""
        r = self._register("threshold")
        self._write_values([(r, r.encode_value(fraction))], "set gate threshold")

    def gate_threshold(self) -> float:
        """Read the gate threshold, fraction of full screen height."""
        r = self._register("threshold")
        return r.decode_value(self._read_values([r], "read gate threshold")[r.name])

    def trigger(self) -> None:
        """Make the device acquire now (its reading counter advances by one)."""
        self._command("trigger")

    def clear_counter(self) -> None:
        """Reset the device's reading counter and measurement block to zero."""
        self._command("clear_counter")
        self._last_counter = None


def _identity_text(name: str, values: Sequence[float]) -> str:
    """``0x5550`` for a magic, ``v1/v2`` for map versions."""
    if name == "magic":
        return "/".join(f"0x{int(v):04X}" for v in values)
    return "/".join(f"v{int(v)}" for v in values)
