"""Register map files: read the TOML map of a Modbus pulser-receiver, validate it, and build the
typed :class:`~drivers.pulser.registers.RegisterMap` client and simulator share.

A map file (``maps/ucal_pulser.toml`` is ucal's own, the default)::

    [map]
    name = "ucal pulser-receiver"       # required
    word_order = "big"                  # 32-bit values: "big" = most significant register
                                        # first (ABCD), "little" = least significant first (CDAB)
    reserved = [{ table = "input", address = 0x0015 }]   # answered, not interpreted

    [registers.gain]                    # a name ucal knows (registers.QUANTITIES)
    table = "holding"                   # "holding" (FC 3/6/16) or "input" (FC 4)
    address = 0x0000                    # protocol address, 0-based
    type = "uint16"                     # uint16, int16, uint32, int32, float32, string
    unit = "dB"                         # the unit `scale`, `range` and `values` are in
    scale = 0.1                         # one count is worth 0.1 dB (default 1)
    range = [0, 80]                     # optional: what the device accepts, in `unit`

Further keys where they apply: ``values`` (the only values the device takes, in ``unit``; for
``command`` a table ``{ none = 0, trigger = 1, clear_counter = 2 }``; required for ``magic`` and
``map_version``), ``bits`` (``status``: ``{ echo = 0, saturated = 1, gate_error = 2 }``),
``access`` (``"read"``, ``"write"``, ``"read-write"``; each name has its default),
``word_order`` (one 32-bit register), ``min_version`` (present on devices whose ``map_version``
is at least this), ``length`` (``string``: characters), ``count`` and ``full_scale``
(``ascan_samples``: samples, and the count of full screen height), ``description``.

Every error is a :class:`RegisterMapError` naming the file and the dotted key
(``registers.tof.scale``); unknown keys are errors, because a misspelt scale is a wrong
calibration, not a warning.
"""

from __future__ import annotations

import functools
import itertools
import math
import tomllib
from collections.abc import Mapping
from fractions import Fraction
from pathlib import Path
from typing import Any

from drivers.pulser.registers import (
    ASCAN_FULL_SCALE,
    ASCAN_HEADER,
    ASCAN_MAX_SAMPLES,
    COMMANDS,
    QUANTITIES,
    STATUS_BITS,
    TABLE_SIZE,
    TYPE_RANGE,
    TYPE_WORDS,
    UNITS,
    WORD_ORDER,
    Register,
    RegisterMap,
)

#: ucal's own register map, shipped with the package: the default.
SHIPPED_MAP_PATH = Path(__file__).resolve().parent / "maps" / "ucal_pulser.toml"

TABLES = ("holding", "input")
ACCESS = ("read", "write", "read-write")
WORD_ORDERS = ("big", "little")
MAP_KEYS = frozenset({"name", "word_order", "reserved", "description"})
REGISTER_KEYS = frozenset(
    {
        "table",
        "address",
        "type",
        "word_order",
        "unit",
        "scale",
        "range",
        "values",
        "bits",
        "access",
        "min_version",
        "length",
        "count",
        "full_scale",
        "description",
    }
)
#: Groups ucal writes (holding registers it reads back, but ``command``, which it only writes).
WRITTEN_GROUPS = ("settings", "front_end", "threshold", "command")


class RegisterMapError(ValueError):
    """A register map file that cannot be read or does not validate: names the file and key."""

    def __init__(self, path: str | Path, key: str | None, message: str):
        self.path = str(path)
        self.key = key
        self.detail = message
        where = f"{self.path}: {key}" if key else self.path
        super().__init__(f"{where}: {message}")


@functools.cache
def shipped_map() -> RegisterMap:
    """ucal's own register map (:data:`SHIPPED_MAP_PATH`), read once."""
    return load_register_map(SHIPPED_MAP_PATH)


