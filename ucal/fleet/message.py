"""The message a cell publishes for each result (schema version 1: ``result-v1.json``).

One JSON object: the schema version, a message id (consumers drop a message whose id they
already hold: QoS 1 delivers at least once), the cell's sequence number (1, 2, ... per cell, in
the order its results were made), the cell, the time (UTC), the command, its exit code and
one-line message, ucal's version, the profile's SHA-256 as the run left it, whether the cell was
simulated, the calibration-target fields and the command's ``--json`` result object.

The calibration-target fields follow the Industrial Automation companion specification's
CalibrationTargetType (OPC 10000-200; the Robotics one, OPC 40010-1, has no calibration node):
``last_validation`` (its LastValidationDate: the newest result of quality ``ok``),
``next_validation`` (NextValidationDate: that plus the profile's ``[cell]
validation_interval_days``; null without one) and ``quality``: ``ok``, ``out_of_tolerance`` or
``not_determined``. ``recent`` holds the cell's last results in brief, oldest first, this one
last: the fleet's trend.
"""

from __future__ import annotations

import json
import math
import socket
import uuid
from collections.abc import Mapping
from dataclasses import dataclass, field
from datetime import UTC, datetime, timedelta
from importlib import resources
from typing import Any

import numpy as np

from ucal import __version__
from ucal.errors import EXIT_OUT_OF_TOLERANCE
from ucal.profile.cell import CellSettings

#: The payload's schema version, and the file in this package that states it.
SCHEMA_VERSION = 1
SCHEMA_FILE = "result-v1.json"
#: The calibration target's quality.
QUALITY_OK = "ok"
QUALITY_OUT = "out_of_tolerance"
QUALITY_UNKNOWN = "not_determined"
#: Commands whose result judges the cell as it is (the others change it).
VALIDATING = frozenset({"check", "verify"})
#: How many of the cell's latest results a message carries in brief (the trend).
RECENT = 10


@dataclass(frozen=True)
class Finished:
    """A run's result once final, as the command line prints it."""

    command: str
    exit_code: int  # 0, 1 (out of tolerance) or 130 (a signal once the result stood)
    message: str  # the one-line error beside exit 1 or 130, "" with exit 0
    result: Mapping[str, Any]  # the ``--json`` object
    written: bool
    out_of_tolerance: bool
    simulated: bool


@dataclass
class CellState:
    """What the cell's queue remembers between runs: the last sequence number, the last
    validation and the latest results in brief."""

    sequence: int = 0
    last_validation: str | None = None
    recent: list[dict[str, Any]] = field(default_factory=list)

    @classmethod
    def from_json(cls, data: Mapping[str, Any]) -> CellState:
        sequence = data.get("sequence", 0)
        last = data.get("last_validation")
        recent = data.get("recent", [])
        return cls(
            sequence if isinstance(sequence, int) and not isinstance(sequence, bool) else 0,
            last if isinstance(last, str) else None,
            [r for r in recent if isinstance(r, dict)] if isinstance(recent, list) else [],
        )

    def to_json(self) -> dict[str, Any]:
        return {
            "sequence": self.sequence,
            "last_validation": self.last_validation,
            "recent": self.recent,
        }


def quality_of(done: Finished) -> str:
    """``out_of_tolerance`` for a result out of tolerance; ``ok`` for a check or verify in
    tolerance and for a calibration written; ``not_determined`` otherwise (a calibration that
    wrote nothing judged nothing)."""
    if done.out_of_tolerance or done.exit_code == EXIT_OUT_OF_TOLERANCE:
        return QUALITY_OUT
    if done.command in VALIDATING or done.written:
        return QUALITY_OK
    return QUALITY_UNKNOWN


def utc_text(t: datetime) -> str:
    """``t`` as ISO 8601 UTC with milliseconds and a ``Z``."""
    return t.astimezone(UTC).isoformat(timespec="milliseconds").replace("+00:00", "Z")


def build_message(
    done: Finished,
    cell: CellSettings,
    profile_sha256: str,
    state: CellState,
    now: datetime,
) -> tuple[dict[str, Any], CellState]:
    """The message for ``done`` and the cell's state after it (``state`` is before)."""
    time = utc_text(now)
    quality = quality_of(done)
    sequence = state.sequence + 1
    last = time if quality == QUALITY_OK else state.last_validation
    due = None
    if last is not None and cell.validation_interval_days is not None:
        start = datetime.fromisoformat(last.replace("Z", "+00:00"))
        due = utc_text(start + timedelta(days=cell.validation_interval_days))
    brief = {
        "sequence": sequence,
        "time": time,
        "command": done.command,
        "exit_code": done.exit_code,
        "quality": quality,
    }
    recent = [*state.recent, brief][-RECENT:]
    message = {
        "schema_version": SCHEMA_VERSION,
        "message_id": uuid.uuid4().hex,
        "sequence": sequence,
        "cell": cell.name,
        "time": time,
        "command": done.command,
        "exit_code": done.exit_code,
        "message": done.message,
        "ucal_version": __version__,
        "profile_sha256": profile_sha256,
        "host": socket.gethostname(),
        "simulated": done.simulated,
        "calibration_target": {
            "last_validation": last,
            "next_validation": due,
            "validation_interval_days": cell.validation_interval_days,
            "quality": quality,
        },
        "recent": recent,
        "result": plain(done.result),
    }
    return message, CellState(sequence, last, recent)


def encode(message: Mapping[str, Any]) -> bytes:
    """The message as it is published: compact UTF-8 JSON, no non-finite number."""
    return json.dumps(plain(message), separators=(",", ":"), allow_nan=False).encode("utf-8")


def plain(value: Any) -> Any:
    """``value`` as plain JSON values: numpy values converted, a non-finite number null."""
    if isinstance(value, Mapping):
        return {str(k): plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [plain(v) for v in value]
    if isinstance(value, np.ndarray):
        return plain(value.tolist())
    if isinstance(value, np.generic):
        return plain(value.item())
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if value is None or isinstance(value, (str, int, float, bool)):
        return value
    return str(value)


def schema() -> dict[str, Any]:
    """The payload's JSON Schema (``result-v1.json``, shipped in this package)."""
    text = resources.files("ucal.fleet").joinpath(SCHEMA_FILE).read_text(encoding="utf-8")
    loaded: dict[str, Any] = json.loads(text)
    return loaded


__all__ = [
    "QUALITY_OK",
    "QUALITY_OUT",
    "QUALITY_UNKNOWN",
    "SCHEMA_VERSION",
    "CellState",
    "Finished",
    "build_message",
    "encode",
    "quality_of",
    "schema",
]
