"""A cell's durable queue of messages to publish: ``PROFILE.history/outbox/``.

Each message is one file, ``NNNNNNNNNN.json`` (its sequence number, ten digits, so that the
names sort in the order the results were made), written atomically as the profile is
(``ucal.files``: a staged, fsync'ed temporary file renamed into place), and removed only once the
broker acknowledged it (QoS 1 PUBACK). A run that is killed, or a broker that is down, leaves
the files; the next run that publishes for the cell sends them first, oldest first. ``state.json``
beside them holds the cell's last sequence number, last validation and latest results in brief
(``ucal.fleet.message.CellState``). Two locks keep two ucal processes on one cell apart: one held
while a message is numbered and written (short, waited for), one held while the queue is
delivered (not waited for: whoever holds it delivers what the other queued).
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import json
import logging
import os
import re
from collections.abc import Callable, Iterator, Mapping
from pathlib import Path
from typing import Any

from ucal import files
from ucal.fleet.message import CellState, encode
from ucal.profile.disk import history_dir

log = logging.getLogger(__name__)

#: The queue's folder inside the profile's history folder.
OUTBOX = "outbox"
STATE_FILE = "state.json"
#: A queued message's file name: its sequence number.
MESSAGE_NAME = re.compile(r"([0-9]{10})\.json")
#: A message file that could not be read as one (kept aside, never sent).
BAD_SUFFIX = ".bad"
_NUMBER_LOCK = ".number.lock"
_DELIVER_LOCK = ".deliver.lock"


def outbox_dir(profile_path: str | Path) -> Path:
    """The queue of the profile at ``profile_path``: ``cell.toml.history/outbox``."""
    return history_dir(profile_path) / OUTBOX


def message_path(directory: Path, sequence: int) -> Path:
    return directory / f"{sequence:010d}.json"


class Outbox:
    """The queue in ``directory`` (made when the first message is queued)."""

    def __init__(self, directory: Path) -> None:
        self.directory = Path(directory)

    def enqueue(
        self, make: Callable[[CellState], tuple[Mapping[str, Any], CellState]]
    ) -> tuple[Path, Mapping[str, Any]]:
        """Queue the message ``make`` builds from the cell's state; return its file and the
        message. The state after it is written once the message file is in place; a file
        left without its state (a crash between the two) still counts for the numbering."""
        self.directory.mkdir(parents=True, exist_ok=True)
        with self._lock(_NUMBER_LOCK, wait=True):
            self._remove_staged()
            state = self.state()
            state.sequence = max(state.sequence, self._highest())
            message, after = make(state)
            path = message_path(self.directory, after.sequence)
            files.commit(files.stage(path, encode(message)), path)
            state_path = self.directory / STATE_FILE
            data = json.dumps(after.to_json(), indent=1).encode("utf-8")
            files.commit(files.stage(state_path, data), state_path)
        return path, message

    def state(self) -> CellState:
        """The cell's state as the last queued message left it (a fresh one if none)."""
        path = self.directory / STATE_FILE
        try:
            data = json.loads(path.read_bytes())
        except FileNotFoundError:
            return CellState()
        except (OSError, ValueError) as e:
            log.warning("%s: unreadable (%s): numbering goes on from the queued files", path, e)
            return CellState()
        return CellState.from_json(data) if isinstance(data, dict) else CellState()

    def pending(self) -> list[Path]:
        """The queued messages, oldest first."""
        try:
            names = os.listdir(self.directory)
        except FileNotFoundError:
            return []
        return [self.directory / n for n in sorted(names) if MESSAGE_NAME.fullmatch(n)]

    def read(self, path: Path) -> tuple[bytes, dict[str, Any]] | None:
        """A queued message's bytes and the message; None, with the file set aside as ``.bad``
        (and a warning), for one that is not a message (a hand edit, a disk fault)."""
        try:
            data = path.read_bytes()
            message = json.loads(data)
            if not isinstance(message, dict):
                raise TypeError("not a JSON object")
            if not isinstance(message.get("message_id"), str):
                raise TypeError("no message_id")
            if not isinstance(message.get("cell"), str):
                raise TypeError("no cell")
        except FileNotFoundError:
            return None  # delivered by another process meanwhile
        except (OSError, ValueError, TypeError, KeyError) as e:
            aside = path.with_name(path.name + BAD_SUFFIX)
            with contextlib.suppress(OSError):
                os.replace(path, aside)
            log.warning("%s is no message (%s): set aside as %s, not sent", path, e, aside.name)
            return None
        return data, message

    def remove(self, path: Path) -> None:
        """Remove a message the broker acknowledged (durably: the folder is synced)."""
        with contextlib.suppress(FileNotFoundError):
            path.unlink()
        files.fsync_dir(self.directory)

    @contextlib.contextmanager
    def delivering(self) -> Iterator[bool]:
        """Hold the right to deliver the queue; yields False when another process holds it."""
        self.directory.mkdir(parents=True, exist_ok=True)
        with self._lock(_DELIVER_LOCK, wait=False) as held:
            yield held

    @contextlib.contextmanager
    def _lock(self, name: str, wait: bool) -> Iterator[bool]:
        fd = os.open(self.directory / name, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o666)
        try:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | (0 if wait else fcntl.LOCK_NB))
            except OSError as e:
                if wait or e.errno not in (errno.EWOULDBLOCK, errno.EAGAIN):
                    raise
                yield False
                return
            yield True
        finally:
            os.close(fd)  # closing releases the lock

    def _highest(self) -> int:
        numbers = [int(m.group(1)) for p in self.pending() if (m := MESSAGE_NAME.fullmatch(p.name))]
        return max(numbers, default=0)

    def _remove_staged(self) -> None:
        """Staged files a killed write left (only the numbering lock's holder stages)."""
        for name in os.listdir(self.directory):
            if name.startswith(".") and name.endswith(files.STAGED_SUFFIX):
                with contextlib.suppress(OSError):
                    os.unlink(self.directory / name)
