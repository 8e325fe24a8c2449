"""An oscilloscope as the digitiser, over SCPI through PyVISA.

The instrument (:class:`ScpiScope`) owns meaning: which commands set the record up, how one
acquisition is made and read back. Its transport (:class:`PyVisaTransport`, or any object with
the same three calls) owns bytes: it writes a program message, reads an answer line, reads n
bytes. The resource is PyVISA's (``pyvisa-py`` by default, any VISA library by name), so a
LAN, USBTMC or VXI-11 scope is the same code; tests inject a scripted resource instead.

The command set (``docs/protocols/scpi_digitizer.md``) is the common subset of the Keysight
InfiniiVision and Rigol programming guides:

- connect: ``*IDN?``; then one message ``*CLS;:WAV:SOUR CHAN1;:WAV:FORM WORD;:WAV:BYT MSBF;
  :WAV:UNS 1;:WAV:POIN:MODE RAW;:WAV:POIN MAX;:TIM:REF LEFT;:TRIG:EDGE:SOUR EXT;
  :CHAN1:RANG <2·full scale>;:CHAN1:OFFS 0;:SYST:ERR?`` whose answer must be error 0;
- configure (what changed only): ``:TIM:RANG <width s>;:TIM:POS <start s>;:ACQ:TYPE NORM``
  (or ``:ACQ:TYPE AVER;:ACQ:COUN <n>``), then ``:SYST:ERR?``;
- one acquisition: ``:DIG;*OPC?`` (``1`` when the acquisition is complete), ``:WAV:PRE?``,
  ``:WAV:DATA?`` (an IEEE 488.2 block).

Fault mapping (every message names the device ``digitizer`` and its URL): no answer in time →
``DeviceTimeout``; an answer that breaks the framing → ``ProtocolError``; an error in the
scope's error queue, a record with holes or another average count than asked →
``DeviceError``; cannot open or the connection drops → ``ConnectionLost``.
"""

from __future__ import annotations

import logging
import math
import threading
from typing import Any, Protocol

import numpy as np

from drivers.device import RequestLink
from drivers.digitizer import scpi
from drivers.digitizer.base import AScanRecord, Digitizer
from drivers.digitizer.urls import DigitizerUrl, parse_digitizer_url
from drivers.errors import ConnectionLost, DeviceError, DeviceTimeout, ProtocolError

log = logging.getLogger(__name__)

#: Default time one request may wait for its answer, s.
DEFAULT_TIMEOUT_S = 2.0
#: The VISA library PyVISA opens the resource with: pyvisa-py, pure Python.
DEFAULT_BACKEND = "@py"
#: ``:ACQuire:COUNt`` range in average mode (InfiniiVision: 2 … 65536).
MAX_AVERAGES = 65536
#: Longest record asked for, s (10 ms: far beyond any immersion round trip).
MAX_WIDTH_S = 10e-3


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
    try:  # request/reply traffic: no Nagle delay on a small command before its answer
        from pyvisa import constants

        handle.set_visa_attribute(constants.ResourceAttribute.tcpip_nodelay, True)
    except Exception:  # not a TCP/IP resource, or a library without the attribute
        pass
    return handle


