"""Publish a run's final result: queue it in the cell's outbox, then deliver the outbox in order.

``prepare`` is called before anything moves: it reads the profile's ``[cell]`` table and
refuses a cell that cannot be named in a topic (``InputError``, exit 2). ``publish`` is called
once the result is final (in tolerance, out of tolerance, or standing after a late signal):
it writes the message to the queue (``ucal.fleet.outbox``) and sends every queued message of
the cell, oldest first, each to ``PREFIX/CELL/result``, the newest also to the retained
``PREFIX/CELL/state``, removing each file once the broker acknowledged it. Nothing here
raises: what went wrong is in the returned ``Delivery``, and the run's outcome and exit code
are the command's alone.
"""

from __future__ import annotations

import hashlib
import logging
from collections.abc import Callable
from contextlib import AbstractContextManager
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path

from ucal import interrupt
from ucal.errors import UcalError
from ucal.fleet.message import Finished, build_message
from ucal.fleet.mqtt import BrokerError, Link, MqttLink
from ucal.fleet.outbox import Outbox, outbox_dir
from ucal.fleet.url import BrokerUrl
from ucal.profile.cell import CellSettings, cell_settings
from ucal.profile.disk import real_path
from ucal.profile.validation import parse_toml_bytes

log = logging.getLogger(__name__)

#: Opens the broker link for one delivery (``MqttLink``; a test gives its own).
LinkFactory = Callable[[BrokerUrl], AbstractContextManager[Link]]


@dataclass(frozen=True)
class Publication:
    """Where a run's result is published: the broker, the profile and the cell's queue."""

    url: BrokerUrl
    profile_path: Path
    cell: CellSettings
    outbox: Outbox


@dataclass(frozen=True)
class Delivery:
    """What became of a published result."""

    queued: Path | None  # the result's message file (None: it could not be queued)
    delivered: int  # messages the broker acknowledged in this run, this one included
    waiting: int  # messages left in the queue
    error: str | None  # why not everything was delivered (None: all was)
    outbox: Path

    @property
    def complete(self) -> bool:
        return self.error is None


def prepare(url: BrokerUrl, profile_path: Path) -> Publication:
    """The publication of a run on the profile at ``profile_path``, checked before the run:
    ``ProfileError``/``InputError`` (exit 2) for a profile that cannot be read or a cell that
    cannot be named in a topic."""
    path = real_path(profile_path)
    data = parse_toml_bytes(_read(path), profile_path)
    cell = cell_settings(Path(profile_path), data)
    return Publication(url, Path(profile_path), cell, Outbox(outbox_dir(profile_path)))


def _read(path: Path) -> bytes:
    try:
        return path.read_bytes()
    except OSError as e:
        raise UcalError(f"{path}: cannot read: {e.strerror or e}") from None


def publish(
    publication: Publication,
    done: Finished,
    deliver: bool = True,
    link: LinkFactory = MqttLink,
    now: datetime | None = None,
) -> Delivery:
    """Queue ``done``'s message and, with ``deliver``, send the cell's queue in order."""
    outbox = publication.outbox
    try:
        raw = _read(real_path(publication.profile_path))
        path = publication.profile_path
        cell = cell_settings(path, parse_toml_bytes(raw, path))
        digest = hashlib.sha256(raw).hexdigest()
        when = now or datetime.now(UTC)
        queued, _ = outbox.enqueue(lambda state: build_message(done, cell, digest, state, when))
    except (OSError, UcalError) as e:
        why = f"{e.strerror or e}" if isinstance(e, OSError) else str(e)
        return Delivery(None, 0, len(outbox.pending()), f"not queued: {why}", outbox.directory)
    if not deliver:
        return Delivery(queued, 0, len(outbox.pending()), "not sent", outbox.directory)
    delivered, error = deliver_queue(publication.url, outbox, link)
    return Delivery(queued, delivered, len(outbox.pending()), error, outbox.directory)


def deliver_queue(
    url: BrokerUrl, outbox: Outbox, link: LinkFactory = MqttLink
) -> tuple[int, str | None]:
    """Send ``outbox``'s messages to the broker at ``url``, oldest first, until none is left;
    return how many the broker acknowledged and why it stopped early (None: it did not)."""
    delivered = 0
    with outbox.delivering() as held:
        if not held:
            return 0, "another ucal process is delivering the cell's queue"
        try:
            with link(url) as broker:
                while batch := outbox.pending():
                    for i, path in enumerate(batch):
                        if interrupt.received:
                            return delivered, "interrupted"
                        item = outbox.read(path)
                        if item is None:
                            continue
                        data, message = item
                        cell = message["cell"]
                        broker.send(url.result_topic(cell), data, retain=False)
                        if i == len(batch) - 1:  # the newest: the cell's latest state
                            broker.send(url.state_topic(cell), data, retain=True)
                        outbox.remove(path)
                        delivered += 1
        except BrokerError as e:
            return delivered, str(e)
        except OSError as e:
            return delivered, f"{e.strerror or e}"
    return delivered, None
