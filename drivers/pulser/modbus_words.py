"""How the pulser's values travel in Modbus registers: the protocol's function and exception
codes, its limits, and the encodings of every value type.

Encodings:

- Every register is big-endian (high byte first), as Modbus prescribes.
- 32-bit values (``uint32``, ``int32``, ``float32`` IEEE 754) occupy two consecutive registers;
  the map says which comes first: ``"big"`` = most significant word at the lower address
  ("ABCD", pymodbus ``convert_to_registers(..., word_order="big")``; ucal's own map),
  ``"little"`` = least significant first ("CDAB").
- ``int16``/``int32`` are two's complement; ``string`` is ASCII, two characters a register,
  the first in the high byte, NUL padded.
- A register's value in ucal's unit is ``raw / counts_per_unit`` (a map file states the
  ``scale`` of one count in a unit of its choice; the loader turns it into counts per ucal
  unit exactly).
- A-scan samples are ``int16``; ``full_scale`` counts (32767 in ucal's map) are full screen
  height (1.0).

pymodbus datastores: ``ModbusDeviceContext`` adds 1 to the protocol address before it indexes
its data blocks (protocol address N is served from block address N + 1). A block that must
serve protocol address N from ``values[0]`` is therefore created at block address
N + :data:`DATASTORE_OFFSET`.
"""

from __future__ import annotations

import enum
import struct
from collections.abc import Sequence

import numpy as np

#: Default word order of 32-bit values (a map file may choose another): most significant
#: register first ("ABCD").
WORD_ORDER = "big"
#: pymodbus ``ModbusDeviceContext`` serves protocol address N from data-block address N + 1.
DATASTORE_OFFSET = 1
#: Most registers one read request (FC 3/4) may ask for (Modbus application protocol §6.3).
MAX_READ_REGISTERS = 125
#: Most registers one write request (FC 16) may carry (Modbus application protocol §6.12).
MAX_WRITE_REGISTERS = 123
#: Registers in one Modbus table (protocol addresses 0 … 65535).
TABLE_SIZE = 0x1_0000

#: Full-scale int16 A-scan sample (= 1.0 of full screen height) of ucal's own map.
ASCAN_FULL_SCALE = 32767
#: Bits of one character on a Modbus serial line: start, 8 data, parity (or a second stop
#: bit), stop (Modbus over serial line §2.5.1).
RTU_BITS_PER_CHAR = 11
#: Bytes of an RTU read request (unit, function, address, count, CRC), of its answer beyond
#: the registers' two bytes each (unit, function, byte count, CRC), and the silence of 3.5
#: characters before each of the two frames.
RTU_READ_REQUEST_BYTES = 8
RTU_READ_ANSWER_BYTES = 5
RTU_FRAME_GAPS_CHARS = 2 * 3.5


class FunctionCode(enum.IntEnum):
    """Modbus function codes the pulser implements."""

    READ_HOLDING_REGISTERS = 0x03
    READ_INPUT_REGISTERS = 0x04
    WRITE_SINGLE_REGISTER = 0x06
    WRITE_MULTIPLE_REGISTERS = 0x10


class ExceptionCode(enum.IntEnum):
    """Modbus exception codes (Modbus application protocol §7) and their readable names."""

    ILLEGAL_FUNCTION = 0x01
    ILLEGAL_DATA_ADDRESS = 0x02
    ILLEGAL_DATA_VALUE = 0x03
    SERVER_DEVICE_FAILURE = 0x04
    ACKNOWLEDGE = 0x05
    SERVER_DEVICE_BUSY = 0x06
    NEGATIVE_ACKNOWLEDGE = 0x07
    MEMORY_PARITY_ERROR = 0x08
    GATEWAY_PATH_UNAVAILABLE = 0x0A
    GATEWAY_TARGET_FAILED_TO_RESPOND = 0x0B

    @property
    def description(self) -> str:
        """Return the name in words, e.g. ``"illegal data address"``."""
        return self.name.lower().replace("_", " ")


