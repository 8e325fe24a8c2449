"""Writing files as the user expects: atomically, a replaced file's mode kept, a new file's
mode from the user's umask (as any other program creates it), never a mode of our own.

The functions raise ``OSError`` and leave nothing behind when they fail; callers turn that
into the one-line error naming the file.
"""

from __future__ import annotations

import contextlib
import os
import re
import secrets
from pathlib import Path
from typing import Any

import numpy as np

#: The mode ``open()`` asks for a new file; the kernel takes the umask off it.
NEW_FILE_MODE = 0o666
#: How a staged file's name ends: ``.NAME.<8 hex digits>.tmp`` beside ``NAME``.
STAGED_SUFFIX = ".tmp"


def existing_mode(path: Path) -> int | None:
    """The permission bits of ``path`` (links followed), or None when it does not exist."""
    try:
        return path.stat().st_mode & 0o7777
    except OSError:
        return None


def create_new(path: Path, mode: int | None = None) -> int:
    """Create ``path`` (it must not exist) and return a descriptor open for writing.

    With ``mode`` the file gets exactly that mode, set while it is still empty (so content
    never sits in a file more open than asked); without, the umask's mode for a new file.
    """
    flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_CLOEXEC", 0)
    fd = os.open(path, flags, NEW_FILE_MODE if mode is None else 0o600)
    if mode is not None:
        try:
            os.fchmod(fd, mode)
        except OSError:
            os.close(fd)
            with contextlib.suppress(OSError):
                os.unlink(path)
            raise
    return fd


def write_new(path: Path, data: bytes, mode: int | None = None) -> None:
    """Write ``data`` to the new file ``path`` (fsync'ed); on failure remove what was made."""
    fd = create_new(path, mode)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
    except OSError:
        with contextlib.suppress(OSError):
            os.unlink(path)
        raise


def stage(path: Path, data: bytes, mode: int | None = None) -> Path:
    """Write ``data`` to a new fsync'ed temporary file beside ``path`` and return it: all that
    needs disk space, before anything is replaced. Its mode is ``mode``, else ``path``'s when
    it exists, else the umask's."""
    if mode is None:
        mode = existing_mode(path)
    for _ in range(100):
        tmp = path.with_name(f".{path.name}.{secrets.token_hex(4)}{STAGED_SUFFIX}")
        try:
            write_new(tmp, data, mode)
        except FileExistsError:
            continue
        return tmp
    raise FileExistsError(f"no free temporary name beside {path}")


def staged_leftovers(path: Path) -> list[Path]:
    """The temporary files ``stage`` made beside ``path`` that are still there: left by a
    process killed between the staging and the rename (only the holder of ``path``'s lock may
    remove them)."""
    pattern = re.compile(rf"\.{re.escape(path.name)}\.[0-9a-f]{{8}}{re.escape(STAGED_SUFFIX)}")
    try:
        names = os.listdir(path.parent)
    except OSError:
        return []
    return [path.parent / n for n in sorted(names) if pattern.fullmatch(n)]


def fsync_dir(directory: Path) -> None:
    """Make a rename in ``directory`` durable (where the platform allows it)."""
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:
        return  # not supported on this platform: the rename itself is still atomic
    try:
        with contextlib.suppress(OSError):
            os.fsync(fd)
    finally:
        os.close(fd)


def commit(tmp: Path, path: Path) -> None:
    """Rename a staged file over ``path`` (atomic; needs no space); remove it on failure."""
    try:
        os.replace(tmp, path)
    except OSError:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise
    fsync_dir(path.parent)


def jsonable(value: Any) -> Any:
    """``json.dumps`` default for numpy values (anything else by its repr)."""
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    return repr(value)
