"""SCPI framing of an oscilloscope's waveform transfer, shared by the client and the simulator.

What travels (``docs/protocols/scpi_digitizer.md``, after the Keysight InfiniiVision and Rigol
programming guides):

- Program messages are ASCII, terminated by LF; several commands may share one message,
  separated by ``;`` (each with its full path from the root ``:``). A query's answer is one
  ASCII line, terminated by LF.
- ``:WAVeform:DATA?`` answers with an IEEE 488.2 *definite-length arbitrary block*:
  ``#`` + one digit *d* (1…9) + *d* ASCII digits giving the byte count *n* + *n* bytes of data,
  then LF. ``#9000001000`` announces 1000 bytes.
- ``:WAVeform:PREamble?`` answers with ten comma-separated fields:
  ``format, type, points, count, xincrement, xorigin, xreference, yincrement, yorigin,
  yreference``; sample k is taken at ``(k − xreference)·xincrement + xorigin`` seconds after
  the trigger and a code c reads ``(c − yreference)·yincrement + yorigin`` volts.
- Codes are unsigned (``:WAVeform:UNSigned 1``): BYTE one byte a sample, WORD two bytes,
  most significant byte first (``:WAVeform:BYTeorder MSBF``) unless ``LSBF`` is chosen. A WORD
  record carries the ADC's bits left-aligned (the low bits are 0). Two codes are flags, as the
  InfiniiVision guide documents them: the lowest nonzero code (0x01 / 0x0001) means clipped
  low, the highest (0xFF / 0xFFFF) clipped high; 0 is a hole (no data acquired there).
"""

from __future__ import annotations

import enum
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from drivers.digitizer.base import left_aligned_step

#: The terminator of every program message and every answer line.
TERMINATOR = b"\n"


class WaveFormat(enum.IntEnum):
    """``:WAVeform:FORMat`` and the preamble's first field."""

    BYTE = 0
    WORD = 1
    ASCII = 2


class AcquireType(enum.IntEnum):
    """``:ACQuire:TYPE`` and the preamble's second field."""

    NORMAL = 0
    PEAK = 1
    AVERAGE = 2
    HRESOLUTION = 3


#: Bytes per sample of the binary formats.
SAMPLE_BYTES = {WaveFormat.BYTE: 1, WaveFormat.WORD: 2}
#: The flag codes of each binary format: hole, clipped low, clipped high.
HOLE = 0
CLIP_LOW = {WaveFormat.BYTE: 0x01, WaveFormat.WORD: 0x0001}
CLIP_HIGH = {WaveFormat.BYTE: 0xFF, WaveFormat.WORD: 0xFFFF}
#: The code of 0 V on screen centre (``yreference``) of each format.
CENTRE_CODE = {WaveFormat.BYTE: 0x80, WaveFormat.WORD: 0x8000}


class ScpiError(ValueError):
    """Bytes that do not follow the SCPI framing; the message says what was expected."""


# --- IEEE 488.2 definite-length arbitrary block ---------------------------------------------


def format_block(payload: bytes, digits: int | None = None) -> bytes:
    """Return ``#<d><n><payload>`` (no terminator); ``digits`` = d, default the fewest that
    hold the length (at most 9)."""
    n = len(payload)
    width = len(str(n)) if digits is None else int(digits)
    if not 1 <= width <= 9 or len(str(n)) > width:
        raise ScpiError(f"a block of {n} bytes cannot have a {width}-digit length")
    return b"#" + str(width).encode() + str(n).zfill(width).encode() + payload


def block_length(header: bytes) -> int:
    """The byte count announced by a block header ``#<d><n>`` (exactly 2 + d bytes)."""
    if len(header) < 2 or header[:1] != b"#":
        raise ScpiError(f"expected a definite-length block '#<d><n>…', got {header[:16]!r}")
    digit = header[1:2]
    if digit == b"0":
        raise ScpiError("indefinite-length block ('#0') is not supported")
    if not digit.isdigit():
        raise ScpiError(f"block header: length digit {digit!r} is not 1…9")
    width = int(digit)
    text = header[2 : 2 + width]
    if len(text) != width or not text.isdigit():
        raise ScpiError(f"block header {header!r}: expected {width} length digits")
    return int(text)


def read_block(read_exact: Callable[[int], bytes]) -> bytes:
    """Read one block through ``read_exact(n)`` (returns exactly n bytes), its terminating LF
    included; return the payload."""
    head = read_exact(2)
    if head[:1] != b"#":
        raise ScpiError(f"expected a definite-length block '#<d><n>…', got {head!r}")
    width = int(head[1:2]) if head[1:2].isdigit() else -1
    if width < 1:
        raise ScpiError(f"block header: length digit {head[1:2]!r} is not 1…9")
    n = block_length(head + read_exact(width))
    payload = read_exact(n)
    end = read_exact(1)
    if end != TERMINATOR:
        raise ScpiError(f"block of {n} bytes not followed by LF but {end!r}")
    return payload


def parse_block(data: bytes) -> tuple[bytes, bytes]:
    """Split ``data`` holding one block (and its LF) into (payload, the bytes after the LF)."""
    if len(data) < 2:
        raise ScpiError(f"block truncated: {data!r}")
    width = int(data[1:2]) if data[1:2].isdigit() else -1
    n = block_length(data[: 2 + max(width, 0)])
    start = 2 + width
    payload = data[start : start + n]
    if len(payload) != n:
        raise ScpiError(f"block announces {n} bytes, {len(payload)} arrived")
    end = data[start + n : start + n + 1]
    if end != TERMINATOR:
        raise ScpiError(f"block of {n} bytes not followed by LF but {end!r}")
    return payload, data[start + n + 1 :]


