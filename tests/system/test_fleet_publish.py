"""Results published to a real broker (Debian's mosquitto on 127.0.0.1, started here) while it
is stopped and restarted: every result of every cell reaches a subscriber once, in order.

100 publications from 10 cells go through the code path ``--publish`` takes
(``ucal.fleet.publish``): the first is a real ``ucal check --sim --publish`` run through the
command line, the others publish its result object again for each cell. The broker is stopped
(SIGTERM: it saves its sessions, as a plant's broker is shut down) and started again twice
during the run; the cells whose results were queued meanwhile deliver them, oldest first, at
their next publication. A subscriber with a persistent session counts what it receives, per
cell, dropping a message id it already holds (QoS 1 delivers at least once); every payload is
validated against the shipped schema. ``ucal fleet`` then lists the cells from their retained
states. Skipped where ``mosquitto`` is not installed (``.ci/run`` installs it).
"""

from __future__ import annotations

import contextlib
import getpass
import json
import shutil
import signal
import socket
import subprocess
import threading
import time
from collections.abc import Callable, Iterator
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any

import pytest

from ucal.fleet.message import Finished, schema
from ucal.fleet.outbox import outbox_dir
from ucal.fleet.publish import Delivery, prepare, publish
from ucal.fleet.url import parse_broker_url
from ucal.profile import default_profile_text

pytestmark = pytest.mark.system

MOSQUITTO = shutil.which("mosquitto") or (
    "/usr/sbin/mosquitto" if Path("/usr/sbin/mosquitto").is_file() else None
)
#: Longest wait for anything the broker or the subscriber does (s): generous, never slept.
WAIT_S = 20.0
CELLS = 10
PUBLICATIONS = 100
#: Before which publication the broker is stopped, and before which it is started again.
STOPS = {30: 45, 65: 80}

RunMain = Callable[[list[str]], tuple[int, str, str]]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
        return port


