"""The pulser-receiver's Modbus registers: the typed register map that client and server
share.

The map itself is data, a TOML file: ``drivers/pulser/maps/ucal_pulser.toml`` is the map ucal
defines (``docs/protocols/pulser_modbus.md`` documents it) and the default; another device
needs another file, not code. ``drivers.pulser.map_file`` reads and validates a file into a
:class:`RegisterMap` of :class:`Register`; ``drivers.pulser.modbus`` (client) and
``drivers.pulser.simulator`` (server) both encode and decode through it, so they cannot
disagree. Addresses are the *protocol* addresses that travel in the PDU (0-based).

The value encodings and the Modbus codes are in ``drivers.pulser.modbus_words``; what each
register name means to ucal in ``drivers.pulser.quantities``; this module holds one register
(:class:`Register`) and the map (:class:`RegisterMap`), and re-exports the names of both.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any

import numpy as np

from drivers.pulser.base import PulserSettings
from drivers.pulser.modbus_words import (
    ASCAN_FULL_SCALE,
    DATASTORE_OFFSET,
    MAX_READ_REGISTERS,
    MAX_WRITE_REGISTERS,
    TABLE_SIZE,
    TYPE_RANGE,
    TYPE_WORDS,
    WORD_ORDER,
    ExceptionCode,
    FunctionCode,
    check_register,
    decode_float32,
    decode_samples,
    decode_string,
    decode_uint32,
    encode_float32,
    encode_samples,
    encode_string,
    encode_uint32,
    exception_name,
)
from drivers.pulser.quantities import (
    ASCAN_HEADER,
    ASCAN_MAX_SAMPLES,
    COMMANDS,
    DEFAULT_THRESHOLD,
    DEVICE_INFO,
    FRONT_END,
    MEASUREMENT,
    MEASUREMENT_COUNT,
    QUANTITIES,
    SETTINGS,
    STATUS_BITS,
    UNITS,
    Quantity,
    Status,
)

__all__ = [
    "ASCAN_FULL_SCALE",
    "ASCAN_HEADER",
    "ASCAN_MAX_SAMPLES",
    "COMMANDS",
    "DATASTORE_OFFSET",
    "DEFAULT_THRESHOLD",
    "DEVICE_INFO",
    "FRONT_END",
    "MAX_READ_REGISTERS",
    "MAX_WRITE_REGISTERS",
    "MEASUREMENT",
    "MEASUREMENT_COUNT",
    "QUANTITIES",
    "SETTINGS",
    "STATUS_BITS",
    "TABLE_SIZE",
    "TYPE_RANGE",
    "TYPE_WORDS",
    "UNITS",
    "WORD_ORDER",
    "AScanHeader",
    "DeviceInfo",
    "ExceptionCode",
    "FunctionCode",
    "Measurement",
    "Quantity",
    "Register",
    "RegisterMap",
    "Status",
    "check_gate",
    "decode_float32",
    "decode_samples",
    "decode_string",
    "decode_uint32",
    "encode_float32",
    "encode_samples",
    "encode_string",
    "encode_uint32",
    "exception_name",
]


# ---------------------------------------------------------------------------------------------
# One register
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Register:
    """One register (or run of registers) of a map: where it is, its type and scaling, what may
    be written to it.

    ``counts_per_unit`` is raw counts per *ucal* unit (0.1 dB → 10 counts per dB; a gate in
    ns → 1000 counts per µs); ``minimum``/``maximum`` and ``values`` are in ucal units too.
    User values are validated against them and rounded to the register resolution
    ``1 / counts_per_unit``; out-of-range values raise, they are never clipped.
    """

    name: str  #: the key in the map file, one of :data:`QUANTITIES`
    table: str  #: "holding" (FC 3, 6, 16) or "input" (FC 4)
    address: int
    type: str  #: uint16, int16, uint32, int32, float32 or string
    words: int = 1  #: registers it occupies
    word_order: str = WORD_ORDER
    counts_per_unit: float = 1.0
    unit: str = ""  #: the unit the map file states it in (documentation)
    access: str = "read"  #: "read", "write" or "read-write"
    minimum: float | None = None
    maximum: float | None = None
    values: tuple[float, ...] | None = None  #: the only values the device takes
    names: Mapping[str, int] = field(default_factory=dict)  #: command values, status bits
    min_version: int | None = None  #: present from this map version on
    full_scale: int = 0  #: A-scan samples: counts of full screen height

    @property
    def quantity(self) -> Quantity:
        return QUANTITIES[self.name]

    @property
    def ucal_name(self) -> str:
        """ucal's name of the value (``gain_db``), as messages use it."""
        return self.quantity.ucal_name

    @property
    def units(self) -> str:
        """ucal's unit of the value (``dB``)."""
        return self.quantity.unit

    @property
    def readable(self) -> bool:
        return "read" in self.access

    @property
    def writable(self) -> bool:
        return "write" in self.access

    @property
    def integer(self) -> bool:
        """Whether the value itself must be a whole number (a count or a code)."""
        return self.quantity.dimension in ("count", "code")

    @cached_property
    def end(self) -> int:
        """The address after its last register."""
        return self.address + self.words

    def where(self) -> str:
        """``"holding 0x0002-0x0003"``: its table and addresses, for messages."""
        last = f"-0x{self.end - 1:04X}" if self.words > 1 else ""
        return f"{self.table} 0x{self.address:04X}{last}"

    @cached_property
    def _allowed_raw(self) -> frozenset[int | float] | None:
        if self.values is None:
            return None
        return frozenset(self._scaled(v) for v in self.values)

    def _scaled(self, value: float) -> int | float:
        raw = float(value) * self.counts_per_unit
        return raw if self.type == "float32" else round(raw)

    def to_raw(self, value: float) -> int | float:
        """Validate a user value (ucal unit) and return its raw register value.

        Raises ``ValueError`` naming the value when it is not a finite number, not an integer
        where one is required, outside ``[minimum, maximum]``, not one of ``values``, or too
        large for the register's type.
        """
        if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
            # ValueError like every other invalid setting: callers catch one type
            raise ValueError(f"{self.ucal_name} must be a number, got {value!r}")
        v = float(value)
        if not math.isfinite(v):
            raise ValueError(f"{self.ucal_name} must be finite, got {value!r}")
        if self.integer and v != round(v):
            raise ValueError(f"{self.ucal_name} must be an integer, got {value!r}")
        lo = -math.inf if self.minimum is None else self.minimum
        hi = math.inf if self.maximum is None else self.maximum
        if not lo <= v <= hi:
            unit = f" {self.units}" if self.units else ""
            raise ValueError(
                f"{self.ucal_name} = {value!r}{unit} is out of range [{lo:g}, {hi:g}]{unit}"
            )
        raw = self._scaled(v)
        allowed = self._allowed_raw
        if allowed is not None and raw not in allowed:
            assert self.values is not None
            shown = ", ".join(f"{x:g}" for x in self.values)
            unit = f" {self.units}" if self.units else ""
            raise ValueError(
                f"{self.ucal_name} = {value!r}{unit} is not one the device takes ({shown}{unit})"
            )
        if not self._fits(raw):
            raise ValueError(
                f"{self.ucal_name} = {value!r} {self.units} does not fit the {self.type} "
                f"register at {self.where()}"
            )
        return raw

    def from_raw(self, raw: float) -> float:
        """Convert a raw register value to ucal's unit."""
        return raw / self.counts_per_unit

    def raw_ok(self, raw: float) -> bool:
        """Tell whether a raw register value is allowed (server side: range and values)."""
        if not (isinstance(raw, int) or math.isfinite(raw)):
            return False
        if self.minimum is not None and raw < self._scaled(self.minimum):
            return False
        if self.maximum is not None and raw > self._scaled(self.maximum):
            return False
        allowed = self._allowed_raw
        return allowed is None or raw in allowed

    def device_raw(self, value: float, wrap: bool = False) -> int | float:
        """The raw value a device stores for a value it produced (ucal unit), unvalidated:
        integer types round, then wrap (``wrap``: counters, clocks) or saturate at the type's
        range; a NaN stores 0. A float32 keeps NaN."""
        raw = float(value) * self.counts_per_unit
        if self.type == "float32":
            return raw
        if not math.isfinite(raw):
            return 0
        lo, hi = TYPE_RANGE[self.type]
        n = round(raw)
        if wrap:
            return (n - lo) % (hi - lo + 1) + lo
        return min(max(n, lo), hi)

    def _fits(self, raw: float) -> bool:
        if self.type == "float32":
            return abs(raw) <= float(np.finfo(np.float32).max)
        lo, hi = TYPE_RANGE[self.type]
        return lo <= raw <= hi

    # -- words ---------------------------------------------------------------------------------
    def encode(self, raw: Any) -> list[int]:
        """The register words of a raw value (a str for ``string``), in address order."""
        if self.type == "string":
            return encode_string(raw, self.words)
        if self.type == "float32":
            return list(encode_float32(raw, self.word_order))
        if not self._fits(raw):
            raise ValueError(f"{self.name}: {raw!r} does not fit a {self.type}")
        n = int(raw)
        if self.words == 1:
            return [n & 0xFFFF]
        return list(encode_uint32(n & 0xFFFF_FFFF, self.word_order))

    def decode(self, words: Sequence[int]) -> Any:
        """The raw value of the register words read (address order); a str for ``string``."""
        if len(words) != self.words:
            raise ValueError(f"{self.name}: need {self.words} registers, got {len(words)}")
        if self.type == "string":
            return decode_string(words)
        if self.type == "float32":
            return decode_float32(words[0], words[1], self.word_order)
        if self.words == 1:
            raw = check_register(words[0])
        else:
            raw = decode_uint32(words[0], words[1], self.word_order)
        signed = self.type.startswith("int")
        bits = 16 * self.words
        return raw - (1 << bits) if signed and raw >= 1 << (bits - 1) else raw

    def encode_value(self, value: float) -> list[int]:
        """Validate a user value (ucal unit) and return its words (:meth:`to_raw`)."""
        return self.encode(self.to_raw(value))

    def decode_value(self, words: Sequence[int]) -> float:
        """The value (ucal unit) of the words read."""
        return self.from_raw(self.decode(words))

    # -- codes ---------------------------------------------------------------------------------
    def encode_status(self, status: Status) -> int:
        """The raw status register of ``status`` (each flag on the map's bit)."""
        return sum(
            1 << self.names[n]
            for n, flag in STATUS_BITS.items()
            if n in self.names and flag in status
        )

    def decode_status(self, raw: int) -> Status:
        """The flags a raw status register holds."""
        out = Status(0)
        for n, flag in STATUS_BITS.items():
            if n in self.names and (int(raw) >> self.names[n]) & 1:
                out |= flag
        return out


