"""The pulser-receiver's Modbus register map, as data, and its value encodings.

The map is the contract between ``drivers.pulser.modbus`` (client) and
``drivers.pulser.simulator`` (server); ``docs/protocols/pulser_modbus.md`` documents it in
tables. Addresses here are the *protocol* addresses that travel in the PDU (0-based).

Encodings:

- Every register is big-endian (high byte first), as Modbus prescribes.
- 32-bit values (``uint32``, ``float32`` IEEE 754) occupy two consecutive registers, most
  significant word first, at the lower address (:data:`WORD_ORDER` = ``"big"``, "ABCD"; the
  same as pymodbus ``convert_to_registers(..., word_order="big")``). Client and server both
  encode through the functions of this module, so they cannot disagree.
- A-scan samples are ``int16`` two's complement; 32767 is full screen height (1.0).

pymodbus datastores: ``ModbusDeviceContext`` adds 1 to the protocol address before it indexes
its data blocks (protocol address N is served from block address N + 1). A block that must
serve protocol address N from ``values[0]`` is therefore created at block address
N + :data:`DATASTORE_OFFSET`.
"""

from __future__ import annotations

import enum
import math
import struct
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from drivers.pulser.base import PulserSettings

#: Word order of every 32-bit value: most significant register first ("ABCD").
WORD_ORDER = "big"
#: pymodbus ``ModbusDeviceContext`` serves protocol address N from data-block address N + 1.
DATASTORE_OFFSET = 1
#: Most registers one read request (FC 3/4) may ask for (Modbus application protocol §6.3).
MAX_READ_REGISTERS = 125
#: Most registers one write request (FC 16) may carry (Modbus application protocol §6.12).
MAX_WRITE_REGISTERS = 123

#: Identity register contents: ASCII "UP" (ultrasonic pulser) and the version of this map.
DEVICE_MAGIC = 0x5550
#: Version 2 adds the front-end settings (pulse voltage, damping, filters; holding registers
#: 0x0009–0x000C) and the device information block (input registers 0x0002–0x000D) after the
#: registers of version 1, whose addresses are unchanged.
MAP_VERSION = 2
#: Map versions the client talks to; a version-1 device has no front-end or device-info block.
SUPPORTED_MAP_VERSIONS = (1, 2)

#: Full-scale int16 A-scan sample (= 1.0 of full screen height).
ASCAN_FULL_SCALE = 32767
#: Longest A-scan the device records, samples (327.68 µs at 100 MS/s).
ASCAN_MAX_SAMPLES = 32768


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


def exception_name(code: int) -> str:
    """Return ``"illegal data address (0x02)"`` for a Modbus exception code, known or not."""
    try:
        return f"{ExceptionCode(code).description} (0x{code:02X})"
    except ValueError:
        return f"unknown exception (0x{code:02X})"


class Status(enum.IntFlag):
    """Status bits of the measurement block (input register ``STATUS``)."""

    ECHO = 0x0001  #: an echo inside the gate crossed the threshold; TOF is valid
    SATURATED = 0x0002  #: the gated peak reached full screen (amplitude clipped at 1.0)
    GATE_ERROR = 0x0004  #: the gate ends after the pulse repetition period; no measurement


class Command(enum.IntEnum):
    """Values of the write-only ``COMMAND`` holding register (it always reads 0)."""

    NONE = 0
    TRIGGER = 1  #: acquire now (counter + 1)
    CLEAR_COUNTER = 2  #: reset the reading counter and the measurement block to zero


