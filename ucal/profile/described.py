"""The cell as its technician described it, kept in the profile beside what ucal measured.

``tool-frame`` writes the tool it measured into ``[tool] position_mm`` and ``rotation_deg``, and
``calibrate`` the block it measured into ``[sample]``: the values every later command uses. The
description they replace (the tool as drawn, the block as placed) is what the simulator builds
its cell from (the demo truth, a world file's defaults): built from ucal's estimates instead, a
simulated cell would move by its own error each time a command wrote a (right) estimate. So
each such write keeps the description in the same table, and marks its own values:

- ``[tool] drawn_position_mm``, ``drawn_rotation_deg``: the tool as drawn;
- ``[sample] placed_position_mm``, ``placed_rotation_deg``: the block as placed;
- ``measured_sha256`` in each: the SHA-256 of the pose the write measured (``pose_digest``).

Reading them back (``read_description``): while ``position_mm`` and ``rotation_deg`` are the
values ucal wrote (their digest is ``measured_sha256``), the description is the kept one; once
the technician edits them (a remounted tool, a moved block), the edit is the description and
the kept keys are stale. So the description is a function of the profile's text alone, whatever
became of its history (a profile copied without its ``.history/`` folder is the same cell).
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Iterable, Mapping
from typing import Any

import numpy as np

from ucal.cell import CellProfile
from ucal.profile.validation import Reader

#: Table → the word of its kept description's keys.
DESCRIBED_AS = {"tool": "drawn", "sample": "placed"}
#: The key that marks the pose ucal wrote.
DIGEST_KEY = "measured_sha256"
#: The keys a measuring write adds to ``[tool]`` and ``[sample]``.
DESCRIPTION_KEYS = {
    table: frozenset({f"{word}_position_mm", f"{word}_rotation_deg", DIGEST_KEY})
    for table, word in DESCRIBED_AS.items()
}

Pose = tuple[np.ndarray, np.ndarray]


def pose_digest(position_mm: Iterable[float], rotation_deg: Iterable[float]) -> str:
    """The SHA-256 of a pose as the profile holds it (floats, which TOML gives back exactly)."""
    text = json.dumps([[float(v) for v in position_mm], [float(v) for v in rotation_deg]])
    return hashlib.sha256(text.encode("ascii")).hexdigest()


def read_description(
    r: Reader,
    table: Mapping[str, Any] | None,
    name: str,
    position: np.ndarray,
    rotation: np.ndarray,
) -> Pose | None:
    """The kept description of ``[name]`` (``tool`` or ``sample``) whose pose is
    ``position``/``rotation``: None when the pose is the description (no keys kept, or the pose
    edited since ucal wrote it). The three keys come together (``ProfileError`` otherwise)."""
    if table is None:
        return None
    word = DESCRIBED_AS[name]
    keys = [f"{word}_position_mm", f"{word}_rotation_deg", DIGEST_KEY]
    values = [r.get(table, f"{name}.{k}") for k in keys]
    if all(v is None for v in values):
        return None
    missing = [k for k, v in zip(keys, values, strict=True) if v is None]
    if missing:
        raise r.error(
            f"{name}.{missing[0]}",
            f"missing: ucal writes {', '.join(keys)} together (the {name} as "
            f"{'drawn' if name == 'tool' else 'placed'}, kept where it wrote what it measured); "
            "restore it or remove all three",
        )
    kept_position = r.vector(f"{name}.{keys[0]}", values[0], 3, unit="mm")
    kept_rotation = r.vector(f"{name}.{keys[1]}", values[1], 3, unit="deg")
    digest = values[2]
    if not isinstance(digest, str) or len(digest) != 64:
        raise r.error(f"{name}.{DIGEST_KEY}", "must be the 64 hex digits ucal wrote")
    if digest != pose_digest(position, rotation):
        return None  # edited since ucal wrote it: the edit is the description
    return kept_position, kept_rotation


def description_keys(
    profile: CellProfile, name: str, position_mm: Iterable[float], rotation_deg: Iterable[float]
) -> dict[str, Any]:
    """The keys a write of the measured pose ``position_mm``/``rotation_deg`` into ``[name]``
    adds: the description as ``profile`` (the profile before the write) has it, and the digest
    of the pose written."""
    described = profile.as_described()
    if name == "tool":
        kept = (described.tool_position_mm, described.tool_rotation_deg)
    else:
        kept = (described.sample_position_mm, described.sample_rotation_deg)
    word = DESCRIBED_AS[name]
    return {
        f"{word}_position_mm": [float(v) for v in kept[0]],
        f"{word}_rotation_deg": [float(v) for v in kept[1]],
        DIGEST_KEY: pose_digest(position_mm, rotation_deg),
    }