# ---------------------------------------------------------------------------------------------
# Values of blocks that travel together
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Measurement:
    """One reading as the device reports it (``MEASUREMENT`` registers).

    ``counter`` and ``device_time_ms`` are None when the map has no such register.
    """

    counter: int | None  #: reading counter, +1 per acquisition, wraps with its type
    device_time_ms: float | None  #: device clock at acquisition, ms
    status: Status  #: status bits
    amplitude: float  #: gated peak, fraction of full screen height
    tof_ns: float  #: round-trip time of flight, ns; NaN without echo


@dataclass(frozen=True)
class DeviceInfo:
    """What the device tells about itself (``DEVICE_INFO`` registers); None where the map has
    no register for it."""

    model: str | None  #: ASCII
    firmware: tuple[int, int] | None  #: (major, minor)
    serial: int | None

    @property
    def firmware_version(self) -> str:
        """The firmware version as ``"major.minor"``."""
        return "" if self.firmware is None else f"{self.firmware[0]}.{self.firmware[1]}"


@dataclass(frozen=True)
class AScanHeader:
    """The A-scan header (``ASCAN_HEADER`` registers)."""

    counter: int | None  #: counter of the acquisition the samples belong to
    length: int  #: number of samples
    sample_rate_hz: float  #: sample rate, Hz
    start_ns: float  #: time of sample 0, ns of round-trip time