# ---------------------------------------------------------------------------------------------
# Holding registers (FC 3 read, FC 6 / FC 16 write)
# ---------------------------------------------------------------------------------------------
class Holding(enum.IntEnum):
    """Holding-register addresses (protocol addresses, 0-based)."""

    GAIN = 0x0000  #: uint16, 0.1 dB
    PRF = 0x0001  #: uint16, Hz
    GATE_START = 0x0002  #: uint32 (2 registers), ns of round-trip time
    GATE_WIDTH = 0x0004  #: uint32 (2 registers), ns
    AVERAGES = 0x0006  #: uint16, acquisitions averaged per reading
    THRESHOLD = 0x0007  #: uint16, 0.1 % of full screen height
    COMMAND = 0x0008  #: uint16, write-only, see :class:`Command`
    PULSE_VOLTAGE = 0x0009  #: uint16, V (map version 2)
    DAMPING = 0x000A  #: uint16, Ω (map version 2)
    HIGH_PASS = 0x000B  #: uint16, 0.01 MHz (map version 2)
    LOW_PASS = 0x000C  #: uint16, 0.01 MHz (map version 2)


#: Number of holding registers (0x0000 … 0x000C).
HOLDING_COUNT = 13
#: The registers :func:`encode_settings` writes in one FC 16 request (GAIN … AVERAGES).
SETTINGS_ADDRESS = Holding.GAIN
SETTINGS_COUNT = 7
#: The registers :func:`encode_front_end` writes in one FC 16 request (map version 2).
FRONT_END_ADDRESS = Holding.PULSE_VOLTAGE
FRONT_END_COUNT = 4


@dataclass(frozen=True)
class Setting:
    """One declared setting: where it lives, its scaling, units and allowed range.

    ``scale`` is register counts per user unit (0.1 dB → 10 counts per dB). User values are
    validated against ``[minimum, maximum]`` (inclusive, in user units) and rounded to the
    register resolution ``1 / scale``; out-of-range values raise, they are never clipped.
    """

    name: str
    address: int
    words: int
    scale: float
    minimum: float
    maximum: float
    units: str
    integer: bool = False
    doc: str = ""

    def to_raw(self, value: float) -> int:
        """Validate a user value and return its raw register value (counts).

        Raises ``ValueError`` naming the setting when the value is not a finite number, not an
        integer where one is required, or outside ``[minimum, maximum]``.
        """
        if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
            # ValueError like every other invalid setting: callers catch one type
            raise ValueError(f"{self.name} must be a number, got {value!r}")
        v = float(value)
        if not math.isfinite(v):
            raise ValueError(f"{self.name} must be finite, got {value!r}")
        if self.integer and v != round(v):
            raise ValueError(f"{self.name} must be an integer, got {value!r}")
        if not self.minimum <= v <= self.maximum:
            raise ValueError(
                f"{self.name} = {value!r} {self.units} is out of range "
                f"[{self.minimum:g}, {self.maximum:g}] {self.units}"
            )
        return round(v * self.scale)

    def from_raw(self, raw: int) -> float:
        """Convert a raw register value (counts) to user units."""
        return raw / self.scale

    def raw_ok(self, raw: int) -> bool:
        """Tell whether a raw register value is inside the allowed range (server side)."""
        return round(self.minimum * self.scale) <= raw <= round(self.maximum * self.scale)

    def registers(self, raw: int) -> list[int]:
        """Split a raw value into its ``words`` registers (:data:`WORD_ORDER`)."""
        return [raw] if self.words == 1 else list(encode_uint32(raw))


GAIN = Setting(
    "gain_db", Holding.GAIN, 1, 10.0, 0.0, 80.0, "dB", doc="Receiver gain, 0.1 dB resolution."
)
PRF = Setting(
    "prf_hz",
    Holding.PRF,
    1,
    1.0,
    1.0,
    20000.0,
    "Hz",
    doc="Pulse repetition frequency, 1 Hz resolution.",
)
GATE_START = Setting(
    "gate_start_us",
    Holding.GATE_START,
    2,
    1000.0,
    0.0,
    1000.0,
    "µs",
    doc="Gate start, round-trip time after the transmit pulse, 1 ns resolution.",
)
GATE_WIDTH = Setting(
    "gate_width_us",
    Holding.GATE_WIDTH,
    2,
    1000.0,
    0.1,
    1000.0,
    "µs",
    doc="Gate width, 1 ns resolution.",
)
AVERAGES = Setting(
    "averages",
    Holding.AVERAGES,
    1,
    1.0,
    1.0,
    1024.0,
    "",
    integer=True,
    doc="Acquisitions averaged into one reading.",
)
THRESHOLD = Setting(
    "gate_threshold",
    Holding.THRESHOLD,
    1,
    1000.0,
    0.0,
    1.0,
    "FSH",
    doc="Gate threshold as a fraction of full screen height, 0.1 % resolution.",
)
COMMAND = Setting(
    "command",
    Holding.COMMAND,
    1,
    1.0,
    0.0,
    float(max(Command)),
    "",
    integer=True,
    doc="Write-only command, see Command.",
)

