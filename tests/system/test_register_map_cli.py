"""A pulser-receiver with another Modbus register map calibrates without code: the profile names
its map (``[pulser] register_map``) and the simulated cell's pulser serves the same map, so
every request of the run uses other addresses, types, scales and word order than ucal's own."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from ucal.profile import create_profile, write_profile

from doubles import ucal_here

pytestmark = pytest.mark.system

SHIFTED_MAP_PATH = Path(__file__).resolve().parents[1] / "data" / "shifted_pulser_map.toml"
OFFSETS_DEG = np.array([-2.0, 1.5, -1.0, 3.0, -2.5, 2.0])


def ucal(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "ucal", *args],
        capture_output=True,
        text=True,
        check=False,
        timeout=300,
        stdin=subprocess.DEVNULL,
    )


def make_cell(directory: Path, register_map: str | None) -> Path:
    """A tx90l profile with an angled tool and a fixtured block, naming ``register_map``."""
    directory.mkdir()
    path = directory / "cell.toml"
    create_profile(path, "tx90l")
    write_profile(
        path,
        {
            "tool": {"rotation_deg": [0.0, 12.0, 0.0]},
            "sample": {"position_std_mm": 0.5, "rotation_std_deg": [0.01, 0.01, 0.01]},
        },
        "test setup",
    )
    if register_map is not None:
        with path.open("a", encoding="utf-8") as f:
            f.write(f'\n[pulser]\nregister_map = "{register_map}"\n')
    return path


def make_world(directory: Path, extra: str = "") -> Path:
    path = directory / "world.toml"
    path.write_text(
        f"[robot]\njoint_offsets_deg = {OFFSETS_DEG.tolist()}\n"
        "[noise]\ntof_ns = 0.5\namplitude = 0.01\nseed = 7\n" + extra
    )
    return path


def calibrate(profile: Path, world: Path) -> dict:
    """``ucal calibrate --json`` on the simulated cell, in this process."""
    out = ucal_here("calibrate", str(profile), "--sim", str(world), "--yes", "--json")
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout)


def test_another_register_map_calibrates_like_the_shipped_one(tmp_path: Path) -> None:
    shipped = calibrate(make_cell(tmp_path / "shipped", None), make_world(tmp_path))
    cell = make_cell(tmp_path / "other", "my_pulser.toml")
    shutil.copy(SHIFTED_MAP_PATH, cell.parent / "my_pulser.toml")
    other = calibrate(cell, make_world(tmp_path))
    assert shipped["written"] is True and other["written"] is True
    assert other["pulser_reads"] > 1000  # every reading went through the other map
    a = np.array(shipped["joint_offsets_deg"])
    b = np.array(other["joint_offsets_deg"])
    std = np.array([np.nan if s is None else s for s in other["std_deg"]])
    seen = np.isfinite(std)
    assert list(np.flatnonzero(~seen) + 1) == other["unobservable_joints"]
    assert seen.sum() >= 5
    # the same cell through another map: the same offsets within their std
    # two runs whose readings differ by the maps' rounding: their noise is not one draw
    assert np.all(np.abs(a - b)[seen] <= 3 * np.sqrt(2) * std[seen]), (a, b, std)
    assert np.all(np.abs(b - OFFSETS_DEG)[seen] <= 3 * std[seen]), (b, std)


def test_a_world_may_give_the_simulated_pulser_another_map(tmp_path: Path) -> None:
    shutil.copy(SHIFTED_MAP_PATH, tmp_path / "other_pulser.toml")
    world = make_world(tmp_path, '[pulser]\nregister_map = "other_pulser.toml"\n')
    # the profile speaks ucal's own map to a pulser that serves another: refused at connect
    out = ucal("calibrate", str(make_cell(tmp_path / "cell", None)), "--sim", str(world), "--yes")
    assert out.returncode == 3, out.stderr
    assert "pulser at modbus-tcp://127.0.0.1:" in out.stderr
    assert "identify: Modbus exception illegal data address" in out.stderr
