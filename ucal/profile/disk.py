"""Where a profile's files sit, and how one of them is replaced atomically.

A profile path that is a symbolic link names the file it points to: ucal writes through the
link, and the history directory ``<profile>.history/`` sits beside the real file. A file is
replaced in two steps: the new bytes are staged in a fsync'ed temporary file beside it (all
that needs disk space), then renamed over it (atomic, needs no space); any failure is a
:class:`ProfileError` naming the file, which is then unchanged.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

from ucal import files
from ucal.errors import ProfileError

HISTORY_SUFFIX = ".history"
HISTORY_INDEX = "history.json"


def real_path(path: str | Path) -> Path:
    """The file a profile path names, symbolic links resolved (the path itself if none)."""
    return Path(os.path.realpath(path))


def history_dir(path: str | Path) -> Path:
    """The history directory of a profile: ``cell.toml`` → ``cell.toml.history``, beside the
    real file when ``path`` is a symbolic link."""
    p = real_path(path)
    return p.with_name(p.name + HISTORY_SUFFIX)


def made_history_dir(path: str | Path) -> Path:
    """The history directory of a profile, created if missing; ProfileError if it cannot be."""
    hdir = history_dir(path)
    try:
        hdir.mkdir(exist_ok=True)
    except OSError as e:
        raise ProfileError(
            hdir, None, f"cannot create history directory: {e.strerror or e}"
        ) from None
    return hdir


def read_index(index: Path, key: str, what: str) -> list[dict[str, Any]]:
    """The entries under ``key`` of a JSON index file (empty when there is none), or a
    ProfileError naming the unreadable ``what``."""
    if not index.exists():
        return []
    try:
        entries = json.loads(index.read_text(encoding="utf-8"))[key]
        if not isinstance(entries, list):
            raise TypeError(f"{key} is not a list")
        return entries
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise ProfileError(index, None, f"unreadable {what}: {e}") from None


def atomic_write(path: Path, data: bytes, mode: int | None = None) -> None:
    """Replace ``path`` with ``data``: temp file in the same directory, fsync, ``os.replace``.

    The file keeps its mode (a new one: ``mode``, else the umask's). On failure the temp file
    is removed and ``path`` is untouched; raises ProfileError.
    """
    commit(stage(path, data, mode), path)


def stage(path: Path, data: bytes, mode: int | None = None) -> Path:
    """Write ``data`` to a new fsync'ed temporary file beside ``path`` and return it: everything
    that needs disk space, before anything is replaced (mode as ``files.stage``)."""
    try:
        return files.stage(path, data, mode)
    except OSError as e:
        raise ProfileError(
            path, None, f"cannot write: {e.strerror or e} (file unchanged)"
        ) from None


def commit(tmp: Path, path: Path) -> None:
    """Rename a staged file over ``path`` (atomic; needs no space); remove it on failure."""
    try:
        files.commit(tmp, path)
    except OSError as e:
        raise ProfileError(
            path, None, f"cannot write: {e.strerror or e} (file unchanged)"
        ) from None
