"""The fleet at a glance: one row per cell from its retained state (``mqtt.read_states``).

Each row: the cell, its last result (command, time, exit code, quality), the last and the next
validation with the days until it is due (negative: overdue), the trend (the qualities of its
latest results, oldest first), the profile's hash and ucal's version that made the result.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import asdict, dataclass
from datetime import datetime
from typing import Any

from ucal.fleet.message import QUALITY_OK, QUALITY_OUT, SCHEMA_VERSION

#: How a quality is drawn in the trend column.
TREND_MARK = {QUALITY_OK: "+", QUALITY_OUT: "x"}
#: The mark of a quality not determined (or unknown to this version).
OTHER_MARK = "."


@dataclass(frozen=True)
class CellRow:
    """One cell's line of the fleet view."""

    cell: str
    command: str
    time: str
    exit_code: int | None
    quality: str
    last_validation: str | None
    next_validation: str | None
    due_in_days: float | None  # negative: overdue
    trend: list[str]  # qualities, oldest first
    sequence: int | None
    profile_sha256: str
    ucal_version: str
    schema_version: int | None

    def to_json(self) -> dict[str, Any]:
        return asdict(self)

    @property
    def trend_marks(self) -> str:
        return "".join(TREND_MARK.get(q, OTHER_MARK) for q in self.trend)


def _time(text: Any) -> datetime | None:
    if not isinstance(text, str):
        return None
    try:
        return datetime.fromisoformat(text.replace("Z", "+00:00"))
    except ValueError:
        return None


def row_of(cell: str, state: Mapping[str, Any], now: datetime) -> CellRow:
    """The row of ``cell`` from its state message (fields a newer schema lacks are blank)."""
    target = state.get("calibration_target")
    target = target if isinstance(target, Mapping) else {}
    due = _time(target.get("next_validation"))
    recent = state.get("recent")
    trend = [
        str(r.get("quality", ""))
        for r in (recent if isinstance(recent, list) else [])
        if isinstance(r, Mapping)
    ]
    exit_code = state.get("exit_code")
    sequence = state.get("sequence")
    version = state.get("schema_version")
    return CellRow(
        cell=cell,
        command=str(state.get("command", "")),
        time=str(state.get("time", "")),
        exit_code=exit_code if isinstance(exit_code, int) else None,
        quality=str(target.get("quality", "")),
        last_validation=target.get("last_validation"),
        next_validation=target.get("next_validation"),
        due_in_days=None if due is None else (due - now).total_seconds() / 86400.0,
        trend=trend,
        sequence=sequence if isinstance(sequence, int) else None,
        profile_sha256=str(state.get("profile_sha256", "")),
        ucal_version=str(state.get("ucal_version", "")),
        schema_version=version if isinstance(version, int) else None,
    )


def fleet_rows(states: Iterable[Mapping[str, Any]], now: datetime) -> list[CellRow]:
    """The rows of every cell's state, by cell name."""
    rows = [row_of(str(s.get("cell", "?")), s, now) for s in states]
    return sorted(rows, key=lambda r: r.cell)


def newer_schema(rows: Iterable[CellRow]) -> list[str]:
    """The cells whose state is of a schema newer than this ucal reads."""
    return [r.cell for r in rows if (r.schema_version or 0) > SCHEMA_VERSION]
