"""Checks in a profile's history: ``PROFILE.history/checks.json``, one entry per ``ucal check``.

A check changes nothing in the profile: it measures the cell and compares it with the
reference the commissioning left (docs/decisions/0009-check-against-a-reference.md). Its
entries sit beside the writes (``history.json``, ``ucal.profile``) in the same history
directory, in their own index, so that ``ucal profile undo`` (which walks the writes) never
meets one and every reader of the writes stays as it was; ``ucal profile history`` lists both
kinds by time.

An entry holds what the check measured (every face measurement as the solver receives it, and
the echo chain's readings), its verdict, each checked quantity and, for the reference, that it
is one. A check is the reference when it was the first to pass after the profile's model last
changed (``model_digest``: a calibration, a tool frame, an undo or an edit of a value), or when
``ucal check --baseline`` asked for one; later checks compare against the newest reference of
the profile as it now is.

The index is replaced atomically (temporary file, fsync, rename; ``ucal.files``) while the run
holds the profile's lock (``ucal.profile.profile_lock``), as every write of the profile is.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import asdict, dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from ucal import files
from ucal.cell import CellProfile
from ucal.errors import ProfileError
from ucal.profile import history_dir, made_history_dir, profile_to_dict, real_path
from ucal.profile.disk import read_index

#: The checks' index in a profile's history directory.
CHECKS_INDEX = "checks.json"
#: The profile tables a check's model reads: a change to one of them starts a new reference.
MODEL_TABLES = ("robot", "tool", "sample", "water", "transducer", "calibration")


@dataclass
class CheckEntry:
    """One check of a profile's cell, as its history keeps it.

    ``verdict``: "ok" (as commissioned) or "out of tolerance"; ``named``: what moved, in
    words; ``reference``: later checks compare against this one; ``quantities``: each checked
    quantity (``ucal.check.judge.Quantity.to_json``); ``faces`` and ``echoes``: what it
    measured (``ucal.check.measure``; ``edges``: its edge crossings), so that a later check solves
    against the measurements
    themselves; ``logged_departure_std_c`` and ``drift_prior_c_per_min``: its water as the
    tank thermometer's log left it (``ucal.model.priors.CellPrior``'s fields: None and
    0 without a log), which a later check's fit gives this run's drift.
    """

    id: int
    time: str
    kind: str  # "check"
    verdict: str
    reference: bool
    model_digest: str
    duration_s: float
    named: list[str] = field(default_factory=list)
    summary: str = ""
    compared_with: int | None = None  # the reference's id; None for a reference check
    quantities: list[dict[str, Any]] = field(default_factory=list)
    faces: list[dict[str, Any]] = field(default_factory=list)
    echoes: list[dict[str, Any]] = field(default_factory=list)
    floor_per_gain: float | None = None
    logged_departure_std_c: float | None = None
    drift_prior_c_per_min: float = 0.0
    #: its crossings of the XY face's far edges (``ucal.check.edges.EdgeReading.to_json``)
    edges: list[dict[str, Any]] = field(default_factory=list)


def model_digest(profile: CellProfile) -> str:
    """SHA-256 of what a check's model reads of ``profile`` (``MODEL_TABLES``: values, not
    comments or layout)."""
    data = profile_to_dict(profile)
    model = {name: data.get(name) for name in MODEL_TABLES}
    return hashlib.sha256(json.dumps(model, sort_keys=True).encode("utf-8")).hexdigest()


def checks_path(profile_path: str | Path) -> Path:
    """The checks' index of a profile (in its history directory)."""
    return history_dir(profile_path) / CHECKS_INDEX


def read_checks(profile_path: str | Path) -> list[CheckEntry]:
    """The checks of a profile, oldest first (empty when it was never checked)."""
    index = checks_path(profile_path)
    entries = read_index(index, "checks", "checks index")
    try:
        return [CheckEntry(**e) for e in entries]
    except TypeError as e:
        raise ProfileError(index, None, f"unreadable checks index: {e}") from None


def reference_check(profile_path: str | Path, digest: str) -> CheckEntry | None:
    """The newest reference check taken with the profile's model as ``digest`` says; None if
    the profile has none (never checked, or its model changed since)."""
    for entry in reversed(read_checks(profile_path)):
        if entry.reference and entry.model_digest == digest:
            return entry
    return None


def append_check(profile_path: str | Path, entry: CheckEntry) -> CheckEntry:
    """Add ``entry`` to the profile's checks under the next id and the current time (UTC);
    the index is replaced atomically, the profile itself is not touched. Returns the entry as
    stored. The caller holds the profile's lock."""
    p = real_path(profile_path)
    made_history_dir(p)
    entries = read_checks(p)
    entry.id = max((e.id for e in entries), default=0) + 1
    entry.time = datetime.now(UTC).isoformat(timespec="seconds")
    data = {"profile": p.name, "checks": [asdict(e) for e in [*entries, entry]]}
    index = checks_path(p)
    text = json.dumps(data, indent=1, allow_nan=False) + "\n"
    # a new index takes the profile's mode (the history holds copies of it); one that exists
    # keeps its own
    mode = None if index.exists() else files.existing_mode(p)
    try:
        files.commit(files.stage(index, text.encode("utf-8"), mode), index)
    except OSError as e:
        raise ProfileError(index, None, f"cannot write: {e.strerror or e} (unchanged)") from None
    return entry
