"""Each oscilloscope family's own SCPI, as data: what ``drivers.digitizer.visa.ScpiScope`` sends
to a scope of that family and how it reads the answers, chosen by the scope's ``*IDN?``.

A :class:`Dialect` is one family's command table, written from its programming manual (each
entry cites the manual's section, the command header it documents): the set-up of the record
(source channel, transfer format, vertical range), the trigger (edge, sweep, source, level)
and its read-back, the record window (time base), the averaging, how one acquisition is
started and how its completion is awaited, and how the preamble's codes and the samples'
codes read. The driver holds no family's command: it follows the table.

Families (``docs/protocols/scpi_digitizer.md``):

- ``keysight``: Keysight (Agilent) InfiniiVision 2000 and 3000 X-Series, *Keysight
  InfiniiVision 2000 X-Series Oscilloscopes Programmer's Guide* (and the 3000 X-Series guide,
  which documents the same commands);
- ``rigol``: Rigol DS1000Z / MSO1000Z, *MSO1000Z/DS1000Z Programming Guide* (chapter 2,
  "Command System").

A new family is a new :class:`Dialect` in :data:`DIALECTS` (and, to rehearse with it, a family
of the simulated scope, ``drivers.digitizer.scpi_simulator.FAMILIES``).
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

from drivers.digitizer import scpi

#: A command and its argument (``""``: none).
Command = tuple[str, str]


def nr3(value: float) -> str:
    """A SCPI <NR3> argument: ``4.000000E-04``, exact to 7 significant digits."""
    return f"{value:.6E}"


@dataclass(frozen=True)
class Codes:
    """How the codes of one binary transfer format read: bytes a sample, the code of a hole
    (no data acquired there; None: the family has none), the codes on the ADC's rails (a
    sample on one is clipped), and whether the ADC's bits are left-aligned in the word (its
    step is then a power of two of codes, read from the codes themselves)."""

    sample_bytes: int
    clip_low: int
    clip_high: int
    hole: int | None = None
    step_from_codes: bool = False

    @property
    def flags(self) -> tuple[int, ...]:
        """The codes that say something other than a level."""
        return tuple(c for c in (self.hole, self.clip_low, self.clip_high) if c is not None)


@dataclass(frozen=True)
class Trigger:
    """The edge trigger: the commands that set it (mode, sweep, slope as fixed commands; the
    source and level headers, whose arguments the scope's URL may choose), the queries that
    read it back, the sources the family's edge trigger takes for the pulser's sync output
    (channel 1 records the RF) and the default one."""

    mode: Command
    sweep: Command
    slope: Command
    source: str
    level: str
    sources: tuple[str, ...]
    default_source: str

    @property
    def sweep_word(self) -> str:
        """What the sweep query must answer once set."""
        return self.sweep[1]


@dataclass(frozen=True)
class Averaging:
    """``:ACQuire:TYPE`` and the average count: the type header and its words for one
    acquisition and for averaged ones, the count header, the counts taken (``allowed``) and
    how to say so (``counts``)."""

    type_header: str
    normal: str
    average: str
    count_header: str
    allowed: Callable[[int], bool]
    counts: str


@dataclass(frozen=True)
class Dialect:
    """One family's command table (module docstring)."""

    family: str
    title: str
    #: ``MANUFACTURER,MODEL`` of the ``*IDN?`` answers it speaks for (case-insensitive).
    identifies: re.Pattern[str]
    #: Several commands in one program message, joined by ``;``: else one message each.
    compound: bool
    #: Set-up after ``*CLS``, in order; arguments may hold ``{format}``, ``{range_v}`` (the
    #: vertical range, V full scale) and ``{scale_v}`` (V per division).
    setup: tuple[Command, ...]
    trigger: Trigger
    #: The commands of a record window ``(start_s, width_s)`` after the trigger; ``ValueError``
    #: for a window the family's time base cannot give.
    window: Callable[[float, float], tuple[Command, ...]]
    averaging: Averaging
    #: Binary transfer formats and ASCII the driver may ask for (the first is the default).
    wave_formats: tuple[str, ...]
    #: The preamble's ``format`` and ``type`` codes, in the family's words.
    formats: Mapping[int, str]
    types: Mapping[int, str]
    #: The ``type`` whose ``count`` is the average count (else ``count`` always is).
    averaged_type: str | None
    #: The ``type`` every record must have (the waveform read mode), if the family says one.
    record_type: str | None
    y_origin_in_codes: bool
    codes: Mapping[str, Codes]
    #: Starts one acquisition; then ``*OPC?`` answers once it is complete (``"opc"``), or the
    #: status query is polled until it says so (``"status"``).
    single: str
    completion: str
    #: ``"opc"``: read the trigger event register around the acquisition (1 = triggered).
    trigger_event: str | None = None
    #: ``"status"``: the query, and its words: armed or acquiring, triggered (acquiring),
    #: complete, free-running.
    status: str | None = None
    armed: tuple[str, ...] = ()
    triggered: tuple[str, ...] = ()
    complete: str = ""
    untriggered: str = ""
    #: The part of the record to transfer (first and last point, 1-based) and the most
    #: points one ``:WAVeform:DATA?`` carries, by format; None: the whole record at once.
    data_range: tuple[str, str] | None = None
    max_points: Mapping[str, int] = field(default_factory=dict)
    error_query: str = ":SYST:ERR?"

    def matches(self, idn: scpi.IdnReply) -> bool:
        """Whether ``idn`` is a scope of this family."""
        return bool(self.identifies.match(f"{idn.manufacturer},{idn.model}"))

    def check_averages(self, averages: int) -> None:
        """``ValueError`` for an average count the family cannot take (1 = none)."""
        if averages != 1 and not self.averaging.allowed(averages):
            raise ValueError(
                f"digitizer: a {self.title} averages {self.averaging.counts}, got {averages!r}"
            )

    def preamble(self, text: str) -> scpi.Preamble:
        """The preamble line in this family's meaning; ``ScpiError`` for codes it does not
        define."""
        v = scpi.preamble_values(text)
        fmt, kind = int(v["format"]), int(v["type"])
        if fmt not in self.formats or kind not in self.types:
            raise scpi.ScpiError(
                f"preamble format/type {fmt}/{kind} is not one the {self.title} sends "
                f"(format {dict(self.formats)}, type {dict(self.types)})"
            )
        return scpi.Preamble(
            format=self.formats[fmt],
            type=self.types[kind],
            points=int(v["points"]),
            count=int(v["count"]),
            x_increment_s=v["xincrement"],
            x_origin_s=v["xorigin"],
            x_reference=int(v["xreference"]),
            y_increment_v=v["yincrement"],
            y_origin=v["yorigin"],
            y_reference=int(v["yreference"]),
            y_origin_in_codes=self.y_origin_in_codes,
        )

    def averaged(self, p: scpi.Preamble) -> int:
        """How many acquisitions the record of preamble ``p`` averages."""
        if self.averaged_type is None:
            return max(p.count, 1)
        return p.count if p.type == self.averaged_type else 1


# --- Keysight InfiniiVision 2000/3000 X-Series ----------------------------------------------


def _keysight_window(start_s: float, width_s: float) -> tuple[Command, ...]:
    # :TIMebase:RANGe — the full-scale horizontal time (10 divisions); :TIMebase:POSition —
    # from the trigger to the reference, which :TIMebase:REFerence LEFT (set up) puts at the
    # left edge: the record starts start_s after the trigger and lasts width_s.
    return ((":TIM:RANG", nr3(width_s)), (":TIM:POS", nr3(start_s)))


KEYSIGHT = Dialect(
    family="keysight",
    title="Keysight InfiniiVision 2000/3000 X-Series",
    # *IDN?: KEYSIGHT TECHNOLOGIES,DSOX3024T,... (AGILENT TECHNOLOGIES,DSO-X 2024A,... before
    # 2014): the 2000 and 3000 X-Series models, DSO and MSO
    identifies=re.compile(r"^(KEYSIGHT|AGILENT) TECHNOLOGIES,[DM]SO-?X ?[23]\d{3}", re.I),
    # "Tree Traversal Rules and Multiple Commands": ;-joined commands, each from the root
    compound=True,
    setup=(
        (":WAV:SOUR", "CHAN1"),  # :WAVeform:SOURce CHANnel1
        (":WAV:FORM", "{format}"),  # :WAVeform:FORMat {WORD | BYTE | ASCii} (p. 639)
        (":WAV:BYT", "MSBF"),  # :WAVeform:BYTeorder: WORD's upper byte first
        (":WAV:UNS", "1"),  # :WAVeform:UNSigned: codes 0 … 65535
        (":WAV:POIN:MODE", "RAW"),  # :WAVeform:POINts:MODE RAW: the acquisition record
        (":WAV:POIN", "MAX"),  # :WAVeform:POINts MAXimum: every point of it
        (":TIM:REF", "LEFT"),  # :TIMebase:REFerence LEFT
        (":CHAN1:RANG", "{range_v}"),  # :CHANnel<n>:RANGe: full-scale vertical (8 divisions)
        (":CHAN1:OFFS", "0"),  # :CHANnel<n>:OFFSet: 0 V at the centre
    ),
    trigger=Trigger(
        mode=(":TRIG:MODE", "EDGE"),  # :TRIGger:MODE EDGE
        # :TRIGger:SWEep {AUTO | NORMal} (p. 600): NORMal acquires only when a trigger
        # arrives; AUTO makes an artificial trigger and acquires unsynchronised data
        sweep=(":TRIG:SWE", "NORM"),
        slope=(":TRIG:EDGE:SLOP", "POS"),  # :TRIGger[:EDGE]:SLOPe POSitive
        # :TRIGger[:EDGE]:SOURce {CHANnel<n> | EXTernal | ...}: the sync output on EXT TRIG IN
        source=":TRIG:EDGE:SOUR",
        level=":TRIG:EDGE:LEV",  # :TRIGger[:EDGE]:LEVel <level> (V) for the edge source
        sources=("EXT", "CHAN2", "CHAN3", "CHAN4"),
        default_source="EXT",
    ),
    window=_keysight_window,
    averaging=Averaging(
        type_header=":ACQ:TYPE",  # :ACQuire:TYPE {NORMal | AVERage | HRESolution | PEAK}
        normal="NORM",
        average="AVER",
        count_header=":ACQ:COUN",  # :ACQuire:COUNt <count>, 2 … 65536 (p. 186)
        allowed=lambda n: 2 <= n <= 65536,
        counts="2 … 65536 acquisitions",
    ),
    wave_formats=("WORD", "BYTE", "ASCII"),
    # :WAVeform:PREamble (p. 644): <format> 0 BYTE, 1 WORD, 4 ASCii; <type> 0 NORMal, 1 PEAK,
    # 2 AVERage (3 HRESolution, 3000T and later); <count> the average count, else 1
    formats={0: "BYTE", 1: "WORD", 4: "ASCII"},
    types={0: "NORMAL", 1: "PEAK", 2: "AVERAGE", 3: "HRESOLUTION"},
    averaged_type="AVERAGE",
    record_type=None,
    # "Data Conversion" (p. 632): voltage = (data value − yreference)·yincrement + yorigin;
    # time = (data point number − xreference)·xincrement + xorigin
    y_origin_in_codes=False,
    # "Data Format for Transfer": WORD left-shifts the ADC's bits (the low bits 0), a hole is
    # 0; 0x01/0x0001 and 0xFF/0xFFFF are the clipped codes (:WAVeform:DATA)
    codes={
        "BYTE": Codes(1, clip_low=0x01, clip_high=0xFF, hole=0, step_from_codes=True),
        "WORD": Codes(2, clip_low=0x0001, clip_high=0xFFFF, hole=0, step_from_codes=True),
    },
    # :DIGitize: one acquisition as :ACQuire sets it (averaged), the operation complete
    # when it is in: *OPC? answers 1 then
    single=":DIG",
    completion="opc",
    # :TER? (p. 181; 3000 X p. 185): the Trigger Event Register, cleared when read:
    # 1 = a trigger has occurred
    trigger_event=":TER?",
)


# --- Rigol DS1000Z / MSO1000Z -----------------------------------------------------------------

#: :TIMebase[:MAIN]:SCALe: 5 ns … 50 s a division, in 1-2-5 steps; 12 divisions a screen.
_RIGOL_SCALES = tuple(m * 10.0**e for e in range(-9, 2) for m in (1.0, 2.0, 5.0))
_RIGOL_DIVISIONS = 12


def _rigol_window(start_s: float, width_s: float) -> tuple[Command, ...]:
    # :TIMebase[:MAIN]:SCALe — the smallest 1-2-5 step whose 12 divisions hold the window;
    # :TIMebase[:MAIN]:OFFSet — the time from the trigger to the screen's centre (the
    # preamble's xorigin is the record's first point): the left edge at start_s
    need = width_s / _RIGOL_DIVISIONS
    scale = next((s for s in _RIGOL_SCALES if s >= need * (1.0 - 1e-9) and s >= 5e-9), None)
    if scale is None or scale > 50.0:
        raise ValueError(
            f"digitizer: a DS1000Z's time base cannot hold a record of {width_s * 1e6:g} µs"
        )
    offset = start_s + 0.5 * _RIGOL_DIVISIONS * scale
    return ((":TIM:MAIN:SCAL", nr3(scale)), (":TIM:MAIN:OFFS", nr3(offset)))


RIGOL = Dialect(
    family="rigol",
    title="Rigol DS1000Z",
    # *IDN?: RIGOL TECHNOLOGIES,DS1104Z,DS1ZA…,00.04.04 (DS1054Z, DS1074Z Plus, MSO1104Z-S …)
    identifies=re.compile(r"^RIGOL TECHNOLOGIES,(DS|MSO)1\d{3}Z(-S)?( PLUS)?$", re.I),
    # one command a message: ucal does not rely on ;-joined messages with this family
    compound=False,
    setup=(
        (":WAV:SOUR", "CHAN1"),  # :WAVeform:SOURce CHANnel1
        # :WAVeform:MODE RAW: the internal memory (read while stopped, as after :SINGle),
        # not the 1200 points on screen (NORMal)
        (":WAV:MODE", "RAW"),
        # :WAVeform:FORMat BYTE: one 8-bit ADC code a point (WORD carries the same byte in
        # its low half)
        (":WAV:FORM", "{format}"),
        (":CHAN1:SCAL", "{scale_v}"),  # :CHANnel<n>:SCALe, V a division, 8 divisions
        (":CHAN1:OFFS", "0"),  # :CHANnel<n>:OFFSet
    ),
    trigger=Trigger(
        mode=(":TRIG:MODE", "EDGE"),  # :TRIGger:MODE EDGE
        sweep=(":TRIG:SWE", "NORM"),  # :TRIGger:SWEep {AUTO|NORMal|SINGle}
        slope=(":TRIG:EDG:SLOP", "POS"),  # :TRIGger:EDGe:SLOPe POSitive
        # :TRIGger:EDGe:SOURce: an analog channel (the DS1000Z's edge trigger lists no EXT
        # input): the sync output on CH2
        source=":TRIG:EDG:SOUR",
        level=":TRIG:EDG:LEV",  # :TRIGger:EDGe:LEVel <level> (V), ±5 divisions − offset
        sources=("CHAN2", "CHAN3", "CHAN4"),
        default_source="CHAN2",
    ),
    window=_rigol_window,
    averaging=Averaging(
        type_header=":ACQ:TYPE",  # :ACQuire:TYPE {NORMal|AVERages|PEAK|HRESolution}
        normal="NORM",
        average="AVER",
        count_header=":ACQ:AVER",  # :ACQuire:AVERages <count>: 2^n, n = 1 … 10
        allowed=lambda n: 2 <= n <= 1024 and n & (n - 1) == 0,
        counts="a power of two of acquisitions, 2 … 1024",
    ),
    wave_formats=("BYTE",),
    # :WAVeform:PREamble?: <format> 0 BYTE, 1 WORD, 2 ASC; <type> 0 NORMal, 1 MAXimum, 2 RAW
    # (the read mode, not the acquisition type); <count> the averages in average mode, else 1
    formats={0: "BYTE", 1: "WORD", 2: "ASCII"},
    types={0: "NORMAL", 1: "MAXIMUM", 2: "RAW"},
    averaged_type=None,
    record_type="RAW",
    # :WAVeform:DATA?: a code reads (code − YORigin − YREFerence)·YINCrement volts; yorigin
    # and yreference are in codes
    y_origin_in_codes=True,
    # 8-bit codes 0 … 255 (no hole code); the ADC's ends are the rails
    codes={"BYTE": Codes(1, clip_low=0x00, clip_high=0xFF)},
    # :SINGle: the single sweep (= :TRIGger:SWEep SINGle): it waits for one trigger, then
    # stops; :TRIGger:STATus? answers TD, WAIT, RUN, AUTO or STOP
    single=":SING",
    completion="status",
    status=":TRIG:STAT?",
    armed=("WAIT", "TD", "RUN"),
    triggered=("TD",),
    complete="STOP",
    untriggered="AUTO",
    # :WAVeform:STARt / :WAVeform:STOP: the points of the memory one :WAVeform:DATA? reads,
    # at most 250 000 in BYTE
    data_range=(":WAV:STAR", ":WAV:STOP"),
    max_points={"BYTE": 250_000},
)


#: Every family ucal speaks, in the order ``*IDN?`` is matched.
DIALECTS: tuple[Dialect, ...] = (KEYSIGHT, RIGOL)
#: By family name.
BY_FAMILY: dict[str, Dialect] = {d.family: d for d in DIALECTS}


def dialect_of(idn: scpi.IdnReply) -> Dialect | None:
    """The family of the scope that answered ``idn`` (None: none ucal speaks)."""
    return next((d for d in DIALECTS if d.matches(idn)), None)


def known_families() -> str:
    """The families ucal speaks, for a message: ``Keysight InfiniiVision …, Rigol DS1000Z``."""
    return ", ".join(d.title for d in DIALECTS)


def parse_level(text: str) -> float:
    """A trigger level query's answer (``+1.40E+00``, ``1.400000e+00``) in volts."""
    value = float(text.strip())
    if not math.isfinite(value):
        raise ValueError(f"trigger level {text!r} is not finite")
    return value
