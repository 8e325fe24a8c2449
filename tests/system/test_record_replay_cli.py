"""``--record`` / ``--replay``: a recorded run solves again offline, bit for bit, from its
measurement lines alone or (``--remeasure``) from its device traffic; calibrate, tool-frame,
verify and check alike."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from ucal.devices.record import read_record
from ucal.profile import default_profile_text

from doubles import ucal_here

pytestmark = pytest.mark.system

Examples = Callable[[list[str]], list[tuple[dict, list[str]]]]
RunMain = Callable[[list[str]], tuple[int, str, str]]


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
    out = ucal_here(
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


#: Result fields only a run on the simulated cell has (the simulator's hidden truth), and one
#: only a run that creates its profile sets.
SIMULATED = {"truth", "truth_offsets_deg", "truth_offsets_block_deg", "simulated_error", "created"}


def stripped(path: Path, d: Path) -> Path:
    """The record at ``path`` with only its header and measurement lines."""
    out = d / f"{path.stem}.stripped.jsonl"
    lines = path.read_text().splitlines()
    kept = [line for line in lines if json.loads(line)["kind"] in ("header", "measurement")]
    out.write_text("\n".join(kept) + "\n")
    return out


def same_result(replayed: dict, recorded: dict) -> None:
    """A replay's result is the recorded one, field for field, but for the simulator's truth."""
    assert replayed.pop("replayed")
    assert set(recorded) - set(replayed) <= SIMULATED
    assert {k: v for k, v in recorded.items() if k not in SIMULATED} == replayed


def test_every_line_has_a_kind(recorded: tuple[Path, dict]) -> None:
    d, result = recorded
    kinds = [json.loads(line)["kind"] for line in (d / "run.jsonl").read_text().splitlines()]
    assert kinds[0] == "header" and kinds[-1] == "result"
    assert set(kinds[1:-1]) == {"call", "measurement"}
    # one line per face measured, the run's counters, the session's duration
    assert kinds.count("measurement") == len(result["residuals"]) + 2


def test_replay_of_the_measurements_alone_gives_the_recorded_result(
    recorded: tuple[Path, dict], run_main: RunMain, monkeypatch: pytest.MonkeyPatch
) -> None:
    d, result = recorded
    measurements = stripped(d / "run.jsonl", d)
    monkeypatch.chdir(d)
    code, out, err = run_main(["calibrate", "cell.toml", "--replay", measurements.name, "--json"])
    assert code in (0, 1), err
    again = json.loads(out)
    assert np.allclose(again["joint_offsets_deg"], result["joint_offsets_deg"], rtol=0, atol=1e-9)
    assert again["std_deg"] == result["std_deg"]
    same_result(again, result)


def test_replay_with_remeasure_searches_again_on_the_traffic(recorded: tuple[Path, dict]) -> None:
    d, result = recorded
    record = read_record(d / "run.jsonl")
    assert record.result is not None
    assert record.result["joint_offsets_deg"] == result["joint_offsets_deg"]
    assert len(record.calls) > result["pulser_reads"]  # every reading, and more
    out = ucal_here(
        "calibrate", "cell.toml", "--replay", "run.jsonl", "--remeasure", "--json", cwd=d
    )
    assert out.returncode in (0, 1), out.stderr
    again = json.loads(out.stdout)
    assert again["joint_offsets_deg"] == result["joint_offsets_deg"]  # bit for bit
    assert again["std_deg"] == result["std_deg"]
    assert again["pulser_reads"] == result["pulser_reads"]
    assert again["written"] is False


def test_replay_with_another_method_solves_the_same_measurements(
    recorded: tuple[Path, dict], help_examples: Examples
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
    out = ucal_here(*args, cwd=d)
    assert out.returncode in (0, 1), out.stderr
    paper = json.loads(out.stdout)
    assert paper["method"] == "paper"
    assert paper["moves"] == result["moves"] and paper["pulser_reads"] == result["pulser_reads"]


def test_replay_takes_no_cell(recorded: tuple[Path, dict]) -> None:
    d, _ = recorded
    out = ucal_here("calibrate", "cell.toml", "--replay", "run.jsonl", "--sim", cwd=d)
    assert out.returncode == 2
    assert "--replay" in out.stderr and "Traceback" not in out.stderr


def test_replay_asked_for_another_level_says_so(recorded: tuple[Path, dict]) -> None:
    d, _ = recorded
    before = sorted(p.name for p in d.iterdir())
    out = ucal_here(
        "calibrate", "cell.toml", "--replay", "run.jsonl", "--level", "full", "--json", cwd=d
    )
    assert out.returncode == 2, out.stderr
    err = json.loads(out.stdout)
    assert err["exit_code"] == 2
    assert "--level offsets" in err["error"] and "--level full" in err["error"]
    assert "run.jsonl" in err["error"] and "Traceback" not in out.stderr
    out = ucal_here("calibrate", "cell.toml", "--replay", "run.jsonl", "--postures", "5", cwd=d)
    assert out.returncode == 2 and "--postures" in out.stderr
    # the level it was recorded at, typed, is no mismatch
    out = ucal_here("calibrate", "cell.toml", "--replay", "run.jsonl", "--level", "offsets", cwd=d)
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
    out = ucal_here("calibrate", "cell.toml", "--replay", "run.jsonl", cwd=tmp_path)
    assert out.returncode == 2
    assert "cut off" in out.stderr


def test_a_version_1_record_still_replays(recorded: tuple[Path, dict]) -> None:
    """The format before kinds: a header, the device calls, an end line; no measurements."""
    d, result = recorded
    v1 = []
    for line in (d / "run.jsonl").read_text().splitlines():
        obj = json.loads(line)
        kind = obj.pop("kind")
        if kind == "header":
            v1.append({**obj, "version": 1})
        elif kind == "call":
            v1.append(obj)
        elif kind == "result":
            v1.append({"end": obj["result"]})
    (d / "v1.jsonl").write_text("".join(json.dumps(o) + "\n" for o in v1))
    out = ucal("calibrate", "cell.toml", "--replay", "v1.jsonl", "--json", cwd=d)  # a warning
    assert out.returncode in (0, 1), out.stderr
    assert "version 1" in out.stderr and "replaying its device traffic" in out.stderr
    again = json.loads(out.stdout)
    assert again["joint_offsets_deg"] == result["joint_offsets_deg"]  # bit for bit
    assert again["std_deg"] == result["std_deg"]


@pytest.fixture(scope="module", params=["tool-frame", "verify", "check"])
def recorded_command(
    request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory
) -> tuple[str, Path, dict, int]:
    """One short recorded run of each other moving command on the demo cell."""
    command = request.param
    d = tmp_path_factory.mktemp(command)
    (d / "cell.toml").write_text(default_profile_text("tx90l"), encoding="utf-8")
    # the check is the profile's first: it goes into the history as the reference, which its
    # replay must not then compare it against
    # the check takes the tank thermometer's log: a heater turning the tank by 0.02 °C
    t_min = np.arange(0.0, 30.0, 0.05)
    tank_c = 20.0 + 0.02 * np.sin(2.0 * np.pi * t_min / 3.0)
    rows = "".join(f"{t:.2f},{c:.4f}\n" for t, c in zip(t_min, tank_c, strict=True))
    (d / "probe.csv").write_text("time_min,temperature_c\n" + rows)
    few = {
        "tool-frame": ["--points", "2"],
        "verify": ["--points", "1"],
        "check": ["--thermometer", "probe.csv"],
    }[command]
    dry_run = [] if command == "check" else ["--dry-run"]
    args = [command, "cell.toml", "--sim", "--yes", "--json", *dry_run, *few]
    out = ucal_here(*args, "--record", "run.jsonl", cwd=d)
    assert out.returncode in (0, 1), out.stderr
    return command, d, json.loads(out.stdout), out.returncode


def test_other_commands_replay_their_measurements_to_their_recorded_result(
    recorded_command: tuple[str, Path, dict, int],
    help_examples: Examples,
    run_main: RunMain,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    command, d, result, code = recorded_command
    record = read_record(d / "run.jsonl")
    assert record.command == command and record.measured
    assert record.result is not None
    assert record.result == {k: v for k, v in result.items() if k not in ("error", "exit_code")}
    # as `ucal COMMAND --help` shows it, on the record stripped to its header and measurements
    (args,) = [a for _, a in help_examples([command]) if "--replay" in a]
    assert args == [command, "cell.toml", "--replay", args[3], "--json"]
    stripped(d / "run.jsonl", d).rename(d / args[3])
    before = files(d)
    monkeypatch.chdir(d)
    exit_code, out, err = run_main(args)
    assert exit_code == code, err  # in or out of tolerance as recorded
    again = json.loads(out)
    if command == "check":  # the recorded check went into the history, its replay does not
        assert result["recorded"] and result["history_entry"] == 1
        # the log, on the run's clock in the record, was taken out of the paths the entry keeps
        assert result["thermometer"]["file"] == "probe.csv" and result["thermometer"]["applied"]
        (entry,) = json.loads((d / "cell.toml.history" / "checks.json").read_text())["checks"]
        assert entry["logged_departure_std_c"] == 0.02
        drift = result["thermometer"]["drift_c_per_min"]  # as --json rounds it
        assert entry["drift_prior_c_per_min"] == pytest.approx(drift, abs=1e-5)
        assert again.pop("recorded") is False and again.pop("history_entry") is None
        result = {k: v for k, v in result.items() if k not in ("recorded", "history_entry")}
    same_result(again, result)
    assert files(d) == before  # a replay moves nothing and writes nothing


def files(d: Path) -> dict[Path, bytes]:
    return {p: p.read_bytes() for p in d.rglob("*") if p.is_file()}


def test_a_replay_refuses_what_the_record_did_not_measure(
    recorded_command: tuple[str, Path, dict, int],
    run_main: RunMain,
) -> None:
    command, d, _, _ = recorded_command
    other = {"tool-frame": ["--method", "paper"], "verify": ["--points", "5"]}
    for args, words in (
        ([*other.get(command, ["--baseline"])], "it cannot be replayed with"),
        (["--remeasure"], "--remeasure"),
    ):
        replay = ["--replay", str(d / "run.jsonl")] if args != ["--remeasure"] else []
        code, _, err = run_main([command, str(d / "cell.toml"), *replay, *args])
        assert code == 2 and words in err, err
    code, _, err = run_main(["calibrate", str(d / "cell.toml"), "--replay", str(d / "run.jsonl")])
    assert code == 2 and f"a record of `ucal {command}`" in err, err
