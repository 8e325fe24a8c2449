"""A pulser-receiver that does not time echoes: an ASCII serial pulser plus an oscilloscope.

The cell as many laboratories build it: a CompactPulser-class pulser-receiver set over a
9600-baud serial line (``drivers.pulser.ascii_commands``), its RF output recorded by an
oscilloscope over SCPI/VISA (``drivers.digitizer.visa``, or any digitiser whose URL scheme the
registry knows, ``drivers.registry.open_digitizer``) triggered by its sync output, and the
time of flight and amplitude computed on the host from the record.

``AsciiPulser`` owns the serial line: commands, queries, the read-back of every setting.
``AsciiScpiPulser`` is the ``PulserReceiver`` ucal's procedures use:

- ``configure`` writes the knobs the device has (gain, PRF, voltage, damping, low-pass, and
  the pulse width when ``pulse_width_ns`` is set), each to the device's own step, reads each
  back, and records what was asked and what the device set (``settings_applied``); the gate is
  the scope's record window and ``averages`` its average count;
- ``read_gate`` makes one acquisition and times its echo on the host, as every pulser whose
  echoes a digitiser records does (``drivers.pulser.digitised``).

Timeouts. The scope, triggered by the pulser's sync output, completes an acquisition once it
has averaged ``averages`` of them at the pulser's PRF: its completion may take that
(``drivers.pulser.base.ReadingWait``, ``reading_wait``: 1 s for 1,000 averages at 1 kHz) plus
``timeout_s``, the link's margin, and the record's preamble and data ``timeout_s`` each. A
query on the serial line waits ``timeout_s``.
"""

from __future__ import annotations

import logging
import threading
import time
from dataclasses import replace
from typing import Any

from serial import SerialException

from drivers.device import RequestLink
from drivers.digitizer.base import Digitizer, EchoTimer
from drivers.errors import ConnectionLost, DeviceError, DeviceTimeout, ProtocolError
from drivers.pulser import ascii_commands as cmd
from drivers.pulser.base import PulserSettings
from drivers.pulser.digitised import DEFAULT_TIMEOUT_S, DigitisedPulser
from drivers.pulser.urls import AsciiUrl, parse_ascii_url
from drivers.serial_port import open_port

log = logging.getLogger(__name__)

#: Pause while a reply is awaited and nothing is waiting, s.
_POLL_S = 0.0005


class AsciiPulser(RequestLink):
    """The serial line of a CompactPulser-class pulser (``ascii://DEVICE[?baud=N]``).

    ``port`` injects an already-open pyserial-compatible port (``write``, ``read``,
    ``in_waiting``, ``close``), e.g. a test double; it is closed by :meth:`close`. No I/O
    before :meth:`connect`.
    """

    device = "pulser"

    def __init__(
        self, url: str | AsciiUrl, timeout_s: float = DEFAULT_TIMEOUT_S, *, port: Any = None
    ):
        self._url = parse_ascii_url(url) if isinstance(url, str) else url
        self._link_to(str(self._url), timeout_s)
        self._injected = port
        self._port: Any = None
        self._rx = b""
        self._lock = threading.RLock()

    def connect(self) -> None:
        """Open the line and check that a pulser answers (``G?``)."""
        with self._lock:
            if self._port is not None:
                return
            self._port = self._open_link(
                self._injected,
                lambda: open_port(self._url.device, self._url.baud, self._timeout_s),
                self._url.device,
                (SerialException, OSError, ValueError),
            )
            self._rx = b""
            try:
                self.read(cmd.Letter.GAIN)
            except BaseException:
                self.close()
                raise

    def close(self) -> None:
        """Close the line. Idempotent."""
        with self._lock:
            port, self._port = self._port, None
            self._close_link(port)

    def write(self, letter: cmd.Letter, code: int) -> None:
        """Send ``<letter><code>`` (the device does not answer)."""
        self._send(cmd.command(letter, code), f"set {letter.value}")

    def read(self, letter: cmd.Letter) -> int:
        """Ask ``<letter>?``; the code of its answer ``<letter>=<n>``."""
        with self._lock:
            self._drain()
            self._send(cmd.query(letter), f"read {letter.value}")
            line = self._line(f"read {letter.value}")
        try:
            return cmd.parse_answer(letter, line)
        except ValueError as e:
            self._rx = b""
            raise ProtocolError(self.device, self._endpoint, f"read {letter.value}: {e}") from None

    def set(self, letter: cmd.Letter, code: int) -> int:
        """Write ``code`` and read it back: what the device set."""
        with self._lock:
            self.write(letter, code)
            return self.read(letter)

    def _require_port(self) -> Any:
        if self._port is None:
            raise ConnectionLost(self.device, self._endpoint, "not connected")
        return self._port

    def _send(self, data: bytes, what: str) -> None:
        port = self._require_port()
        log.debug("pulser %s WRITE: %r", self._endpoint, data)
        try:
            port.write(data)
        except (SerialException, OSError) as exc:
            self.close()
            raise ConnectionLost(self.device, self._endpoint, f"{what}: {exc}") from exc

    def _drain(self) -> None:
        """Drop what arrived unasked (a late answer must not pass for the next one)."""
        port = self._require_port()
        try:
            waiting = port.in_waiting
            stale = self._rx + (port.read(waiting) if waiting else b"")
        except (SerialException, OSError) as exc:
            self.close()
            raise ConnectionLost(self.device, self._endpoint, f"read: {exc}") from exc
        if stale:
            log.debug("pulser %s: dropped %r", self._endpoint, stale)
        self._rx = b""

    def _line(self, what: str) -> bytes:
        """Read up to and including the next CR, within the timeout."""
        port = self._require_port()
        deadline = time.monotonic() + self._timeout_s
        while cmd.TERMINATOR not in self._rx:
            if time.monotonic() > deadline:
                got, self._rx = self._rx, b""
                raise DeviceTimeout(
                    self.device,
                    self._endpoint,
                    f"{what}: no answer within {self._timeout_s:.3g} s"
                    + (f" (received {got!r})" if got else ""),
                )
            try:
                waiting = port.in_waiting
                chunk = port.read(max(1, waiting))
            except (SerialException, OSError) as exc:
                self.close()
                raise ConnectionLost(self.device, self._endpoint, f"{what}: {exc}") from exc
            if chunk:
                self._rx += chunk
            else:
                time.sleep(_POLL_S)
        line, _, self._rx = self._rx.partition(cmd.TERMINATOR)
        log.debug("pulser %s READ: %r", self._endpoint, line + cmd.TERMINATOR)
        return line


