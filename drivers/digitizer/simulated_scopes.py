"""The simulated oscilloscope's families as data: what a scope of each family answers and takes.

A :class:`Family` holds what a scope of that family answers to ``*IDN?``, the mnemonics it takes
(long and short forms, optional nodes), every setting it holds with its power-on value and what
it takes (a :class:`Setting`), its actions (run, stop, single, digitize, force) and queries,
which settings play which role in an acquisition, and how its preamble and codes read.
``drivers.digitizer.scpi_simulator`` plays any of them; :data:`FAMILIES` holds

- ``keysight``: an InfiniiVision X-Series (DSOX3024T), after the *Keysight InfiniiVision 2000 /
  3000 X-Series Programmer's Guides*;
- ``rigol``: a DS1000Z (DS1104Z), after the *MSO1000Z/DS1000Z Programming Guide*.

The driver's own tables (``drivers.digitizer.dialects``) cite the guides' sections for the
commands ucal sends; these hold as well what a user's script commonly sends (run, stop, single,
the time base's scale, the sweep …), so that a script rehearsed here meets what the scope takes.
A new family is one more :class:`Family` here (and a ``Dialect`` for the driver).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field

#: The serial number a simulated scope gives in ``*IDN?``.
SIMULATED_SERIAL = "UCAL-SIM"


@dataclass(frozen=True)
class Setting:
    """A setting the scope holds: its power-on value and what it takes. Discrete (``choices``,
    short forms) or numeric (``low`` … ``high``; ``integer``; ``powers_of_two``; ``steps_125``:
    rounded to the nearest 1-2-5 value; ``words``: words a numeric setting also takes)."""

    default: str
    choices: tuple[str, ...] = ()
    low: float = -math.inf
    high: float = math.inf
    integer: bool = False
    powers_of_two: bool = False
    steps_125: bool = False
    words: tuple[str, ...] = ()


def _discrete(default: str, *choices: str) -> Setting:
    return Setting(default, choices=choices)


def _number(
    default: str,
    low: float,
    high: float,
    *,
    integer: bool = False,
    powers_of_two: bool = False,
    steps_125: bool = False,
) -> Setting:
    return Setting(
        default,
        low=low,
        high=high,
        integer=integer,
        powers_of_two=powers_of_two,
        steps_125=steps_125,
    )


#: Argument words in long form → short form, every family.
WORDS = {
    "NORMAL": "NORM",
    "AVERAGE": "AVER",
    "AVERAGES": "AVER",
    "HRESOLUTION": "HRES",
    "CENTER": "CENT",
    "RIGHT": "RIGH",
    "EXTERNAL": "EXT",
    "MSBFIRST": "MSBF",
    "LSBFIRST": "LSBF",
    "MAXIMUM": "MAX",
    "MINIMUM": "MIN",
    "ASCII": "ASC",
    "ON": "1",
    "OFF": "0",
    "POSITIVE": "POS",
    "NEGATIVE": "NEG",
    "EITHER": "EITH",
    "ALTERNATE": "ALT",
    "RFALL": "RFAL",
    "SINGLE": "SING",
    "GLITCH": "GLIT",
    "PATTERN": "PATT",
    "PULSE": "PULS",
    "SLOPE": "SLOP",
    "RTIME": "RTIM",
    "SEGMENTED": "SEGM",
    "ONEMEG": "ONEM",
    "FIFTY": "FIFT",
    "WINDOW": "WIND",
    **{f"CHANNEL{n}": f"CHAN{n}" for n in range(1, 5)},
}
#: Mnemonics in long form → short form that every family spells alike.
_MNEMONICS = {
    "WAVEFORM": "WAV",
    "SOURCE": "SOUR",
    "FORMAT": "FORM",
    "POINTS": "POIN",
    "PREAMBLE": "PRE",
    "TIMEBASE": "TIM",
    "POSITION": "POS",
    "REFERENCE": "REF",
    "TRIGGER": "TRIG",
    "SWEEP": "SWE",
    "LEVEL": "LEV",
    "SLOPE": "SLOP",
    "COUPLING": "COUP",
    "ACQUIRE": "ACQ",
    "SRATE": "SRAT",
    "SINGLE": "SING",
    "SYSTEM": "SYST",
    "ERROR": "ERR",
    "OFFSET": "OFFS",
    "SCALE": "SCAL",
    "RANGE": "RANG",
    "DISPLAY": "DISP",
    "CHAN": "CHAN1",
    **{f"CHANNEL{n}": f"CHAN{n}" for n in range(1, 5)},
}


@dataclass(frozen=True)
class Family:
    """A scope family as data (module docstring). Settings, actions and queries are keyed by
    the short-form header; ``aliases`` maps a header with an optional node left out (or a
    synonym) to the one the family stores it under; ``linked`` a header stored as another
    times a factor (a Keysight's ``:TIMebase:SCALe`` is its ``:TIMebase:RANGe`` over 10)."""

    name: str
    idn: str
    mnemonics: Mapping[str, str]
    aliases: Mapping[str, str]
    settings: Mapping[str, Setting]
    linked: Mapping[str, tuple[str, float]]
    actions: Mapping[str, str]
    queries: Mapping[str, str]
    #: roles: the headers of the settings the acquisition reads
    roles: Mapping[str, str]
    #: ``"range"`` (width = the range, start from the position and the reference) or
    #: ``"scale"`` (width = ``divisions`` × scale, centred on the offset after the trigger)
    timebase: str
    divisions: int
    #: ``"keysight"`` (ADC over 8 divisions, WORD left-aligned, flag codes; y origin in volts)
    #: or ``"rigol"`` (8-bit codes, 25 a division about 127; y origin in codes)
    codes: str
    preamble_formats: Mapping[str, int]
    preamble_types: Mapping[str, int]
    #: the preamble's ``type`` is the acquisition type (``"acquisition"``) or the read mode
    preamble_type_of: str
    sync_input: str
    max_points: Mapping[str, int] = field(default_factory=dict)
    signed_numbers: bool = False
    default_bits: int = 12
    fixed_bits: bool = False
    default_memory_points: int = 4_000_000

    def number(self, value: float) -> str:
        """A numeric answer as the family writes it."""
        return f"{value:+.8E}" if self.signed_numbers else f"{value:.6e}"

    def integer(self, value: int) -> str:
        """An integer answer (NR1) as the family writes it."""
        return f"{value:+d}" if self.signed_numbers else str(value)


KEYSIGHT = Family(
    name="keysight",
    idn=f"KEYSIGHT TECHNOLOGIES,DSOX3024T,{SIMULATED_SERIAL},07.50.2021102830",
    mnemonics={
        **_MNEMONICS,
        "BYTEORDER": "BYT",
        "UNSIGNED": "UNS",
        "COUNT": "COUN",
        "DIGITIZE": "DIG",
        "FORCE": "FORC",
        "IMPEDANCE": "IMP",
        "STATUS": "STAT",
    },
    aliases={
        # :TRIGger[:EDGE]:… — the EDGE node is optional
        ":TRIG:SOUR": ":TRIG:EDGE:SOUR",
        ":TRIG:LEV": ":TRIG:EDGE:LEV",
        ":TRIG:SLOP": ":TRIG:EDGE:SLOP",
        ":TRIG:COUP": ":TRIG:EDGE:COUP",
        ":TIM:MAIN:RANG": ":TIM:RANG",
        ":TIM:MAIN:POS": ":TIM:POS",
        ":TIM:MAIN:SCAL": ":TIM:SCAL",
    },
    settings={
        ":WAV:SOUR": _discrete("CHAN1", "CHAN1", "CHAN2", "CHAN3", "CHAN4"),
        ":WAV:FORM": _discrete("BYTE", "WORD", "BYTE", "ASC"),
        ":WAV:BYT": _discrete("MSBF", "MSBF", "LSBF"),
        ":WAV:UNS": _discrete("1", "0", "1"),
        ":WAV:POIN:MODE": _discrete("NORM", "NORM", "MAX", "RAW"),
        ":WAV:POIN": Setting("1000", low=100, high=8_000_000, integer=True, words=("MAX", "MIN")),
        ":TIM:RANG": _number("1.000000E-03", 2e-8, 500.0),
        ":TIM:POS": _number("0.000000E+00", -500.0, 500.0),
        ":TIM:REF": _discrete("CENT", "LEFT", "CENT", "RIGH"),
        ":TIM:MODE": _discrete("MAIN", "MAIN", "WIND", "XY", "ROLL"),
        ":TRIG:MODE": _discrete("EDGE", "EDGE", "GLIT", "PATT", "TV"),
        ":TRIG:SWE": _discrete("AUTO", "AUTO", "NORM"),
        ":TRIG:EDGE:SOUR": _discrete(
            "CHAN1", "CHAN1", "CHAN2", "CHAN3", "CHAN4", "EXT", "LINE", "WGEN"
        ),
        ":TRIG:EDGE:LEV": _number("0.000000E+00", -8.0, 8.0),
        ":TRIG:EDGE:SLOP": _discrete("POS", "POS", "NEG", "EITH", "ALT"),
        ":TRIG:EDGE:COUP": _discrete("DC", "DC", "AC", "LFR", "HFR"),
        ":ACQ:TYPE": _discrete("NORM", "NORM", "AVER", "HRES", "PEAK"),
        ":ACQ:COUN": _number("8", 2, 65536, integer=True),
        ":ACQ:MODE": _discrete("RTIM", "RTIM", "SEGM"),
        ":CHAN1:RANG": _number("8.000000E+00", 8e-3, 40.0),
        ":CHAN1:OFFS": _number("0.000000E+00", -20.0, 20.0),
        ":CHAN1:DISP": _discrete("1", "0", "1"),
        ":CHAN1:COUP": _discrete("DC", "DC", "AC"),
        ":CHAN1:IMP": _discrete("ONEM", "ONEM", "FIFT"),
    },
    linked={":TIM:SCAL": (":TIM:RANG", 10.0), ":CHAN1:SCAL": (":CHAN1:RANG", 8.0)},
    actions={
        ":RUN": "run",
        ":STOP": "stop",
        ":SING": "digitize",
        ":DIG": "digitize",
        ":TRIG:FORC": "force",
        ":CDIS": "nothing",
    },
    queries={
        ":WAV:PRE?": "preamble",
        ":WAV:DATA?": "data",
        ":WAV:POIN?": "points",
        ":ACQ:SRAT?": "sample rate",
        ":SYST:ERR?": "error",
        ":TER?": "trigger event",
    },
    roles={
        "width": ":TIM:RANG",
        "start": ":TIM:POS",
        "reference": ":TIM:REF",
        "range": ":CHAN1:RANG",
        "offset": ":CHAN1:OFFS",
        "type": ":ACQ:TYPE",
        "count": ":ACQ:COUN",
        "format": ":WAV:FORM",
        "byte order": ":WAV:BYT",
        "unsigned": ":WAV:UNS",
        "mode": ":WAV:POIN:MODE",
        "trigger mode": ":TRIG:MODE",
        "sweep": ":TRIG:SWE",
        "source": ":TRIG:EDGE:SOUR",
        "level": ":TRIG:EDGE:LEV",
    },
    timebase="range",
    divisions=10,
    codes="keysight",
    preamble_formats={"BYTE": 0, "WORD": 1, "ASC": 4},
    preamble_types={"NORM": 0, "PEAK": 1, "AVER": 2, "HRES": 3},
    preamble_type_of="acquisition",
    sync_input="EXT",
    signed_numbers=True,
)

RIGOL = Family(
    name="rigol",
    idn=f"RIGOL TECHNOLOGIES,DS1104Z,{SIMULATED_SERIAL},00.04.05.SP2",
    mnemonics={
        **_MNEMONICS,
        "EDGE": "EDG",
        "MODE": "MODE",
        "START": "STAR",
        "STATUS": "STAT",
        "AVERAGES": "AVER",
        "MDEPTH": "MDEP",
        "TFORCE": "TFOR",
        "CLEAR": "CLE",
    },
    aliases={
        # :TIMebase[:MAIN]:… — the MAIN node is optional; :SYSTem:ERRor[:NEXT]?
        ":TIM:SCAL": ":TIM:MAIN:SCAL",
        ":TIM:OFFS": ":TIM:MAIN:OFFS",
        ":SYST:ERR:NEXT?": ":SYST:ERR?",
    },
    settings={
        ":WAV:SOUR": _discrete("CHAN1", "CHAN1", "CHAN2", "CHAN3", "CHAN4", "MATH"),
        ":WAV:MODE": _discrete("NORM", "NORM", "MAX", "RAW"),
        ":WAV:FORM": _discrete("BYTE", "WORD", "BYTE", "ASC"),
        ":WAV:STAR": _number("1", 1, 24_000_000, integer=True),
        ":WAV:STOP": _number("1200", 1, 24_000_000, integer=True),
        ":TIM:MAIN:SCAL": _number("1.000000e-06", 5e-9, 50.0, steps_125=True),
        ":TIM:MAIN:OFFS": _number("0.000000e+00", -500.0, 500.0),
        ":TIM:MODE": _discrete("MAIN", "MAIN", "XY", "ROLL"),
        ":TRIG:MODE": _discrete("EDGE", "EDGE", "PULS", "SLOP", "PATT"),
        ":TRIG:SWE": _discrete("AUTO", "AUTO", "NORM", "SING"),
        ":TRIG:EDG:SOUR": _discrete("CHAN1", "CHAN1", "CHAN2", "CHAN3", "CHAN4", "AC"),
        ":TRIG:EDG:LEV": _number("0.000000e+00", -5.0, 5.0),
        ":TRIG:EDG:SLOP": _discrete("POS", "POS", "NEG", "RFAL"),
        ":TRIG:COUP": _discrete("DC", "DC", "AC", "LFR", "HFR"),
        ":ACQ:TYPE": _discrete("NORM", "NORM", "AVER", "PEAK", "HRES"),
        ":ACQ:AVER": _number("2", 2, 1024, integer=True, powers_of_two=True),
        ":ACQ:MDEP": _discrete("AUTO", "AUTO", "12000", "120000", "1200000", "12000000"),
        ":CHAN1:SCAL": _number("1.000000e+00", 1e-3, 10.0),
        ":CHAN1:OFFS": _number("0.000000e+00", -100.0, 100.0),
        ":CHAN1:DISP": _discrete("1", "0", "1"),
        ":CHAN1:COUP": _discrete("DC", "DC", "AC", "GND"),
    },
    linked={},
    actions={
        ":RUN": "run",
        ":STOP": "stop",
        ":SING": "single",
        ":TFOR": "force",
        ":CLE": "nothing",
    },
    queries={
        ":WAV:PRE?": "preamble",
        ":WAV:DATA?": "data",
        ":ACQ:SRAT?": "sample rate",
        ":SYST:ERR?": "error",
        ":TRIG:STAT?": "trigger status",
    },
    roles={
        "scale": ":TIM:MAIN:SCAL",
        "start": ":TIM:MAIN:OFFS",
        "range": ":CHAN1:SCAL",
        "offset": ":CHAN1:OFFS",
        "type": ":ACQ:TYPE",
        "count": ":ACQ:AVER",
        "format": ":WAV:FORM",
        "mode": ":WAV:MODE",
        "first": ":WAV:STAR",
        "last": ":WAV:STOP",
        "trigger mode": ":TRIG:MODE",
        "sweep": ":TRIG:SWE",
        "source": ":TRIG:EDG:SOUR",
        "level": ":TRIG:EDG:LEV",
    },
    timebase="scale",
    divisions=12,
    codes="rigol",
    preamble_formats={"BYTE": 0, "WORD": 1, "ASC": 2},
    preamble_types={"NORM": 0, "MAX": 1, "RAW": 2},
    preamble_type_of="read mode",
    sync_input="CHAN2",
    max_points={"BYTE": 250_000, "WORD": 125_000, "ASC": 15_625},
    default_bits=8,
    fixed_bits=True,
    default_memory_points=12_000_000,
)

#: Every simulated family, by name.
FAMILIES: dict[str, Family] = {f.name: f for f in (KEYSIGHT, RIGOL)}