class Broker:
    """mosquitto on 127.0.0.1:``port``, its configuration and persistence in ``directory``."""

    def __init__(self, directory: Path) -> None:
        self.port = free_port()
        self.directory = directory
        self.config = directory / "mosquitto.conf"
        self.config.write_text(
            f"listener {self.port} 127.0.0.1\n"
            "allow_anonymous true\n"
            "persistence true\n"
            f"persistence_location {directory}/\n"
            f"user {getpass.getuser()}\n"  # as root, mosquitto would become "mosquitto"
            f"log_dest file {directory}/mosquitto.log\n",
            encoding="utf-8",
        )
        self.process: subprocess.Popen[bytes] | None = None
        self.starts = 0

    def start(self) -> None:
        assert MOSQUITTO is not None
        self.process = subprocess.Popen(
            [MOSQUITTO, "-c", str(self.config)],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        self.starts += 1
        deadline = time.monotonic() + WAIT_S
        while time.monotonic() < deadline:
            assert self.process.poll() is None, self.log()
            with (
                contextlib.suppress(OSError),
                socket.create_connection(("127.0.0.1", self.port), timeout=1.0),
            ):
                return
            time.sleep(0.02)  # polling the port: the broker says nothing else when it listens
        raise AssertionError(f"mosquitto did not listen within {WAIT_S} s: {self.log()}")

    def stop(self) -> None:
        if self.process is None:
            return
        self.process.send_signal(signal.SIGTERM)
        self.process.wait(timeout=WAIT_S)
        self.process = None

    def log(self) -> str:
        path = self.directory / "mosquitto.log"
        return path.read_text(errors="replace")[-2000:] if path.exists() else ""


@pytest.fixture
def broker(tmp_path: Path) -> Iterator[Broker]:
    if MOSQUITTO is None:
        pytest.skip("mosquitto is not installed (apt-get install mosquitto)")
    directory = tmp_path / "broker"
    directory.mkdir()
    b = Broker(directory)
    b.start()
    try:
        yield b
    finally:
        b.stop()


class Subscriber:
    """A persistent-session subscriber to every cell's results that counts per cell."""

    def __init__(self, port: int, prefix: str) -> None:
        import paho.mqtt.client as mqtt
        from jsonschema import Draft202012Validator
        from paho.mqtt.enums import CallbackAPIVersion

        self.validator = Draft202012Validator(schema())
        self.cond = threading.Condition()
        self.ids: dict[str, list[str]] = {}
        self.sequences: dict[str, list[int]] = {}
        self.duplicates: dict[str, int] = {}
        self.invalid: list[str] = []
        self.connects = 0
        client = mqtt.Client(
            CallbackAPIVersion.VERSION2,
            client_id="fleet-test-counter",
            clean_session=False,
            protocol=mqtt.MQTTv311,
        )
        client.reconnect_delay_set(min_delay=0.05, max_delay=0.5)  # type: ignore[arg-type]

        def on_connect(client: Any, userdata: Any, flags: Any, reason: Any, props: Any) -> None:
            client.subscribe(f"{prefix}/+/result", qos=1)
            with self.cond:
                self.connects += 1
                self.cond.notify_all()

        def on_message(client: Any, userdata: Any, message: Any) -> None:
            payload = json.loads(message.payload)
            errors = [e.message for e in self.validator.iter_errors(payload)]
            with self.cond:
                self.invalid += errors
                cell, mid = payload["cell"], payload["message_id"]
                if mid in self.ids.setdefault(cell, []):
                    self.duplicates[cell] = self.duplicates.get(cell, 0) + 1
                else:
                    self.ids[cell].append(mid)
                    self.sequences.setdefault(cell, []).append(payload["sequence"])
                self.cond.notify_all()

        client.on_connect = on_connect
        client.on_message = on_message
        client.connect("127.0.0.1", port, keepalive=5)
        client.loop_start()
        self.client = client
        assert self.wait(lambda: self.connects >= 1), "the subscriber did not connect"

    def wait(self, done: Callable[[], bool]) -> bool:
        with self.cond:
            return self.cond.wait_for(done, WAIT_S)

    def received(self) -> int:
        return sum(len(v) for v in self.ids.values())

    def close(self) -> None:
        self.client.disconnect()
        self.client.loop_stop()


def cell_profile(directory: Path, i: int) -> Path:
    """Cell ``i``: odd ones named by a ``[cell]`` table (with a validation interval), even ones
    by their file's stem."""
    path = directory / f"cell-{i:02d}.toml"
    text = default_profile_text("tx90l")
    if i % 2:
        text += f'\n[cell]\nname = "line-{i:02d}"\nvalidation_interval_days = 30\n'
    path.write_text(text, encoding="utf-8")
    return path


@pytest.mark.long
def test_results_reach_a_subscriber_once_in_order_through_two_broker_restarts(
    broker: Broker,
    tmp_path: Path,
    run_main: RunMain,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    for name in ("UCAL_SIM", "UCAL_CONTROLLER", "UCAL_PULSER", "UCAL_PUBLISH"):
        monkeypatch.delenv(name, raising=False)
    prefix = "plant/ucal"
    url_text = f"mqtt://127.0.0.1:{broker.port}/{prefix}"
    url = parse_broker_url(url_text)
    profiles = [cell_profile(tmp_path, i) for i in range(CELLS)]
    subscriber = Subscriber(broker.port, prefix)
    try:
        # publication 0: a real check through the command line, published by it
        code, out, err = run_main(
            ["check", str(profiles[0]), "--sim", "--yes", "--json", "--publish", url_text]
        )
        assert code == 0, err
        result = json.loads(out)
        assert "published the check result" in err
        publications = {i: prepare(url, p) for i, p in enumerate(profiles)}
        names = {i: pub.cell.name for i, pub in publications.items()}
        queued_while_down = 0
        restarts = 0
        down = False
        for n in range(1, PUBLICATIONS):
            if n in STOPS:
                broker.stop()
                down = True
            if n in STOPS.values():
                broker.start()
                restarts += 1
                down = False
            i = n % CELLS
            done = Finished("check", 0, "", result, True, False, True)
            delivery: Delivery = publish(publications[i], done)
            if down:
                assert delivery.queued is not None and not delivery.complete, delivery
                queued_while_down += 1
            else:
                assert delivery.complete, (n, delivery, broker.log())
        assert restarts == 2 and broker.starts == 3
        assert queued_while_down == sum(b - a for a, b in STOPS.items())
        assert all(
            not outbox_dir(p).exists() or not list(outbox_dir(p).glob("0*.json")) for p in profiles
        ), "a queue was left undelivered"
        assert subscriber.wait(lambda: subscriber.received() >= PUBLICATIONS), (
            subscriber.sequences,
            broker.log(),
        )
        per_cell = PUBLICATIONS // CELLS
        report = {
            names[i]: {
                "delivered": len(subscriber.sequences.get(names[i], [])),
                "duplicates": subscriber.duplicates.get(names[i], 0),
                "lost": per_cell - len(subscriber.sequences.get(names[i], [])),
            }
            for i in range(CELLS)
        }
        with capsys.disabled():  # the measured numbers, shown with -s
            counts = {"restarts": restarts, "queued_while_down": queued_while_down}
            print("\n" + json.dumps({**counts, "cells": report}))
        assert subscriber.invalid == []
        for i in range(CELLS):
            assert subscriber.sequences[names[i]] == list(range(1, per_cell + 1)), names[i]
        assert sum(r["delivered"] for r in report.values()) == PUBLICATIONS
    finally:
        subscriber.close()

    # the fleet: every cell's latest state, retained through the restarts
    code, out, err = run_main(["fleet", url_text, "--json"])
    assert code == 0, err
    fleet = json.loads(out)
    assert [c["cell"] for c in fleet["cells"]] == sorted(names.values())
    now = datetime.now(UTC)
    for c in fleet["cells"]:
        assert c["sequence"] == PUBLICATIONS // CELLS and c["quality"] == "ok"
        assert c["trend"] == ["ok"] * 10
        if c["cell"].startswith("line-"):  # a validation interval: due in 30 days
            due = datetime.fromisoformat(c["next_validation"].replace("Z", "+00:00"))
            assert abs(due - (now + timedelta(days=30))) < timedelta(minutes=5)
        else:
            assert c["next_validation"] is None
    code, out, err = run_main(["fleet", url_text])
    assert code == 0, err
    for name in names.values():
        assert name in out
    assert "+" * 10 in out and "in 30 d" in out
