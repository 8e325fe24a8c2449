"""``calibrate --record`` / ``--replay``: a recorded run solves again offline, bit for bit."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import pytest

from ucal.record import read_record

pytestmark = pytest.mark.system


def ucal(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "ucal", *args],
        check=False,
        capture_output=True,
        text=True,
        cwd=cwd,
        stdin=subprocess.DEVNULL,
        timeout=300,
    )


@pytest.fixture(scope="module")
def recorded(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict]:
    d = tmp_path_factory.mktemp("record")
    out = ucal(
        "calibrate",
        "cell.toml",
        "--sim",
        "--yes",
        "--json",
        "--dry-run",
        "--record",
        "run.jsonl",
        cwd=d,
    )
    assert out.returncode in (0, 1), out.stderr
    return d, json.loads(out.stdout)


def test_replay_gives_the_recorded_result(recorded: tuple[Path, dict]) -> None:
    d, result = recorded
    record = read_record(d / "run.jsonl")
    assert record.result is not None
    assert record.result["joint_offsets_deg"] == result["joint_offsets_deg"]
    assert len(record.calls) > result["pulser_reads"]  # every reading, and more
    out = ucal("calibrate", "cell.toml", "--replay", "run.jsonl", "--json", cwd=d)
    assert out.returncode in (0, 1), out.stderr
    again = json.loads(out.stdout)
    assert again["joint_offsets_deg"] == result["joint_offsets_deg"]  # bit for bit
    assert again["std_deg"] == result["std_deg"]
    assert again["pulser_reads"] == result["pulser_reads"]
    assert again["written"] is False


def test_replay_with_another_method_solves_the_same_measurements(
    recorded: tuple[Path, dict], help_examples: Callable[[list[str]], list[tuple[dict, list[str]]]]
) -> None:
    d, result = recorded
    # as `ucal calibrate --help` shows it (every other example runs in test_help_examples)
    (args,) = [a for _, a in help_examples(["calibrate"]) if "--replay" in a]
    assert args == [
        "calibrate",
        "cell.toml",
        "--replay",
        "run.jsonl",
        "--method",
        "paper",
        "--json",
    ]
    out = ucal(*args, cwd=d)
    assert out.returncode in (0, 1), out.stderr
    paper = json.loads(out.stdout)
    assert paper["method"] == "paper"
    assert paper["moves"] == result["moves"] and paper["pulser_reads"] == result["pulser_reads"]


def test_replay_takes_no_cell(recorded: tuple[Path, dict]) -> None:
    d, _ = recorded
    out = ucal("calibrate", "cell.toml", "--replay", "run.jsonl", "--sim", cwd=d)
    assert out.returncode == 2
    assert "--replay" in out.stderr and "Traceback" not in out.stderr


def test_replay_asked_for_another_level_says_so(recorded: tuple[Path, dict]) -> None:
    d, _ = recorded
    before = sorted(p.name for p in d.iterdir())
    out = ucal(
        "calibrate", "cell.toml", "--replay", "run.jsonl", "--level", "full", "--json", cwd=d
    )
    assert out.returncode == 2, out.stderr
    err = json.loads(out.stdout)
    assert err["exit_code"] == 2
    assert "--level offsets" in err["error"] and "--level full" in err["error"]
    assert "run.jsonl" in err["error"] and "Traceback" not in out.stderr
    out = ucal("calibrate", "cell.toml", "--replay", "run.jsonl", "--postures", "5", cwd=d)
    assert out.returncode == 2 and "--postures" in out.stderr
    # the level it was recorded at, typed, is no mismatch
    out = ucal("calibrate", "cell.toml", "--replay", "run.jsonl", "--level", "offsets", cwd=d)
    assert out.returncode in (0, 1), out.stderr
    assert sorted(p.name for p in d.iterdir()) == before  # a replay writes nothing


def test_a_run_killed_mid_way_leaves_a_readable_record(tmp_path: Path) -> None:
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "ucal",
            "calibrate",
            "cell.toml",
            "--sim",
            "--yes",
            "--dry-run",
            "--record",
            "run.jsonl",
        ],
        cwd=tmp_path,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        stdin=subprocess.DEVNULL,
    )
    record = tmp_path / "run.jsonl"
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and proc.poll() is None:
            if record.exists() and record.stat().st_size > 200_000:
                break
            time.sleep(0.05)
        proc.send_signal(signal.SIGTERM)
        proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 130
    cut = read_record(record)
    assert cut.result is None and len(cut.calls) > 100
    assert any(c["call"] == "pulser.read_gate" for c in cut.calls)
    out = ucal("calibrate", "cell.toml", "--replay", "run.jsonl", cwd=tmp_path)
    assert out.returncode == 2
    assert "cut off" in out.stderr
