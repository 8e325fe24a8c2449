"""Key validators shared by the profile and world loaders.

Every validator takes the file it reads (for the message), the dotted key (``robot.dh[2].a_mm``)
and the raw value parsed from TOML, and either returns a clean Python/numpy value or raises
:class:`ucal.errors.ProfileError`, whose one-line message names the file and the key. Validators
raise, they never clip or repair. Array indices in keys are 0-based, as in the TOML array.
"""

from __future__ import annotations

import difflib
import math
import re
import tomllib
from collections.abc import Collection, Iterable, Mapping
from pathlib import Path
from typing import Any

import numpy as np
import tomlkit
from tomlkit.exceptions import ParseError, TOMLKitError

from drivers.pulser.map_file import RegisterMapError, load_register_map
from drivers.pulser.registers import RegisterMap
from ucal.errors import ProfileError

#: Column names of one DH row, in the order of ``RobotModel.dh``.
DH_KEYS = ("theta_offset_deg", "d_mm", "a_mm", "alpha_deg")

#: Two touched points closer than this (mm) are the same point.
DUPLICATE_POINT_MM = 0.01
#: Reflector points whose spread across their best-fit line is below this fraction of their
#: spread along it cannot define a plane.
COLLINEAR_RATIO = 1e-3
#: An unknown key at least this similar to a known one (difflib's ratio, 0..1) is taken for
#: its misspelling: ``frequncy_mhz`` for ``frequency_mhz`` (0.96), ``tof_n`` for ``tof_ns``.
TYPO_CUTOFF = 0.8


def describe(value: Any) -> str:
    """Short text of a bad value for an error message (strings quoted, long values cut)."""
    if isinstance(value, str):
        text = repr(value)
    elif isinstance(value, Mapping):
        text = "a table"
    else:
        text = repr(_plain(value))
    return text if len(text) <= 60 else text[:57] + "..."


def _plain(value: Any) -> Any:
    """tomlkit items → plain Python values (for messages)."""
    unwrap = getattr(value, "unwrap", None)
    return unwrap() if callable(unwrap) else value