class AsciiScpiPulser(DigitisedPulser):
    """The ASCII serial pulser and the SCPI oscilloscope as one pulser-receiver (module
    docstring).

    ``digitizer`` is the scope's URL (``visa://RESOURCE``, opened by the back-end of its scheme
    with ``digitizer_options``) or a ``Digitizer``; ``full_screen_v``
    the RF output (V) that is full screen height; ``pulse_width_ns`` the pulse width written
    with the settings (None: the device's own). ``echo_timer`` times the echo in a record
    (ucal injects it; without one ``read_gate`` refuses). No I/O before :meth:`connect`.
    """

    def __init__(
        self,
        url: str | AsciiUrl,
        digitizer: str | Digitizer,
        timeout_s: float = DEFAULT_TIMEOUT_S,
        *,
        port: Any = None,
        full_screen_v: float = 1.0,
        pulse_width_ns: float | None = None,
        echo_timer: EchoTimer | None = None,
        digitizer_options: dict[str, Any] | None = None,
    ):
        self.line = AsciiPulser(url, timeout_s, port=port)
        self._attach(digitizer, timeout_s, full_screen_v, echo_timer, digitizer_options)
        self.pulse_width_ns = pulse_width_ns
        self._written: dict[cmd.Letter, int] = {}
        #: What the last ``configure`` asked and what the devices set, by setting.
        self.settings_applied: dict[str, dict[str, float]] = {}

    @classmethod
    def from_url(
        cls,
        url: str,
        timeout_s: float = DEFAULT_TIMEOUT_S,
        digitizer: str | Digitizer | None = None,
        retries: int = 0,
        **options: Any,
    ) -> AsciiScpiPulser:
        """Build the back-end from ``ascii://DEVICE[?baud=N]`` and its digitiser
        (``visa://RESOURCE``). ``ValueError`` for a malformed URL or a missing digitiser
        (it is the one that records the echo). Does not connect. ``retries`` (the profile's
        ``[pulser] retries``) is taken and not used: a command on the ASCII line has no answer
        to wait for, and the scope's requests are VISA's to bound."""
        if digitizer is None:
            parse_ascii_url(url)
            raise ValueError(
                f"{url}: an ascii pulser does not digitise: give its digitiser, "
                "--digitizer visa://RESOURCE (or UCAL_DIGITIZER)"
            )
        return cls(url, digitizer, timeout_s, **options)

    # --- PulserReceiver ---------------------------------------------------------------------
    @property
    def endpoint(self) -> str:
        """The pulser's URL, ``ascii://DEVICE[?baud=N]``."""
        return self.line.endpoint

    def connect(self) -> None:
        """Open the serial line and the scope; ``ConnectionLost``/``DeviceTimeout`` if not."""
        self.line.connect()
        try:
            self.digitizer.connect()
        except BaseException:
            self.line.close()
            raise

    def close(self) -> None:
        """Close both. Idempotent."""
        try:
            self.digitizer.close()
        finally:
            self.line.close()
            self._written = {}

    def check_settings(self, settings: PulserSettings) -> None:
        """Validate the settings against the pulser's knobs and the scope, sending nothing."""
        self._codes(settings)

    def _codes(self, settings: PulserSettings) -> dict[cmd.Letter, int]:
        """The pulser's code of each knob; ``ValueError`` for what the pulser or the scope
        cannot take (``configure`` and ``check_settings``)."""
        codes = cmd.settings_codes(settings)
        if self.pulse_width_ns is not None:
            codes[cmd.Letter.WIDTH] = cmd.KNOBS[cmd.Letter.WIDTH].code(self.pulse_width_ns)
        start_ns = settings.gate_start_us * 1e3
        width_ns = settings.gate_width_us * 1e3
        if (start_ns + width_ns) * 1e-9 * settings.prf_hz > 1.0:
            raise ValueError(
                f"gate {settings.gate_start_us:g} + {settings.gate_width_us:g} µs ends after "
                f"the pulse repetition period ({1e6 / settings.prf_hz:g} µs at "
                f"{settings.prf_hz:g} Hz)"
            )
        self.digitizer.check(start_ns, width_ns, int(settings.averages))
        return codes

    def configure(self, settings: PulserSettings) -> dict[str, dict[str, float]] | None:
        """Write the settings: the scope's window (gate) and averages, then every pulser knob
        that changed, each read back.

        Raises ``ValueError`` naming the setting, before anything is written, for a value
        the devices cannot take (values are rounded to the device's own steps; what was asked
        and what was set is returned, and kept in ``settings_applied``), and ``DeviceError``
        when the pulser sets another value than the one written.
        """
        codes = self._codes(settings)
        start_ns = settings.gate_start_us * 1e3
        width_ns = settings.gate_width_us * 1e3
        self.connect()
        self.digitizer.configure(start_ns, width_ns, int(settings.averages))
        applied: dict[str, dict[str, float]] = {}
        for letter, code in codes.items():
            knob = cmd.KNOBS[letter]
            if self._written.get(letter) != code:
                got = self.line.set(letter, code)
                if got != code:
                    self._written.pop(letter, None)
                    raise DeviceError(
                        self.device,
                        self.endpoint,
                        f"wrote {letter.value}{code} ({knob.value(code):g} {knob.unit}), the "
                        f"pulser set {letter.value}={got}: its values differ from "
                        "docs/protocols/ascii_pulser.md",
                    )
                self._written[letter] = code
            name = knob.field or "pulse_width_ns"
            asked = (
                float(getattr(settings, knob.field))
                if knob.field
                else float(self.pulse_width_ns or 0.0)
            )
            applied[name] = {"asked": asked, "set": knob.value(code)}
        applied["high_pass_mhz"] = {"asked": settings.high_pass_mhz, "set": cmd.FIXED_HIGH_PASS_MHZ}
        for name in ("gate_start_us", "gate_width_us", "averages"):
            value = float(getattr(settings, name))
            applied[name] = {"asked": value, "set": value}
        self.settings_applied = applied
        self._settings = settings
        log.debug("pulser %s: configured %s", self.endpoint, applied)
        return applied

    def settings(self) -> PulserSettings:
        """The settings as the devices hold them: the pulser's knobs read back, the scope's
        window and averages as last configured (the defaults before any)."""
        self.connect()
        got: dict[str, Any] = {
            knob.field: knob.value(self.line.read(letter))
            for letter, knob in cmd.KNOBS.items()
            if knob.field is not None
        }
        if got["prf_hz"] <= 0:
            raise DeviceError(self.device, self.endpoint, "the pulser is not pulsing (P=0)")
        base = self._settings or PulserSettings()
        return replace(base, high_pass_mhz=cmd.FIXED_HIGH_PASS_MHZ, **got)

    def identity(self) -> dict[str, object]:
        """The command set, the scope's ``*IDN?``, how echoes are timed, and what the last
        ``configure`` asked and set."""
        self.connect()
        out: dict[str, object] = {
            "command_set": "CompactPulser ASCII (docs/protocols/ascii_pulser.md)",
            "digitizer": {"endpoint": self.digitizer.endpoint, **self.digitizer.identity()},
            "timing": self.timing_label(),
        }
        if self.settings_applied:
            out["settings_applied"] = self.settings_applied
        return out
