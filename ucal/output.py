"""Files an export writes for the user: its directory made and checked, each file written
atomically (``ucal.files``: a temporary file beside it, renamed; a replaced file keeps its
mode). Errors are ``InputError`` (exit 2) naming the directory or the file."""

from __future__ import annotations

import os
from pathlib import Path

from ucal import files
from ucal.errors import InputError


def writable_directory(directory: Path) -> None:
    """Create ``directory`` if needed; refuse (exit 2, naming it) one that cannot be written."""
    try:
        directory.mkdir(parents=True, exist_ok=True)
    except FileExistsError:
        raise InputError(f"{directory}: cannot write: not a directory") from None
    except OSError as e:
        raise InputError(f"{directory}: cannot create the directory: {e.strerror or e}") from None
    if not os.access(directory, os.W_OK | os.X_OK):
        raise InputError(f"{directory}: cannot write: the directory is not writable")


def write_file(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically; exit 2 naming the file when it cannot be."""
    try:
        files.commit(files.stage(path, data), path)
    except OSError as e:
        raise InputError(f"{path}: cannot write: {e.strerror or e}") from None
