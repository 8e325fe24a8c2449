"""An oscilloscope as the digitiser, over SCPI through PyVISA, in its own family's dialect.

The instrument (:class:`ScpiScope`) owns meaning: which commands set the record and the trigger
up, how one acquisition is made and read back. What those commands are is its family's
(``drivers.digitizer.dialects``: a command table a family, chosen by the scope's ``*IDN?``);
the driver follows the table and holds no family's command. Its transport
(:class:`PyVisaTransport`, or any object with the same calls) owns bytes: it writes a program
message, reads an answer line, reads n bytes. The resource is PyVISA's (``pyvisa-py`` by
default, any VISA library by name), so a LAN, USBTMC or VXI-11 scope is the same code; tests
inject a scripted resource instead.

What it does (``docs/protocols/scpi_digitizer.md`` gives each family's messages):

- connect: ``*IDN?``, the family (a scope of no family ucal speaks is a ``DeviceError`` naming
  its answer); then ``*CLS``, the record's set-up (channel 1, transfer format, vertical range),
  the trigger (edge, NORMal sweep, the sync output's input and level, rising), the trigger
  read back and the error queue (``:SYST:ERR?``), which must be empty: a trigger that reads
  back otherwise than set is a ``DeviceError`` naming it;
- configure (what changed only): the time base of the window, the averaging, the error queue;
- one acquisition: the family's single acquisition, awaited (``*OPC?``, or its status polled),
  refused if it arrived untriggered; its preamble; its data (IEEE 488.2 blocks).

Fault mapping (every message names the device ``digitizer`` and its URL): no answer in time,
or no trigger within the acquisition's deadline → ``DeviceTimeout`` (naming the trigger); an
answer that breaks the framing → ``ProtocolError``; an unknown scope, an error in its queue, a
trigger that reads back otherwise, an untriggered record, a record with holes or another average
count than asked → ``DeviceError``; cannot open or the connection drops → ``ConnectionLost``.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from typing import Any

import numpy as np

from drivers.device import RequestLink
from drivers.digitizer import scpi
from drivers.digitizer.base import AScanRecord, Digitizer
from drivers.digitizer.dialects import (
    Command,
    Dialect,
    dialect_of,
    known_families,
    nr3,
    parse_level,
)
from drivers.digitizer.urls import DigitizerUrl, parse_digitizer_url, trigger_source
from drivers.digitizer.visa_transport import (
    PyVisaTransport,
    ScpiTransport,
    is_timeout,
    open_visa_resource,
)
from drivers.errors import ConnectionLost, DeviceError, DeviceTimeout, ProtocolError

log = logging.getLogger(__name__)

#: Default time one request may wait for its answer, s.
DEFAULT_TIMEOUT_S = 2.0
#: The VISA library PyVISA opens the resource with: pyvisa-py, pure Python.
DEFAULT_BACKEND = "@py"
#: Largest average count any family takes (InfiniiVision: 65536).
MAX_AVERAGES = 65536
#: Longest record asked for, s (10 ms: far beyond any immersion round trip).
MAX_WIDTH_S = 10e-3
#: How far a trigger level may read back from the one set: 10 mV and 2 % (a scope's step).
LEVEL_TOLERANCE_V = 0.01
LEVEL_TOLERANCE = 0.02
#: Polling a family's acquisition status: the first pause once it says the same again, and the
#: longest (s); a status that changed is asked again at once.
POLL_FIRST_S = 0.0005
POLL_MAX_S = 0.02
#: The argument of each transfer format in ``:WAVeform:FORMat``.
_FORMAT_ARGUMENT = {"WORD": "WORD", "BYTE": "BYTE", "ASCII": "ASC"}


class ScpiScope(RequestLink, Digitizer):
    """An oscilloscope recording the receiver's RF output on channel 1, triggered by the
    pulser's sync output (on the input the URL's ``trigger`` names, else the family's: EXT on a
    Keysight, CH2 on a Rigol DS1000Z) at the URL's ``level``.

    ``full_scale_v`` (V) is what the record must hold on either side of 0 V (the channel's
    vertical range is twice it); ``wave_format`` is ``"WORD"`` (the ADC's full resolution),
    ``"BYTE"`` (8 bits, half the bytes) or ``"ASCII"`` (volts as text), among those of the
    scope's family (None: its first, WORD on a Keysight, BYTE on a Rigol). ``resource``
    injects an already-open PyVISA-like resource (tests); otherwise ``backend`` names the VISA
    library PyVISA opens the URL's resource with. No I/O before :meth:`connect`.
    """

    def __init__(
        self,
        url: str | DigitizerUrl,
        timeout_s: float = DEFAULT_TIMEOUT_S,
        *,
        full_scale_v: float = 1.0,
        wave_format: str | None = None,
        resource: Any = None,
        backend: str = DEFAULT_BACKEND,
    ):
        parsed = parse_digitizer_url(url) if isinstance(url, str) else url
        self._link_to(str(parsed), timeout_s)
        if not (math.isfinite(full_scale_v) and full_scale_v > 0):
            raise ValueError(f"full_scale_v must be a positive voltage, got {full_scale_v!r}")
        if wave_format is not None and wave_format.upper() not in _FORMAT_ARGUMENT:
            raise ValueError(f"wave_format must be WORD, BYTE or ASCII, got {wave_format!r}")
        self._url = parsed
        self.full_scale_v = float(full_scale_v)
        self._asked_format = None if wave_format is None else wave_format.upper()
        self._backend = backend
        self._injected = resource
        self._transport: ScpiTransport | None = None
        self._lock = threading.RLock()
        self._idn: scpi.IdnReply | None = None
        self._dialect: Dialect | None = None
        self._format = self._asked_format or "WORD"
        self._written: dict[str, str] = {}  # command header → argument last written
        self._window_ns: tuple[float, float] | None = None
        self._averages = 1
        self.acquisitions = 0  #: acquisitions made since the connection opened

    @classmethod
    def from_url(cls, url: str, timeout_s: float = DEFAULT_TIMEOUT_S, **options: Any) -> ScpiScope:
        """Build a scope from ``visa://RESOURCE[?trigger=…&level=…]`` (``ValueError`` if
        malformed); no I/O."""
        return cls(url, timeout_s, **options)

    # --- what it is -------------------------------------------------------------------------
    @property
    def dialect(self) -> Dialect | None:
        """The family's command table, once the scope has said who it is (:meth:`connect`)."""
        return self._dialect

    @property
    def trigger_source(self) -> str:
        """The input the trigger is set to: the URL's, else the family's (EXT before connect)."""
        if self._url.trigger_source is not None:
            return self._url.trigger_source
        return self._dialect.trigger.default_source if self._dialect else "EXT"

    @property
    def trigger_level_v(self) -> float:
        """The trigger level (V)."""
        return self._url.trigger_level_v

    def _trigger_text(self) -> str:
        sweep = self._dialect.trigger.sweep_word if self._dialect else "NORM"
        return f"{self.trigger_source} rising through {self.trigger_level_v:g} V (sweep {sweep})"

    # --- lifecycle --------------------------------------------------------------------------
    def connect(self) -> None:
        """Open the resource, identify the scope's family and set it up: the record, the
        trigger (read back) and an empty error queue."""
        with self._lock:
            if self._transport is not None:
                return
            log.debug("digitizer %s: connecting", self._endpoint)
            # pyvisa-py raises plain Exception for a refused socket: any error is a lost link.
            resource = self._open_link(
                self._injected,
                lambda: open_visa_resource(self._url.resource, self._backend, self._timeout_s),
                self._url.resource,
            )
            self._transport = PyVisaTransport(resource)
            self._written = {}
            self._window_ns = None
            self.acquisitions = 0
            try:
                self._idn = scpi.parse_idn(self._query("*IDN?", "identify"))
                self._dialect = self._family(self._idn)
                self._set_up(self._dialect)
            except BaseException:
                self.close()
                raise
            log.debug(
                "digitizer %s: connected to %s (%s)", self._endpoint, self._idn, self._dialect.title
            )

    def _family(self, idn: scpi.IdnReply) -> Dialect:
        dialect = dialect_of(idn)
        if dialect is None:
            raise DeviceError(
                self.device,
                self._endpoint,
                f"*IDN? answered {str(idn)!r}: not a scope family ucal speaks ({known_families()}; "
                "docs/protocols/scpi_digitizer.md says how to add one)",
            )
        fmt = self._asked_format or dialect.wave_formats[0]
        if fmt not in dialect.wave_formats:
            raise DeviceError(
                self.device,
                self._endpoint,
                f"a {dialect.title} transfers {', '.join(dialect.wave_formats)}, not {fmt}",
            )
        if self._source_for(dialect) not in dialect.trigger.sources:
            raise DeviceError(
                self.device,
                self._endpoint,
                f"a {dialect.title}'s edge trigger takes {', '.join(dialect.trigger.sources)} "
                f"for the pulser's sync output, not {self._url.trigger_source} (the URL's "
                "trigger=)",
            )
        self._format = fmt
        return dialect

    def _source_for(self, dialect: Dialect) -> str:
        """The trigger input on a scope of ``dialect``'s family: the URL's, else its default."""
        return self._url.trigger_source or dialect.trigger.default_source

    def _set_up(self, d: Dialect) -> None:
        arguments = {
            "format": _FORMAT_ARGUMENT[self._format],
            "range_v": nr3(2.0 * self.full_scale_v),
            "scale_v": nr3(2.0 * self.full_scale_v / 8.0),
        }
        t = d.trigger
        commands: list[Command] = [("*CLS", "")]
        commands += [(h, a.format(**arguments)) for h, a in d.setup]
        commands += [
            t.mode,
            t.sweep,
            (t.source, self.trigger_source),
            (t.level, nr3(self.trigger_level_v)),
            t.slope,
        ]
        sweep, source, level = self._exchange(
            commands, [f"{t.sweep[0]}?", f"{t.source}?", f"{t.level}?"], "set up"
        )
        self._check_trigger(sweep, source, level)

    def _check_trigger(self, sweep: str, source: str, level: str) -> None:
        """The trigger as read back must be the one set (``DeviceError`` naming both)."""
        assert self._dialect is not None
        try:
            got_source = trigger_source(source)
        except ValueError:
            got_source = source.strip()
        try:
            got_level = parse_level(level)
        except ValueError:
            got_level = math.nan
        asked = self.trigger_level_v
        tolerance = LEVEL_TOLERANCE_V + LEVEL_TOLERANCE * abs(asked)
        if (
            not sweep.strip().upper().startswith(self._dialect.trigger.sweep_word)
            or got_source != self.trigger_source
            or not abs(got_level - asked) <= tolerance
        ):
            self._written = {}
            raise DeviceError(
                self.device,
                self._endpoint,
                f"set up: the trigger reads back sweep {sweep.strip()}, source "
                f"{source.strip()}, level {level.strip()} V; ucal set {self._trigger_text()} "
                "(a level the input's range cannot take is one cause)",
            )

    def close(self) -> None:
        """Close the resource. Idempotent."""
        with self._lock:
            transport, self._transport = self._transport, None
            self._close_link(transport)

    def identity(self) -> dict[str, object]:
        """``*IDN?`` (manufacturer, model, serial number, firmware), the family ucal speaks
        with it and the trigger it set."""
        self.connect()
        assert self._idn is not None and self._dialect is not None
        return {
            "manufacturer": self._idn.manufacturer,
            "model": self._idn.model,
            "serial": self._idn.serial,
            "firmware": self._idn.firmware,
            "family": self._dialect.family,
            "trigger": {
                "source": self.trigger_source,
                "level_v": self.trigger_level_v,
                "sweep": self._dialect.trigger.sweep_word,
            },
        }

    # --- the record -------------------------------------------------------------------------
    def check(self, start_ns: float, width_ns: float, averages: int) -> None:
        """``ValueError`` for a window longer than the scope records or an average count it
        does not take (its family's, once connected; before, what any family takes), sending
        nothing."""
        if not (math.isfinite(start_ns) and math.isfinite(width_ns) and width_ns > 0):
            raise ValueError(f"digitizer: record window {start_ns} + {width_ns} ns is not valid")
        if width_ns * 1e-9 > MAX_WIDTH_S:
            raise ValueError(
                f"digitizer: a record of {width_ns * 1e-3:g} µs is longer than "
                f"{MAX_WIDTH_S * 1e6:g} µs"
            )
        if averages != int(averages) or not 1 <= int(averages) <= MAX_AVERAGES:
            raise ValueError(f"digitizer: averages must be 1 … {MAX_AVERAGES}, got {averages!r}")
        if self._dialect is not None:
            self._dialect.check_averages(int(averages))
            self._dialect.window(start_ns * 1e-9, width_ns * 1e-9)

    def configure(self, start_ns: float, width_ns: float, averages: int) -> None:
        """Record ``width_ns`` from ``start_ns`` after the trigger (the family's time base),
        averaging ``averages`` acquisitions (1 = none). Writes only what changed, then reads the
        error queue; ``ValueError`` before anything is written for a window or count the scope
        cannot take."""
        with self._lock:
            self.connect()
            self.check(start_ns, width_ns, averages)
            d = self._dialect
            assert d is not None
            a = d.averaging
            commands = list(d.window(start_ns * 1e-9, width_ns * 1e-9))
            if averages > 1:
                commands += [(a.type_header, a.average), (a.count_header, str(int(averages)))]
            else:
                commands.append((a.type_header, a.normal))
            changed = [(h, v) for h, v in commands if self._written.get(h) != v]
            if changed:
                self._exchange(changed, [], "configure")
            self._window_ns = (float(start_ns), float(width_ns))
            self._averages = int(averages)

    def acquire(self, timeout_s: float | None = None, acquisition_s: float = 0.0) -> AScanRecord:
        """One acquisition (the family's single acquisition, awaited), its preamble and its
        data, in volts.

        The acquisition may take ``acquisition_s`` (s, the averages at the trigger's rate) and
        ``timeout_s`` (s) for the link (None: the scope's ``timeout_s``); past that it is a
        ``DeviceTimeout`` naming the trigger it waits for. The preamble and each read of the
        data ``timeout_s`` each (VISA bounds each read of a long record's block, not the
        whole). A record that arrived untriggered is a ``DeviceError``.
        """
        wait = self._timeout_s if timeout_s is None else float(timeout_s)
        if not (math.isfinite(acquisition_s) and acquisition_s >= 0):
            raise ValueError(f"acquisition_s must be 0 or more seconds, got {acquisition_s!r}")
        with self._lock:
            self.connect()
            d = self._dialect
            assert d is not None
            if d.completion == "opc":
                preamble = self._acquire_opc(d, wait, acquisition_s)
            else:
                self._acquire_polled(d, wait, acquisition_s)
                preamble = self._preamble(self._query(":WAV:PRE?", "read preamble", wait))
            self.acquisitions += 1
            first, payload = self._data(d, preamble, wait)
            host_time_s = self.clock.now()
        return self._record(preamble, first, payload, host_time_s)

    def _late(
        self, waited_s: float, acquisition_s: float, wait: float, state: str = ""
    ) -> DeviceTimeout:
        """The timeout of an acquisition: how long it waited and what of it was the averaging;
        the trigger it waits for, or (a status that says it triggered) that it did not end."""
        triggered = self._dialect is not None and state in self._dialect.triggered
        what = (
            f"triggered ({state}), the acquisition did not complete"
            if triggered
            else f"no trigger on {self._trigger_text()}? Is the pulser's sync output wired "
            "there, and pulsing?"
        )
        return DeviceTimeout(
            self.device,
            self._endpoint,
            f"acquire: no record within {waited_s:.3g} s ({acquisition_s:.3g} s of it for the "
            f"acquisition of {self._averages} averages, then timeout_s = {wait:g} s for the "
            f"link): {what}",
        )

    def _acquire_opc(self, d: Dialect, wait: float, acquisition_s: float) -> scpi.Preamble:
        """``:TER?`` (cleared), the acquisition and ``*OPC?``; then ``:TER?`` (1: triggered)
        and the preamble, in one message each."""
        clear = [d.trigger_event] if d.trigger_event else []
        message = ";".join([*clear, d.single, "*OPC?"])
        try:
            answer = self._query(message, "acquire", acquisition_s + wait)
        except DeviceTimeout as exc:
            raise self._late(acquisition_s + wait, acquisition_s, wait) from exc
        done = answer.split(";")[-1].strip()
        if done not in ("1", "+1"):
            raise ProtocolError(
                self.device, self._endpoint, f"acquire: *OPC? answered {answer!r}, not 1"
            )
        if not d.trigger_event:
            return self._preamble(self._query(":WAV:PRE?", "read preamble", wait))
        answer = self._query(f"{d.trigger_event};:WAV:PRE?", "read preamble", wait)
        event, _, text = answer.partition(";")
        if event.strip() not in ("1", "+1"):
            raise DeviceError(
                self.device,
                self._endpoint,
                f"acquire: the record arrived untriggered ({d.trigger_event} answered "
                f"{event.strip()!r}: no trigger event): refused; ucal set {self._trigger_text()}",
            )
        return self._preamble(text)

    def _acquire_polled(self, d: Dialect, wait: float, acquisition_s: float) -> None:
        """The single acquisition, then its status polled until it is complete: once the scope
        has said it is armed or acquiring, or once the acquisition's own time has passed (a
        status read before it had begun says the last one's); a free-running status is an
        untriggered record. The deadline is the acquisition's time and ``wait``; a status that
        says the trigger came gives it ``wait`` more (the answer may come late on a busy host,
        as VISA's would)."""
        assert d.status is not None
        self._write(d.single, "acquire")
        started = time.monotonic()
        deadline = started + acquisition_s + wait
        pause, armed, last = POLL_FIRST_S, False, ""
        while True:
            state = self._query(d.status, "acquire", wait).strip().upper()
            now = time.monotonic()
            if state == d.untriggered:
                raise DeviceError(
                    self.device,
                    self._endpoint,
                    f"acquire: the scope runs untriggered ({d.status} answered {state}): "
                    f"refused; ucal set {self._trigger_text()}",
                )
            if state == d.complete and (armed or now - started >= acquisition_s):
                return
            armed = armed or state in d.armed
            if state in d.triggered and last not in d.triggered:
                deadline = max(deadline, now + wait)
            if now > deadline:
                self.close()
                raise self._late(now - started, acquisition_s, wait, state)
            if state != last:  # it moved on: ask again at once, then back off
                pause, last = POLL_FIRST_S, state
                continue
            time.sleep(min(pause, max(deadline - now, 0.0)))
            pause = min(2 * pause, POLL_MAX_S)

    def _preamble(self, text: str) -> scpi.Preamble:
        assert self._dialect is not None
        try:
            p = self._dialect.preamble(text)
        except scpi.ScpiError as e:
            raise ProtocolError(self.device, self._endpoint, str(e)) from None
        if p.format != self._format:
            raise ProtocolError(
                self.device,
                self._endpoint,
                f"preamble format {p.format}, asked for {self._format}",
            )
        record_type = self._dialect.record_type
        if record_type is not None and p.type != record_type:
            raise ProtocolError(
                self.device,
                self._endpoint,
                f"preamble type {p.type}: the record is read in {record_type} mode",
            )
        return p

    def _data(self, d: Dialect, p: scpi.Preamble, wait: float) -> tuple[int, bytes]:
        """The record's data: index of its first point in the acquisition and its bytes; the
        whole record, or (a family that reads by parts) the points of the configured window,
        in as many reads as the family's largest one allows."""
        if d.data_range is None:
            return 0, self._block(":WAV:DATA?", "read waveform data", wait)
        first, last = self._span(p)
        step = d.max_points.get(p.format, last - first + 1)
        parts = []
        for start in range(first, last + 1, step):
            stop = min(start + step - 1, last)
            self._write_changed(
                [(d.data_range[0], str(start + 1)), (d.data_range[1], str(stop + 1))]
            )
            parts.append(self._block(":WAV:DATA?", "read waveform data", wait))
        return first, b"".join(parts)

    def _span(self, p: scpi.Preamble) -> tuple[int, int]:
        """First and last point (0-based) of the configured window in a record of ``p``."""
        if p.points < 2:
            raise DeviceError(self.device, self._endpoint, f"record of {p.points} samples")
        if self._window_ns is None:
            return 0, p.points - 1
        start_ns, width_ns = self._window_ns
        first = math.floor((start_ns - p.t0_ns) / p.dt_ns + 1e-6)
        last = math.ceil((start_ns + width_ns - p.t0_ns) / p.dt_ns - 1e-6)
        first, last = max(first, 0), min(last, p.points - 1)
        if last - first < 1:
            raise DeviceError(
                self.device,
                self._endpoint,
                f"the record ({p.t0_ns:g} ns + {p.points} × {p.dt_ns:g} ns) misses the window "
                f"{start_ns:g} + {width_ns:g} ns",
            )
        return first, last

    def _record(
        self, p: scpi.Preamble, first: int, payload: bytes, host_time_s: float
    ) -> AScanRecord:
        assert self._dialect is not None
        expected = p.points if self._dialect.data_range is None else None
        if p.format == "ASCII":
            samples = self._ascii_samples(payload)
            low, high = -self.full_scale_v, self.full_scale_v
            clipped = bool(samples.size and np.max(np.abs(samples)) >= self.full_scale_v)
            lsb = p.y_increment_v
        else:
            codes_of = self._dialect.codes[p.format]
            try:
                codes = scpi.decode_codes(payload, codes_of.sample_bytes)
            except scpi.ScpiError as e:
                raise ProtocolError(self.device, self._endpoint, f"waveform data: {e}") from None
            if expected is not None and codes.size != expected:
                raise ProtocolError(
                    self.device,
                    self._endpoint,
                    f"waveform data holds {codes.size} samples, the preamble says {expected}",
                )
            if codes_of.hole is not None and codes.size and codes.min() == codes_of.hole:
                holes = int(np.count_nonzero(codes == codes_of.hole))
                raise DeviceError(
                    self.device,
                    self._endpoint,
                    f"{holes} of {codes.size} samples were not acquired (holes in the record)",
                )
            samples = p.volts(codes)
            low, high = (
                float(v) for v in p.volts(np.array([codes_of.clip_low, codes_of.clip_high]))
            )
            clipped = bool(
                codes.size
                and (codes.min() <= codes_of.clip_low or codes.max() >= codes_of.clip_high)
            )
            step = (
                scpi.code_step(codes, p.y_reference, codes_of.flags)
                if codes_of.step_from_codes
                else 1
            )
            lsb = step * p.y_increment_v
        if samples.size < 2:
            raise DeviceError(self.device, self._endpoint, f"record of {samples.size} samples")
        averaged = self._dialect.averaged(p)
        if averaged != self._averages:
            raise DeviceError(
                self.device,
                self._endpoint,
                f"asked for {self._averages} averages, the record averages {averaged}",
            )
        return AScanRecord(
            t0_ns=p.t0_ns + first * p.dt_ns,
            dt_ns=p.dt_ns,
            samples=samples,
            rails=(low, high),
            lsb=lsb,
            clipped=clipped,
            averages=averaged,
            counter=self.acquisitions,
            host_time_s=host_time_s,
        )

    def _ascii_samples(self, payload: bytes) -> np.ndarray:
        try:
            return scpi.decode_ascii(payload)
        except scpi.ScpiError as e:
            raise ProtocolError(self.device, self._endpoint, f"waveform data: {e}") from None

    # --- transport --------------------------------------------------------------------------
    def _exchange(self, commands: list[Command], queries: list[str], what: str) -> list[str]:
        """Write ``commands``, ask ``queries`` and read the error queue: in one program message
        (a family that takes them), else one message each. The queries' answers; a nonzero
        error is a ``DeviceError`` quoting it. Remembers what was written."""
        assert self._dialect is not None
        d = self._dialect
        texts = [f"{h} {a}" if a else h for h, a in commands]
        if d.compound:
            answer = self._query(";".join([*texts, *queries, d.error_query]), what)
            parts = answer.split(";", len(queries))
            if len(parts) != len(queries) + 1:
                raise ProtocolError(
                    self.device,
                    self._endpoint,
                    f"{what}: answered {answer!r} to {len(queries) + 1} queries",
                )
            answers, error = parts[:-1], parts[-1]
        else:
            for text in texts:
                self._write(text, what)
            answers = [self._query(q, what) for q in queries]
            error = self._query(d.error_query, what)
        code, _, message = error.partition(",")
        try:
            number = int(code)
        except ValueError:
            raise ProtocolError(
                self.device, self._endpoint, f"{what}: {d.error_query} answered {error!r}"
            ) from None
        if number != 0:
            self._written = {}  # what the scope took is unknown now
            raise DeviceError(
                self.device, self._endpoint, f"{what}: the scope reports error {number} {message}"
            )
        self._written.update({h: a for h, a in commands if not h.startswith("*")})
        return answers

    def _write_changed(self, commands: list[Command]) -> None:
        """Write those of ``commands`` whose argument differs from the last written."""
        for header, argument in commands:
            if self._written.get(header) != argument:
                self._write(f"{header} {argument}", "set the transfer")
                self._written[header] = argument

    def _transport_or_fail(self) -> ScpiTransport:
        if self._transport is None:
            raise ConnectionLost(self.device, self._endpoint, "not connected")
        return self._transport

    def _write(self, message: str, what: str) -> None:
        transport = self._transport_or_fail()
        log.debug("digitizer %s WRITE: %s", self._endpoint, message)
        try:
            transport.write(message)
        except Exception as exc:
            raise self._fault(exc, what, self._timeout_s) from exc

    def _query(self, message: str, what: str, timeout_s: float | None = None) -> str:
        transport = self._transport_or_fail()
        wait = self._timeout_s if timeout_s is None else timeout_s
        log.debug("digitizer %s WRITE: %s", self._endpoint, message)
        try:
            transport.write(message)
            answer = transport.read_line(wait)
        except Exception as exc:
            raise self._fault(exc, what, wait) from exc
        log.debug("digitizer %s READ: %s", self._endpoint, answer)
        return answer

    def _block(self, message: str, what: str, timeout_s: float) -> bytes:
        transport = self._transport_or_fail()
        log.debug("digitizer %s WRITE: %s", self._endpoint, message)
        try:
            transport.write(message)
            payload = scpi.read_block(lambda n: transport.read_exact(n, timeout_s))
        except Exception as exc:
            raise self._fault(exc, what, timeout_s) from exc
        log.debug("digitizer %s READ: block of %d bytes", self._endpoint, len(payload))
        return payload

    def _fault(self, exc: Exception, what: str, timeout_s: float) -> Exception:
        """The ``drivers.errors`` fault of a transport exception (the link is dropped: the
        stream is out of step, or a late answer would be read as the next one's)."""
        if isinstance(exc, scpi.ScpiError):
            self.close()
            return ProtocolError(self.device, self._endpoint, f"{what}: {exc}")
        if is_timeout(exc):
            self.close()
            return DeviceTimeout(
                self.device, self._endpoint, f"{what}: no answer within {timeout_s:.3g} s"
            )
        self.close()
        return ConnectionLost(self.device, self._endpoint, f"{what}: {exc}")
