"""The cell's queue: one atomic file per message, sent oldest first, removed only once the
broker acknowledged it; a broker that is down or a run killed before the acknowledgement loses
nothing (a broker stand-in here; tests/system/test_fleet_publish.py runs a real one)."""

from __future__ import annotations

import json
import os
from collections.abc import Iterator
from contextlib import contextmanager
from datetime import UTC, datetime
from pathlib import Path

import pytest

from ucal import files
from ucal.fleet.message import CellState, Finished
from ucal.fleet.mqtt import BrokerError
from ucal.fleet.outbox import STATE_FILE, Outbox, outbox_dir
from ucal.fleet.publish import Delivery, deliver_queue, prepare, publish
from ucal.fleet.url import BrokerUrl, parse_broker_url
from ucal.profile import default_profile_text

URL = parse_broker_url("mqtt://127.0.0.1:1883/plant")
T0 = datetime(2025, 3, 1, 8, 0, tzinfo=UTC)


class Killed(BaseException):
    """The process dies where this is raised (nothing after it runs)."""


class StandInBroker:
    """Acknowledges what it is sent, until told to fail at a given send."""

    def __init__(self) -> None:
        self.sent: list[tuple[str, dict, bool]] = []
        self.fail_at: int | None = None  # index of the send that is not acknowledged
        self.kill_after: int | None = None  # index of the send after whose PUBACK we die
        self.down = False
        self.connections = 0

    @contextmanager
    def link(self, url: BrokerUrl) -> Iterator[StandInBroker]:
        if self.down:
            raise BrokerError(f"cannot connect to {url.host}:{url.port}: Connection refused")
        self.connections += 1
        yield self

    def send(self, topic: str, payload: bytes, retain: bool) -> None:
        n = len(self.sent)
        if self.fail_at is not None and n >= self.fail_at:
            raise BrokerError("the broker closed the connection")
        self.sent.append((topic, json.loads(payload), retain))
        if self.kill_after is not None and n == self.kill_after:
            raise Killed

    def results(self) -> list[int]:
        return [m["sequence"] for t, m, _ in self.sent if t.endswith("/result")]


@pytest.fixture
def profile(tmp_path: Path) -> Path:
    path = tmp_path / "cell-7.toml"
    path.write_text(default_profile_text("tx90l"), encoding="utf-8")
    return path


def finished(code: int = 0) -> Finished:
    return Finished("check", code, "", {"verdict": "ok"}, True, code == 1, False)


def queued(profile: Path) -> list[str]:
    return sorted(p.name for p in outbox_dir(profile).glob("*.json") if p.name != STATE_FILE)


def test_the_queue_is_beside_the_profile_in_its_history_folder(profile: Path) -> None:
    assert outbox_dir(profile) == profile.parent / "cell-7.toml.history" / "outbox"


def test_a_broker_that_is_down_leaves_every_result_queued_in_order(profile: Path) -> None:
    broker = StandInBroker()
    broker.down = True
    publication = prepare(URL, profile)
    for _ in range(3):
        delivery = publish(publication, finished(), link=broker.link)
        assert not delivery.complete and "Connection refused" in (delivery.error or "")
    assert queued(profile) == ["0000000001.json", "0000000002.json", "0000000003.json"]
    assert delivery.waiting == 3 and delivery.outbox == outbox_dir(profile)
    broker.down = False
    delivery = publish(publication, finished(), link=broker.link)
    assert delivery.complete and delivery.delivered == 4 and delivery.waiting == 0
    assert broker.results() == [1, 2, 3, 4]
    assert queued(profile) == []
    # the latest state, retained, once: the newest message
    states = [(m["sequence"], retain) for t, m, retain in broker.sent if t.endswith("/state")]
    assert states == [(4, True)]
    assert all(t == "plant/cell-7/result" for t, _, r in broker.sent if not r)


def test_the_files_are_written_whole_with_nothing_staged_left(profile: Path) -> None:
    broker = StandInBroker()
    broker.down = True
    publish(prepare(URL, profile), finished(), link=broker.link)
    names = sorted(os.listdir(outbox_dir(profile)))
    assert [n for n in names if n.endswith(files.STAGED_SUFFIX)] == []
    message = json.loads((outbox_dir(profile) / "0000000001.json").read_bytes())
    assert message["cell"] == "cell-7" and message["sequence"] == 1
    state = json.loads((outbox_dir(profile) / STATE_FILE).read_bytes())
    assert state["sequence"] == 1