class ScpiScope(RequestLink, Digitizer):
    """An oscilloscope recording the receiver's RF output on channel 1, triggered by the
    pulser's sync output on EXT.

    ``full_scale_v`` (V) is what the record must hold on either side of 0 V (the channel's
    vertical range is twice it); ``wave_format`` is ``"WORD"`` (the ADC's full resolution) or
    ``"BYTE"`` (8 bits, half the bytes). ``resource`` injects an already-open PyVISA-like
    resource (tests); otherwise ``backend`` names the VISA library PyVISA opens the URL's
    resource with. No I/O before :meth:`connect`.
    """

    def __init__(
        self,
        url: str | DigitizerUrl,
        timeout_s: float = DEFAULT_TIMEOUT_S,
        *,
        full_scale_v: float = 1.0,
        wave_format: str = "WORD",
        resource: Any = None,
        backend: str = DEFAULT_BACKEND,
    ):
        parsed = parse_digitizer_url(url) if isinstance(url, str) else url
        self._link_to(str(parsed), timeout_s)
        if not (math.isfinite(full_scale_v) and full_scale_v > 0):
            raise ValueError(f"full_scale_v must be a positive voltage, got {full_scale_v!r}")
        try:
            self._format = scpi.WaveFormat[wave_format.upper()]
        except KeyError:
            raise ValueError(f"wave_format must be WORD or BYTE, got {wave_format!r}") from None
        if self._format not in scpi.SAMPLE_BYTES:
            raise ValueError(f"wave_format must be WORD or BYTE, got {wave_format!r}")
        self._url = parsed
        self.full_scale_v = float(full_scale_v)
        self._backend = backend
        self._injected = resource
        self._transport: ScpiTransport | None = None
        self._lock = threading.RLock()
        self._idn: scpi.IdnReply | None = None
        self._written: dict[str, str] = {}  # command header → argument last written
        self._averages = 1
        self.acquisitions = 0  #: acquisitions made since the connection opened

    @classmethod
    def from_url(cls, url: str, timeout_s: float = DEFAULT_TIMEOUT_S, **options: Any) -> ScpiScope:
        """Build a scope from ``visa://RESOURCE`` (``ValueError`` if malformed); no I/O."""
        return cls(url, timeout_s, **options)

    # --- lifecycle --------------------------------------------------------------------------
    def connect(self) -> None:
        """Open the resource, identify the scope and set it up for single acquisitions."""
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
            self.acquisitions = 0
            try:
                self._idn = scpi.parse_idn(self._query("*IDN?", "identify"))
                self._setup(
                    [
                        ("*CLS", ""),
                        (":WAV:SOUR", "CHAN1"),
                        (":WAV:FORM", self._format.name),
                        (":WAV:BYT", "MSBF"),
                        (":WAV:UNS", "1"),
                        (":WAV:POIN:MODE", "RAW"),
                        (":WAV:POIN", "MAX"),
                        (":TIM:REF", "LEFT"),
                        (":TRIG:EDGE:SOUR", "EXT"),
                        (":CHAN1:RANG", _number(2.0 * self.full_scale_v)),
                        (":CHAN1:OFFS", "0"),
                    ],
                    "set up",
                )
            except BaseException:
                self.close()
                raise
            log.debug("digitizer %s: connected to %s", self._endpoint, self._idn)

    def close(self) -> None:
        """Close the resource. Idempotent."""
        with self._lock:
            transport, self._transport = self._transport, None
            self._close_link(transport)

    def identity(self) -> dict[str, object]:
        """``*IDN?``: manufacturer, model, serial number and firmware."""
        self.connect()
        assert self._idn is not None
        return {
            "manufacturer": self._idn.manufacturer,
            "model": self._idn.model,
            "serial": self._idn.serial,
            "firmware": self._idn.firmware,
        }

    # --- the record -------------------------------------------------------------------------
    def check(self, start_ns: float, width_ns: float, averages: int) -> None:
        """``ValueError`` for a window longer than the scope records or an average count
        outside 1 … 65536, sending nothing."""
        if not (math.isfinite(start_ns) and math.isfinite(width_ns) and width_ns > 0):
            raise ValueError(f"digitizer: record window {start_ns} + {width_ns} ns is not valid")
        if width_ns * 1e-9 > MAX_WIDTH_S:
            raise ValueError(
                f"digitizer: a record of {width_ns * 1e-3:g} µs is longer than "
                f"{MAX_WIDTH_S * 1e6:g} µs"
            )
        if averages != int(averages) or not 1 <= int(averages) <= MAX_AVERAGES:
            raise ValueError(f"digitizer: averages must be 1 … {MAX_AVERAGES}, got {averages!r}")

    def configure(self, start_ns: float, width_ns: float, averages: int) -> None:
        """Record ``width_ns`` from ``start_ns`` after the trigger (time base, reference at
        the left edge), averaging ``averages`` acquisitions (``:ACQ:TYPE AVER``, 2 … 65536;
        1 = ``NORM``). Writes only what changed; ``ValueError`` before anything is written
        for a window or count the scope cannot take."""
        self.check(start_ns, width_ns, averages)
        commands = [
            (":TIM:RANG", _number(width_ns * 1e-9)),
            (":TIM:POS", _number(start_ns * 1e-9)),
            (":ACQ:TYPE", "AVER" if averages > 1 else "NORM"),
        ]
        if averages > 1:
            commands.append((":ACQ:COUN", str(int(averages))))
        with self._lock:
            self.connect()
            changed = [(h, a) for h, a in commands if self._written.get(h) != a]
            if changed:
                self._setup(changed, "configure")
            self._averages = int(averages)

    def acquire(self, timeout_s: float | None = None, acquisition_s: float = 0.0) -> AScanRecord:
        """One acquisition (``:DIG;*OPC?``), its preamble and its data, in volts.

        ``*OPC?`` answers once the acquisition is complete: it may take ``acquisition_s`` (s,
        the averages at the trigger's rate) and ``timeout_s`` (s) for the link (None: the
        scope's ``timeout_s``); the preamble and the data, ``timeout_s`` each (VISA bounds each
        read of a long record's block, not the whole). ``DeviceTimeout`` says how long it
        waited and what of it was the acquisition.
        """
        wait = self._timeout_s if timeout_s is None else float(timeout_s)
        if not (math.isfinite(acquisition_s) and acquisition_s >= 0):
            raise ValueError(f"acquisition_s must be 0 or more seconds, got {acquisition_s!r}")
        with self._lock:
            self.connect()
            try:
                done = self._query(":DIG;*OPC?", "acquire", acquisition_s + wait)
            except DeviceTimeout as exc:
                raise DeviceTimeout(
                    self.device,
                    self._endpoint,
                    f"acquire: no answer within {acquisition_s + wait:.3g} s "
                    f"({acquisition_s:.3g} s of it for the acquisition of {self._averages} "
                    f"averages, then timeout_s = {wait:g} s for the link)",
                ) from exc
            if done.strip() not in ("1", "+1"):
                raise ProtocolError(
                    self.device, self._endpoint, f"acquire: *OPC? answered {done!r}, not 1"
                )
            self.acquisitions += 1
            preamble = self._preamble(wait)
            payload = self._block(":WAV:DATA?", "read waveform data", wait)
            host_time_s = self.clock.now()
        return self._record(preamble, payload, host_time_s)

    def _record(self, p: scpi.Preamble, payload: bytes, host_time_s: float) -> AScanRecord:
        try:
            codes = scpi.decode_codes(payload, p.format)
        except scpi.ScpiError as e:
            raise ProtocolError(self.device, self._endpoint, f"waveform data: {e}") from None
        if codes.size != p.points:
            raise ProtocolError(
                self.device,
                self._endpoint,
                f"waveform data holds {codes.size} samples, the preamble says {p.points}",
            )
        if codes.size < 2:
            raise DeviceError(self.device, self._endpoint, f"record of {codes.size} samples")
        holes = int(np.count_nonzero(codes == scpi.HOLE)) if codes.min() == scpi.HOLE else 0
        if holes:
            raise DeviceError(
                self.device,
                self._endpoint,
                f"{holes} of {codes.size} samples were not acquired (holes in the record)",
            )
        averaged = p.count if p.type == scpi.AcquireType.AVERAGE else 1
        if averaged != self._averages:
            raise DeviceError(
                self.device,
                self._endpoint,
                f"asked for {self._averages} averages, the record averages {averaged}",
            )
        low, high = scpi.CLIP_LOW[p.format], scpi.CLIP_HIGH[p.format]
        clipped = bool(codes.min() <= low or codes.max() >= high)
        step = scpi.code_step(codes, p.format, p.y_reference)
        return AScanRecord(
            t0_ns=p.t0_ns,
            dt_ns=p.dt_ns,
            samples=p.volts(codes),
            rails=(float(p.volts(np.array([low]))[0]), float(p.volts(np.array([high]))[0])),
            lsb=step * p.y_increment_v,
            clipped=clipped,
            averages=averaged,
            counter=self.acquisitions,
            host_time_s=host_time_s,
        )

    def _preamble(self, timeout_s: float) -> scpi.Preamble:
        text = self._query(":WAV:PRE?", "read preamble", timeout_s)
        try:
            p = scpi.parse_preamble(text)
        except scpi.ScpiError as e:
            raise ProtocolError(self.device, self._endpoint, str(e)) from None
        if p.format != self._format:
            raise ProtocolError(
                self.device,
                self._endpoint,
                f"preamble format {p.format.name}, asked for {self._format.name}",
            )
        return p

    # --- transport --------------------------------------------------------------------------
    def _setup(self, commands: list[tuple[str, str]], what: str) -> None:
        """Write ``commands`` in one program message ending in ``:SYST:ERR?``; error 0 or
        ``DeviceError``. Remembers what was written."""
        message = ";".join(f"{h} {a}" if a else h for h, a in commands) + ";:SYST:ERR?"
        answer = self._query(message, what)
        code, _, text = answer.partition(",")
        try:
            number = int(code)
        except ValueError:
            raise ProtocolError(
                self.device, self._endpoint, f"{what}: :SYST:ERR? answered {answer!r}"
            ) from None
        if number != 0:
            self._written = {}  # what the scope took is unknown now
            raise DeviceError(
                self.device, self._endpoint, f"{what}: the scope reports error {number} {text}"
            )
        self._written.update({h: a for h, a in commands if h != "*CLS"})

    def _transport_or_fail(self) -> ScpiTransport:
        if self._transport is None:
            raise ConnectionLost(self.device, self._endpoint, "not connected")
        return self._transport

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
        """The ``drivers.errors`` fault of a transport exception (the link is dropped unless
        the answer merely broke the framing)."""
        if isinstance(exc, scpi.ScpiError):
            self.close()  # the stream is out of step
            return ProtocolError(self.device, self._endpoint, f"{what}: {exc}")
        if _is_timeout(exc):
            self.close()  # a late answer would be read as the next one's
            return DeviceTimeout(
                self.device, self._endpoint, f"{what}: no answer within {timeout_s:.3g} s"
            )
        self.close()
        return ConnectionLost(self.device, self._endpoint, f"{what}: {exc}")


def _is_timeout(exc: Exception) -> bool:
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


def _number(value: float) -> str:
    """A SCPI <NR3> argument: ``4.000000E-04``, exact to 7 significant digits."""
    return f"{value:.6E}"
