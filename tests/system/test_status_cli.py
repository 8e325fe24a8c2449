"""``ucal status`` against the simulated controller and pulser on 127.0.0.1: fields, no motion."""

from __future__ import annotations

import json
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from drivers.pulser.base import PulserSettings
from drivers.pulser.modbus import ModbusPulser
from drivers.pulser.simulator import DEVICE_INFO
from ucal.profile import default_profile_text, load_profile
from ucal.sim.demo import demo_world
from ucal.sim.serve import SimulatedCellServer

pytestmark = pytest.mark.system

RunMain = Callable[[list[str]], tuple[int, str, str]]


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[SimulatedCellServer]:
    path = tmp_path_factory.mktemp("status") / "cell.toml"
    path.write_text(default_profile_text("tx90l"), encoding="utf-8")
    with SimulatedCellServer(None, load_profile(path), time_scale=0.0) as cell:
        yield cell


def test_json_reports_joints_controller_and_pulser_and_moves_nothing(
    server: SimulatedCellServer, run_main: RunMain
) -> None:
    urls = server.urls
    wanted = PulserSettings(gain_db=33.0, pulse_voltage_v=200.0, low_pass_mhz=40.0)
    with ModbusPulser.from_url(urls["pulser"]) as pulser:
        pulser.configure(wanted)
    moves, stops, motions = (
        server.controller.moves_executed,
        server.controller.stops_received,
        server.motions,
    )

    code, out, err = run_main(
        ["status", "--controller", urls["controller"], "--pulser", urls["pulser"], "--json"]
    )

    assert code == 0, err
    result = json.loads(out)
    assert set(result) == {"joints_deg", "controller", "pulser"}
    assert result["joints_deg"] == pytest.approx(list(server.world.initial_joints_deg), abs=1e-4)
    stream = result["controller"].pop("stream")
    assert result["controller"] == {
        "endpoint": urls["controller"],
        "drives_powered": True,
        "e_stopped": False,
        "in_motion": False,
        "in_error": False,
        "error_code": 0,
        "mode": "auto",
        "motion_possible": True,
    }
    # the plain simulated server: STATUS with every frame, no VAL3 server
    assert (stream["joint_message"], stream["status_every"], stream["server"]) == (
        "JOINT_POSITION",
        1,
        "unknown",
    )
    pulser = result["pulser"]
    assert pulser["endpoint"] == urls["pulser"]
    assert pulser["register_map_version"] == 2
    assert (pulser["model"], pulser["firmware"], pulser["serial"]) == (
        DEVICE_INFO.model,
        DEVICE_INFO.firmware_version,
        DEVICE_INFO.serial,
    )
    assert pulser["settings"] == pytest.approx(
        {
            "gain_db": 33.0,
            "prf_hz": 1000.0,
            "gate_start_us": 5.0,
            "gate_width_us": 200.0,
            "averages": 1,
            "pulse_voltage_v": 200.0,
            "damping_ohm": 50.0,
            "high_pass_mhz": 1.0,
            "low_pass_mhz": 40.0,
        }
    )
    assert pulser["gate_threshold"] == pytest.approx(0.02)
    # nothing moved, and not even STOP was sent
    assert (server.controller.moves_executed, server.controller.stops_received, server.motions) == (
        moves,
        stops,
        motions,
    )


def test_the_released_val3_server_is_recognised_by_its_stream(
    tmp_path: Path, run_main: RunMain
) -> None:
    path = tmp_path / "cell.toml"
    path.write_text(default_profile_text("tx90l"), encoding="utf-8")
    profile = load_profile(path)
    world = demo_world(profile).replace(controller_silence_s=0.3)
    with SimulatedCellServer(world, profile, time_scale=0.0, server="val3") as cell:
        code, out, err = run_main(["status", "--controller", cell.urls["controller"], "--json"])
    assert code == 0, err
    stream = json.loads(out)["controller"]["stream"]
    assert (stream["joint_message"], stream["status_every"]) == ("JOINT_POSITION", 5)
    assert stream["joint_rate_hz"] == pytest.approx(50.0, rel=0.2)
    assert stream["first_state_s"] >= 0.3
    assert stream["server"] == "VAL3 ros_server, released (staubli_val3_driver master)"


