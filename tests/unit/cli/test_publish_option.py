"""``--publish URL`` on the moving commands and ``ucal fleet``: a bad URL or cell name is refused
before anything runs; a broker that is down leaves the result queued with one warning and the
exit code unchanged; a result out of tolerance is published too; a dry run publishes nothing.
(A real broker: tests/system/test_fleet_publish.py.)"""

from __future__ import annotations

import json
import socket
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import click
import pytest

from ucal.cell_choice import CellChoice
from ucal.cli.procedure import finish
from ucal.cli.publishing import prepare_publication
from ucal.errors import OutOfToleranceError
from ucal.fleet.outbox import outbox_dir
from ucal.fleet.url import parse_broker_url
from ucal.procedure import Outcome, RunOptions

RunMain = Callable[[list[str]], tuple[int, str, str]]


@pytest.fixture
def no_broker() -> Iterator[str]:
    """A broker URL whose port is held but not listened on: a connection is refused at once."""
    with socket.socket() as held:
        held.bind(("127.0.0.1", 0))
        yield f"mqtt://127.0.0.1:{held.getsockname()[1]}/plant"


def messages(profile: Path) -> list[dict[str, Any]]:
    directory = outbox_dir(profile)
    return [json.loads(p.read_bytes()) for p in sorted(directory.glob("0*.json"))]


@pytest.mark.parametrize("command", ["calibrate", "tool-frame", "verify", "check"])
def test_every_moving_command_takes_publish_and_its_environment_variable(
    command: str, run_main: RunMain
) -> None:
    code, out, _ = run_main([command, "--help"])
    assert code == 0
    assert "--publish URL" in out and "UCAL_PUBLISH" in out


@pytest.mark.parametrize(
    "url", ["tcp://127.0.0.1:1883/ucal", "mqtt://127.0.0.1:1883/plant/+", "mqtt://:1883"]
)
def test_a_bad_broker_url_is_a_usage_error_before_anything_runs(
    profile: Path, url: str, run_main: RunMain
) -> None:
    before = profile.read_bytes()
    code, out, err = run_main(["check", str(profile), "--sim", "--yes", "--json", "--publish", url])
    assert code == 2 and "--publish" in err
    assert json.loads(out)["exit_code"] == 2
    assert profile.read_bytes() == before and not outbox_dir(profile).exists()


def test_a_bad_broker_url_in_the_environment_names_the_variable(
    profile: Path, run_main: RunMain, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("UCAL_PUBLISH", "http://broker/ucal")
    code, _, err = run_main(["check", str(profile), "--sim", "--yes"])
    assert code == 2 and "UCAL_PUBLISH" in err


def test_a_cell_name_that_is_no_topic_level_is_refused_naming_the_key(
    profile: Path, run_main: RunMain, no_broker: str
) -> None:
    profile.write_text(profile.read_text() + '\n[cell]\nname = "line/3"\n', encoding="utf-8")
    code, _, err = run_main(["check", str(profile), "--sim", "--yes", "--publish", no_broker])
    assert code == 2 and "cell.name" in err and "'/'" in err
    assert not outbox_dir(profile).exists()


def test_a_broker_that_is_down_queues_the_result_and_keeps_the_exit_code(
    profile: Path, run_main: RunMain, no_broker: str
) -> None:
    args = ["check", str(profile), "--sim", "--yes", "--json", "--publish", no_broker]
    code, out, err = run_main(args)
    assert code == 0, err
    result = json.loads(out)  # stdout is still the one result object
    warnings = [ln for ln in err.splitlines() if ln.startswith("warning:")]
    assert len(warnings) == 1 and "queued in" in warnings[0], err
    assert str(outbox_dir(profile)) in warnings[0] and "Connection refused" in warnings[0]
    (message,) = messages(profile)
    assert message["result"] == json.loads(json.dumps(result))
    assert message["cell"] == "cell" and message["command"] == "check"
    assert message["exit_code"] == 0 and message["simulated"] is True
    assert message["calibration_target"]["quality"] == "ok"


def test_a_dry_run_publishes_nothing(profile: Path, run_main: RunMain, no_broker: str) -> None:
    code, _, err = run_main(["check", str(profile), "--dry-run", "--yes", "--publish", no_broker])
    assert code == 0, err
    assert "a dry run writes nothing: its result is not published" in err
    assert not outbox_dir(profile).exists()


@dataclass
class _Result:
    def to_json(self) -> dict[str, Any]:
        return {"verdict": "moved", "moved": ["J2"], "written": False}


@dataclass
class _Job:
    profile_path: Path


def test_a_result_out_of_tolerance_is_published_before_the_exit_1(
    profile: Path, no_broker: str
) -> None:
    url = parse_broker_url(no_broker)
    outcome: Outcome[Any] = Outcome(
        "check", _Result(), written=False, out_of_tolerance=True, message="J2 moved"
    )
    with click.Context(click.Command("check")) as ctx:
        ctx.meta["publish_url"] = url
        options = RunOptions(CellChoice(None, "tcp://192.0.2.7:11000", "modbus-tcp://x:502"))
        prepare_publication(_Job(profile), options)  # type: ignore[arg-type]
        with pytest.raises(OutOfToleranceError):
            finish(outcome, True, lambda o: None)
    (message,) = messages(profile)
    assert message["exit_code"] == 1 and message["message"] == "J2 moved"
    assert message["calibration_target"]["quality"] == "out_of_tolerance"
    assert message["simulated"] is False and message["result"]["moved"] == ["J2"]


def test_fleet_with_no_broker_is_a_communication_fault_naming_it(
    run_main: RunMain, no_broker: str
) -> None:
    code, out, err = run_main(["fleet", no_broker, "--json"])
    assert code == 3 and str(parse_broker_url(no_broker)) in err
    assert json.loads(out)["exit_code"] == 3


def test_fleet_refuses_a_bad_url(run_main: RunMain) -> None:
    code, _, err = run_main(["fleet", "http://broker/ucal"])
    assert code == 2 and "mqtt://" in err
