"""The ``ucal profile`` and ``ucal fk`` commands as a user runs them (a separate process, then
the same command line in this one), and a non-editable install that finds its shipped robot
models from any directory."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import sysconfig
from pathlib import Path

import numpy as np
import pytest

from ucal.kinematics.dh import fk, fk_frames, transform
from ucal.kinematics.rotations import matrix_to_pose, pose_to_matrix, rpy_to_matrix
from ucal.profile import load_profile, write_profile

from doubles import ucal_here

REPO = Path(__file__).resolve().parents[2]

pytestmark = pytest.mark.system


def ucal_process(*args: str, cwd: Path | None = None) -> subprocess.CompletedProcess[str]:
    """Run ``python -m ucal ARGS`` in a separate process."""
    return subprocess.run(
        [sys.executable, "-m", "ucal", *args],
        check=False,
        capture_output=True,
        text=True,
        cwd=cwd,
        timeout=60,
    )


#: The tests but the first two (a separate process, and its output in a pipe) run the same
#: command line in this process: a new interpreter's imports test nothing of these commands.
ucal = ucal_here


def test_init_validate_show(tmp_path: Path) -> None:
    path = tmp_path / "cell.toml"
    r = ucal_process("profile", "init", "tx90xl", str(path))
    assert r.returncode == 0, r.stderr
    assert r.stdout == ""
    r = ucal_process("profile", "validate", str(path))
    assert r.returncode == 0, r.stderr
    assert "valid (tx90xl)" in r.stdout
    r = ucal_process("profile", "show", str(path), "--json")
    assert r.returncode == 0, r.stderr
    data = json.loads(r.stdout)
    assert data["robot"]["model"] == "tx90xl"
    assert len(data["robot"]["dh"]) == 6
    assert data["tool"]["position_mm"] == [0.0, 0.0, 80.0]
    assert data["calibration"] == {"joint_offsets_deg": [0.0] * 6, "unobservable_joints": []}
    r = ucal_process("profile", "show", str(path))
    assert r.returncode == 0 and "tx90xl" in r.stdout


def test_tables_in_a_pipe_are_not_cut(tmp_path: Path) -> None:
    """stdout is a pipe here: no cell is cut at rich's default 80 columns ("unobserva…")."""
    path = tmp_path / "cell.toml"
    assert ucal_process("profile", "init", "tx90l", str(path)).returncode == 0
    write_profile(path, {"calibration": {"unobservable_joints": [1, 6]}}, reason="test")
    r = ucal_process("profile", "show", str(path))
    assert r.returncode == 0, r.stderr
    assert r.stdout.count("0.0000 (unobservable)") == 2, r.stdout
    assert "…" not in r.stdout
    assert max(len(line) for line in r.stdout.splitlines()) > 80


def test_init_errors_exit_2(tmp_path: Path) -> None:
    path = tmp_path / "cell.toml"
    assert ucal("profile", "init", "tx90", str(path)).returncode == 0
    before = path.read_bytes()
    r = ucal("profile", "init", "tx90l", str(path))
    assert r.returncode == 2
    assert f"{path}: already exists" in r.stderr and "Traceback" not in r.stderr
    assert path.read_bytes() == before
    r = ucal("profile", "init", "kr16", str(tmp_path / "other.toml"))
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert not (tmp_path / "other.toml").exists()


def test_fk_json_applies_offsets_and_tool(tmp_path: Path) -> None:
    path = tmp_path / "cell.toml"
    assert ucal("profile", "init", "tx90l", str(path)).returncode == 0
    offsets = np.array([0.3, -0.5, 0.7, 0.2, -0.4, 1.1])
    tool_pos, tool_rot = np.array([1.5, -2.0, 82.0]), np.array([2.0, -1.0, 30.0])
    write_profile(
        path,
        {
            "calibration": {"joint_offsets_deg": offsets},
            "tool": {"position_mm": tool_pos, "rotation_deg": tool_rot},
        },
        reason="test",
    )
    joints = np.array([30.53, 31.15, 109.49, 5.0, 39.36, 30.54])
    r = ucal("fk", str(path), "--joints", ",".join(map(str, joints)), "--json")
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout)
    assert set(out) == {"joints_deg", "pose"}
    np.testing.assert_allclose(out["joints_deg"], joints)

    model = load_profile(path).model
    # Independent of the fk() tool/offset arguments: add the offsets to the readings and
    # compose the tool transform by hand.
    flange = fk_frames(model, joints + offsets)[-1]
    expected = flange @ transform(tool_pos, rpy_to_matrix(tool_rot))
    np.testing.assert_allclose(pose_to_matrix(np.array(out["pose"])), expected, atol=1e-9)
    tool = transform(tool_pos, rpy_to_matrix(tool_rot))
    np.testing.assert_allclose(
        out["pose"], matrix_to_pose(fk(model, joints, tool=tool, offsets_deg=offsets)), atol=1e-9
    )
    # the offsets matter: without them the TCP is millimetres away
    without = fk_frames(model, joints)[-1] @ transform(tool_pos, rpy_to_matrix(tool_rot))
    assert np.linalg.norm(without[:3, 3] - np.array(out["pose"][:3])) > 1.0


