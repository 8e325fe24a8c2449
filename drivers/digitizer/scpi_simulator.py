"""A simulated oscilloscope on 127.0.0.1 that speaks SCPI over a raw TCP socket, in the dialect
of one family (``docs/protocols/scpi_digitizer.md``).

The instrument is data: a family (``drivers.digitizer.simulated_scopes``: its ``*IDN?``, its
mnemonics, every setting with its power-on value and what it takes, its actions and queries,
its preamble's codes) for the Keysight InfiniiVision X-Series and the Rigol DS1000Z; the code
below plays any of them. Both answer every IEEE 488.2 mandatory common command (§10: ``*CLS``,
``*ESE``, ``*ESE?``, ``*ESR?``, ``*IDN?``, ``*OPC``, ``*OPC?``, ``*RST``, ``*SRE``, ``*SRE?``,
``*STB?``, ``*TST?``, ``*WAI``) with the status model of §11, minimal but right: the standard
event status register (bit 0 OPC, 2 query error, 3 device-dependent error, 4 execution error, 5
command error, 7 power on, set at power-on), read and cleared by ``*ESR?``, summarised in the
status byte's bit 5 (ESB) through ``*ESE``; bit 4 (MAV) when an answer waits in the output
queue; bit 6 (MSS) when a bit enabled by ``*SRE`` is set; a Keysight adds bit 0 (TRG, its
trigger event register). ``*TST?`` answers 0 (passed), ``*OPC?`` 1 (every operation here
completes in order), ``*RST`` restores every setting's power-on value. An unknown header or a
bad value puts an error in the queue, read by ``:SYSTem:ERRor?`` (−113 undefined header, −109
missing parameter, −222 data out of range, −224 illegal parameter value, −230 data stale, −240
hardware error, −350 queue overflow), and the command is ignored, as a scope does.

What it records is injected: ``signal(request) -> volts`` returns the analog input of channel 1
(its noise included, averaged as asked) at the request's sample times; the scope adds its own
front end's noise (``noise_lsb``, one sigma in ADC levels, over √averages), quantises with its
ADC (a Keysight's ``bits`` over the 8 divisions of its vertical range, left-aligned in WORD; a
Rigol's 8 bits, 25 codes a division about code 127), flags what is beyond the ADC and answers
the preamble and the data block as its family does. Its noise is drawn from a generator seeded
``seed``, in the order of the acquisitions.

The trigger: the pulser's sync output (a pulse of ``sync_v`` volts at t = 0) is wired to
``sync_input`` (default: the family's, EXT on a Keysight, CHAN2 on a Rigol). An acquisition
triggers when the edge trigger's source is that input and its level lies between 0 and
``sync_v``. Otherwise, in AUTO sweep it auto-triggers (the record is taken at a time unrelated
to the pulse: its echo anywhere or nowhere; a Keysight's trigger event register stays 0); in
NORMal or SINGle sweep it waits: a Keysight's ``:DIGitize`` then answers nothing more of its
program message (the next message ends the wait), a Rigol's ``:TRIGger:STATus?`` stays WAIT.

Sample rate and length: the scope samples at ``sample_rate_hz`` unless the screen's time does
not fit its memory (``memory_points``), then as fast as the memory allows. The time the
averages take at the trigger's rate is the signal's to let pass, as the simulated cell's does
(``ucal.sim.serve``).

One connection is served at a time per client thread; the state is shared. Faults for tests:
:meth:`SimulatedScope.set_silent` (commands are read, never answered).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from drivers.digitizer import scpi
from drivers.digitizer.simulated_scopes import FAMILIES, WORDS
from drivers.digitizer.urls import format_digitizer_url, socket_resource
from drivers.loopback import LoopbackServer

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class AcquisitionRequest:
    """What one acquisition records: ``n`` samples, sample k at ``t0_ns + k·dt_ns`` after the
    pulse, averaging ``averages`` acquisitions; ``triggered`` False when the scope took it
    without a trigger (its times are then unrelated to the pulse)."""

    t0_ns: float
    dt_ns: float
    n: int
    averages: int
    triggered: bool = True

    @property
    def t_ns(self) -> np.ndarray:
        """Time of each sample (ns)."""
        return self.t0_ns + self.dt_ns * np.arange(self.n)


#: ``signal(request) -> volts (n,)``: the analog input of channel 1.
SignalModel = Callable[[AcquisitionRequest], np.ndarray]


#: IEEE 488.2 §11.5.1: the standard event status register's bits.
ESR_OPC, ESR_QYE, ESR_DDE, ESR_EXE, ESR_CME, ESR_PON = 0x01, 0x04, 0x08, 0x10, 0x20, 0x80
#: IEEE 488.2 §11.2: the status byte's bits (MAV, ESB, MSS), and a Keysight's TRG.
STB_TRG, STB_MAV, STB_ESB, STB_MSS = 0x01, 0x10, 0x20, 0x40
#: Entries the error queue holds; past them the last is −350 "Queue overflow".
ERROR_QUEUE = 30
#: An auto-triggered record is taken this long (ns, at most) away from the pulse.
UNTRIGGERED_SPREAD_NS = 1e6
#: A Rigol's codes: a division's worth, and the code of the screen's centre.
RIGOL_CODES_PER_DIVISION = 25
RIGOL_CENTRE_CODE = 127
#: A Rigol's points on screen (:WAVeform:MODE NORMal).
RIGOL_SCREEN_POINTS = 1200


class _Refused(Exception):
    """A command the scope does not take: its error queue entry."""

    def __init__(self, code: int, text: str):
        super().__init__(f'{code},"{text}"')
        self.code = code
        self.text = text


class _Waiting(Exception):
    """The scope waits for a trigger: nothing more of the program message is answered."""


def _nearest_125(value: float) -> float:
    """The 1-2-5 value nearest ``value`` (> 0) on a log scale."""
    exponent = math.floor(math.log10(value))
    candidates = [m * 10.0**e for e in (exponent - 1, exponent, exponent + 1) for m in (1, 2, 5)]
    return min(candidates, key=lambda c: abs(math.log(c / value)))


class SimulatedScope(LoopbackServer):
    """A SCPI oscilloscope of ``family`` (``FAMILIES``) on 127.0.0.1 whose channel 1 sees
    ``signal``. Context manager.

    ``sample_rate_hz`` is its fastest sampling, ``bits`` its ADC's resolution (8 … 16; None:
    the family's, 12 for a Keysight; a Rigol's is 8), ``memory_points`` its record memory
    (None: the family's), ``noise_lsb`` its front end's noise (ADC levels, one sigma) drawn with
    ``seed``; ``sync_input`` the input the pulser's sync output is wired to (None: the
    family's) and ``sync_v`` its pulse's height (V); ``on_transfer(points, bytes)`` is told of
    every data block before it is answered. ``port`` 0 picks a free port; :attr:`url`
    tells it after :meth:`start`. Nothing is opened before :meth:`start`.
    """

    what = "simulated scope"
    terminator = scpi.TERMINATOR

    def __init__(
        self,
        signal: SignalModel,
        host: str = "127.0.0.1",
        port: int = 0,
        sample_rate_hz: float = 200e6,
        bits: int | None = None,
        memory_points: int | None = None,
        noise_lsb: float = 0.5,
        seed: int = 0,
        *,
        family: str = "keysight",
        sync_input: str | None = None,
        sync_v: float = 5.0,
        on_transfer: Callable[[int, int], None] | None = None,
    ):
        if not callable(signal):
            raise TypeError("signal must be callable: signal(request) -> volts")
        super().__init__(host, port)
        if family not in FAMILIES:
            raise ValueError(f"family must be one of {', '.join(FAMILIES)}, got {family!r}")
        self.family = FAMILIES[family]
        if not (math.isfinite(sample_rate_hz) and sample_rate_hz > 0):
            raise ValueError(f"sample_rate_hz must be positive, got {sample_rate_hz!r}")
        bits = self.family.default_bits if bits is None else int(bits)
        if self.family.fixed_bits and bits != self.family.default_bits:
            raise ValueError(
                f"a simulated {family} scope has a {self.family.default_bits}-bit ADC, "
                f"got bits={bits}"
            )
        if not 8 <= bits <= 16:
            raise ValueError(f"bits must be 8 … 16, got {bits!r}")
        if not (math.isfinite(noise_lsb) and noise_lsb >= 0):
            raise ValueError(f"noise_lsb must be 0 or more, got {noise_lsb!r}")
        if not (math.isfinite(sync_v) and sync_v > 0):
            raise ValueError(f"sync_v must be a positive voltage, got {sync_v!r}")
        self.signal = signal
        self.sample_rate_hz = float(sample_rate_hz)
        self.bits = bits
        self.memory_points = int(memory_points or self.family.default_memory_points)
        self.noise_lsb = float(noise_lsb)
        self.sync_input = sync_input or self.family.sync_input
        self.sync_v = float(sync_v)
        #: ``on_transfer(points, bytes)``: told of every data block before it is answered
        #: (the simulated cell lets its transfer time pass there).
        self.on_transfer = on_transfer
        self._rng = np.random.default_rng(int(seed))
        self._trigger_rng = np.random.default_rng([int(seed), 0x7819])
        self.acquisitions = 0  #: acquisitions made (``signal`` calls)
        self._esr = ESR_PON  # IEEE 488.2 §11.5.1.1.2: power on
        self._ese = 0
        self._sre = 0
        self._errors: list[str] = []
        self._reset()

    def _reset(self) -> None:
        """Every setting's power-on value, and no record (``*RST``; the status registers and
        the error queue are kept, IEEE 488.2 §10.32)."""
        self.state: dict[str, str] = {h: s.default for h, s in self.family.settings.items()}
        self._last: tuple[scpi.Preamble, np.ndarray, str] | None = None
        self._trigger_event = False
        self._running = True
        self._single = ""  # a Rigol's single sweep: "" none, "WAIT" armed, "TD" just triggered

    @property
    def resource(self) -> str:
        """``TCPIP::127.0.0.1::PORT::SOCKET``."""
        return socket_resource(self.host, self.port)

    @property
    def url(self) -> str:
        """``visa://TCPIP::127.0.0.1::PORT::SOCKET``."""
        return format_digitizer_url(self.resource)

    # --- the trigger ------------------------------------------------------------------------
    def _role(self, role: str) -> str:
        return self.state[self.family.roles[role]]

    def can_trigger(self) -> bool:
        """Whether the sync output reaches the edge trigger as set: its input, a level it
        crosses."""
        return (
            self._role("trigger mode") == "EDGE"
            and self._role("source") == self.sync_input
            and 0.0 < float(self._role("level")) < self.sync_v
        )

    def trigger_status(self) -> str:
        """A Rigol's ``:TRIGger:STATus?``: TD, WAIT, RUN, AUTO or STOP."""
        if self._single:
            state, self._single = self._single, "" if self._single == "TD" else self._single
            return state
        if not self._running:
            return "STOP"
        if self.can_trigger():
            return "TD"
        return "AUTO" if self._role("sweep") == "AUTO" else "WAIT"

    # --- the instrument ---------------------------------------------------------------------
    def request(self) -> AcquisitionRequest:
        """What the next acquisition records, from the time base and acquisition settings."""
        f = self.family
        if f.timebase == "range":
            width_s = float(self._role("width"))
            where = {"LEFT": 0.0, "CENT": 0.5, "RIGH": 1.0}[self._role("reference")]
            start_s = float(self._role("start")) - where * width_s
        else:
            scale = float(self._role("scale"))
            width_s = f.divisions * scale
            start_s = float(self._role("start")) - 0.5 * width_s
        dt_s = max(1.0 / self.sample_rate_hz, width_s / max(self.memory_points - 1, 1))
        n = math.floor(width_s / dt_s + 1e-9) + 1
        averages = int(self._role("count")) if self._role("type") == "AVER" else 1
        return AcquisitionRequest(start_s * 1e9, dt_s * 1e9, n, averages)

    def _acquire(self, triggered: bool) -> None:
        request = self.request()
        seen = request
        if not triggered:  # a record taken at a time unrelated to the pulse
            shift = float(self._trigger_rng.uniform(0.0, UNTRIGGERED_SPREAD_NS))
            seen = AcquisitionRequest(
                request.t0_ns + shift, request.dt_ns, request.n, request.averages, False
            )
        volts = np.asarray(self.signal(seen), float)
        if volts.shape != (request.n,):
            raise ValueError(f"signal returned shape {volts.shape}, expected ({request.n},)")
        self.acquisitions += 1
        if self.family.codes == "keysight":
            self._last = self._keysight_record(request, volts)
        else:
            self._last = self._rigol_record(request, volts)
        if triggered:
            self._trigger_event = True

    def _noisy_levels(self, volts: np.ndarray, step_v: float, averages: int) -> np.ndarray:
        """The ADC's input in levels of ``step_v``, its front end's noise added."""
        levels = volts / step_v
        if self.noise_lsb > 0:
            noise = self._rng.standard_normal(volts.size, dtype=np.float32)
            levels += noise * (self.noise_lsb / math.sqrt(averages))
        return levels

    def _keysight_record(
        self, request: AcquisitionRequest, volts: np.ndarray
    ) -> tuple[scpi.Preamble, np.ndarray, str]:
        fmt = self._role("format")
        word = fmt in ("WORD", "ASC")
        offset_v = float(self._role("offset"))
        step_v = float(self._role("range")) / 2**self.bits  # one ADC level
        adc = np.rint(self._noisy_levels(volts - offset_v, step_v, request.averages))
        top = 2 ** (self.bits - 1) - 1
        centre, low, high = (0x8000, 0x0001, 0xFFFF) if word else (0x80, 0x01, 0xFF)
        if word:
            shift = 2 ** (16 - self.bits)
            y_increment = step_v / shift
        else:
            shift = 2 ** (self.bits - 8)
            adc = np.floor(adc / shift)  # right-shifted: truncated
            top = 126  # 0x02 … 0xFE: 0x01 and 0xFF flag clipping
            shift, y_increment = 1, step_v * shift
        np.clip(adc, -top - 1, top + 1, out=adc)
        codes = (centre + adc * shift).astype(np.int64)
        codes[adc > top] = high
        codes[adc < -top] = low
        kind = self._role("type")
        preamble = scpi.Preamble(
            format=fmt,
            type=kind if kind in self.family.preamble_types else "NORM",
            points=request.n,
            count=request.averages if kind == "AVER" else 1,
            x_increment_s=request.dt_ns * 1e-9,
            x_origin_s=request.t0_ns * 1e-9,
            x_reference=0,
            y_increment_v=y_increment,
            y_origin=offset_v,
            y_reference=centre,
        )
        return preamble, codes, fmt

    def _rigol_record(
        self, request: AcquisitionRequest, volts: np.ndarray
    ) -> tuple[scpi.Preamble, np.ndarray, str]:
        scale_v = float(self._role("range"))
        y_increment = scale_v / RIGOL_CODES_PER_DIVISION
        y_origin = round(float(self._role("offset")) / y_increment)
        levels = self._noisy_levels(volts, y_increment, request.averages)
        codes = np.clip(np.rint(levels) + y_origin + RIGOL_CENTRE_CODE, 0, 255).astype(np.int64)
        preamble = scpi.Preamble(
            format="BYTE",
            type="RAW",
            points=request.n,
            count=request.averages,
            x_increment_s=request.dt_ns * 1e-9,
            x_origin_s=request.t0_ns * 1e-9,
            x_reference=0,
            y_increment_v=y_increment,
            y_origin=float(y_origin),
            y_reference=RIGOL_CENTRE_CODE,
            y_origin_in_codes=True,
        )
        return preamble, codes, "BYTE"

    def _transfer(self) -> tuple[scpi.Preamble, np.ndarray]:
        """The latest record as it is read: a Rigol's screen (NORMal) or memory (RAW, MAX
        while stopped) in the format set; a Keysight's as acquired."""
        if self._last is None:
            raise _Refused(-230, "Data corrupt or stale")
        preamble, codes, _ = self._last
        fmt = self._role("format")
        if self.family.codes == "rigol":
            count = preamble.count if self._role("type") == "AVER" else 1
            mode = self._role("mode")
            if mode == "NORM" or (mode == "MAX" and self._running):
                pick = np.rint(np.linspace(0, codes.size - 1, RIGOL_SCREEN_POINTS)).astype(int)
                codes = codes[pick]
                width_s = preamble.x_increment_s * (preamble.points - 1)
                # NORMal: XINCrement = TimeScale/100, 1200 points over the 12 divisions
                preamble = replace(preamble, x_increment_s=width_s / RIGOL_SCREEN_POINTS)
            preamble = replace(preamble, format=fmt, type=mode, points=codes.size, count=count)
        elif fmt != preamble.format:  # a Keysight reads what it acquired in the format asked
            preamble, codes = self._keysight_format(preamble, codes, fmt)
        return preamble, codes

    @staticmethod
    def _keysight_format(
        p: scpi.Preamble, codes: np.ndarray, fmt: str
    ) -> tuple[scpi.Preamble, np.ndarray]:
        word = fmt in ("WORD", "ASC")
        was_word = p.format in ("WORD", "ASC")
        if word == was_word:
            return replace(p, format=fmt), codes
        if word:  # BYTE → WORD: left-shifted by 8
            return replace(
                p, format=fmt, y_increment_v=p.y_increment_v / 256, y_reference=0x8000
            ), (codes * 256)
        flags_low, flags_high = codes == 0x0001, codes == 0xFFFF
        narrow = codes // 256
        narrow[flags_low], narrow[flags_high] = 0x01, 0xFF
        return replace(p, format=fmt, y_increment_v=p.y_increment_v * 256, y_reference=0x80), narrow

    def _preamble_text(self, p: scpi.Preamble) -> str:
        """The preamble as the family writes it: a Keysight's floats to the last bit and its y
        origin in volts, a Rigol's floats to 7 digits and its y origin in codes."""
        f = self.family
        head = (
            f"{f.preamble_formats[p.format]},{f.preamble_types.get(p.type, 0)},{p.points},{p.count}"
        )
        if f.codes == "rigol":
            return (
                f"{head},{p.x_increment_s:.6e},{p.x_origin_s:.6e},{p.x_reference},"
                f"{p.y_increment_v:.6e},{int(p.y_origin)},{p.y_reference}"
            )
        return (
            f"{head},{p.x_increment_s!r},{p.x_origin_s!r},{p.x_reference},"
            f"{p.y_increment_v!r},{float(p.y_origin)!r},{p.y_reference}"
        )

    def _data(self) -> bytes:
        """``:WAVeform:DATA?``: the block of the points set (a Rigol's ``:WAV:STARt`` …
        ``:WAV:STOP``, at most its largest read), after ``on_transfer`` has had them."""
        p, codes = self._transfer()
        f = self.family
        if f.codes == "rigol":
            first, last = int(self._role("first")), int(self._role("last"))
            last = min(last, codes.size)
            most = f.max_points.get(p.format, codes.size)
            if first > last or last - first + 1 > most:
                raise _Refused(-222, "Data out of range")
            codes = codes[first - 1 : last]
        if p.format == "ASC":
            payload = scpi.encode_ascii(p.volts(codes))
        elif f.codes == "keysight" and self._role("unsigned") == "0":
            dtype = ">i2" if p.format == "WORD" else "i1"
            if p.format == "WORD" and self._role("byte order") == "LSBF":
                dtype = "<i2"
            payload = (codes - p.y_reference).astype(dtype).tobytes()
        else:
            order = self._role("byte order") if f.codes == "keysight" else "LSBF"
            payload = scpi.encode_codes(codes, 2 if p.format == "WORD" else 1, order)
        if self.on_transfer is not None:
            self.on_transfer(int(codes.size), len(payload))
        return scpi.format_block(payload, 9)

    # --- messages ---------------------------------------------------------------------------
    def _header(self, text: str) -> str:
        """The short form of a command header (``:WAVeform:DATA?`` → ``:WAV:DATA?``), with
        the family's optional nodes resolved."""
        if text.startswith("*"):
            return text.upper()
        query = text.endswith("?")
        nodes = text.upper().rstrip("?").lstrip(":").split(":")
        head = ":" + ":".join(self.family.mnemonics.get(n, n) for n in nodes)
        if query:
            asked = head + "?"
            return self.family.aliases.get(asked, self.family.aliases.get(head, head) + "?")
        return self.family.aliases.get(head, head)

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
                head = self._header(head)
                if not head.startswith("*"):
                    path = head.rsplit(":", 1)[0]
                try:
                    answer = self._command(head, arg.strip(), bool(answers))
                except _Refused as e:
                    self._error(e.code, e.text)
                    log.debug("simulated scope refused %r: %d %s", command, e.code, e.text)
                    continue
                except _Waiting:  # its answer is never completed: none of it is sent
                    log.debug("simulated scope: %r waits for a trigger", command)
                    return None
                except Exception:  # a failing signal model is a hardware error, not a crash
                    log.exception("simulated scope: %r failed", command)
                    self._error(-240, "Hardware error")
                    self._last = None
                    continue
                if answer is not None:
                    answers.append(answer)
        if not answers:
            return None
        return b";".join(answers) + scpi.TERMINATOR

    def _error(self, code: int, text: str) -> None:
        """Queue an error and set its class's bit in the event status register (IEEE 488.2
        §11.5.1.1: −1xx command, −2xx execution, −3xx device-dependent, −4xx query)."""
        if len(self._errors) >= ERROR_QUEUE:
            self._errors[-1] = self._entry(-350, "Queue overflow")
        else:
            self._errors.append(self._entry(code, text))
        self._esr |= {1: ESR_CME, 2: ESR_EXE, 3: ESR_DDE, 4: ESR_QYE}.get(-code // 100, 0)

    def _entry(self, code: int, text: str) -> str:
        return f'{self.family.integer(code)},"{text}"'

    def status_byte(self, message_available: bool = False) -> int:
        """IEEE 488.2 §11.2: MAV, ESB and MSS (and a Keysight's TRG)."""
        stb = STB_MAV if message_available else 0
        if self._esr & self._ese:
            stb |= STB_ESB
        if self.family.name == "keysight" and self._trigger_event:
            stb |= STB_TRG
        if stb & self._sre & ~STB_MSS:
            stb |= STB_MSS
        return stb

    def _common(self, head: str, arg: str, message_available: bool) -> bytes | None:
        """The IEEE 488.2 common commands (§10)."""
        f = self.family
        if head == "*IDN?":
            return f.idn.encode()
        if head == "*CLS":  # §10.3: clears the event registers and the error queue
            self._esr, self._errors, self._trigger_event = 0, [], False
            return None
        if head in ("*ESE", "*SRE"):
            value = self._register_value(arg)
            if head == "*ESE":
                self._ese = value
            else:
                self._sre = value & ~STB_MSS  # §11.3.2.3: bit 6 is not enabled
            return None
        if head == "*ESE?":
            return f.integer(self._ese).encode()
        if head == "*SRE?":
            return f.integer(self._sre).encode()
        if head == "*ESR?":  # §10.12: read and cleared
            value, self._esr = self._esr, 0
            return f.integer(value).encode()
        if head == "*STB?":
            return f.integer(self.status_byte(message_available)).encode()
        if head == "*OPC":  # §10.18: every operation here is complete once parsed
            self._esr |= ESR_OPC
            return None
        if head == "*OPC?":
            return b"1"
        if head == "*RST":
            self._reset()
            return None
        if head == "*TST?":  # §10.38: 0 = the self-test passed
            return f.integer(0).encode()
        if head == "*WAI":
            return None
        raise _Refused(-113, "Undefined header")

    @staticmethod
    def _register_value(arg: str) -> int:
        if not arg:
            raise _Refused(-109, "Missing parameter")
        try:
            value = float(arg)
        except ValueError:
            raise _Refused(-104, "Data type error") from None
        if not (math.isfinite(value) and 0 <= round(value) <= 255):
            raise _Refused(-222, "Data out of range")
        return round(value)

    def _command(self, head: str, arg: str, message_available: bool) -> bytes | None:
        f = self.family
        if head.startswith("*"):
            return self._common(head, arg, message_available)
        if head in f.actions:
            return self._action(f.actions[head])
        if head in f.queries:
            return self._query(f.queries[head])
        if head.endswith("?"):
            setting = head[:-1]
            if setting in f.linked:
                stored, factor = f.linked[setting]
                return f.number(float(self.state[stored]) / factor).encode()
            if setting in f.settings:
                return self.state[setting].encode()
            raise _Refused(-113, "Undefined header")
        if head in f.linked:
            stored, factor = f.linked[head]
            value = self._value(stored, WORDS.get(arg.upper(), arg.upper()), factor)
            self.state[stored] = value
            return None
        if head not in f.settings:
            raise _Refused(-113, "Undefined header")
        self.state[head] = self._value(head, WORDS.get(arg.upper(), arg.upper()))
        return None

    def _action(self, action: str) -> bytes | None:
        f = self.family
        if action == "run":
            self._running, self._single = True, ""
        elif action == "stop":
            self._running, self._single = False, ""
        elif action == "digitize":  # a Keysight's :DIGitize (and :SINGle): one acquisition
            if self.can_trigger():
                self._acquire(triggered=True)
            elif self.state[f.roles["sweep"]] == "AUTO":
                self._acquire(triggered=False)
            else:
                raise _Waiting
            self._running = False
        elif action == "single":  # a Rigol's :SINGle: the single sweep, armed
            self.state[f.roles["sweep"]] = "SING"
            self._running = False
            if self.can_trigger():
                self._acquire(triggered=True)
                self._single = "TD"
            else:
                self._single = "WAIT"
        elif action == "force":  # :TRIGger:FORCe / :TFORce: a record without a trigger
            self._acquire(triggered=False)
            self._single = ""
            self._running = False
        return None

    def _query(self, query: str) -> bytes:
        f = self.family
        if query == "error":
            return (self._errors.pop(0) if self._errors else self._entry(0, "No error")).encode()
        if query == "preamble":
            return self._preamble_text(self._transfer()[0]).encode()
        if query == "data":
            return self._data()
        if query == "points":
            return f.integer(self.request().n).encode()
        if query == "sample rate":
            return f.number(1e9 / self.request().dt_ns).encode()
        if query == "trigger event":  # a Keysight's :TER?: read and cleared
            event, self._trigger_event = self._trigger_event, False
            return f.integer(int(event)).encode()
        if query == "trigger status":
            return self.trigger_status().encode()
        raise _Refused(-113, "Undefined header")  # pragma: no cover - the tables name them

    def _value(self, head: str, word: str, factor: float = 1.0) -> str:
        """Check a setting's argument (``factor``: given in a linked unit); the value stored."""
        setting = self.family.settings[head]
        if not word:
            raise _Refused(-109, "Missing parameter")
        if setting.choices:
            if word not in setting.choices:
                raise _Refused(-224, "Illegal parameter value")
            return word
        if word in setting.words:
            return word
        try:
            value = float(word) * factor
        except ValueError:
            raise _Refused(-224, "Illegal parameter value") from None
        if not (math.isfinite(value) and setting.low <= value <= setting.high):
            raise _Refused(-222, "Data out of range")
        if setting.integer:
            if value != round(value):
                raise _Refused(-224, "Illegal parameter value")
            n = round(value)
            if setting.powers_of_two and n & (n - 1):
                raise _Refused(-224, "Illegal parameter value")
            return str(n)
        if setting.steps_125:
            value = min(max(_nearest_125(value), setting.low), setting.high)
        return self.family.number(value)

    # --- server threads ---------------------------------------------------------------------
    def _answer(self, line: bytes) -> bytes | None:
        return self.execute(line.decode("ascii", errors="replace"))