PULSE_VOLTAGE = Setting(
    "pulse_voltage_v",
    Holding.PULSE_VOLTAGE,
    1,
    1.0,
    10.0,
    500.0,
    "V",
    doc="Pulse voltage (sets the pulse energy), 1 V resolution.",
)
DAMPING = Setting(
    "damping_ohm",
    Holding.DAMPING,
    1,
    1.0,
    10.0,
    2000.0,
    "Ω",
    doc="Damping resistance across the transducer, 1 Ω resolution.",
)
HIGH_PASS = Setting(
    "high_pass_mhz",
    Holding.HIGH_PASS,
    1,
    100.0,
    0.0,
    100.0,
    "MHz",
    doc="Receiver high-pass cut-off (0 = DC coupled), 0.01 MHz resolution.",
)
LOW_PASS = Setting(
    "low_pass_mhz",
    Holding.LOW_PASS,
    1,
    100.0,
    0.1,
    500.0,
    "MHz",
    doc="Receiver low-pass cut-off, 0.01 MHz resolution.",
)

#: The settings of :class:`PulserSettings` in the first block (map version 1), register order.
SETTINGS: tuple[Setting, ...] = (GAIN, PRF, GATE_START, GATE_WIDTH, AVERAGES)
#: The front-end settings of :class:`PulserSettings` (map version 2), register order.
FRONT_END_SETTINGS: tuple[Setting, ...] = (PULSE_VOLTAGE, DAMPING, HIGH_PASS, LOW_PASS)
#: Every holding-register setting, in register order.
HOLDING_SETTINGS: tuple[Setting, ...] = SETTINGS + (THRESHOLD, COMMAND) + FRONT_END_SETTINGS
#: Gate threshold of a freshly powered device, fraction of full screen height.
DEFAULT_THRESHOLD = 0.02


def check_gate(settings: PulserSettings) -> None:
    """Raise ``ValueError`` when the gate ends after the pulse repetition period.

    The receiver listens for ``1 / prf_hz`` after each transmit pulse; a gate ending later
    (``gate_start_us + gate_width_us > 1e6 / prf_hz``) would look into the next pulse.
    """
    period_us = 1e6 / float(settings.prf_hz)
    end_us = float(settings.gate_start_us) + float(settings.gate_width_us)
    if end_us > period_us:
        raise ValueError(
            f"gate_width_us: the gate ends at {end_us:g} µs, after the pulse repetition "
            f"period of {period_us:g} µs (prf_hz = {settings.prf_hz:g})"
        )


def encode_settings(settings: PulserSettings) -> list[int]:
    """Validate ``settings`` and return the :data:`SETTINGS_COUNT` registers from ``GAIN``.

    Raises ``ValueError`` naming the first invalid setting; nothing is clipped.
    """
    registers: list[int] = []
    for s in SETTINGS:
        registers += s.registers(s.to_raw(getattr(settings, s.name)))
    check_gate(settings)
    return registers


def encode_front_end(settings: PulserSettings) -> list[int]:
    """Validate the front-end settings; return the :data:`FRONT_END_COUNT` registers from
    ``PULSE_VOLTAGE`` (map version 2). Raises ``ValueError`` naming the first invalid one."""
    registers: list[int] = []
    for s in FRONT_END_SETTINGS:
        registers += s.registers(s.to_raw(getattr(settings, s.name)))
    if registers[-1] <= registers[-2]:  # the band after rounding to 0.01 MHz
        raise ValueError(
            f"low_pass_mhz = {settings.low_pass_mhz:g} MHz must be above "
            f"high_pass_mhz = {settings.high_pass_mhz:g} MHz"
        )
    return registers


