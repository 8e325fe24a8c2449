"""Hold a profile for one run (:func:`profile_lock`); check there is room to write it
(:func:`check_writable`)."""

from __future__ import annotations

import contextlib
import fcntl
import json
import logging
import os
import shutil
import socket
import sys
from collections.abc import Iterator
from dataclasses import asdict, dataclass
from datetime import UTC, datetime
from pathlib import Path

from ucal import files
from ucal.errors import InputError, ProfileError
from ucal.profile.disk import HISTORY_INDEX, history_dir, real_path

log = logging.getLogger(__name__)

LOCK_SUFFIX = ".lock"
#: Free space a profile write needs besides the profile's own bytes (temporary file, history
#: copy, index): the profile's size three times over plus this margin.
MIN_FREE_BYTES = 1 << 20


@dataclass(frozen=True)
class LockHolder:
    """Who holds a profile: process id, host, command line and UTC start time."""

    pid: int
    host: str
    command: str
    started: str

    def describe(self) -> str:
        """The holder in words, for the refusal message."""
        return f"pid {self.pid} on {self.host}, started {self.started}: {self.command}"


def lock_path(path: str | Path) -> Path:
    """The lock file of a profile: ``cell.toml`` → ``cell.toml.lock``, beside the real file."""
    p = real_path(path)
    return p.with_name(p.name + LOCK_SUFFIX)


def _read_holder(fd: int) -> LockHolder | None:
    try:
        raw = os.pread(fd, 65536, 0)
        return LockHolder(**json.loads(raw.decode("utf-8")))
    except (OSError, ValueError, TypeError):
        return None  # the holder is still writing it, or it is not ours


@contextlib.contextmanager
def profile_lock(path: str | Path, command: str | None = None) -> Iterator[LockHolder]:
    """Hold the profile for one run: a second run on the same profile refuses at once.

    An advisory ``fcntl.flock`` on ``<profile>.lock`` beside the real file (symbolic links
    resolved, so two links to one profile share the lock). The operating system releases it
    when the process ends, however it ends: a crashed run never leaves a lock that blocks.
    The file records the holder (pid, host, command, start time) for the refusal, which is an
    ``InputError`` (exit 2) naming the profile and the holder. The file is removed on release.
    """
    lock = lock_path(path)
    me = LockHolder(
        pid=os.getpid(),
        host=socket.gethostname(),
        command=command or " ".join(["ucal", *sys.argv[1:]]),
        started=datetime.now(UTC).isoformat(timespec="seconds"),
    )
    while True:
        try:
            fd = os.open(lock, os.O_RDWR | os.O_CREAT, 0o644)
        except OSError as e:
            raise ProfileError(
                lock.parent,
                None,
                f"cannot create the lock file {lock.name} "
                f"for {real_path(path).name}: "
                f"{e.strerror or e}",
            ) from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            holder = _read_holder(fd)
            os.close(fd)
            who = holder.describe() if holder else "another process"
            raise InputError(
                f"{real_path(path)}: in use by another run ({who}); wait for it "
                f"to finish (the lock is {lock})"
            ) from None
        try:
            same = os.fstat(fd).st_ino == os.stat(lock).st_ino
        except OSError:
            same = False
        if same:
            break
        os.close(fd)  # the holder removed the file between our open and our lock: again
    try:
        data = json.dumps(asdict(me)).encode("utf-8")
        with contextlib.suppress(OSError):  # the holder's name is a courtesy, the lock is not
            os.ftruncate(fd, 0)
            os.pwrite(fd, data, 0)
        log.debug("%s: locked (%s)", lock, me.describe())
        _remove_leftovers(real_path(path))
        yield me
    finally:
        with contextlib.suppress(OSError):
            os.unlink(lock)  # while still held: a waiting opener then sees another inode
        os.close(fd)


def _remove_leftovers(path: Path) -> None:
    """Remove the staged files a write killed before its renames left beside the profile and
    its history index (``ucal.files.stage``): the lock is held, so no write of ours is under
    way. The profile and the index themselves were never touched by such a write."""
    for target in (path, history_dir(path) / HISTORY_INDEX):
        for tmp in files.staged_leftovers(target):
            try:
                tmp.unlink()
            except FileNotFoundError:
                continue
            except OSError as e:
                log.warning("%s: cannot remove what a killed write left: %s", tmp, e.strerror)
                continue
            log.info("%s: removed, left by a write that was killed", tmp)


def check_writable(path: str | Path, min_free_bytes: int = MIN_FREE_BYTES) -> None:
    """Preflight before the first motion: the profile's directory and its history directory
    must be writable and hold room for the write; else ``ProfileError`` (exit 2) naming the
    directory. ``min_free_bytes`` is the margin over three times the profile's size."""
    p = real_path(path)
    hdir = history_dir(p)
    try:
        size = p.stat().st_size
    except OSError:
        size = 0
    need = 3 * size + int(min_free_bytes)
    for directory, what in ((p.parent, "profile directory"), (hdir, "history directory")):
        if not directory.exists():
            if directory == hdir:
                continue  # created by the first write, in the profile directory checked above
            raise ProfileError(directory, None, f"{what} of {p.name} does not exist")
        if not directory.is_dir():
            raise ProfileError(directory, None, f"{what} of {p.name} is not a directory")
        if not os.access(directory, os.W_OK | os.X_OK):
            raise ProfileError(
                directory,
                None,
                f"{what} is not writable: the results for "
                f"{p.name} could not be written after the run",
            )
        try:
            free = shutil.disk_usage(directory).free
        except OSError as e:
            raise ProfileError(
                directory, None, f"cannot check free space: {e.strerror or e}"
            ) from None
        if free < need:
            raise ProfileError(
                directory,
                None,
                f"{what} has {free} bytes free, {need} needed to write {p.name} and its history",
            )