# --- the preamble ---------------------------------------------------------------------------


@dataclass(frozen=True)
class Preamble:
    """``:WAVeform:PREamble?``: format, acquisition type, points, average count, and the
    x (s) and y (V) axes: ``t_k = (k − x_reference)·x_increment + x_origin``,
    ``v = (code − y_reference)·y_increment + y_origin``."""

    format: WaveFormat
    type: AcquireType
    points: int
    count: int
    x_increment_s: float
    x_origin_s: float
    x_reference: int
    y_increment_v: float
    y_origin_v: float
    y_reference: int

    @property
    def t0_ns(self) -> float:
        """Time of sample 0 after the trigger (ns)."""
        return (self.x_origin_s - self.x_reference * self.x_increment_s) * 1e9

    @property
    def dt_ns(self) -> float:
        """Sample interval (ns)."""
        return self.x_increment_s * 1e9

    def volts(self, codes: np.ndarray) -> np.ndarray:
        """Volts of ``codes`` (any integer array)."""
        return (np.asarray(codes, float) - self.y_reference) * self.y_increment_v + self.y_origin_v


def format_preamble(p: Preamble) -> str:
    """The preamble as a scope sends it (no terminator; floats to the last bit)."""
    return (
        f"{int(p.format)},{int(p.type)},{p.points},{p.count},{float(p.x_increment_s)!r},"
        f"{float(p.x_origin_s)!r},{p.x_reference},{float(p.y_increment_v)!r},"
        f"{float(p.y_origin_v)!r},{p.y_reference}"
    )


def parse_preamble(text: str) -> Preamble:
    """Parse a preamble line (its LF stripped or not); ``ScpiError`` says which field is bad."""
    fields = [f.strip() for f in text.strip().split(",")]
    if len(fields) < 10:
        raise ScpiError(f"preamble has {len(fields)} fields, expected 10: {text.strip()!r}")
    names = (
        "format",
        "type",
        "points",
        "count",
        "xincrement",
        "xorigin",
        "xreference",
        "yincrement",
        "yorigin",
        "yreference",
    )
    values: list[float] = []
    for name, field in zip(names, fields[:10], strict=True):
        try:
            values.append(float(field))
        except ValueError:
            raise ScpiError(f"preamble field {name} is not a number: {field!r}") from None
    if not all(math.isfinite(v) for v in values):
        raise ScpiError(f"preamble has a field that is not finite: {text.strip()!r}")
    ints = [0, 1, 2, 3, 6, 9]
    for i in ints:
        if values[i] != round(values[i]):
            raise ScpiError(f"preamble field {names[i]} is not an integer: {fields[i]!r}")
    try:
        fmt = WaveFormat(int(values[0]))
        kind = AcquireType(int(values[1]))
    except ValueError:
        raise ScpiError(f"preamble format/type {fields[0]}/{fields[1]} unknown") from None
    p = Preamble(
        fmt,
        kind,
        int(values[2]),
        int(values[3]),
        values[4],
        values[5],
        int(values[6]),
        values[7],
        values[8],
        int(values[9]),
    )
    if p.points < 0 or p.x_increment_s <= 0 or p.y_increment_v <= 0:
        raise ScpiError(
            f"preamble: points {p.points}, x increment {p.x_increment_s} s and "
            f"y increment {p.y_increment_v} V must be positive"
        )
    return p


# --- sample codes ---------------------------------------------------------------------------


def _dtype(fmt: WaveFormat, byte_order: str) -> np.dtype:
    if fmt == WaveFormat.BYTE:
        return np.dtype("u1")
    if fmt == WaveFormat.WORD:
        return np.dtype(">u2" if byte_order == "MSBF" else "<u2")
    raise ScpiError(f"{fmt.name} data is not binary")


def decode_codes(payload: bytes, fmt: WaveFormat, byte_order: str = "MSBF") -> np.ndarray:
    """The unsigned sample codes of a binary block (int32 array)."""
    dtype = _dtype(fmt, byte_order)
    if len(payload) % dtype.itemsize:
        raise ScpiError(f"{len(payload)} bytes is not a whole number of {fmt.name} samples")
    return np.frombuffer(payload, dtype=dtype).astype(np.int32)


def encode_codes(codes: np.ndarray, fmt: WaveFormat, byte_order: str = "MSBF") -> bytes:
    """The bytes of unsigned sample codes in ``fmt``."""
    return np.asarray(codes).astype(_dtype(fmt, byte_order)).tobytes()


def code_step(codes: np.ndarray, fmt: WaveFormat, y_reference: int) -> int:
    """The ADC's step in codes: the largest power of two that divides every sample's distance
    from ``y_reference`` (a WORD record carries fewer bits left-aligned); 1 when every sample
    sits on the reference (nothing shows)."""
    distances = np.asarray(codes, np.int32) - np.int32(y_reference)
    flagged = (codes == HOLE) | (codes == CLIP_LOW[fmt]) | (codes == CLIP_HIGH[fmt])
    if np.any(flagged):
        distances = distances[~flagged]
    return left_aligned_step(distances)


@dataclass(frozen=True)
class IdnReply:
    """``*IDN?``: manufacturer, model, serial number, firmware (IEEE 488.2 §10.14)."""

    manufacturer: str
    model: str
    serial: str
    firmware: str


def parse_idn(text: str) -> IdnReply:
    """Parse ``*IDN?``'s four comma-separated fields (missing ones empty)."""
    fields = [f.strip() for f in text.strip().split(",", 3)]
    fields += [""] * (4 - len(fields))
    return IdnReply(*fields[:4])