def front_end_is_default(settings: PulserSettings) -> bool:
    """Tell whether the front-end settings are the defaults (what a version-1 map implies)."""
    default = PulserSettings()
    return all(getattr(settings, s.name) == getattr(default, s.name) for s in FRONT_END_SETTINGS)


def decode_settings(registers: Sequence[int]) -> PulserSettings:
    """Decode holding registers read from ``GAIN`` into :class:`PulserSettings`.

    The first :data:`SETTINGS_COUNT` registers are required; the front-end settings are decoded
    when the registers reach ``LOW_PASS`` (a map-version-2 read), else they keep their defaults.
    """
    if len(registers) < SETTINGS_COUNT:
        raise ValueError(f"need {SETTINGS_COUNT} registers, got {len(registers)}")
    values: dict[str, float] = {}
    settings = SETTINGS
    if len(registers) >= FRONT_END_ADDRESS + FRONT_END_COUNT - SETTINGS_ADDRESS:
        settings = SETTINGS + FRONT_END_SETTINGS
    for s in settings:
        i = s.address - SETTINGS_ADDRESS
        raw = registers[i] if s.words == 1 else decode_uint32(registers[i], registers[i + 1])
        values[s.name] = s.from_raw(raw)
    values["averages"] = int(values["averages"])
    return PulserSettings(**values)  # type: ignore[arg-type]


def power_on_holding() -> list[int]:
    """The :data:`HOLDING_COUNT` holding registers of a freshly powered device: the
    :class:`PulserSettings` defaults, :data:`DEFAULT_THRESHOLD` and no command."""
    defaults = PulserSettings()
    return (
        encode_settings(defaults)
        + [THRESHOLD.to_raw(DEFAULT_THRESHOLD), int(Command.NONE)]
        + encode_front_end(defaults)
    )


# ---------------------------------------------------------------------------------------------
# Input registers (FC 4, read-only)
# ---------------------------------------------------------------------------------------------
class Input(enum.IntEnum):
    """Input-register addresses (protocol addresses, 0-based)."""

    MAGIC = 0x0000  #: uint16, :data:`DEVICE_MAGIC`
    MAP_VERSION = 0x0001  #: uint16, :data:`MAP_VERSION`
    MODEL = 0x0002  #: 16 bytes ASCII, NUL padded (8 registers, map version 2)
    FIRMWARE = 0x000A  #: uint16 major, uint16 minor (map version 2)
    SERIAL = 0x000C  #: uint32 serial number (map version 2)
    COUNTER = 0x0010  #: uint32, reading counter (+1 per acquisition, wraps at 2**32)
    DEVICE_TIME = 0x0012  #: uint32, device clock at acquisition, ms (wraps after 49.7 days)
    STATUS = 0x0014  #: uint16, :class:`Status` bits
    AMPLITUDE = 0x0016  #: float32, gated peak amplitude, fraction of full screen height
    TOF = 0x0018  #: float32, round-trip time of flight at the peak, ns; NaN = no echo
    ASCAN_COUNTER = 0x0100  #: uint32, counter of the acquisition the A-scan belongs to
    ASCAN_LENGTH = 0x0102  #: uint16, number of samples (0 … ASCAN_MAX_SAMPLES)
    ASCAN_RATE = 0x0104  #: float32, sample rate, Hz
    ASCAN_START = 0x0106  #: uint32, time of sample 0 (= gate start), ns
    ASCAN_SAMPLES = 0x0200  #: int16 × ASCAN_MAX_SAMPLES, 32767 = full screen height


IDENTITY_ADDRESS = Input.MAGIC
IDENTITY_COUNT = 2
DEVICE_INFO_ADDRESS = Input.MODEL
DEVICE_INFO_COUNT = 12
#: Bytes of the model name (2 per register).
MODEL_BYTES = 16
MEASUREMENT_ADDRESS = Input.COUNTER
MEASUREMENT_COUNT = 10
ASCAN_HEADER_ADDRESS = Input.ASCAN_COUNTER
ASCAN_HEADER_COUNT = 8