def register_map_of(register_map: RegisterMap | str | Path | None) -> RegisterMap:
    """``register_map`` itself, the map in that file (:class:`RegisterMapError`, a
    ``ValueError``, when it is not a valid one), or for None ucal's own."""
    if register_map is None:
        return shipped_map()
    if isinstance(register_map, RegisterMap):
        return register_map
    return load_register_map(register_map)


def load_register_map(path: str | Path) -> RegisterMap:
    """Read and validate the map file at ``path``; raise :class:`RegisterMapError`."""
    p = Path(path)
    try:
        raw = p.read_bytes()
    except OSError as e:
        raise RegisterMapError(p, None, f"cannot read: {e.strerror or e}") from None
    try:
        data = tomllib.loads(raw.decode("utf-8"))
    except UnicodeDecodeError as e:
        raise RegisterMapError(p, None, f"not UTF-8 text (byte {e.start})") from None
    except tomllib.TOMLDecodeError as e:
        raise RegisterMapError(p, None, f"not valid TOML: {e}") from None
    return register_map_from_data(data, p)


def register_map_from_data(data: Mapping[str, Any], path: str | Path) -> RegisterMap:
    """Validate parsed map data (a dict as ``tomllib`` gives it); errors name ``path``."""
    return _Reader(path).read(data)


def _describe(value: Any) -> str:
    text = "a table" if isinstance(value, Mapping) else repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


