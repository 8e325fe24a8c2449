"""The ASCII serial pulser + SCPI oscilloscope back-end from the command line: a calibration of
a simulated ascii-scpi cell agrees with the Modbus back-end's on the same world, ``sim serve``
serves it, and the digitiser's URL is asked for where it is needed and only there."""

from __future__ import annotations

import json
import select
import signal
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from ucal.sim.demo import DEMO_JOINT_OFFSETS_DEG

from doubles import finished_json, noisy_world, std_of

pytestmark = pytest.mark.system

RunMain = Callable[[list[str]], tuple[int, str, str]]

OFFSETS_DEG = DEMO_JOINT_OFFSETS_DEG


def calibrate(tmp_path: Path, kind: str) -> subprocess.Popen[str]:
    """``ucal calibrate`` of a new profile against a simulated cell speaking ``kind``."""
    world = tmp_path / f"{kind}.toml"
    world.write_text(noisy_world(kind=kind, sample_rate_mhz=100.0))
    return subprocess.Popen(
        [sys.executable, "-m", "ucal", "calibrate", str(tmp_path / f"cell-{kind}.toml")]
        + ["--sim", str(world), "--yes", "--json", "-q"]
        + ["--record", str(tmp_path / f"{kind}.jsonl")],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        stdin=subprocess.DEVNULL,
        text=True,
    )


def test_the_ascii_scpi_cell_calibrates_as_the_modbus_cell_does(tmp_path: Path) -> None:
    runs = {kind: calibrate(tmp_path, kind) for kind in ("ascii-scpi", "modbus")}
    host, modbus = (finished_json(runs[k]) for k in ("ascii-scpi", "modbus"))
    assert host["written"] and host["fit"]["verdict"] == "ok"
    assert host["unobservable_joints"] == modbus["unobservable_joints"]
    reported = np.isfinite(std_of(host))
    # covered: the world's offsets within 3 reported sigmas
    error = np.abs(np.array(host["joint_offsets_deg"]) - OFFSETS_DEG)[reported]
    assert np.all(error <= 3 * std_of(host)[reported]), (error, std_of(host))
    # agreement: the two back-ends' estimates differ by less than 3 sigmas of their difference
    difference = np.abs(np.subtract(host["joint_offsets_deg"], modbus["joint_offsets_deg"]))
    both = np.hypot(std_of(host), std_of(modbus))[reported]
    assert np.all(difference[reported] <= 3 * both), (difference, both)
    # the host-timed run replays bit for bit: its reference capture's calls are replayed too
    replay = subprocess.run(
        [sys.executable, "-m", "ucal", "calibrate", str(tmp_path / "again.toml")]
        + ["--replay", str(tmp_path / "ascii-scpi.jsonl"), "--remeasure", "--json"],
        capture_output=True,
        text=True,
        stdin=subprocess.DEVNULL,
        check=False,
    )
    assert replay.returncode == 0, replay.stderr[-2000:]
    again = json.loads(replay.stdout)
    assert again["joint_offsets_deg"] == host["joint_offsets_deg"]
    assert again["std_deg"] == host["std_deg"]
    assert again["reference_echo"]["source"] == host["reference_echo"]["source"] == "captured"


def test_sim_serve_serves_the_ascii_scpi_cell_and_status_reads_it(
    run_main: RunMain, monkeypatch: pytest.MonkeyPatch
) -> None:
    proc = subprocess.Popen(
        [sys.executable, "-m", "ucal", "sim", "serve", "--pulser-kind", "ascii-scpi"]
        + ["--time-scale", "0"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        ready, _, _ = select.select([proc.stdout], [], [], 20.0)
        assert ready, "ucal sim serve printed nothing within 20 s"
        assert proc.stdout is not None
        urls = json.loads(proc.stdout.readline())
        assert set(urls) == {"controller", "pulser", "digitizer"}
        assert urls["pulser"].startswith("ascii://socket://127.0.0.1:")
        assert urls["digitizer"].startswith("visa://TCPIP::127.0.0.1::")
        monkeypatch.setenv("UCAL_DIGITIZER", urls["digitizer"])
        code, out, err = run_main(
            ["status", "--controller", urls["controller"], "--pulser", urls["pulser"], "--json"]
        )
        assert code == 0, err
        pulser = json.loads(out)["pulser"]
        assert pulser["digitizer"]["model"] == "SIMULATED SCOPE"
        assert pulser["settings"]["low_pass_mhz"] == 96.0  # L3 at power-on
    finally:
        proc.send_signal(signal.SIGTERM)
        proc.communicate(timeout=10)
    assert proc.returncode == 0


@pytest.mark.parametrize(
    "cell, message",
    [
        (
            ["--controller", "tcp://127.0.0.1:11000", "--pulser", "ascii:///dev/ttyUSB0"],
            "does not digitise: give its digitiser, --digitizer visa://RESOURCE",
        ),
        (
            ["--controller", "tcp://127.0.0.1:11000", "--pulser", "modbus-tcp://127.0.0.1:502"]
            + ["--digitizer", "visa://TCPIP::127.0.0.1::5025::SOCKET"],
            "--digitizer is for a pulser that does not digitise",
        ),
        (
            ["--controller", "tcp://127.0.0.1:11000", "--pulser", "ascii:///dev/ttyUSB0"]
            + ["--digitizer", "visa://TCPIP::127.0.0.1::SOCKET"],
            "not a VISA resource string",
        ),
        (["--sim", "--digitizer", "visa://TCPIP::127.0.0.1::5025::SOCKET"], "cannot be combined"),
    ],
)
def test_the_digitizer_is_asked_for_where_needed_and_only_there(
    run_main: RunMain, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, cell, message
) -> None:
    for name in ("UCAL_SIM", "UCAL_CONTROLLER", "UCAL_PULSER", "UCAL_DIGITIZER"):
        monkeypatch.delenv(name, raising=False)
    code, out, _ = run_main(["calibrate", str(tmp_path / "cell.toml"), *cell, "--yes", "--json"])
    assert code == 2
    assert message in json.loads(out)["error"]