class Reader:
    """Read and validate the keys of one parsed TOML file.

    ``path`` names the file in every error. Methods take the dotted key of the value and the
    raw value (``MISSING`` when the key is absent).
    """

    def __init__(self, path: str | Path, data: Mapping[str, Any]):
        self.path = Path(path)
        self.data = data

    # -- access ------------------------------------------------------------------------------

    def error(self, key: str | None, message: str) -> ProfileError:
        """A :class:`ProfileError` naming this file and ``key``."""
        return ProfileError(self.path, key, message)

    def table(self, name: str, required: bool = False) -> Mapping[str, Any] | None:
        """The top-level table ``name`` (``None`` if absent and not required)."""
        value = self.data.get(name)
        if value is None:
            if required:
                raise self.error(name, "missing table")
            return None
        if not isinstance(value, Mapping):
            raise self.error(name, f"must be a table, got {describe(value)}")
        return value

    def get(self, table: Mapping[str, Any] | None, dotted: str, required: bool = False) -> Any:
        """Raw value of ``dotted`` (``"tool.position_mm"``) inside ``table``; None if absent."""
        if table is None or dotted.rsplit(".", 1)[-1] not in table:
            if required:
                raise self.error(dotted, "missing key")
            return None
        return table[dotted.rsplit(".", 1)[-1]]

    def refuse_misspelt(
        self, where: str, table: Mapping[str, Any], known: Iterable[str], what: str = "key"
    ) -> None:
        """Refuse a key of ``table`` (dotted name ``where``; ``""`` = top level) that is not in
        ``known`` but close to a known key the table lacks: a misspelling, which would
        otherwise be ignored while the key it stands for goes missing or keeps its default.
        The error names the typo and the key it should be."""
        known = sorted(known)
        for name in table:
            guess = misspelling_of(name, known)
            if guess is not None and guess not in table:
                key = f"{where}.{name}" if where else name
                kind = "table" if not where and isinstance(table[name], Mapping) else what
                shown = f"[{guess}]" if kind == "table" else guess
                raise self.error(key, f"unknown {kind}; did you mean {shown}?")

    # -- scalars -----------------------------------------------------------------------------

    def number(
        self,
        key: str,
        value: Any,
        *,
        lo: float | None = None,
        hi: float | None = None,
        lo_open: bool = False,
        hi_open: bool = False,
        unit: str = "",
    ) -> float:
        """A finite number (int or float, not bool) inside ``[lo, hi]`` (ends open if asked)."""
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise self.error(key, f"must be a finite number, got {describe(value)}")
        x = float(value)
        if not math.isfinite(x):
            raise self.error(key, f"must be a finite number, got {describe(value)}")
        u = f" {unit}" if unit else ""
        if lo is not None and (x <= lo if lo_open else x < lo):
            raise self.error(key, f"must be {'>' if lo_open else '>='} {lo:g}{u}, got {x:g}")
        if hi is not None and (x >= hi if hi_open else x > hi):
            raise self.error(key, f"must be {'<' if hi_open else '<='} {hi:g}{u}, got {x:g}")
        return x

    def integer(self, key: str, value: Any, *, lo: int | None = None, hi: int | None = None) -> int:
        """An integer (not bool, not float) inside ``[lo, hi]``."""
        if isinstance(value, bool) or not isinstance(value, int):
            raise self.error(key, f"must be an integer, got {describe(value)}")
        n = int(value)
        if lo is not None and n < lo:
            raise self.error(key, f"must be >= {lo}, got {n}")
        if hi is not None and n > hi:
            raise self.error(key, f"must be <= {hi}, got {n}")
        return n

    def flag(self, key: str, value: Any) -> bool:
        """A TOML boolean (``true`` or ``false``; not 0 or 1)."""
        if not isinstance(value, bool):
            raise self.error(key, f"must be true or false, got {value!r}")
        return value

    def string(self, key: str, value: Any) -> str:
        """A non-empty string."""
        if not isinstance(value, str) or not value.strip():
            raise self.error(key, f"must be a non-empty string, got {describe(value)}")
        return str(value)

    # -- arrays ------------------------------------------------------------------------------

    def array(self, key: str, value: Any, n: int | None = None, min_len: int = 0) -> list[Any]:
        """A TOML array, of exactly ``n`` items if given, at least ``min_len`` items."""
        if isinstance(value, (str, bytes, Mapping)) or not isinstance(value, (list, tuple)):
            raise self.error(key, f"must be an array, got {describe(value)}")
        if n is not None and len(value) != n:
            raise self.error(key, f"must have {n} values, got {len(value)}")
        if len(value) < min_len:
            raise self.error(key, f"must have at least {min_len} values, got {len(value)}")
        return list(value)

    def vector(
        self,
        key: str,
        value: Any,
        n: int,
        *,
        lo: float | None = None,
        hi: float | None = None,
        lo_open: bool = False,
        unit: str = "",
    ) -> np.ndarray:
        """An array of ``n`` finite numbers, each inside ``[lo, hi]`` → float array (n,)."""
        items = self.array(key, value, n)
        return np.array(
            [
                self.number(f"{key}[{i}]", v, lo=lo, hi=hi, lo_open=lo_open, unit=unit)
                for i, v in enumerate(items)
            ],
            dtype=float,
        )

    def direction(self, key: str, value: Any) -> np.ndarray:
        """A non-zero 3-vector → unit vector (3,)."""
        v = self.vector(key, value, 3)
        norm = float(np.linalg.norm(v))
        if norm < 1e-9:
            raise self.error(key, "must be a non-zero vector")
        return v / norm

    def dh_table(self, key: str, value: Any) -> np.ndarray:
        """Six DH rows, each a table of ``theta_offset_deg, d_mm, a_mm, alpha_deg`` or an array
        of these four numbers (mm, deg) → (6, 4)."""
        rows = self.array(key, value, 6)
        out = np.empty((6, 4))
        for i, row in enumerate(rows):
            rkey = f"{key}[{i}]"
            if isinstance(row, Mapping):
                self.refuse_misspelt(rkey, row, DH_KEYS, "DH column")
                for j, name in enumerate(DH_KEYS):
                    if name not in row:
                        raise self.error(f"{rkey}.{name}", "missing key")
                    out[i, j] = self.number(f"{rkey}.{name}", row[name])
                extra = sorted(set(row) - set(DH_KEYS))
                if extra:
                    raise self.error(
                        f"{rkey}.{extra[0]}", f"unknown DH column (known: {', '.join(DH_KEYS)})"
                    )
            else:
                out[i] = self.vector(rkey, row, 4)
        return out

    def split_beta(self, key: str, raw: Any, max_deg: float) -> tuple[list[Any], np.ndarray]:
        """Take the optional Hayati ``beta_deg`` (|β| <= ``max_deg``) out of six DH rows (tables
        with a ``beta_deg`` key, or arrays with a fifth number): the rows without it (for
        ``dh_table``) and the six twists (deg, 0 where absent)."""
        rows = self.array(key, raw, 6)
        beta = np.zeros(6)
        stripped: list[Any] = []
        for i, row in enumerate(rows):
            if isinstance(row, Mapping) and "beta_deg" in row:
                beta[i] = self.number(
                    f"{key}[{i}].beta_deg", row["beta_deg"], lo=-max_deg, hi=max_deg, unit="deg"
                )
                row = {k: v for k, v in row.items() if k != "beta_deg"}
            elif isinstance(row, (list, tuple)) and len(row) == 5:
                beta[i] = self.number(f"{key}[{i}][4]", row[4], lo=-max_deg, hi=max_deg, unit="deg")
                row = list(row[:4])
            stripped.append(row)
        return stripped, beta

    def register_map(
        self, key: str, value: Any, base_dir: Path | None = None
    ) -> tuple[Path, RegisterMap]:
        """A Modbus register map file (``drivers.pulser.map_file``), relative to ``base_dir``
        (default: this file's directory) → its path and the validated map. A bad map raises
        :class:`ProfileError` naming the map file and its key, and ``key`` of this file."""
        name = self.string(key, value)
        p = Path(name).expanduser()
        if not p.is_absolute():
            p = (self.path.parent if base_dir is None else base_dir) / p
        try:
            return p, load_register_map(p)
        except RegisterMapError as e:
            raise ProfileError(e.path, e.key, f"{e.detail} ({key} in {self.path})") from None

    def joint_ranges(
        self, key_min: str, lo: Any, key_max: str, hi: Any
    ) -> tuple[np.ndarray, np.ndarray]:
        """Joint ranges (deg): 6 minima, 6 maxima, ``min < max`` for every joint."""
        jmin = self.vector(key_min, lo, 6, lo=-720.0, hi=720.0, unit="deg")
        jmax = self.vector(key_max, hi, 6, lo=-720.0, hi=720.0, unit="deg")
        for i in range(6):
            if not jmin[i] < jmax[i]:
                raise self.error(
                    f"{key_min}[{i}]",
                    f"joint {i + 1}: minimum {jmin[i]:g} deg must be below maximum {jmax[i]:g} deg",
                )
        return jmin, jmax

    def joints_within(self, key: str, value: Any, jmin: np.ndarray, jmax: np.ndarray) -> np.ndarray:
        """Six joint readings (deg), each inside its joint range."""
        j = self.vector(key, value, 6, unit="deg")
        for i in range(6):
            if not jmin[i] <= j[i] <= jmax[i]:
                raise self.error(
                    f"{key}[{i}]",
                    f"joint {i + 1} at {j[i]:g} deg is outside its "
                    f"range [{jmin[i]:g}, {jmax[i]:g}] deg",
                )
        return j

    def joint_offsets(self, key: str, value: Any) -> np.ndarray:
        """Six joint zero offsets (deg), each |offset| <= 30 deg."""
        return self.vector(key, value, 6, lo=-30.0, hi=30.0, unit="deg")

    def joint_numbers(self, key: str, value: Any) -> tuple[int, ...]:
        """Distinct 1-based joint numbers (1..6), sorted."""
        items = self.array(key, value)
        nums = [self.integer(f"{key}[{i}]", v, lo=1, hi=6) for i, v in enumerate(items)]
        if len(set(nums)) != len(nums):
            raise self.error(key, f"joint numbers must be distinct, got {nums}")
        return tuple(sorted(nums))

    def plane_points(self, key: str, value: Any) -> np.ndarray:
        """Three or more touched points (mm) that define a plane → (n, 3).

        Rejects duplicates (closer than 0.01 mm) and collinear sets (the spread across the
        best-fit line below 1/1000 of the spread along it).
        """
        items = self.array(key, value, min_len=3)
        pts = np.array([self.vector(f"{key}[{i}]", p, 3, unit="mm") for i, p in enumerate(items)])
        for i in range(len(pts)):
            for j in range(i + 1, len(pts)):
                if np.linalg.norm(pts[i] - pts[j]) < DUPLICATE_POINT_MM:
                    raise self.error(f"{key}[{j}]", f"duplicates point {i}")
        sv = np.linalg.svd(pts - pts.mean(0), compute_uv=False)
        if sv[1] < COLLINEAR_RATIO * sv[0]:
            raise self.error(key, "points are collinear: they do not define a plane")
        return pts


