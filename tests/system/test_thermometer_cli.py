"""``calibrate --thermometer``: a heater that turns the tank during the run, the thermometer's
log taking the turn out of the water paths, on the simulated cell and in its record."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from ucal.profile import default_profile_text

from doubles import ucal_here

OFFSETS = np.array([0.3, -0.2, 0.15, 0.4, -0.25, 0.1])
BACKLASH_DEG = 0.01


@pytest.fixture(scope="module")
def heated(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict]:
    """The offsets level on a tank whose heater cycles every 1.5 min by ±0.25 °C, with the
    thermometer's log (0.1 min behind, 0.3 °C off, 0.01 °C resolution), recorded."""
    d = tmp_path_factory.mktemp("thermometer")
    # the simulated arm is rigid and the profile says so: the water's turn alone is at stake
    rigid = "backlash_std_deg = 0.01"
    stated = f"stiffness_nm_per_rad = {[0.0] * 6}\n{rigid}"
    (d / "cell.toml").write_text(default_profile_text("tx90l").replace(rigid, stated))
    t = np.arange(0.0, 10.0, 0.05)
    tank = 20.0 + 0.25 * np.sin(2.0 * np.pi * t / 1.5)
    rows = "".join(f"{a:.2f},{b:.5f}\n" for a, b in zip(t, tank, strict=True))
    (d / "tank.csv").write_text("time_min,temperature_c\n" + rows)
    probe = np.round((np.interp(t - 0.1, t, tank) + 0.3) / 0.01) * 0.01
    rows = "".join(f"{a:.2f},{b:.2f}\n" for a, b in zip(t, probe, strict=True))
    (d / "probe.csv").write_text("time_min,temperature_c\n" + rows)
    (d / "world.toml").write_text(
        f'[robot]\nmodel = "tx90l"\njoint_offsets_deg = {OFFSETS.tolist()}\n'
        f"backlash_deg = {[BACKLASH_DEG] * 6}\n"
        '[water]\ntemperature_log = "tank.csv"\n[noise]\ntof_ns = 1.0\namplitude = 0.01\nseed = 3\n'
    )
    out = ucal_here(
        "calibrate", "cell.toml", "--sim", "world.toml", "--thermometer", "probe.csv",
        "--record", "run.jsonl", "--dry-run", "--yes", "--json", cwd=d,
    )  # fmt: skip
    assert out.returncode == 0, out.stderr
    return d, json.loads(out.stdout)


def _z(result: dict) -> np.ndarray:
    """|error| / std of the joints with a std (J1 carries the block's yaw)."""
    truth = OFFSETS - 0.5 * BACKLASH_DEG  # every posture reached from below
    got = np.array(result["joint_offsets_deg"], float)
    std = np.array([np.nan if s is None else s for s in result["std_deg"]], float)
    return np.abs(got - truth)[1:5] / std[1:5]


def test_the_log_takes_the_heaters_turn_out_of_the_offsets(heated: tuple[Path, dict]) -> None:
    _, result = heated
    water = result["thermometer"]
    assert water["file"].endswith("probe.csv")
    assert water["applied"] is True
    assert water["departure_c"] > 3.0 * water["noise_c"]
    assert np.all(_z(result) <= 3.0), _z(result)


def test_the_record_replays_with_the_log_and_without_it_does_not_cover(
    heated: tuple[Path, dict],
) -> None:
    """The record keeps the log on the run's clock: a replay gives the recorded result. The
    same measurements with the log taken out of the record: J3's offset lies beyond 3 std (the
    heater's turn is what the log measured)."""
    d, result = heated
    out = ucal_here("calibrate", "cell.toml", "--replay", "run.jsonl", "--json", cwd=d)
    assert out.returncode == 0, out.stderr
    replayed = json.loads(out.stdout)
    assert replayed["joint_offsets_deg"] == result["joint_offsets_deg"]
    assert replayed["thermometer"] == result["thermometer"]
    lines = [json.loads(line) for line in (d / "run.jsonl").read_text().splitlines()]
    for line in lines:
        if line.get("of") == "session":
            assert line["thermometer"]["source"].endswith("probe.csv")
            line["thermometer"] = None
    (d / "bare.jsonl").write_text("".join(json.dumps(line) + "\n" for line in lines))
    out = ucal_here("calibrate", "cell.toml", "--replay", "bare.jsonl", "--json", cwd=d)
    assert out.returncode == 0, out.stderr
    bare = json.loads(out.stdout)
    assert "thermometer" not in bare
    assert np.max(_z(bare)) > 3.0


@pytest.mark.parametrize(
    ("command", "log", "words"),
    [
        ("calibrate", "2026-11-26T07:00:00Z,twenty", "probe.csv: row 2: expected an ISO 8601"),
        ("calibrate", "2026-11-26T07:00:00Z,20", "the simulated cell runs on its own clock"),
        ("check", "2026-11-26T07:00:00Z,twenty", "probe.csv: row 2: expected an ISO 8601 time"),
    ],
)
def test_a_bad_log_is_refused_before_anything_moves(
    tmp_path: Path, command: str, log: str, words: str
):
    """A log that cannot be read, or whose times are not the cell's clock: exit 2, naming the
    file, before the plan (nothing moved)."""
    (tmp_path / "cell.toml").write_text(default_profile_text("tx90l"))
    (tmp_path / "probe.csv").write_text(f"time,temperature_c\n{log}\n")
    out = ucal_here(
        command, "cell.toml", "--sim", "--thermometer", "probe.csv", "--yes", "--json",
        cwd=tmp_path,
    )  # fmt: skip
    assert out.returncode == 2
    assert words in json.loads(out.stdout)["error"]
    assert {"calibrate": "Calibration plan", "check": "Check plan"}[command] not in out.stderr


def test_a_logger_not_writing_now_is_refused_before_the_cell_is_opened(tmp_path: Path) -> None:
    """A real cell's log whose last row is hours old by the host's clock (a logger stopped, or
    local times of another zone): exit 2 naming the file and the host's zone, before the plan
    and before either device is asked (their addresses answer nothing)."""
    (tmp_path / "cell.toml").write_text(default_profile_text("tx90l"))
    (tmp_path / "probe.csv").write_text("time,temperature_c\n2026-01-05T07:00:00,20\n")
    out = ucal_here(
        "calibrate", "cell.toml", "--controller", "tcp://127.0.0.1:9",
        "--pulser", "modbus-tcp://127.0.0.1:9", "--thermometer", "probe.csv", "--yes", "--json",
        cwd=tmp_path,
    )  # fmt: skip
    assert out.returncode == 2
    error = json.loads(out.stdout)["error"]
    assert error.startswith("probe.csv: its last row is ")
    assert "min old by this host's clock" in error
    assert "a time without a zone is this host's local time, UTC" in error
    assert "Calibration plan" not in out.stderr