class _Reader:
    def __init__(self, path: str | Path):
        self.path = Path(path)

    def error(self, key: str | None, message: str) -> RegisterMapError:
        return RegisterMapError(self.path, key, message)

    # -- scalars -------------------------------------------------------------------------------
    def table(self, key: str, value: Any) -> Mapping[str, Any]:
        if not isinstance(value, Mapping):
            raise self.error(key, f"must be a table, got {_describe(value)}")
        return value

    def known(self, key: str, table: Mapping[str, Any], keys: frozenset[str]) -> None:
        for k in table:
            if k not in keys:
                raise self.error(f"{key}.{k}", f"unknown key (known: {', '.join(sorted(keys))})")

    def string(self, key: str, value: Any, choices: tuple[str, ...] | None = None) -> str:
        if not isinstance(value, str) or not value.strip():
            raise self.error(key, f"must be a non-empty string, got {_describe(value)}")
        if choices is not None and value not in choices:
            raise self.error(key, f"must be one of {', '.join(choices)}; got {value!r}")
        return value

    def integer(self, key: str, value: Any, lo: int, hi: int) -> int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise self.error(key, f"must be an integer, got {_describe(value)}")
        if not lo <= value <= hi:
            raise self.error(key, f"must be {lo} … {hi}, got {value}")
        return value

    def number(self, key: str, value: Any) -> Fraction:
        """A finite number, exactly as written (0.1 is one tenth, not the nearest double)."""
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise self.error(key, f"must be a number, got {_describe(value)}")
        if not math.isfinite(value):
            raise self.error(key, f"must be finite, got {value!r}")
        return Fraction(value) if isinstance(value, int) else Fraction(repr(value))

    # -- the file ------------------------------------------------------------------------------
    def read(self, data: Mapping[str, Any]) -> RegisterMap:
        for k in data:
            if k not in ("map", "registers"):
                raise self.error(k, "unknown table (known: map, registers)")
        if "map" not in data:
            raise self.error("map", "missing table")
        head = self.table("map", data["map"])
        self.known("map", head, MAP_KEYS)
        if "name" not in head:
            raise self.error("map.name", "missing key")
        name = self.string("map.name", head["name"])
        word_order = self.string("map.word_order", head.get("word_order", WORD_ORDER), WORD_ORDERS)
        if "description" in head:
            self.string("map.description", head["description"])
        reserved = self.reserved(head.get("reserved", []))

        if "registers" not in data:
            raise self.error("registers", "missing table")
        table = self.table("registers", data["registers"])
        registers: dict[str, Register] = {}
        for n, raw in table.items():
            if n not in QUANTITIES:
                raise self.error(
                    f"registers.{n}", f"unknown register (known: {', '.join(QUANTITIES)})"
                )
            registers[n] = self.register(n, self.table(f"registers.{n}", raw), word_order)
        self.check_map(registers, reserved)
        return RegisterMap(name, registers, reserved, str(self.path))

    def reserved(self, value: Any) -> tuple[tuple[str, int, int], ...]:
        if not isinstance(value, list):
            raise self.error("map.reserved", f"must be an array of tables, got {_describe(value)}")
        out = []
        for i, item in enumerate(value):
            key = f"map.reserved[{i}]"
            entry = self.table(key, item)
            self.known(key, entry, frozenset({"table", "address", "count"}))
            for k in ("table", "address"):
                if k not in entry:
                    raise self.error(f"{key}.{k}", "missing key")
            t = self.string(f"{key}.table", entry["table"], TABLES)
            address = self.integer(f"{key}.address", entry["address"], 0, TABLE_SIZE - 1)
            count = self.integer(f"{key}.count", entry.get("count", 1), 1, TABLE_SIZE - address)
            out.append((t, address, count))
        return tuple(out)

    # -- one register --------------------------------------------------------------------------
    def register(self, n: str, t: Mapping[str, Any], map_word_order: str) -> Register:
        key = f"registers.{n}"
        q = QUANTITIES[n]
        self.known(key, t, REGISTER_KEYS)
        for k in ("table", "address", "type"):
            if k not in t:
                raise self.error(f"{key}.{k}", "missing key")
        table = self.string(f"{key}.table", t["table"], TABLES)
        address = self.integer(f"{key}.address", t["address"], 0, TABLE_SIZE - 1)
        kind = self.string(f"{key}.type", t["type"], (*TYPE_WORDS, "string"))
        if "description" in t:
            self.string(f"{key}.description", t["description"])

        # the type and the size
        if q.dimension == "text":
            if kind != "string":
                raise self.error(f"{key}.type", f"must be string for {n}, got {kind!r}")
        elif kind == "string":
            raise self.error(f"{key}.type", f"{n} is a number: string is for the model name")
        if q.dimension == "samples" and kind != "int16":
            raise self.error(f"{key}.type", f"must be int16 for A-scan samples, got {kind!r}")
        if q.dimension in ("count", "code") and kind == "float32":
            raise self.error(f"{key}.type", f"{n} is a whole number: an integer type, not float32")
        self.only(key, t, "length", q.dimension == "text", "string registers")
        self.only(key, t, "count", q.dimension == "samples", "ascan_samples")
        self.only(key, t, "full_scale", q.dimension == "samples", "ascan_samples")
        self.only(key, t, "bits", n == "status", "status")
        full_scale = 0
        if q.dimension == "text":
            if "length" not in t:
                raise self.error(f"{key}.length", "missing key (characters)")
            words = (self.integer(f"{key}.length", t["length"], 1, 2 * 123) + 1) // 2
        elif q.dimension == "samples":
            if "count" not in t:
                raise self.error(f"{key}.count", "missing key (the most samples an A-scan has)")
            words = self.integer(f"{key}.count", t["count"], 1, ASCAN_MAX_SAMPLES)
            full_scale = self.integer(
                f"{key}.full_scale", t.get("full_scale", ASCAN_FULL_SCALE), 1, 0x7FFF
            )
        else:
            words = TYPE_WORDS[kind]
        if address + words > TABLE_SIZE:
            raise self.error(
                f"{key}.address", f"{words} registers from 0x{address:04X} pass 0xFFFF"
            )
        word_order = map_word_order
        if "word_order" in t:
            if words != 2 or kind == "string":
                raise self.error(f"{key}.word_order", "only 32-bit types have a word order")
            word_order = self.string(f"{key}.word_order", t["word_order"], WORD_ORDERS)

        # access
        written = q.group in WRITTEN_GROUPS
        default_access = "write" if n == "command" else "read-write" if written else "read"
        access = self.string(f"{key}.access", t.get("access", default_access), ACCESS)
        if written and table != "holding":
            raise self.error(f"{key}.table", f"must be holding: ucal writes {n}")
        if table == "input" and access != "read":
            raise self.error(f"{key}.access", "input registers are read-only")
        if written and "write" not in access:
            raise self.error(f"{key}.access", f"ucal writes {n}: it must be writable")
        if n != "command" and "read" not in access:
            raise self.error(f"{key}.access", f"ucal reads {n}: it must be readable")

        # units and scale: counts per ucal unit, exactly
        if q.dimension in UNITS:
            units = UNITS[q.dimension]
            if "unit" not in t:
                raise self.error(f"{key}.unit", f"missing key (one of {', '.join(units)})")
            unit = self.string(f"{key}.unit", t["unit"], tuple(units))
            scale = self.number(f"{key}.scale", t.get("scale", 1))
            if scale <= 0:
                raise self.error(f"{key}.scale", f"must be > 0, got {t['scale']!r}")
            to_ucal = _exact(units[unit]) / _exact(units[q.unit])  # one `unit` in ucal's
        else:
            for k in ("unit", "scale"):
                if k in t and t[k] not in ("", 1):
                    raise self.error(f"{key}.{k}", f"{n} has no unit: leave {k} out")
            unit, scale, to_ucal = "", Fraction(1), Fraction(1)
        counts_per_unit = 1 / (scale * to_ucal)

        in_unit = f" {unit}" if unit else ""

        def raw_of(k: str, v: Any) -> tuple[float, int | float]:
            """A value in `unit` → ucal unit, raw; it must fit the type."""
            x = self.number(k, v) * to_ucal
            raw: int | float = float(x * counts_per_unit)
            if kind in TYPE_RANGE:
                raw = round(x * counts_per_unit)
                lo, hi = TYPE_RANGE[kind]
                if not lo <= raw <= hi:
                    raise self.error(k, f"{v!r}{in_unit} is {raw} counts: beyond a {kind}")
            return float(x), raw

        minimum = maximum = None
        if "range" in t:
            k = f"{key}.range"
            if n in ("status", "command", "magic", "map_version") or q.dimension in (
                "text",
                "samples",
            ):
                raise self.error(k, f"{n} has no range")
            r = t["range"]
            if not isinstance(r, list) or len(r) != 2:
                raise self.error(k, f"must be [minimum, maximum], got {_describe(r)}")
            minimum, _ = raw_of(f"{k}[0]", r[0])
            maximum, _ = raw_of(f"{k}[1]", r[1])
            if minimum > maximum:
                raise self.error(k, f"minimum {r[0]!r} is above maximum {r[1]!r}")

        values: tuple[float, ...] | None = None
        names: dict[str, int] = {}
        if n == "command":
            v = t.get("values")
            if v is None:
                raise self.error(f"{key}.values", "missing key ({ none = 0, trigger = 1, ... })")
            table_v = self.table(f"{key}.values", v)
            self.known(f"{key}.values", table_v, frozenset(COMMANDS))
            if "none" not in table_v:
                raise self.error(f"{key}.values.none", "missing key (what it reads when idle)")
            for c, x in table_v.items():
                lo, hi = TYPE_RANGE[kind]
                names[c] = self.integer(f"{key}.values.{c}", x, lo, hi)
            if len(set(names.values())) != len(names):
                raise self.error(f"{key}.values", "two commands share a value")
            values = tuple(float(x) for x in names.values())
        elif "values" in t:
            k = f"{key}.values"
            if n == "status" or q.dimension in ("text", "samples"):
                raise self.error(k, f"{n} has no list of values")
            v = t["values"]
            if not isinstance(v, list) or not v:
                raise self.error(k, f"must be a non-empty array, got {_describe(v)}")
            values = tuple(raw_of(f"{k}[{i}]", x)[0] for i, x in enumerate(v))
            for i, x in enumerate(values):
                if (minimum is not None and x < minimum) or (maximum is not None and x > maximum):
                    raise self.error(f"{k}[{i}]", f"{v[i]!r}{in_unit} is outside range")
        elif n in ("magic", "map_version"):
            raise self.error(f"{key}.values", "missing key (what the device must answer)")
        if n == "status":
            if "bits" not in t:
                raise self.error(f"{key}.bits", "missing key ({ echo = 0, ... })")
            bits = self.table(f"{key}.bits", t["bits"])
            self.known(f"{key}.bits", bits, frozenset(STATUS_BITS))
            if "echo" not in bits:
                raise self.error(f"{key}.bits.echo", "missing key (the bit of a valid echo)")
            for b, x in bits.items():
                names[b] = self.integer(f"{key}.bits.{b}", x, 0, 16 * words - 1)
            if len(set(names.values())) != len(names):
                raise self.error(f"{key}.bits", "two flags share a bit")

        min_version = None
        if "min_version" in t:
            if n in ("magic", "map_version") or q.required:
                raise self.error(f"{key}.min_version", f"{n} is in every version of a map")
            min_version = self.integer(f"{key}.min_version", t["min_version"], 0, 0xFFFF)

        return Register(
            name=n,
            table=table,
            address=address,
            type=kind,
            words=words,
            word_order=word_order,
            counts_per_unit=float(counts_per_unit),
            unit=unit,
            access=access,
            minimum=minimum,
            maximum=maximum,
            values=values,
            names=names,
            min_version=min_version,
            full_scale=full_scale,
        )

    def only(self, key: str, t: Mapping[str, Any], k: str, allowed: bool, what: str) -> None:
        if k in t and not allowed:
            raise self.error(f"{key}.{k}", f"only {what} take {k}")

    # -- the whole map -------------------------------------------------------------------------
    def check_map(
        self, registers: Mapping[str, Register], reserved: tuple[tuple[str, int, int], ...]
    ) -> None:
        for n, q in QUANTITIES.items():
            if q.required and n not in registers:
                needed = ", ".join(k for k, v in QUANTITIES.items() if v.required)
                raise self.error(f"registers.{n}", f"missing (every map needs {needed})")
        if "status" not in registers and registers["tof"].type != "float32":
            raise self.error(
                "registers.status",
                "missing: an integer tof cannot say 'no echo' (NaN) without a status echo bit",
            )
        ascan = [n for n in (*ASCAN_HEADER, "ascan_samples") if n in registers]
        if ascan:
            for n in ("ascan_length", "ascan_rate", "ascan_start", "ascan_samples"):
                if n not in registers:
                    raise self.error(
                        f"registers.{n}",
                        f"missing: an A-scan needs ascan_length, ascan_rate, ascan_start and "
                        f"ascan_samples (the map has {ascan[0]})",
                    )
        versions = registers["map_version"].values if "map_version" in registers else None
        for n, r in registers.items():
            if r.min_version is None:
                continue
            if versions is None:
                raise self.error(
                    f"registers.{n}.min_version", "needs a map_version register to compare with"
                )
            if r.min_version > max(versions):
                raise self.error(
                    f"registers.{n}.min_version",
                    f"{r.min_version} is above every map_version value ({max(versions):g})",
                )
        # no address is two things
        spans = [(r.table, r.address, r.end, f"registers.{n}") for n, r in registers.items()]
        spans += [(t, a, a + c, f"map.reserved[{i}]") for i, (t, a, c) in enumerate(reserved)]
        spans.sort()
        for (t1, a1, e1, k1), (t2, a2, _, k2) in itertools.pairwise(spans):
            if t1 == t2 and a2 < e1:
                raise self.error(
                    k2 if k2.startswith("map") else f"{k2}.address",
                    f"{t2} 0x{a2:04X} overlaps {k1} ({t1} 0x{a1:04X}-0x{e1 - 1:04X})",
                )


def _exact(x: int | float) -> Fraction:
    return Fraction(x) if isinstance(x, int) else Fraction(repr(x))
