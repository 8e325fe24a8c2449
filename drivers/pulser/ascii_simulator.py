"""A simulated CompactPulser-class pulser on 127.0.0.1, speaking the ASCII command set over TCP.

A client reaches it as a serial device through pyserial's ``socket://127.0.0.1:PORT``
(``ascii://socket://127.0.0.1:PORT``), the way a serial-to-Ethernet converter is reached. It
plays the device of ``docs/protocols/ascii_pulser.md`` (``drivers.pulser.ascii_commands``):
a command inside the knob's range sets it and is not answered, a query is answered
``<letter>=<n>\\r``, and anything else — an unknown letter, a value outside the range, a line
that is not a command — is ignored, as the device does. It pulses and receives nothing
itself: what its receiver puts out is the simulated cell's business, which reads
:attr:`SimulatedAsciiPulser.settings` (the gain above all) when the simulated scope acquires.

Faults for tests: :meth:`SimulatedAsciiPulser.set_silent` (lines are read and executed, never
answered).
"""

from __future__ import annotations

import logging
from typing import Any

from drivers.loopback import LoopbackServer
from drivers.pulser import ascii_commands as cmd
from drivers.pulser.base import PulserSettings
from drivers.pulser.urls import format_ascii_url

log = logging.getLogger(__name__)

#: The knobs at power-on (codes): 20 dB, 1000 Hz, 100 V, 50 ns, 50 Ω, 96 MHz.
POWER_ON: dict[cmd.Letter, int] = {
    cmd.Letter.GAIN: 200,
    cmd.Letter.PRF: 100,
    cmd.Letter.VOLTAGE: 100,
    cmd.Letter.WIDTH: 50,
    cmd.Letter.DAMPING: 0,
    cmd.Letter.LOW_PASS: 3,
}


class SimulatedAsciiPulser(LoopbackServer):
    """The ASCII pulser on 127.0.0.1 (context manager). ``port`` 0 picks a free port;
    :attr:`url` tells it after :meth:`start`. Nothing is opened before :meth:`start`."""

    what = "simulated ascii pulser"
    terminator = cmd.TERMINATOR

    def __init__(self, host: str = "127.0.0.1", port: int = 0):
        super().__init__(host, port)
        self._codes = dict(POWER_ON)
        self.commands = 0  #: settings taken since start
        self.ignored = 0  #: lines ignored since start

    @property
    def url(self) -> str:
        """``ascii://socket://127.0.0.1:PORT``."""
        return format_ascii_url(f"socket://{self.host}:{self.port}")

    # --- the device -------------------------------------------------------------------------
    def code(self, letter: cmd.Letter) -> int:
        """The code a knob holds."""
        with self._lock:
            return self._codes[letter]

    @property
    def pulsing(self) -> bool:
        """Whether it pulses (``P0`` stops it)."""
        return self.code(cmd.Letter.PRF) > 0

    @property
    def settings(self) -> PulserSettings:
        """The knobs as ``PulserSettings`` (gate and averages are the scope's: defaults; a
        stopped pulser reports its lowest rate: see :attr:`pulsing`)."""
        with self._lock:
            codes = dict(self._codes)
        codes[cmd.Letter.PRF] = max(codes[cmd.Letter.PRF], 1)
        values: dict[str, Any] = {
            k.field: k.value(codes[letter])
            for letter, k in cmd.KNOBS.items()
            if k.field is not None
        }
        return PulserSettings(high_pass_mhz=cmd.FIXED_HIGH_PASS_MHZ, **values)

    @property
    def pulse_width_ns(self) -> float:
        """The pulse width (ns)."""
        return cmd.KNOBS[cmd.Letter.WIDTH].value(self.code(cmd.Letter.WIDTH))

    def execute(self, line: bytes) -> bytes | None:
        """Run one line; the answer (CR included) or None."""
        parsed = cmd.parse_line(line)
        with self._lock:
            if parsed is None:
                self.ignored += 1
                log.debug("simulated ascii pulser ignores %r", line)
                return None
            letter, code = parsed
            if code is None:
                return cmd.answer(letter, self._codes[letter])
            knob = cmd.KNOBS[letter]
            if letter == cmd.Letter.PRF and code == 0:
                self._codes[letter] = 0  # P0: pulsing stopped
            elif knob.lo <= code <= knob.hi:
                self._codes[letter] = code
            else:
                self.ignored += 1
                log.debug("simulated ascii pulser ignores %r (out of range)", line)
                return None
            self.commands += 1
            return None

    # --- server threads ---------------------------------------------------------------------
    def _normalise(self, chunk: bytes) -> bytes:
        return chunk.replace(b"\n", b"\r")  # a terminal's Enter ends a line too

    def _answer(self, line: bytes) -> bytes | None:
        return self.execute(line) if line.strip() else None