# ---------------------------------------------------------------------------------------------
# The map
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class RegisterMap:
    """A device's register map: its registers by name, and how requests group them.

    Build it with ``drivers.pulser.map_file.load_register_map`` (or ``shipped_map``). A
    request may span every address the map declares — its registers' and the ``reserved``
    ones ``(table, address, count)`` — so the client reads a block in one request where the
    device has one, and never touches an address the map does not declare.
    """

    name: str
    registers: Mapping[str, Register]
    reserved: tuple[tuple[str, int, int], ...] = ()
    source: str = ""  #: the file it was read from

    def __getitem__(self, name: str) -> Register:
        return self.registers[name]

    def __contains__(self, name: object) -> bool:
        return name in self.registers

    def get(self, name: str) -> Register | None:
        return self.registers.get(name)

    def __str__(self) -> str:
        return f"{self.name} ({self.source})" if self.source else self.name

    # -- addresses -----------------------------------------------------------------------------
    @cached_property
    def _declared(self) -> dict[str, frozenset[int]]:
        out: dict[str, set[int]] = {"holding": set(), "input": set()}
        for r in self.registers.values():
            out[r.table].update(range(r.address, r.end))
        for table, address, count in self.reserved:
            out[table].update(range(address, address + count))
        return {t: frozenset(a) for t, a in out.items()}

    def declared(self, table: str, address: int, count: int = 1) -> bool:
        """Whether every address of ``[address, address + count)`` of ``table`` is declared."""
        return count > 0 and self._declared[table].issuperset(range(address, address + count))

    def span(self, table: str) -> int:
        """The address after the last declared one of ``table`` (0 if none)."""
        addresses = self._declared[table]
        return max(addresses) + 1 if addresses else 0

    @cached_property
    def _present(self) -> dict[tuple[tuple[str, ...], int | None], tuple[Register, ...]]:
        return {}  # present()'s answers: the map does not change, and every reading asks

    def present(self, names: Iterable[str], version: int | None = None) -> list[Register]:
        """The registers of ``names`` the map has, on a device reporting ``version`` (None: the
        device's version is not known; every register counts)."""
        key = (tuple(names), version)
        found = self._present.get(key)
        if found is None:
            found = self._present[key] = tuple(
                r
                for r in map(self.registers.get, key[0])
                if r is not None and (version is None or (r.min_version or 0) <= version)
            )
        return list(found)

    def read_requests(self, registers: Iterable[Register]) -> list[tuple[str, int, int]]:
        """The reads ``(table, address, count)`` that fetch ``registers``: neighbours share a
        request when every address between them is declared and it stays within
        :data:`MAX_READ_REGISTERS`. Ordered by table ("holding" first) and address."""
        requests: list[tuple[str, int, int]] = []
        for r in sorted(registers, key=lambda r: (r.table, r.address)):
            if requests:
                table, start, count = requests[-1]
                end = start + count
                if (
                    r.table == table
                    and r.end - start <= MAX_READ_REGISTERS
                    and (r.address <= end or self.declared(table, end, r.address - end))
                ):
                    requests[-1] = (table, start, max(end, r.end) - start)
                    continue
            requests.append((r.table, r.address, r.words))
        return requests

    @staticmethod
    def write_requests(
        entries: Iterable[tuple[Register, list[int]]],
    ) -> list[tuple[int, list[int]]]:
        """The writes ``(address, words)`` (FC 16) of holding registers and their words:
        registers that follow each other without a gap share a request of at most
        :data:`MAX_WRITE_REGISTERS`."""
        requests: list[tuple[int, list[int]]] = []
        for r, words in sorted(entries, key=lambda e: e[0].address):
            if requests:
                start, prev = requests[-1]
                if start + len(prev) == r.address and len(prev) + len(words) <= MAX_WRITE_REGISTERS:
                    prev.extend(words)
                    continue
            requests.append((r.address, list(words)))
        return requests

    @staticmethod
    def pick(
        registers: Iterable[Register],
        requests: Iterable[tuple[str, int, int]],
        words: Sequence[Sequence[int]],
    ) -> dict[str, list[int]]:
        """Each register's words out of the answers ``words`` to ``requests``."""
        out: dict[str, list[int]] = {}
        for r in registers:
            for (table, start, count), got in zip(requests, words, strict=True):
                if r.table == table and start <= r.address and r.end <= start + count:
                    out[r.name] = list(got[r.address - start : r.end - start])
                    break
        return out

    # -- groups --------------------------------------------------------------------------------
    @property
    def versions(self) -> tuple[int, ...]:
        """The map versions a device may report (``map_version``'s values); () if it has none."""
        r = self.registers.get("map_version")
        return () if r is None or r.values is None else tuple(int(v) for v in r.values)

    @cached_property
    def measurement_trigger(self) -> Register:
        """The reading's register the client reads first: a read of it is an acquisition."""
        return self._first(MEASUREMENT)

    @cached_property
    def ascan_trigger(self) -> Register | None:
        """The A-scan header's register the client reads first (it freezes the A-scan)."""
        return self._first(ASCAN_HEADER) if "ascan_samples" in self.registers else None

    def _first(self, names: Sequence[str]) -> Register:
        return min(self.present(names), key=lambda r: (r.table, r.address))

    # -- settings ------------------------------------------------------------------------------
    def encode_settings(
        self, settings: PulserSettings, names: Sequence[str]
    ) -> list[tuple[Register, list[int]]]:
        """Validate the ``names`` settings of ``settings``; return each register and its words.

        A setting the map has no register for may only keep its default. Raises ``ValueError``
        naming the first invalid setting; nothing is clipped.
        """
        default = PulserSettings()
        out: list[tuple[Register, list[int]]] = []
        for n in names:
            name = QUANTITIES[n].ucal_name
            value = getattr(settings, name)
            r = self.registers.get(n)
            if r is None:
                if value != getattr(default, name):
                    raise ValueError(
                        f"{name} = {value!r} cannot be set: the register map {self} has no "
                        f"{n} register (only the default, {getattr(default, name)!r})"
                    )
                continue
            out.append((r, r.encode_value(value)))
        if "gate_width" in names:
            check_gate(settings)
        by_name = {r.name: r.decode_value(w) for r, w in out}
        band = ("high_pass", "low_pass")
        if all(n in by_name for n in band) and by_name["low_pass"] <= by_name["high_pass"]:
            raise ValueError(
                f"low_pass_mhz = {settings.low_pass_mhz:g} MHz must be above "
                f"high_pass_mhz = {settings.high_pass_mhz:g} MHz"
            )
        return out

    def decode_settings(self, words: Mapping[str, Sequence[int]]) -> PulserSettings:
        """``PulserSettings`` from the words of the setting registers read (by register name);
        a setting not read keeps its default."""
        values: dict[str, Any] = {}
        for n in SETTINGS + FRONT_END:
            if n in words:
                values[QUANTITIES[n].ucal_name] = self.registers[n].decode_value(words[n])
        if "averages" in values:
            values["averages"] = int(values["averages"])
        return PulserSettings(**values)

    def power_on(self) -> list[tuple[Register, list[int]]]:
        """The holding registers of a freshly powered device: the ``PulserSettings`` defaults,
        :data:`DEFAULT_THRESHOLD` and no command."""
        default = PulserSettings()
        out = [
            (r, r.encode(_nearest_raw(r, getattr(default, r.ucal_name))))
            for r in self.present(SETTINGS + FRONT_END)
        ]
        threshold = self.registers.get("threshold")
        if threshold is not None:
            out.append((threshold, threshold.encode(_nearest_raw(threshold, DEFAULT_THRESHOLD))))
        command = self.registers.get("command")
        if command is not None:
            out.append((command, command.encode(command.names["none"])))
        return out

    # -- readings ------------------------------------------------------------------------------
    def encode_measurement(self, m: Measurement) -> list[tuple[Register, list[int]]]:
        """The words of a reading in the registers the map has (server side)."""
        values = {
            "counter": m.counter,
            "device_time": m.device_time_ms,
            "amplitude": m.amplitude,
            "tof": m.tof_ns,
        }
        out = []
        for r in self.present(MEASUREMENT):
            if r.name == "status":
                raw: int | float = r.encode_status(m.status)
            else:
                value = values[r.name]
                raw = r.device_raw(
                    0.0 if value is None else value, wrap=r.name in ("counter", "device_time")
                )
            out.append((r, r.encode(raw)))
        return out

    def decode_measurement(self, words: Mapping[str, Sequence[int]]) -> Measurement:
        """A reading from the words of its registers. Without a ``status`` register a finite
        TOF is an echo and a full-screen amplitude is saturated."""
        amplitude = self["amplitude"].decode_value(words["amplitude"])
        tof_ns = self["tof"].decode_value(words["tof"])
        if "status" in words:
            status = self["status"].decode_status(self["status"].decode(words["status"]))
        else:
            status = Status(0)
            if math.isfinite(tof_ns):
                status |= Status.ECHO
            if amplitude >= 1.0:
                status |= Status.SATURATED
        counter = self["counter"].decode(words["counter"]) if "counter" in words else None
        device_time = (
            self["device_time"].decode_value(words["device_time"])
            if "device_time" in words
            else None
        )
        return Measurement(counter, device_time, status, amplitude, tof_ns)

    def encode_device_info(self, info: DeviceInfo) -> list[tuple[Register, list[int]]]:
        """The words of the device information in the registers the map has (server side)."""
        values: dict[str, Any] = {
            "model": info.model or "",
            "firmware_major": info.firmware[0] if info.firmware else 0,
            "firmware_minor": info.firmware[1] if info.firmware else 0,
            "serial": info.serial or 0,
        }
        return [(r, r.encode(values[r.name])) for r in self.present(DEVICE_INFO)]

    def decode_device_info(self, words: Mapping[str, Sequence[int]]) -> DeviceInfo:
        """The device information from the words of its registers (None where not read)."""

        def get(n: str) -> Any:
            return self[n].decode(words[n]) if n in words else None

        major, minor = get("firmware_major"), get("firmware_minor")
        firmware = None if major is None and minor is None else (major or 0, minor or 0)
        return DeviceInfo(model=get("model"), firmware=firmware, serial=get("serial"))

    def encode_ascan_header(self, h: AScanHeader) -> list[tuple[Register, list[int]]]:
        """The words of an A-scan header in the registers the map has (server side)."""
        values = {
            "ascan_counter": h.counter or 0,
            "ascan_length": h.length,
            "ascan_rate": h.sample_rate_hz,
            "ascan_start": h.start_ns,
        }
        return [
            (r, r.encode(r.device_raw(values[r.name], wrap=r.name == "ascan_counter")))
            for r in self.present(ASCAN_HEADER)
        ]

    def decode_ascan_header(self, words: Mapping[str, Sequence[int]]) -> AScanHeader:
        """An A-scan header from the words of its registers."""
        counter = (
            self["ascan_counter"].decode(words["ascan_counter"])
            if "ascan_counter" in words
            else None
        )
        return AScanHeader(
            counter=counter,
            length=int(self["ascan_length"].decode_value(words["ascan_length"])),
            sample_rate_hz=self["ascan_rate"].decode_value(words["ascan_rate"]),
            start_ns=self["ascan_start"].decode_value(words["ascan_start"]),
        )


def _nearest_raw(r: Register, value: float) -> int | float:
    """The raw value of ``value``, or of the allowed value nearest to it when the device's range
    leaves it out (a power-on state must exist whatever ucal's defaults are)."""
    try:
        return r.to_raw(value)
    except ValueError:
        allowed = r.values or [x for x in (r.minimum, r.maximum) if x is not None] or [0.0]
        return r.device_raw(min(allowed, key=lambda x: abs(x - value)))


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