def test_urls_from_the_environment_and_human_output(
    server: SimulatedCellServer, monkeypatch: pytest.MonkeyPatch, run_main: RunMain
) -> None:
    monkeypatch.setenv("UCAL_CONTROLLER", server.urls["controller"])
    monkeypatch.setenv("UCAL_PULSER", server.urls["pulser"])
    code, out, err = run_main(["status"])
    assert code == 0, err
    for text in (
        server.urls["controller"],
        "powered",
        "released",
        "at rest",
        "auto",
        "JOINT_POSITION at",
        DEVICE_INFO.model,
        "pulse_voltage_v",
        "damping_ohm",
    ):
        assert text in out


def test_without_a_pulser_the_pulser_is_null(
    server: SimulatedCellServer, run_main: RunMain
) -> None:
    code, out, _ = run_main(["status", "--controller", server.urls["controller"], "--json"])
    assert code == 0
    assert json.loads(out)["pulser"] is None


def test_an_engaged_emergency_stop_is_shown_not_a_failure(
    server: SimulatedCellServer, run_main: RunMain
) -> None:
    server.controller.set_fault(e_stopped=True)
    try:
        code, out, _ = run_main(["status", "--controller", server.urls["controller"]])
    finally:
        server.controller.set_fault(e_stopped=False)
    assert code == 0
    assert "ENGAGED" in out


def test_unreachable_pulser_is_exit_3_naming_it(
    server: SimulatedCellServer, tmp_path: Path, run_main: RunMain
) -> None:
    dead = "modbus-tcp://127.0.0.1:1?unit=1"
    code, out, err = run_main(
        ["status", "--controller", server.urls["controller"], "--pulser", dead, "--json"]
    )
    assert code == 3
    assert json.loads(out) == {"error": json.loads(out)["error"], "exit_code": 3}
    assert json.loads(out)["error"].startswith(f"pulser at {dead}: ")
    assert err.strip().splitlines() == [f"error: {json.loads(out)['error']}"]


def test_silent_pulser_is_exit_3_naming_it(server: SimulatedCellServer, run_main: RunMain) -> None:
    server.pulser.set_silent(True)
    try:
        code, _, err = run_main(
            ["status", "--controller", server.urls["controller"], "--pulser", server.urls["pulser"]]
        )
    finally:
        server.pulser.set_silent(False)
    assert code == 3
    assert err.startswith(f"error: pulser at {server.urls['pulser']}: ")
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1


def test_unreachable_controller_is_exit_3_naming_it(run_main: RunMain) -> None:
    code, out, _ = run_main(["status", "--controller", "tcp://127.0.0.1:1?state=2", "--json"])
    assert code == 3
    assert json.loads(out)["error"].startswith("controller at tcp://127.0.0.1:1?state=2: ")
    assert json.loads(out)["exit_code"] == 3


@pytest.mark.parametrize(
    ("args", "message"),
    [
        ([], "give --controller URL (or set UCAL_CONTROLLER)"),
        (["--controller", "udp://10.0.0.1:11000"], "unknown controller URL scheme 'udp'"),
        (
            ["--controller", "tcp://10.0.0.1:11000", "--pulser", "gpib://3"],
            "unknown pulser URL scheme 'gpib'",
        ),
    ],
)
def test_missing_or_malformed_urls_are_exit_2(
    args: list[str], message: str, monkeypatch: pytest.MonkeyPatch, run_main: RunMain
) -> None:
    monkeypatch.delenv("UCAL_CONTROLLER", raising=False)
    monkeypatch.delenv("UCAL_PULSER", raising=False)
    code, out, err = run_main(["status", *args, "--json"])
    assert code == 2
    assert message in json.loads(out)["error"] and json.loads(out)["exit_code"] == 2
    assert "Traceback" not in err