def test_a_write_that_fails_queues_nothing_and_says_so(
    profile: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    def full(path: Path, data: bytes, mode: int | None = None) -> Path:
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(files, "stage", full)
    delivery = publish(prepare(URL, profile), finished(), link=StandInBroker().link)
    assert delivery.queued is None and "No space left" in (delivery.error or "")
    assert queued(profile) == []


def test_a_run_killed_between_the_write_and_the_acknowledgement_keeps_the_message(
    profile: Path,
) -> None:
    """Killed once the broker has the first message but before its file is removed: the next
    run sends it again (the subscriber sees its id twice and keeps one), then the rest."""
    broker = StandInBroker()
    broker.down = True
    publication = prepare(URL, profile)
    publish(publication, finished(), link=broker.link)
    publish(publication, finished(), link=broker.link)
    broker.down = False
    broker.kill_after = 0
    with pytest.raises(Killed):
        publish(publication, finished(), link=broker.link)
    assert queued(profile) == ["0000000001.json", "0000000002.json", "0000000003.json"]
    broker.kill_after = None
    delivery = publish(publication, finished(), link=broker.link)
    assert delivery.complete and queued(profile) == []
    assert broker.results() == [1, 1, 2, 3, 4]
    ids = [m["message_id"] for t, m, _ in broker.sent if t.endswith("/result")]
    assert ids[0] == ids[1] and len(set(ids)) == 4  # the consumer's dedupe key


def test_a_connection_lost_midway_keeps_what_was_not_acknowledged(profile: Path) -> None:
    broker = StandInBroker()
    broker.down = True
    publication = prepare(URL, profile)
    for _ in range(3):
        publish(publication, finished(), link=broker.link)
    broker.down = False
    broker.fail_at = 2  # messages 1 and 2 acknowledged, 3 not
    delivery = publish(publication, finished(), link=broker.link)
    assert delivery.delivered == 2 and delivery.waiting == 2
    assert queued(profile) == ["0000000003.json", "0000000004.json"]
    broker.fail_at = None
    assert deliver_queue(URL, Outbox(outbox_dir(profile)), broker.link) == (2, None)
    assert broker.results() == [1, 2, 3, 4]


def test_numbering_goes_on_from_the_queued_files_when_the_state_is_lost(profile: Path) -> None:
    """A crash between a message's file and the state's: the file still counts."""
    broker = StandInBroker()
    broker.down = True
    publication = prepare(URL, profile)
    publish(publication, finished(), link=broker.link)
    publish(publication, finished(), link=broker.link)
    (outbox_dir(profile) / STATE_FILE).unlink()
    publish(publication, finished(), link=broker.link)
    assert queued(profile)[-1] == "0000000003.json"


def test_a_file_that_is_no_message_is_set_aside_and_the_rest_delivered(profile: Path) -> None:
    broker = StandInBroker()
    broker.down = True
    publication = prepare(URL, profile)
    publish(publication, finished(), link=broker.link)
    (outbox_dir(profile) / "0000000001.json").write_text("{not json", encoding="utf-8")
    broker.down = False
    delivery = publish(publication, finished(), link=broker.link)
    assert delivery.complete and broker.results() == [2]
    assert (outbox_dir(profile) / "0000000001.json.bad").exists()


def test_a_queue_another_process_delivers_is_left_to_it(profile: Path) -> None:
    broker = StandInBroker()
    outbox = Outbox(outbox_dir(profile))
    outbox.enqueue(lambda s: ({"message_id": "a" * 32, "cell": "c"}, CellState(s.sequence + 1)))
    with outbox.delivering() as held:
        assert held
        assert deliver_queue(URL, outbox, broker.link) == (
            0,
            "another ucal process is delivering the cell's queue",
        )
    assert deliver_queue(URL, outbox, broker.link) == (1, None)


def test_an_interrupted_run_queues_without_sending(profile: Path) -> None:
    broker = StandInBroker()
    delivery: Delivery = publish(prepare(URL, profile), finished(130), deliver=False)
    assert delivery.queued is not None and delivery.error == "not sent"
    assert broker.sent == [] and queued(profile) == ["0000000001.json"]
