"""The history of a profile's writes, and undo.

Every write keeps the bytes it replaces: they are copied into the history directory
``<profile>.history/`` (``cell.toml`` → ``cell.toml.history/``) as ``NNNN-before.toml`` and an
entry is added to ``history.json`` there (id, UTC time, reason, SHA-256 of the bytes before and
after); then the new bytes replace the profile atomically. If any step fails the profile is
byte-for-byte unchanged and the history entry is withdrawn.

:func:`undo_profile` restores the bytes of the newest entry not yet undone (again atomically),
after saving the bytes it replaces as ``NNNN-after.toml``: an undo loses nothing.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import logging
from dataclasses import asdict, dataclass
from datetime import UTC, datetime
from pathlib import Path

from ucal import files, interrupt
from ucal.errors import ProfileError
from ucal.profile.disk import (
    HISTORY_INDEX,
    atomic_write,
    commit,
    history_dir,
    made_history_dir,
    read_index,
    real_path,
    stage,
)
from ucal.profile.lock import profile_lock

log = logging.getLogger(__name__)


@dataclass
class HistoryEntry:
    """One write of a profile: what it replaced and why.

    ``before`` is the file (in the history directory) holding the replaced bytes; the hashes
    are SHA-256 hex digests of the profile bytes before and after the write. ``after`` names
    the copy of the replaced-by-undo bytes once the entry has been undone.
    """

    id: int
    time: str
    reason: str
    before: str
    before_sha256: str
    after_sha256: str
    undone: bool = False
    undone_time: str | None = None
    after: str | None = None


def _sha(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def _now() -> str:
    return datetime.now(UTC).isoformat(timespec="seconds")


def profile_history(path: str | Path) -> list[HistoryEntry]:
    """The history entries of a profile, oldest first (empty if it was never rewritten)."""
    index = history_dir(path) / HISTORY_INDEX
    entries = read_index(index, "entries", "history index")
    try:
        return [HistoryEntry(**e) for e in entries]
    except TypeError as e:
        raise ProfileError(index, None, f"unreadable history index: {e}") from None


#: History reasons of the writes that put a measurement into a profile.
MEASURED_BY = ("tool-frame", "calibrate")


def last_measurement(path: str | Path) -> HistoryEntry | None:
    """The newest write of ``tool-frame`` or ``calibrate`` in a profile's history that was not
    undone (its ``time`` is when that result went into the profile); None if there is none."""
    for entry in reversed(profile_history(path)):
        if entry.reason.startswith(MEASURED_BY) and not entry.undone:
            return entry
    return None


def _index_bytes(path: Path, entries: list[HistoryEntry]) -> bytes:
    data = {"profile": path.name, "entries": [asdict(e) for e in entries]}
    return (json.dumps(data, indent=1) + "\n").encode("utf-8")


def _save_history(path: Path, entries: list[HistoryEntry]) -> None:
    atomic_write(history_dir(path) / HISTORY_INDEX, _index_bytes(path, entries), _index_mode(path))


def _index_mode(path: Path) -> int | None:
    """The history holds copies of the profile: a new index takes the profile's mode (an
    existing one keeps its own)."""
    return None if (history_dir(path) / HISTORY_INDEX).exists() else files.existing_mode(path)


def _replace_both(path: Path, data: bytes, entries: list[HistoryEntry], copy: Path) -> None:
    """Replace the history index (``entries``) and then the profile (``data``).

    Both new files are written and fsync'ed before either is renamed into place, so a full
    disk fails before anything changes: the staged files and the new history ``copy`` are
    removed, and the index and the profile keep their bytes.
    """
    index = history_dir(path) / HISTORY_INDEX
    staged: list[Path] = []
    try:
        staged.append(stage(index, _index_bytes(path, entries), _index_mode(path)))
        staged.append(stage(path, data))
        commit(staged[0], index)
    except ProfileError:
        for tmp in staged:
            with contextlib.suppress(OSError):
                tmp.unlink()
        with contextlib.suppress(OSError):
            copy.unlink()
        raise
    commit(staged[1], path)


def _write_new(path: Path, data: bytes, mode: int | None) -> None:
    """Write a history copy (fsync'ed, with ``mode``: the profile's); it is new, so no rename
    is needed.

    A copy that cannot be written whole (e.g. the disk is full) is removed again, so that no
    empty or truncated ``NNNN-before.toml`` is left to collide with the next write.
    """
    try:
        files.write_new(path, data, mode)
    except OSError as e:
        raise ProfileError(path, None, f"cannot write history copy: {e.strerror or e}") from None


def _next_history_id(hdir: Path, entries: list[HistoryEntry]) -> int:
    """The next free history id: past every indexed entry and every ``NNNN-*.toml`` present
    (a copy left behind by an interrupted write must not block the next one)."""
    ids = [e.id for e in entries]
    with contextlib.suppress(OSError):
        for f in hdir.iterdir():
            head = f.name.split("-", 1)[0]
            if f.suffix == ".toml" and head.isdigit():
                ids.append(int(head))
    return max(ids, default=0) + 1


def _replace_with_history(
    path: Path, after: bytes, reason: str, before: bytes | None = None
) -> HistoryEntry:
    """Record ``before`` (default: the current bytes) in the history, then replace ``path``
    with ``after`` atomically; withdraw the entry if the replacement fails. Once the process
    received SIGINT or SIGTERM nothing is written (``ucal.interrupt``): an interrupted run
    leaves the profile as it was, even where its ``KeyboardInterrupt`` was swallowed."""
    interrupt.check()
    path = real_path(path)
    if before is None:
        before = path.read_bytes()
    hdir = made_history_dir(path)
    entries = profile_history(path)
    new_id = _next_history_id(hdir, entries)
    copy = hdir / f"{new_id:04d}-before.toml"
    _write_new(copy, before, files.existing_mode(path))
    entry = HistoryEntry(
        id=new_id,
        time=_now(),
        reason=reason,
        before=copy.name,
        before_sha256=_sha(before),
        after_sha256=_sha(after),
    )
    # a signal from here on is acted on once both files are replaced, never between them
    with interrupt.deferred():
        try:
            _replace_both(path, after, entries + [entry], copy)
        except ProfileError:
            _withdraw(path, entries, copy)  # only needed when the final rename failed
            raise
    log.info("%s: written (%s); previous version kept as %s", path, reason, copy)
    return entry


def _withdraw(path: Path, entries: list[HistoryEntry], copy: Path) -> None:
    """Best effort: put the index back as it was (if it lists ``copy``) and remove ``copy``."""
    try:
        if any(e.before == copy.name for e in profile_history(path)):
            _save_history(path, entries)
    except ProfileError:
        log.warning("%s: could not withdraw history entry %s", path, copy.name)
    try:
        copy.unlink()
    except FileNotFoundError:
        pass
    except OSError:
        log.warning("%s: could not remove the unused history copy %s", path, copy.name)


def undo_profile(path: str | Path, force: bool = False) -> HistoryEntry:
    """Restore the profile bytes replaced by the newest write not yet undone, atomically.

    Refuses (exit 2) when there is nothing to undo, or when the profile was changed since that
    write (its SHA-256 differs), unless ``force``. The bytes replaced by the undo are kept as
    ``NNNN-after.toml``. Returns the undone entry.
    """
    p = real_path(path)
    with profile_lock(p, f"ucal profile undo {p}"):
        return _undo_held(p, force)


def _undo_held(p: Path, force: bool) -> HistoryEntry:
    """``undo_profile`` with the profile held."""
    entries = profile_history(p)
    pending = [e for e in entries if not e.undone]
    if not pending:
        raise ProfileError(p, None, "nothing to undo (no recorded write)")
    entry = pending[-1]
    hdir = history_dir(p)
    try:
        current = p.read_bytes()
        previous = (hdir / entry.before).read_bytes()
    except OSError as e:
        raise ProfileError(p, None, f"cannot read for undo: {e.strerror or e}") from None
    if _sha(previous) != entry.before_sha256:
        raise ProfileError(hdir / entry.before, None, "history copy is corrupt (hash mismatch)")
    if _sha(current) != entry.after_sha256 and not force:
        raise ProfileError(
            p,
            None,
            f"changed since write {entry.id} ({entry.reason}, "
            f"{entry.time}); use --force to undo anyway",
        )
    after_copy = hdir / f"{entry.id:04d}-after.toml"
    if after_copy.exists():  # left over by an undo whose rename failed
        stamp = datetime.now(UTC).strftime("%Y%m%dT%H%M%S%f")
        after_copy = hdir / f"{entry.id:04d}-after-{stamp}.toml"
    _write_new(after_copy, current, files.existing_mode(p))
    entry.undone, entry.undone_time, entry.after = True, _now(), after_copy.name
    try:
        _replace_both(p, previous, entries, after_copy)
    except ProfileError:
        entry.undone, entry.undone_time, entry.after = False, None, None
        try:
            if any(e.id == entry.id and e.undone for e in profile_history(p)):
                _save_history(p, entries)  # only when the final rename failed
        except ProfileError:
            log.warning("%s: could not withdraw the undo record", p)
        with contextlib.suppress(OSError):
            after_copy.unlink()
        raise
    return entry