def rtu_read_line_s(registers: int, baud: int) -> float:
    """Time on an RTU line at ``baud`` of reading ``registers`` registers in requests of at
    most ``MAX_READ_REGISTERS``, s: requests, answers and the silences before them (a
    10-register block at 19,200 baud: 22.9 ms; 400 A-scan samples: 0.50 s)."""
    if registers <= 0:
        return 0.0
    requests = -(-int(registers) // MAX_READ_REGISTERS)
    frame_chars = RTU_READ_REQUEST_BYTES + RTU_READ_ANSWER_BYTES + RTU_FRAME_GAPS_CHARS
    chars = requests * frame_chars + 2 * int(registers)
    return chars * RTU_BITS_PER_CHAR / float(baud)


def exception_name(code: int) -> str:
    """Return ``"illegal data address (0x02)"`` for a Modbus exception code, known or not."""
    try:
        return f"{ExceptionCode(code).description} (0x{code:02X})"
    except ValueError:
        return f"unknown exception (0x{code:02X})"


#: Words of each value type (a string's come from its length).
TYPE_WORDS = {"uint16": 1, "int16": 1, "uint32": 2, "int32": 2, "float32": 2}
#: Raw range of each integer type.
TYPE_RANGE = {
    "uint16": (0, 0xFFFF),
    "int16": (-0x8000, 0x7FFF),
    "uint32": (0, 0xFFFF_FFFF),
    "int32": (-0x8000_0000, 0x7FFF_FFFF),
}


def check_register(value: int) -> int:
    """``value`` if it fits in one register (uint16), else ``ValueError``."""
    if not 0 <= value <= 0xFFFF:
        raise ValueError(f"register value {value!r} is not a uint16")
    return value


def encode_uint32(value: int, word_order: str = WORD_ORDER) -> tuple[int, int]:
    """Split an unsigned 32-bit integer into two registers, in ``word_order``."""
    if not 0 <= int(value) <= 0xFFFF_FFFF:
        raise ValueError(f"{value!r} does not fit in a uint32")
    hi, lo = divmod(int(value), 0x1_0000)
    return (hi, lo) if word_order == "big" else (lo, hi)


def decode_uint32(first: int, second: int, word_order: str = WORD_ORDER) -> int:
    """Join two registers (in address order) into an unsigned 32-bit integer."""
    hi, lo = (first, second) if word_order == "big" else (second, first)
    return (check_register(hi) << 16) | check_register(lo)


def encode_float32(value: float, word_order: str = WORD_ORDER) -> tuple[int, int]:
    """Encode an IEEE 754 float32 into two registers, in ``word_order``.

    Values are rounded to the nearest float32; finite values beyond the float32 range raise
    ``OverflowError``; NaN and ±inf are kept.
    """
    raw = struct.unpack(">I", struct.pack(">f", float(value)))[0]
    return encode_uint32(raw, word_order)


def decode_float32(first: int, second: int, word_order: str = WORD_ORDER) -> float:
    """Decode two registers (in address order) holding an IEEE 754 float32."""
    raw = decode_uint32(first, second, word_order)
    return float(struct.unpack(">f", struct.pack(">I", raw))[0])


def encode_string(text: str, words: int) -> list[int]:
    """ASCII ``text`` in ``words`` registers (two characters each, the first in the high byte,
    NUL padded); ``ValueError`` if it is longer."""
    raw = text.encode("ascii")
    if len(raw) > 2 * words:
        raise ValueError(f"{text!r} is longer than {2 * words} bytes")
    raw = raw.ljust(2 * words, b"\0")
    return [int.from_bytes(raw[i : i + 2], "big") for i in range(0, 2 * words, 2)]


def decode_string(registers: Sequence[int]) -> str:
    """The ASCII text of registers (up to the first NUL)."""
    raw = b"".join(check_register(w).to_bytes(2, "big") for w in registers)
    return raw.split(b"\0", 1)[0].decode("ascii", errors="replace")


def encode_samples(samples: np.ndarray, full_scale: int = ASCAN_FULL_SCALE) -> list[int]:
    """Encode normalised samples (1.0 = full screen) as int16 registers, saturating at ±1.0.

    Saturation here is the receiver's ADC clipping a too-strong signal, not input validation.
    """
    counts = np.rint(np.clip(np.asarray(samples, float), -1.0, 1.0) * full_scale)
    words: list[int] = (counts.astype(np.int16).view(np.uint16)).astype(int).tolist()
    return words


def decode_samples(registers: Sequence[int], full_scale: int = ASCAN_FULL_SCALE) -> np.ndarray:
    """Decode int16 registers into normalised samples (float64, 1.0 = full screen)."""
    raw = np.asarray(registers, dtype=np.uint16).view(np.int16)
    return raw.astype(float) / full_scale