#: Readable input-register ranges ``(first, count)``; a read must lie inside one of them.
INPUT_RANGES: tuple[tuple[int, int], ...] = (
    (IDENTITY_ADDRESS, IDENTITY_COUNT),
    (DEVICE_INFO_ADDRESS, DEVICE_INFO_COUNT),
    (MEASUREMENT_ADDRESS, MEASUREMENT_COUNT),
    (ASCAN_HEADER_ADDRESS, ASCAN_HEADER_COUNT),
    (Input.ASCAN_SAMPLES, ASCAN_MAX_SAMPLES),
)
#: Size of an input-register image that covers every range (protocol addresses 0 … end - 1).
INPUT_SPAN = Input.ASCAN_SAMPLES + ASCAN_MAX_SAMPLES


@dataclass(frozen=True)
class Measurement:
    """The measurement block, ``MEASUREMENT_COUNT`` input registers from ``COUNTER``."""

    counter: int  #: reading counter, uint32
    device_time_ms: int  #: device clock at acquisition, ms, uint32
    status: Status  #: status bits
    amplitude: float  #: gated peak, fraction of full screen height (float32)
    tof_ns: float  #: round-trip time of flight, ns (float32), NaN without echo

    def to_registers(self) -> list[int]:
        """Encode into registers: counter, time, status, reserved 0, amplitude, tof."""
        return [
            *encode_uint32(self.counter),
            *encode_uint32(self.device_time_ms),
            int(self.status) & 0xFFFF,
            0,  # reserved: keeps the float32 pairs on even addresses
            *encode_float32(self.amplitude),
            *encode_float32(self.tof_ns),
        ]

    @classmethod
    def from_registers(cls, registers: Sequence[int]) -> Measurement:
        """Decode ``MEASUREMENT_COUNT`` registers read from ``COUNTER``."""
        if len(registers) != MEASUREMENT_COUNT:
            raise ValueError(f"need {MEASUREMENT_COUNT} registers, got {len(registers)}")
        r = list(registers)
        return cls(
            counter=decode_uint32(r[0], r[1]),
            device_time_ms=decode_uint32(r[2], r[3]),
            status=Status(r[4] & int(Status.ECHO | Status.SATURATED | Status.GATE_ERROR)),
            amplitude=decode_float32(r[6], r[7]),
            tof_ns=decode_float32(r[8], r[9]),
        )


@dataclass(frozen=True)
class DeviceInfo:
    """The device information block, ``DEVICE_INFO_COUNT`` input registers from ``MODEL``."""

    model: str  #: ASCII, at most :data:`MODEL_BYTES` characters
    firmware: tuple[int, int]  #: (major, minor)
    serial: int  #: uint32

    def to_registers(self) -> list[int]:
        """Encode into registers: model (NUL padded, 2 bytes per register, high byte first),
        firmware major, minor, serial (uint32)."""
        raw = self.model.encode("ascii")
        if len(raw) > MODEL_BYTES:
            raise ValueError(f"model name {self.model!r} is longer than {MODEL_BYTES} bytes")
        raw = raw.ljust(MODEL_BYTES, b"\0")
        words = [int.from_bytes(raw[i : i + 2], "big") for i in range(0, MODEL_BYTES, 2)]
        major, minor = self.firmware
        return [*words, _check_register(major), _check_register(minor), *encode_uint32(self.serial)]

    @classmethod
    def from_registers(cls, registers: Sequence[int]) -> DeviceInfo:
        """Decode ``DEVICE_INFO_COUNT`` registers read from ``MODEL``."""
        if len(registers) != DEVICE_INFO_COUNT:
            raise ValueError(f"need {DEVICE_INFO_COUNT} registers, got {len(registers)}")
        r = list(registers)
        n = MODEL_BYTES // 2
        raw = b"".join(_check_register(w).to_bytes(2, "big") for w in r[:n])
        model = raw.split(b"\0", 1)[0].decode("ascii", errors="replace")
        return cls(model=model, firmware=(r[n], r[n + 1]), serial=decode_uint32(r[n + 2], r[n + 3]))

    @property
    def firmware_version(self) -> str:
        """The firmware version as ``"major.minor"``."""
        return f"{self.firmware[0]}.{self.firmware[1]}"


