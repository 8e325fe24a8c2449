"""A simulated oscilloscope on 127.0.0.1 that speaks SCPI over a raw TCP socket.

It plays the instrument of ``docs/protocols/scpi_digitizer.md`` (the subset of the Keysight
InfiniiVision / Rigol command set that ``drivers.digitizer.visa`` uses, plus the matching
queries): time base, vertical range, acquisition type and count, waveform format and transfer,
error queue. What it records is injected: ``signal(request) -> volts`` returns the analog input
of channel 1 (its noise included, averaged as asked) at the request's sample times; the scope
adds its own front end's noise (``noise_lsb``, one sigma in ADC levels, over √averages; a real
ADC is never quieter than a fraction of a level), quantises with its ADC (``bits`` over the 8
divisions of its vertical range), flags what is beyond the ADC (clipped codes) and answers the
preamble and the data block as a scope does. Its noise is drawn from a generator seeded
``seed``, in the order of the acquisitions.

Sample rate and length: the scope samples at ``sample_rate_hz`` unless ``:TIM:RANG`` does not
fit its memory (``memory_points``), then as fast as the memory allows; a record holds every
sample of the range (``:WAV:POIN:MODE RAW``, ``:WAV:POIN MAX``).

Acquisition policy: ``:DIGitize`` and ``:SINGle`` each make one acquisition (``signal`` is called
once; ``averages`` > 1 in average mode); ``*OPC?`` then answers 1. The time the averages take
at the trigger's rate is the signal's to let pass, as the simulated cell's does
(``ucal.sim.serve``, scaled by its time scale). ``:WAV:PRE?`` and
``:WAV:DATA?`` describe the latest acquisition. An unknown header or a bad value puts an error
in the queue (``:SYST:ERR?``: -113 undefined header, -222 data out of range, -224 illegal
parameter value, -230 data stale) and the command is ignored, as a scope does.

One connection is served at a time per client thread; the state is shared. Faults for tests:
:meth:`SimulatedScope.set_silent` (commands are read, never answered).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from drivers.digitizer import scpi
from drivers.digitizer.urls import format_digitizer_url, socket_resource
from drivers.loopback import LoopbackServer

log = logging.getLogger(__name__)

#: What ``*IDN?`` answers.
IDN = "UCAL,SIMULATED SCOPE,SIM0001,1.0"
#: Vertical divisions the ADC spans, and horizontal ones of ``:TIM:RANG``.
VERTICAL_DIVISIONS = 8


@dataclass(frozen=True)
class AcquisitionRequest:
    """What one acquisition records: ``n`` samples, sample k at ``t0_ns + k·dt_ns`` after the
    trigger, averaging ``averages`` acquisitions."""

    t0_ns: float
    dt_ns: float
    n: int
    averages: int

    @property
    def t_ns(self) -> np.ndarray:
        """Time of each sample (ns)."""
        return self.t0_ns + self.dt_ns * np.arange(self.n)


#: ``signal(request) -> volts (n,)``: the analog input of channel 1.
SignalModel = Callable[[AcquisitionRequest], np.ndarray]

#: Long forms of the mnemonics used, and their short forms (SCPI: either is accepted).
_SHORT = {
    "WAVEFORM": "WAV",
    "SOURCE": "SOUR",
    "FORMAT": "FORM",
    "BYTEORDER": "BYT",
    "UNSIGNED": "UNS",
    "POINTS": "POIN",
    "PREAMBLE": "PRE",
    "TIMEBASE": "TIM",
    "RANGE": "RANG",
    "POSITION": "POS",
    "REFERENCE": "REF",
    "TRIGGER": "TRIG",
    "ACQUIRE": "ACQ",
    "COUNT": "COUN",
    "SRATE": "SRAT",
    "DIGITIZE": "DIG",
    "SINGLE": "SING",
    "SYSTEM": "SYST",
    "ERROR": "ERR",
    "OFFSET": "OFFS",
    "CHANNEL1": "CHAN1",
    "CHANNEL": "CHAN1",
    "CHAN": "CHAN1",
}
_WORDS = {
    "AVERAGE": "AVER",
    "NORMAL": "NORM",
    "CENTER": "CENT",
    "EXTERNAL": "EXT",
    "CHANNEL1": "CHAN1",
    "CHANNEL": "CHAN1",
    "MSBFIRST": "MSBF",
    "LSBFIRST": "LSBF",
    "MAXIMUM": "MAX",
    "MINIMUM": "MIN",
    "ASCII": "ASC",
    "ON": "1",
    "OFF": "0",
}


class _Refused(Exception):
    """A command the scope does not take: its error queue entry."""

    def __init__(self, code: int, text: str):
        super().__init__(f'{code},"{text}"')
        self.entry = f'{code},"{text}"'


def _header(text: str) -> str:
    """The short form of a command header (``:WAVeform:DATA?`` → ``:WAV:DATA?``)."""
    if text.startswith("*"):
        return text.upper()
    query = text.endswith("?")
    nodes = text.upper().rstrip("?").lstrip(":").split(":")
    return ":" + ":".join(_SHORT.get(n, n) for n in nodes) + ("?" if query else "")


class SimulatedScope(LoopbackServer):
    """A SCPI oscilloscope on 127.0.0.1 whose channel 1 sees ``signal``. Context manager.

    ``sample_rate_hz`` is its fastest sampling, ``bits`` its ADC's resolution (8 … 16),
    ``memory_points`` its record memory, ``noise_lsb`` its front end's noise (ADC levels, one
    sigma) drawn with ``seed``. ``port`` 0 picks a free port; :attr:`url` tells it after
    :meth:`start`. Nothing is opened before :meth:`start`.
    """

    what = "simulated scope"
    terminator = scpi.TERMINATOR

    def __init__(
        self,
        signal: SignalModel,
        host: str = "127.0.0.1",
        port: int = 0,
        sample_rate_hz: float = 200e6,
        bits: int = 12,
        memory_points: int = 4_000_000,
        noise_lsb: float = 0.5,
        seed: int = 0,
    ):
        if not callable(signal):
            raise TypeError("signal must be callable: signal(request) -> volts")
        super().__init__(host, port)
        if not (math.isfinite(sample_rate_hz) and sample_rate_hz > 0):
            raise ValueError(f"sample_rate_hz must be positive, got {sample_rate_hz!r}")
        if not 8 <= int(bits) <= 16:
            raise ValueError(f"bits must be 8 … 16, got {bits!r}")
        self.signal = signal
        self.sample_rate_hz = float(sample_rate_hz)
        self.bits = int(bits)
        self.memory_points = int(memory_points)
        if not (math.isfinite(noise_lsb) and noise_lsb >= 0):
            raise ValueError(f"noise_lsb must be 0 or more, got {noise_lsb!r}")
        self.noise_lsb = float(noise_lsb)
        self._rng = np.random.default_rng(int(seed))
        self.acquisitions = 0  #: acquisitions made (``signal`` calls)
        self._reset()

    def _reset(self) -> None:
        """Power-on state (``*RST``)."""
        self.state: dict[str, str] = {
            ":WAV:SOUR": "CHAN1",
            ":WAV:FORM": "BYTE",
            ":WAV:BYT": "MSBF",
            ":WAV:UNS": "1",
            ":WAV:POIN:MODE": "NORM",
            ":WAV:POIN": "1000",
            ":TIM:RANG": "1.000000E-03",
            ":TIM:POS": "0",
            ":TIM:REF": "CENT",
            ":TRIG:EDGE:SOUR": "CHAN1",
            ":ACQ:TYPE": "NORM",
            ":ACQ:COUN": "8",
            ":CHAN1:RANG": "8.0",
            ":CHAN1:OFFS": "0",
        }
        self._errors: list[str] = []
        self._last: tuple[scpi.Preamble, np.ndarray] | None = None

    @property
    def resource(self) -> str:
        """``TCPIP::127.0.0.1::PORT::SOCKET``."""
        return socket_resource(self.host, self.port)

    @property
    def url(self) -> str:
        """``visa://TCPIP::127.0.0.1::PORT::SOCKET``."""
        return format_digitizer_url(self.resource)

    # --- the instrument ---------------------------------------------------------------------
    def _float(self, key: str) -> float:
        return float(self.state[key])

    def request(self) -> AcquisitionRequest:
        """What the next acquisition records, from the time base and acquisition settings."""
        width_s = self._float(":TIM:RANG")
        dt_s = max(1.0 / self.sample_rate_hz, width_s / max(self.memory_points - 1, 1))
        n = math.floor(width_s / dt_s + 1e-9) + 1
        start_s = self._float(":TIM:POS")
        if self.state[":TIM:REF"] == "CENT":
            start_s -= 0.5 * width_s
        averages = int(self.state[":ACQ:COUN"]) if self.state[":ACQ:TYPE"] == "AVER" else 1
        return AcquisitionRequest(start_s * 1e9, dt_s * 1e9, n, averages)

    def _acquire(self) -> None:
        request = self.request()
        volts = np.asarray(self.signal(request), float)
        if volts.shape != (request.n,):
            raise ValueError(f"signal returned shape {volts.shape}, expected ({request.n},)")
        self.acquisitions += 1
        fmt = scpi.WaveFormat.WORD if self.state[":WAV:FORM"] == "WORD" else scpi.WaveFormat.BYTE
        step_v = self._float(":CHAN1:RANG") / 2**self.bits  # one ADC level
        levels = (volts - self._float(":CHAN1:OFFS")) / step_v
        if self.noise_lsb > 0:
            noise = self._rng.standard_normal(request.n, dtype=np.float32)
            levels += noise * (self.noise_lsb / math.sqrt(request.averages))
        adc = np.rint(levels)
        top = 2 ** (self.bits - 1) - 1
        if fmt == scpi.WaveFormat.WORD:
            shift = 2 ** (16 - self.bits)
            y_increment = step_v / shift
        else:
            shift = 2 ** (self.bits - 8)
            adc = np.floor(adc / shift)  # right-shifted: truncated
            top = 126  # 0x02 … 0xFE: 0x01 and 0xFF flag clipping
            shift, y_increment = 1, step_v * shift
        np.clip(adc, -top - 1, top + 1, out=adc)
        codes = (scpi.CENTRE_CODE[fmt] + adc * shift).astype(np.int64)
        if adc.min() < -top or adc.max() > top:  # beyond the ADC: the clipped codes
            codes[adc > top] = scpi.CLIP_HIGH[fmt]
            codes[adc < -top] = scpi.CLIP_LOW[fmt]
        preamble = scpi.Preamble(
            format=fmt,
            type=scpi.AcquireType.AVERAGE if request.averages > 1 else scpi.AcquireType.NORMAL,
            points=request.n,
            count=request.averages,
            x_increment_s=request.dt_ns * 1e-9,
            x_origin_s=request.t0_ns * 1e-9,
            x_reference=0,
            y_increment_v=y_increment,
            y_origin_v=self._float(":CHAN1:OFFS"),
            y_reference=scpi.CENTRE_CODE[fmt],
        )
        self._last = (preamble, codes)

    def execute(self, message: str) -> bytes | None:
        """Run one program message; the answer bytes (LF included), or None."""
        answers: list[bytes] = []
        path = ""
        with self._lock:
            for part in message.strip().split(";"):
                command = part.strip()
                if not command:
                    continue
                head, _, arg = command.partition(" ")
                if not head.startswith((":", "*")) and path:
                    head = path + ":" + head  # SCPI: relative to the previous command's path
                head = _header(head)
                if not head.startswith("*"):
                    path = head.rsplit(":", 1)[0]
                try:
                    answer = self._command(head, arg.strip())
                except _Refused as e:
                    self._errors.append(e.entry)
                    log.debug("simulated scope refused %r: %s", command, e.entry)
                    continue
                except Exception:  # a failing signal model is a hardware error, not a crash
                    log.exception("simulated scope: %r failed", command)
                    self._errors.append('-240,"Hardware error"')
                    self._last = None
                    continue
                if answer is not None:
                    answers.append(answer)
        if not answers:
            return None
        return b";".join(answers) + scpi.TERMINATOR

    def _command(self, head: str, arg: str) -> bytes | None:
        word = _WORDS.get(arg.upper(), arg.upper())
        if head == "*IDN?":
            return IDN.encode()
        if head == "*OPC?":
            return b"1"
        if head == "*CLS":
            self._errors.clear()
            return None
        if head == "*RST":
            self._reset()
            return None
        if head == ":SYST:ERR?":
            return (self._errors.pop(0) if self._errors else '+0,"No error"').encode()
        if head in (":DIG", ":SING"):
            self._acquire()
            return None
        if head == ":WAV:PRE?":
            if self._last is None:
                raise _Refused(-230, "Data corrupt or stale")
            return scpi.format_preamble(self._last[0]).encode()
        if head == ":WAV:DATA?":
            if self._last is None:
                raise _Refused(-230, "Data corrupt or stale")
            preamble, codes = self._last
            order = self.state[":WAV:BYT"]
            return scpi.format_block(scpi.encode_codes(codes, preamble.format, order), 9)
        if head == ":ACQ:SRAT?":
            return f"{1e9 / self.request().dt_ns:.6E}".encode()
        if head == ":WAV:POIN?":
            return str(self.request().n).encode()
        if head.endswith("?") and head[:-1] in self.state:
            return self.state[head[:-1]].encode()
        if head not in self.state:
            raise _Refused(-113, "Undefined header")
        self.state[head] = self._value(head, word)
        return None

    def _value(self, head: str, word: str) -> str:
        """Check a setting's argument; the value stored."""
        choices = {
            ":WAV:SOUR": ("CHAN1",),
            ":WAV:FORM": ("BYTE", "WORD"),
            ":WAV:BYT": ("MSBF", "LSBF"),
            ":WAV:UNS": ("1",),
            ":WAV:POIN:MODE": ("NORM", "RAW", "MAX"),
            ":TIM:REF": ("LEFT", "CENT"),
            ":TRIG:EDGE:SOUR": ("EXT", "CHAN1"),
            ":ACQ:TYPE": ("NORM", "AVER"),
        }
        if head in choices:
            if word not in choices[head]:
                raise _Refused(-224, "Illegal parameter value")
            return word
        if head == ":WAV:POIN" and word in ("MAX", "MIN"):
            return word
        try:
            value = float(word)
        except ValueError:
            raise _Refused(-224, "Illegal parameter value") from None
        limits = {
            ":WAV:POIN": (100.0, float(self.memory_points)),
            ":TIM:RANG": (1e-9, 50.0),
            ":TIM:POS": (-50.0, 50.0),
            ":ACQ:COUN": (2.0, 65536.0),
            ":CHAN1:RANG": (8e-3, 40.0),
            ":CHAN1:OFFS": (-20.0, 20.0),
        }
        lo, hi = limits[head]
        if not (math.isfinite(value) and lo <= value <= hi):
            raise _Refused(-222, "Data out of range")
        if head == ":ACQ:COUN" and value != round(value):
            raise _Refused(-224, "Illegal parameter value")
        return word

    # --- server threads ---------------------------------------------------------------------
    def _answer(self, line: bytes) -> bytes | None:
        return self.execute(line.decode("ascii", errors="replace"))
