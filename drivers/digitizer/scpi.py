"""SCPI framing of an oscilloscope's waveform transfer, shared by the client and the simulator:
what every family's scope sends the same way (``docs/protocols/scpi_digitizer.md``).

- Program messages are ASCII, terminated by LF; a family that takes several commands in one
  message separates them by ``;`` (each with its full path from the root ``:``). A query's
  answer is one ASCII line, terminated by LF (IEEE 488.2 §8.5, §7.5).
- ``:WAVeform:DATA?`` answers with an IEEE 488.2 *definite-length arbitrary block*
  (§8.7.9): ``#`` + one digit *d* (1…9) + *d* ASCII digits giving the byte count *n* + *n*
  bytes of data, then LF. ``#9000001000`` announces 1000 bytes.
- ``:WAVeform:PREamble?`` answers with ten comma-separated numbers, ``format, type, points,
  count, xincrement, xorigin, xreference, yincrement, yorigin, yreference``, in every family
  that ucal speaks; what the codes of ``format`` and ``type`` mean and how ``yorigin`` enters
  the volts differ by family, so :func:`preamble_values` only reads the numbers and a dialect
  (``drivers.digitizer.dialects``) gives them their meaning in a :class:`Preamble`.
- ``*IDN?`` answers manufacturer, model, serial number and firmware (IEEE 488.2 §10.14).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from drivers.digitizer.base import left_aligned_step

#: The terminator of every program message and every answer line.
TERMINATOR = b"\n"


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

#: The ten fields of ``:WAVeform:PREamble?``, in their order.
PREAMBLE_FIELDS = (
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
#: The fields that are integers in every family (``yorigin`` is one in some only).
_INTEGER_FIELDS = ("format", "type", "points", "count", "xreference", "yreference")


def preamble_values(text: str) -> dict[str, float]:
    """The ten numbers of a preamble line (its LF stripped or not), by field name;
    ``ScpiError`` says which field is missing, not a number, not finite or not an integer."""
    fields = [f.strip() for f in text.strip().split(",")]
    if len(fields) != len(PREAMBLE_FIELDS):
        raise ScpiError(f"preamble has {len(fields)} fields, expected 10: {text.strip()!r}")
    values: dict[str, float] = {}
    for name, field in zip(PREAMBLE_FIELDS, fields, strict=True):
        try:
            value = float(field)
        except ValueError:
            raise ScpiError(f"preamble field {name} is not a number: {field!r}") from None
        if not math.isfinite(value):
            raise ScpiError(f"preamble field {name} is not finite: {field!r}")
        if name in _INTEGER_FIELDS and value != round(value):
            raise ScpiError(f"preamble field {name} is not an integer: {field!r}")
        values[name] = value
    return values


@dataclass(frozen=True)
class Preamble:
    """A preamble as its family means it: the transfer format (``"BYTE"``, ``"WORD"``,
    ``"ASCII"``), the type field in the family's own words, the points and average count,
    and the axes: sample k is taken ``(k − x_reference)·x_increment_s + x_origin_s`` after
    the trigger; a code c reads ``(c − y_reference)·y_increment_v + y_origin`` volts when
    ``y_origin`` is in volts (Keysight), ``(c − y_origin − y_reference)·y_increment_v`` when it
    is in codes (Rigol, ``y_origin_in_codes``)."""

    format: str
    type: str
    points: int
    count: int
    x_increment_s: float
    x_origin_s: float
    x_reference: int
    y_increment_v: float
    y_origin: float
    y_reference: int
    y_origin_in_codes: bool = False

    def __post_init__(self) -> None:
        if self.points < 0 or not self.x_increment_s > 0 or not self.y_increment_v > 0:
            raise ScpiError(
                f"preamble: points {self.points}, x increment {self.x_increment_s} s and "
                f"y increment {self.y_increment_v} V must be positive"
            )

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
        c = np.asarray(codes, float)
        if self.y_origin_in_codes:
            return (c - self.y_origin - self.y_reference) * self.y_increment_v
        return (c - self.y_reference) * self.y_increment_v + self.y_origin

    def codes_of(self, volts: np.ndarray) -> np.ndarray:
        """The (real-valued) codes that read ``volts``: the inverse of :meth:`volts`."""
        v = np.asarray(volts, float)
        if self.y_origin_in_codes:
            return v / self.y_increment_v + self.y_origin + self.y_reference
        return (v - self.y_origin) / self.y_increment_v + self.y_reference


# --- samples --------------------------------------------------------------------------------


def _dtype(sample_bytes: int, byte_order: str) -> np.dtype:
    if sample_bytes == 1:
        return np.dtype("u1")
    if sample_bytes == 2:
        return np.dtype(">u2" if byte_order == "MSBF" else "<u2")
    raise ScpiError(f"{sample_bytes}-byte samples are not a binary format ucal reads")


def decode_codes(payload: bytes, sample_bytes: int, byte_order: str = "MSBF") -> np.ndarray:
    """The unsigned sample codes of a binary block of ``sample_bytes`` a sample (int32)."""
    dtype = _dtype(sample_bytes, byte_order)
    if len(payload) % dtype.itemsize:
        raise ScpiError(
            f"{len(payload)} bytes is not a whole number of {sample_bytes}-byte samples"
        )
    return np.frombuffer(payload, dtype=dtype).astype(np.int32)


def encode_codes(codes: np.ndarray, sample_bytes: int, byte_order: str = "MSBF") -> bytes:
    """The bytes of unsigned sample codes, ``sample_bytes`` a sample."""
    return np.asarray(codes).astype(_dtype(sample_bytes, byte_order)).tobytes()


def decode_ascii(payload: bytes) -> np.ndarray:
    """The values of an ASCII block (comma-separated numbers, NR1/NR2/NR3), float64."""
    text = payload.decode("ascii", errors="replace").strip().rstrip(",")
    if not text:
        return np.zeros(0)
    try:
        values = np.array([float(v) for v in text.split(",")], float)
    except ValueError:
        raise ScpiError(
            f"ASCII waveform data is not comma-separated numbers: {text[:40]!r}"
        ) from None
    if not np.all(np.isfinite(values)):
        raise ScpiError("ASCII waveform data holds a value that is not finite")
    return values


def encode_ascii(volts: np.ndarray) -> bytes:
    """Volts as an ASCII block's payload: comma-separated NR3 numbers."""
    return ",".join(f"{float(v):+.6E}" for v in np.asarray(volts, float)).encode("ascii")


def code_step(codes: np.ndarray, y_reference: int, flags: tuple[int, ...] = ()) -> int:
    """The ADC's step in codes: the largest power of two that divides every sample's distance
    from ``y_reference`` (a record that carries fewer bits left-aligned in wider words), flag
    codes (``flags``) left out; 1 when every sample sits on the reference (nothing shows)."""
    codes = np.asarray(codes, np.int32)
    distances = codes - np.int32(y_reference)
    if flags:
        distances = distances[~np.isin(codes, flags)]
    return left_aligned_step(distances)


# --- identification -------------------------------------------------------------------------


@dataclass(frozen=True)
class IdnReply:
    """``*IDN?``: manufacturer, model, serial number, firmware (IEEE 488.2 §10.14)."""

    manufacturer: str
    model: str
    serial: str
    firmware: str

    def __str__(self) -> str:
        return ",".join((self.manufacturer, self.model, self.serial, self.firmware))


def parse_idn(text: str) -> IdnReply:
    """Parse ``*IDN?``'s four comma-separated fields (missing ones empty)."""
    fields = [f.strip() for f in text.strip().split(",", 3)]
    fields += [""] * (4 - len(fields))
    return IdnReply(*fields[:4])