def misspelling_of(name: str, known: Collection[str]) -> str | None:
    """The known key ``name`` is most likely a misspelling of (``TYPO_CUTOFF``), or None."""
    if name in known:
        return None
    close = difflib.get_close_matches(name, list(known), n=1, cutoff=TYPO_CUTOFF)
    return close[0] if close else None


def _table_names(known: Mapping[str, frozenset[str] | None]) -> frozenset[str]:
    """The top-level names of ``known``: its tables and its top-level keys."""
    return frozenset(n for n in known if n) | (known.get("") or frozenset())


def unknown_keys(data: Mapping[str, Any], known: Mapping[str, frozenset[str] | None]) -> list[str]:
    """Dotted keys of ``data`` not listed in ``known`` (table name → its keys; ``""`` = top
    level; ``None`` = any key allowed in that table). Unknown keys are allowed by SPEC.md, so
    callers report them as warnings: they are usually typos (one close to a known key the
    file lacks is refused by :func:`refuse_misspelt_keys`)."""
    out: list[str] = []
    top = known.get("", frozenset())
    for name, value in data.items():
        if name in known:
            keys = known[name]
            if isinstance(value, Mapping) and keys is not None:
                out.extend(f"{name}.{k}" for k in value if k not in keys)
        elif top is not None and name not in top:
            out.append(name)
    return out


