"""The shipped example scan (``examples/scan.csv``): it runs on the built-in profile as its
header says, in one arm configuration, and the file documents its columns."""

from __future__ import annotations

import csv
import json
import re
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from ucal.cli.path import read_pose_csv
from ucal.kinematics.configuration import arm_configs
from ucal.kinematics.dh import fk
from ucal.kinematics.rotations import pose_to_matrix, rotation_angle_deg
from ucal.profile import load_profile

RunMain = Callable[[list[str]], tuple[int, str, str]]
EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "scan.csv"


@pytest.fixture
def cell(tmp_path: Path, run_main: RunMain, monkeypatch: pytest.MonkeyPatch) -> Path:
    """``ucal profile init tx90l cell.toml`` in a directory holding ``examples/scan.csv``."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "examples").mkdir()
    (tmp_path / "examples" / "scan.csv").write_bytes(EXAMPLE.read_bytes())
    assert run_main(["profile", "init", "tx90l", "cell.toml"])[0] == 0
    return tmp_path / "cell.toml"


def header_commands() -> list[list[str]]:
    """The ``ucal`` command lines the example's comment header gives."""
    return [
        line.split()[2:]
        for line in EXAMPLE.read_text(encoding="utf-8").splitlines()
        if re.match(r"^#\s+ucal ", line)
    ]


def test_the_example_runs_as_its_header_says(cell: Path, run_main: RunMain) -> None:
    commands = header_commands()
    assert commands[0] == ["profile", "init", "tx90l", "cell.toml"]
    (path_args,) = [c for c in commands if c[0] == "path"]
    code, out, err = run_main([*path_args, "--json"])
    assert code == 0 and err == "", err
    data = json.loads(out)
    assert data["points"] == 153 and data["configuration_changes"] == []
    assert data["max_step_deg"] < 2.0

    rows = list(csv.reader(Path(data["output"]).read_text(encoding="utf-8").splitlines()))
    joints = np.array([r[:6] for r in rows[1:]], float)
    words = [tuple(r[6:]) for r in rows[1:]]
    profile = load_profile(cell)
    assert words == [c.words() for c in arm_configs(profile.model, joints)]
    assert set(words) == {("lefty", "epositive", "wpositive")}
    # the rows reach the example's poses
    poses, _ = read_pose_csv(EXAMPLE)
    asked = pose_to_matrix(poses)
    reached = fk(profile.model, joints, profile.tool_matrix, profile.joint_offsets_deg)
    assert np.max(np.linalg.norm(reached[:, :3, 3] - asked[:, :3, 3], axis=-1)) < 1e-6
    assert np.max(rotation_angle_deg(asked[:, :3, :3], reached[:, :3, :3])) < 1e-6


def test_the_example_documents_its_columns() -> None:
    text = EXAMPLE.read_text(encoding="utf-8")
    comments = "\n".join(line for line in text.splitlines() if line.startswith("#"))
    for word in ("X, Y, Z", "RX, RY, RZ", "mm", "deg", "base frame", "Rot(x,RX)", "+Z"):
        assert word in comments, word
    header = next(line for line in text.splitlines() if not line.startswith("#"))
    assert header == "X,Y,Z,RX,RY,RZ"