@dataclass(frozen=True)
class AScanHeader:
    """The A-scan header, ``ASCAN_HEADER_COUNT`` input registers from ``ASCAN_COUNTER``."""

    counter: int  #: counter of the acquisition the samples belong to
    length: int  #: number of samples
    sample_rate_hz: float  #: sample rate, Hz (float32)
    start_ns: int  #: time of sample 0, ns of round-trip time

    def to_registers(self) -> list[int]:
        """Encode into registers: counter, length, reserved 0, rate, start."""
        return [
            *encode_uint32(self.counter),
            self.length & 0xFFFF,
            0,  # reserved
            *encode_float32(self.sample_rate_hz),
            *encode_uint32(self.start_ns),
        ]

    @classmethod
    def from_registers(cls, registers: Sequence[int]) -> AScanHeader:
        """Decode ``ASCAN_HEADER_COUNT`` registers read from ``ASCAN_COUNTER``."""
        if len(registers) != ASCAN_HEADER_COUNT:
            raise ValueError(f"need {ASCAN_HEADER_COUNT} registers, got {len(registers)}")
        r = list(registers)
        return cls(
            counter=decode_uint32(r[0], r[1]),
            length=r[2],
            sample_rate_hz=decode_float32(r[4], r[5]),
            start_ns=decode_uint32(r[6], r[7]),
        )


# ---------------------------------------------------------------------------------------------
# Value encodings
# ---------------------------------------------------------------------------------------------
def _check_register(value: int) -> int:
    if not 0 <= value <= 0xFFFF:
        raise ValueError(f"register value {value!r} is not a uint16")
    return value


def encode_uint32(value: int) -> tuple[int, int]:
    """Split an unsigned 32-bit integer into two registers, :data:`WORD_ORDER` first."""
    if not 0 <= int(value) <= 0xFFFF_FFFF:
        raise ValueError(f"{value!r} does not fit in a uint32")
    hi, lo = divmod(int(value), 0x1_0000)
    return (hi, lo) if WORD_ORDER == "big" else (lo, hi)


def decode_uint32(first: int, second: int) -> int:
    """Join two registers (in address order) into an unsigned 32-bit integer."""
    hi, lo = (first, second) if WORD_ORDER == "big" else (second, first)
    return (_check_register(hi) << 16) | _check_register(lo)


def encode_float32(value: float) -> tuple[int, int]:
    """Encode an IEEE 754 float32 into two registers, :data:`WORD_ORDER` first.

    Values are rounded to the nearest float32; finite values beyond the float32 range raise
    ``OverflowError``; NaN and ±inf are kept.
    """
    raw = struct.unpack(">I", struct.pack(">f", float(value)))[0]
    return encode_uint32(raw)


def decode_float32(first: int, second: int) -> float:
    """Decode two registers (in address order) holding an IEEE 754 float32."""
    raw = decode_uint32(first, second)
    return struct.unpack(">f", struct.pack(">I", raw))[0]


def encode_samples(samples: np.ndarray) -> list[int]:
    """Encode normalised samples (1.0 = full screen) as int16 registers, saturating at ±1.0.

    Saturation here is the receiver's ADC clipping a too-strong signal, not input validation.
    """
    counts = np.rint(np.clip(np.asarray(samples, float), -1.0, 1.0) * ASCAN_FULL_SCALE)
    return (counts.astype(np.int16).view(np.uint16)).astype(int).tolist()


def decode_samples(registers: Sequence[int]) -> np.ndarray:
    """Decode int16 registers into normalised samples (float64, 1.0 = full screen)."""
    raw = np.asarray(registers, dtype=np.uint16).view(np.int16)
    return raw.astype(float) / ASCAN_FULL_SCALE
