"""The ASCII serial command set of a CompactPulser-class pulser-receiver, shared by the client
(``drivers.pulser.ascii``) and the simulator (``drivers.pulser.ascii_simulator``).

Framing (``docs/protocols/ascii_pulser.md``): 9600 baud, 8 data bits, no parity, 1 stop bit, no
flow control. A command is a letter and an integer (``G400``), a query a letter and ``?``
(``G?``), each terminated by CR. A command has no answer; a query's answer is ``<letter>=<n>``
terminated by CR (``G=400``). The device ignores what it does not take (an unknown letter, a
value outside its range), which only the query shows: so the client reads every setting back.

The knobs (letter, unit of the integer, the device's own values): what public control code for
the US Ultratek CompactPulser shows is marked *public*, the rest is this project's assumption
and says so in the protocol document.

- ``G`` receiver gain, 0.1 dB, −120 … 840 (−12.0 … 84.0 dB) — public;
- ``P`` pulse repetition frequency, 10 Hz, 1 … 500 (10 … 5000 Hz; ``P0`` stops pulsing) — public;
- ``V`` pulse voltage, V, 50 … 300 (``V300`` public; the range assumed);
- ``W`` pulse width, ns, 10 … 500 (public: the width of a half cycle, 500 / f_MHz ns; the range
  assumed);
- ``D`` damping, index 0 … 3 → 50, 100, 200, 500 Ω (the letter public, the table assumed);
- ``L`` low-pass filter, index 0 … 3 → 12, 24, 48, 96 MHz (``L2`` = 48 MHz public, the rest
  assumed).

The receiver's high-pass has no command in that set: it is taken as fixed at 1 MHz (AC
coupling), the ``PulserSettings`` default.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Mapping
from dataclasses import dataclass

from drivers.pulser.base import PulserSettings

#: Serial line of the device (8N1, no flow control).
DEFAULT_BAUD = 9600
#: Terminator of every command, query and answer.
TERMINATOR = b"\r"
#: Bits per character on the serial line (start, 8 data, stop).
BITS_PER_CHAR = 10
#: The receiver's fixed high-pass (MHz): no command sets it.
FIXED_HIGH_PASS_MHZ = 1.0


class Letter(enum.StrEnum):
    """The command letters."""

    GAIN = "G"
    PRF = "P"
    VOLTAGE = "V"
    WIDTH = "W"
    DAMPING = "D"
    LOW_PASS = "L"


@dataclass(frozen=True)
class Knob:
    """One setting: its letter, the ``PulserSettings`` field it serves (None: none), the
    unit of one count, and the device's codes: a range (``lo`` … ``hi``) or a table of values
    by index (``table``)."""

    letter: Letter
    field: str | None
    unit: str
    lo: int
    hi: int
    per_count: float = 1.0  # physical value of one count (table knobs: unused)
    table: tuple[float, ...] | None = None

    def value(self, code: int) -> float:
        """The physical value of ``code``."""
        if self.table is not None:
            return self.table[code]
        return code * self.per_count

    def code(self, asked: float) -> int:
        """The device code nearest ``asked`` (physical units); ``ValueError`` naming the
        setting when ``asked`` is outside what the device can do (more than half a step
        beyond its extreme values). Never clips."""
        name = self.field or self.letter.name.lower()
        if not math.isfinite(asked):
            raise ValueError(f"{name} must be finite, got {asked!r}")
        values = self.table or (self.lo * self.per_count, self.hi * self.per_count)
        if self.table is not None:
            # the nearest table entry on a log scale (ohms, megahertz are ratios), within
            # half the ratio to the neighbour beyond the extremes
            if asked <= 0:
                raise ValueError(f"{name} must be positive, got {asked!r}")
            logs = [math.log(v) for v in self.table]
            half_low = 0.5 * (logs[1] - logs[0])
            half_high = 0.5 * (logs[-1] - logs[-2])
            la = math.log(asked)
            if not logs[0] - half_low <= la <= logs[-1] + half_high:
                raise ValueError(
                    f"{name} = {asked:g} {self.unit} is outside what the pulser takes "
                    f"({', '.join(f'{v:g}' for v in self.table)} {self.unit})"
                )
            return min(range(len(logs)), key=lambda i: abs(logs[i] - la))
        code = round(asked / self.per_count)
        if not self.lo <= code <= self.hi:
            raise ValueError(
                f"{name} = {asked:g} {self.unit} is outside what the pulser takes "
                f"({values[0]:g} … {values[1]:g} {self.unit}, in steps of "
                f"{self.per_count:g} {self.unit})"
            )
        return code


#: The knobs, by letter (module docstring).
KNOBS: Mapping[Letter, Knob] = {
    Letter.GAIN: Knob(Letter.GAIN, "gain_db", "dB", -120, 840, per_count=0.1),
    Letter.PRF: Knob(Letter.PRF, "prf_hz", "Hz", 1, 500, per_count=10.0),
    Letter.VOLTAGE: Knob(Letter.VOLTAGE, "pulse_voltage_v", "V", 50, 300),
    Letter.WIDTH: Knob(Letter.WIDTH, None, "ns", 10, 500),
    Letter.DAMPING: Knob(
        Letter.DAMPING, "damping_ohm", "Ω", 0, 3, table=(50.0, 100.0, 200.0, 500.0)
    ),
    Letter.LOW_PASS: Knob(
        Letter.LOW_PASS, "low_pass_mhz", "MHz", 0, 3, table=(12.0, 24.0, 48.0, 96.0)
    ),
}
#: The knobs ``PulserSettings`` sets, in the order they are written.
SETTINGS_KNOBS = (Letter.GAIN, Letter.PRF, Letter.VOLTAGE, Letter.DAMPING, Letter.LOW_PASS)


def command(letter: Letter, code: int) -> bytes:
    """``<letter><code>\\r``."""
    return f"{letter.value}{int(code)}".encode("ascii") + TERMINATOR


def query(letter: Letter) -> bytes:
    """``<letter>?\\r``."""
    return f"{letter.value}?".encode("ascii") + TERMINATOR


def answer(letter: Letter, code: int) -> bytes:
    """``<letter>=<code>\\r``: a query's answer."""
    return f"{letter.value}={int(code)}".encode("ascii") + TERMINATOR


