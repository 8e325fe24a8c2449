"""The profile's ``[cell]`` table: how the cell is named to a plant, and how often it is due.

``name`` is the cell's name in published results (``ucal.fleet``): one MQTT topic level, so no
``/``, ``+``, ``#`` or NUL, not starting with ``$`` (the broker's own topics); without it the
profile's file name stem names the cell. ``validation_interval_days`` is how long a validation
(a result of quality ``ok``) holds: a published result's next validation date is the last
validation plus it; without it the results carry no next date.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ucal.errors import InputError
from ucal.profile.validation import Reader

#: The keys of ``[cell]``.
CELL_KEYS = frozenset({"name", "validation_interval_days"})
#: Longest cell name (characters): a topic level a dashboard can show.
MAX_NAME_CHARS = 64
#: Longest validation interval (days): ten years.
MAX_INTERVAL_DAYS = 3650.0


@dataclass(frozen=True)
class CellSettings:
    """The ``[cell]`` table: the name the cell publishes under, its validation interval."""

    name: str
    validation_interval_days: float | None = None


def name_problem(name: str) -> str | None:
    """Why ``name`` cannot be a cell's topic level, or None when it can."""
    if not name or not name.strip():
        return "is empty"
    if len(name) > MAX_NAME_CHARS:
        return f"is longer than {MAX_NAME_CHARS} characters"
    bad = sorted({c for c in name if c in "/+#\0" or not c.isprintable()})
    if bad:
        shown = ", ".join(repr(c) for c in bad)
        return f"holds {shown}, which an MQTT topic level cannot"
    if name.startswith("$"):
        return "starts with '$', which MQTT keeps for the broker's own topics"
    return None


def read_cell(r: Reader, table: Mapping[str, Any] | None, stem: str) -> CellSettings:
    """Read ``[cell]`` (``ProfileError`` naming the file and key); ``stem`` names the cell
    when the table gives no ``name``."""
    if table is None:
        return CellSettings(stem)
    name = stem
    raw = r.get(table, "cell.name")
    if raw is not None:
        name = r.string("cell.name", raw)
        problem = name_problem(name)
        if problem is not None:
            raise r.error("cell.name", f"{name!r} {problem}")
    interval = None
    raw = r.get(table, "cell.validation_interval_days")
    if raw is not None:
        interval = r.number(
            "cell.validation_interval_days",
            raw,
            lo=0.0,
            lo_open=True,
            hi=MAX_INTERVAL_DAYS,
            unit="days",
        )
    return CellSettings(name, interval)


def cell_settings(path: Path, data: Mapping[str, Any]) -> CellSettings:
    """The ``[cell]`` settings of the profile ``path`` parsed as ``data``; a cell named by its
    file name that cannot be a topic level is refused (``InputError``, exit 2) with the cure."""
    r = Reader(path, data)
    settings = read_cell(r, r.table("cell"), Path(path).stem)
    problem = name_problem(settings.name)
    if problem is not None:
        raise InputError(
            f"{path}: the cell is named by its file name {settings.name!r}, which {problem}: "
            'give it a name in the profile ([cell] name = "...")'
        )
    return settings