def describe_unknown(key: str, known: Mapping[str, frozenset[str] | None]) -> str:
    """The warning for an unknown dotted ``key`` of :func:`unknown_keys`, with the known key
    it is probably a misspelling of."""
    table, _, name = key.partition(".")
    if name and known.get(table):
        guess = misspelling_of(name, known[table] or ())
    else:
        guess = misspelling_of(key, _table_names(known))
    return f"unknown key {key} (ignored" + (f"; did you mean {guess}?)" if guess else ")")


def refuse_misspelt_keys(r: Reader, known: Mapping[str, frozenset[str] | None]) -> None:
    """Refuse (:class:`ProfileError`, exit 2) the first key or table of ``r``'s file that is a
    misspelling of a known one the file lacks (``Reader.refuse_misspelt``). Other unknown keys
    stay allowed (SPEC.md: more keys are welcome)."""
    r.refuse_misspelt("", r.data, _table_names(known), "key")
    for name, keys in known.items():
        table = r.data.get(name)
        if name and keys is not None and isinstance(table, Mapping):
            r.refuse_misspelt(name, table, keys)


def read_toml(path: str | Path) -> Any:
    """Parse a TOML file with tomlkit → its document (comments and order kept).

    Raises :class:`ProfileError` naming the file if it cannot be read, is not UTF-8 or is not
    valid TOML (with line and column).
    """
    p = Path(path)
    try:
        raw = p.read_bytes()
    except OSError as e:
        raise ProfileError(p, None, f"cannot read: {e.strerror or e}") from None
    return parse_toml_bytes(raw, p)


def parse_toml_bytes(raw: bytes, path: str | Path) -> Any:
    """Parse TOML bytes (UTF-8) with tomlkit; errors name ``path``."""
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as e:
        raise ProfileError(path, None, f"not UTF-8 text (byte {e.start})") from None
    try:
        return tomlkit.parse(text)
    except ParseError as e:
        raise ProfileError(path, None, f"not valid TOML: {_toml_problem(e, text)}") from None
    except TOMLKitError as e:  # a key twice in an inline table or an array's table: no line
        raise ProfileError(path, None, f"not valid TOML: {_toml_problem(e, text)}") from None


def _toml_problem(error: TOMLKitError, text: str) -> str:
    """What is wrong with ``text``, with its line: a key defined twice is named with the line
    of its second definition (tomlkit's ``KeyAlreadyPresent`` has none, so the standard
    library's parser, which stops at the same place, gives it)."""
    named = re.fullmatch(r'Key "(.*)" already exists\.(?: at line (\d+) col (\d+))?', str(error))
    if named is None:
        return str(error)
    key, line = named.group(1), named.group(2)
    try:  # the standard library's line: tomlkit's is the line after a table's second header
        tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        at = re.search(r"line (\d+)", str(e))
        line = at.group(1) if at else line
    where = f" (line {line})" if line else ""
    return f"'{key}' is defined twice{where}: keep one of the two"