def parse_answer(letter: Letter, line: bytes) -> int:
    """The code in ``<letter>=<n>`` (terminator stripped or not); ``ValueError`` otherwise."""
    text = line.rstrip(b"\r\n").decode("ascii", errors="replace").strip()
    head, sep, number = text.partition("=")
    if not sep or head != letter.value:
        raise ValueError(f"expected '{letter.value}=<n>', got {text!r}")
    try:
        return int(number)
    except ValueError:
        raise ValueError(f"expected '{letter.value}=<n>', got {text!r}") from None


def parse_line(line: bytes) -> tuple[Letter, int | None] | None:
    """What a device reads in one line: (letter, code) for a command, (letter, None) for a
    query, None for anything it does not understand."""
    text = line.rstrip(b"\r\n").decode("ascii", errors="replace").strip()
    if not text:
        return None
    try:
        letter = Letter(text[0].upper())
    except ValueError:
        return None
    rest = text[1:].strip()
    if rest == "?":
        return letter, None
    try:
        return letter, int(rest)
    except ValueError:
        return None


def settings_codes(settings: PulserSettings) -> dict[Letter, int]:
    """The codes of the knobs ``settings`` sets (``ValueError`` naming the first setting the
    device cannot take; nothing is clipped). The receiver's fixed high-pass must be asked as
    it is."""
    if abs(settings.high_pass_mhz - FIXED_HIGH_PASS_MHZ) > 1e-9:
        raise ValueError(
            f"high_pass_mhz = {settings.high_pass_mhz:g} MHz cannot be set: this pulser's "
            f"high-pass is fixed at {FIXED_HIGH_PASS_MHZ:g} MHz"
        )
    codes: dict[Letter, int] = {}
    for letter in SETTINGS_KNOBS:
        knob = KNOBS[letter]
        assert knob.field is not None
        codes[letter] = knob.code(float(getattr(settings, knob.field)))
    return codes


def transfer_s(chars: int, baud: int = DEFAULT_BAUD) -> float:
    """Time ``chars`` characters take on the serial line (s)."""
    return chars * BITS_PER_CHAR / baud