def test_fk_at_zero_is_the_arm_straight_up(tmp_path: Path) -> None:
    path = tmp_path / "cell.toml"
    assert ucal("profile", "init", "tx90xl", str(path)).returncode == 0
    r = ucal("fk", str(path), "--joints", "0,0,0,0,0,0", "--json")
    assert r.returncode == 0, r.stderr
    # SPEC.md: at zero the TX90XL flange is at (50, 50, 650 + 650 + 100) mm, z up; tool +80 z.
    np.testing.assert_allclose(json.loads(r.stdout)["pose"], [50, 50, 1480, 0, 0, 0], atol=1e-9)


@pytest.mark.parametrize("joints", ["1,2,3", "a,0,0,0,0,0", "0,0,0,0,0,nan"])
def test_fk_bad_joints_exit_2(joints: str, tmp_path: Path) -> None:
    path = tmp_path / "cell.toml"
    assert ucal("profile", "init", "tx90", str(path)).returncode == 0
    r = ucal("fk", str(path), "--joints", joints, "--json")
    assert r.returncode == 2
    assert "--joints" in r.stderr and "Traceback" not in r.stderr
    out = json.loads(r.stdout)  # the SPEC error object, nothing else
    assert set(out) == {"error", "exit_code"} and out["exit_code"] == 2
    assert "--joints" in out["error"] and out["error"] in r.stderr


def test_fk_missing_profile_exit_2(tmp_path: Path) -> None:
    r = ucal("fk", str(tmp_path / "none.toml"), "--joints", "0,0,0,0,0,0")
    assert r.returncode == 2
    assert f"{tmp_path / 'none.toml'}: cannot read" in r.stderr


def test_history_and_undo_commands(tmp_path: Path) -> None:
    path = tmp_path / "cell.toml"
    assert ucal("profile", "init", "tx90l", str(path)).returncode == 0
    v0 = path.read_bytes()
    write_profile(path, {"calibration": {"joint_offsets_deg": [0.1] * 6}}, reason="calibrate")
    r = ucal("profile", "history", str(path), "--json")
    assert r.returncode == 0, r.stderr
    entries = json.loads(r.stdout)["entries"]
    assert [(e["id"], e["reason"], e["undone"]) for e in entries] == [(1, "calibrate", False)]
    r = ucal("profile", "undo", str(path))
    assert r.returncode == 0, r.stderr
    assert path.read_bytes() == v0
    r = ucal("profile", "undo", str(path))
    assert r.returncode == 2 and "nothing to undo" in r.stderr


def _copy_source(dst: Path) -> Path:
    ignore = shutil.ignore_patterns(
        ".git",
        "build",
        "dist",
        "*.egg-info",
        "__pycache__",
        ".pytest_cache",
        "*.history",
        ".venv",
        "venv",
    )
    shutil.copytree(REPO, dst, ignore=ignore)
    return dst


@pytest.mark.long
def test_non_editable_install_finds_shipped_profiles(tmp_path: Path) -> None:
    """``pip install .`` ships the robot models as package data: ``ucal profile init`` works
    from an unrelated directory, with ucal imported from the install, not the source tree.

    Third-party dependencies come from this interpreter's environment (a ``.pth`` line) so the
    test exercises ucal's own packaging without downloading numpy/scipy again; this
    interpreter's pip builds and installs into the bare virtual environment, with the build
    backend (setuptools, a test dependency) from this environment too.
    """
    src = _copy_source(tmp_path / "src")
    venv = tmp_path / "venv"
    subprocess.run(
        [sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True, timeout=120
    )
    py = venv / "bin" / "python"
    code = "import sysconfig; print(sysconfig.get_paths()['purelib'])"
    site = subprocess.run(
        [str(py), "-c", code], check=True, capture_output=True, text=True
    ).stdout.strip()
    deps = {sysconfig.get_paths()["purelib"], sysconfig.get_paths()["platlib"]}
    (Path(site) / "zz_test_deps.pth").write_text("\n".join(sorted(deps)) + "\n")
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    r = subprocess.run(
        [
            sys.executable,
            "-m",
            "pip",
            "--python",
            str(py),
            "install",
            "--no-deps",
            "--no-build-isolation",
            "--quiet",
            str(src),
        ],
        check=False,
        capture_output=True,
        text=True,
        timeout=600,
        env=env,
    )
    assert r.returncode == 0, r.stdout + r.stderr

    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    code = (
        "import json, ucal, ucal.profile.models; from importlib import resources; "
        "print(ucal.__file__); print(json.dumps(sorted(p.name for p in "
        "resources.files('ucal.profiles').iterdir() if p.name.endswith('.toml'))))"
    )
    r = subprocess.run(
        [str(py), "-c", code],
        check=False,
        capture_output=True,
        text=True,
        cwd=elsewhere,
        env=env,
        timeout=60,
    )
    assert r.returncode == 0, r.stderr
    where, names = r.stdout.splitlines()
    assert Path(where).resolve().is_relative_to(Path(site).resolve())
    shipped = {"tx90.toml", "tx90l.toml", "tx90xl.toml", "example_cell.toml"}
    assert shipped <= set(json.loads(names))

    ucal_bin = str(venv / "bin" / "ucal")
    for model in ("tx90", "tx90l", "tx90xl"):
        for cmd in (["init", model, f"{model}.toml"], ["validate", f"{model}.toml"]):
            r = subprocess.run(
                [ucal_bin, "profile", *cmd],
                check=False,
                capture_output=True,
                text=True,
                cwd=elsewhere,
                env=env,
                timeout=60,
            )
            assert r.returncode == 0, r.stderr
