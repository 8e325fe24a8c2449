"""``ucal ik`` and ``ucal path`` as a user runs them: the first test in a separate process, the
others the same command line in this one."""

from __future__ import annotations

import csv
import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from ucal.kinematics.dh import fk
from ucal.kinematics.ik import ik
from ucal.kinematics.path import plan_joint_path
from ucal.kinematics.rotations import matrix_to_pose, pose_to_matrix, rotation_angle_deg
from ucal.profile import create_profile, load_profile, write_profile
from ucal.profile.models import load_model

from doubles import ucal_here

OFFSETS = [0.4, -0.3, 0.2, 0.5, -0.25, 0.1]


def ucal_process(*args: str) -> subprocess.CompletedProcess[str]:
    """Run ``python -m ucal ARGS`` in a separate process."""
    return subprocess.run(
        [sys.executable, "-m", "ucal", *args],
        check=False,
        capture_output=True,
        text=True,
        timeout=60,
    )


#: The other tests run the same command line in this process: a new interpreter's imports
#: cost half a second of CPU each and test nothing of ik or path.
ucal = ucal_here


@pytest.fixture
def profile_path(tmp_path: Path) -> Path:
    """A TX90L cell profile with non-zero joint offsets and a tilted tool."""
    path = tmp_path / "cell.toml"
    create_profile(path, "tx90l")
    write_profile(
        path,
        {
            "calibration": {"joint_offsets_deg": OFFSETS},
            "tool": {"position_mm": [2.0, -1.0, 85.0], "rotation_deg": [0.0, 5.0, 0.0]},
        },
        reason="test",
    )
    return path


def _csv(values: np.ndarray) -> str:
    return ",".join(repr(float(v)) for v in values)


def _tool_pose(path: Path, joints: np.ndarray) -> np.ndarray:
    p = load_profile(path)
    return matrix_to_pose(fk(p.model, joints, p.tool_matrix, p.joint_offsets_deg))


def test_ik_json_nearest_and_all(profile_path: Path) -> None:
    q = np.array([25.0, 30.0, 100.0, 15.0, 40.0, 20.0])
    pose = _tool_pose(profile_path, q)
    r = ucal_process("ik", str(profile_path), "--pose", _csv(pose), "--near", _csv(q), "--json")
    assert r.returncode == 0, r.stderr
    sols = json.loads(r.stdout)["solutions"]
    assert len(sols) == 1
    np.testing.assert_allclose(sols[0], q, atol=1e-7)  # offsets taken out: readings

    r = ucal_process("ik", str(profile_path), "--pose", _csv(pose), "--all", "--json")
    assert r.returncode == 0, r.stderr
    sols = np.array(json.loads(r.stdout)["solutions"])
    p = load_profile(profile_path)
    expected = ik(
        p.model, pose_to_matrix(pose), p.tool_matrix, p.joint_offsets_deg, all_solutions=True
    )
    assert 1 < len(sols) <= 8 and sols.shape == expected.shape
    np.testing.assert_allclose(sols, expected, atol=1e-9)
    assert np.all(p.model.within_limits(sols))
    back = matrix_to_pose(fk(p.model, sols, p.tool_matrix, p.joint_offsets_deg))
    np.testing.assert_allclose(back[:, :3], np.broadcast_to(pose[:3], (len(sols), 3)), atol=1e-8)
    # nearest first: weighted distance to the default reference (zeros) never decreases
    cost = np.sum(np.array([6, 5, 4, 3, 2, 1]) * np.abs(sols), -1)
    assert np.all(np.diff(cost) >= 0)


def test_ik_table_output(profile_path: Path) -> None:
    pose = _tool_pose(profile_path, np.array([0.0, 20.0, 90.0, 0.0, 60.0, 0.0]))
    r = ucal("ik", str(profile_path), "--pose", _csv(pose), "--all")
    assert r.returncode == 0, r.stderr
    assert "J1" in r.stdout and "J6" in r.stdout and "tx90l" in r.stdout


def test_ik_all_says_why_the_others_are_not_offered(profile_path: Path) -> None:
    """``--all`` accounts for all 8: the offered ones as rows, each other with its reason."""
    pose = _tool_pose(profile_path, np.array([22.0, 12.0, 99.0, 0.0, 67.0, -158.0]))
    r = ucal("ik", str(profile_path), "--pose", _csv(pose), "--all", "--json")
    assert r.returncode == 0, r.stderr
    data = json.loads(r.stdout)
    assert set(data) == {"solutions", "rejected"}
    assert len(data["solutions"]) + len(data["rejected"]) == 8 and data["rejected"]
    p = load_profile(profile_path)
    for rejected in data["rejected"]:
        assert set(rejected) == {"configuration", "joints_deg", "reason"}
        assert re.fullmatch(r"out of range: J5 at -?\d+\.\d\d deg is .*", rejected["reason"])
        assert not np.all(p.model.within_limits(rejected["joints_deg"]))
    configurations = {c["configuration"] for c in data["rejected"]}

    r = ucal("ik", str(profile_path), "--pose", _csv(pose), "--all")
    assert r.returncode == 0, r.stderr
    lines = r.stdout.splitlines()
    for name in configurations:  # a row of the "Not offered" table each, with its reason
        (line,) = [ln for ln in lines if name in ln]
        assert "out of range: J5 at" in line
    offered = [ln for ln in lines if "shoulder" in ln and "out of range" not in ln]
    assert len(offered) == len(data["solutions"])

    # without --all: the one nearest solution and nothing else
    r = ucal("ik", str(profile_path), "--pose", _csv(pose), "--json")
    assert set(json.loads(r.stdout)) == {"solutions"}


def test_ik_unreachable_exit_4(profile_path: Path) -> None:
    r = ucal("ik", str(profile_path), "--pose", "5000,0,0,0,0,0", "--json")
    assert r.returncode == 4
    assert "unreachable" in r.stderr and "Traceback" not in r.stderr
    assert json.loads(r.stdout) == {
        "error": r.stderr.strip().removeprefix("error: "),
        "exit_code": 4,
    }


def test_ik_bad_pose_exit_2(profile_path: Path) -> None:
    r = ucal("ik", str(profile_path), "--pose", "1,2,3")
    assert r.returncode == 2
    assert "--pose" in r.stderr and "Traceback" not in r.stderr
    r = ucal("ik", str(profile_path.with_name("missing.toml")), "--pose", "0,0,0,0,0,0")
    assert r.returncode == 2 and "Traceback" not in r.stderr


def _singular_path(profile_path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Joints (41, 6) that take θ5 (kinematic) through 0 with joint 4 at 40°, and their poses."""
    q = np.tile([10.0, 20.0, 80.0, 40.0, 0.0, -30.0], (41, 1))
    q[:, 4] = np.linspace(-10.0, 10.0, 41) - OFFSETS[4]
    q[:, 1] += np.linspace(0.0, 4.0, 41)
    return q, _tool_pose(profile_path, q)


def test_path_through_wrist_singularity(profile_path: Path, tmp_path: Path) -> None:
    """J5 changes sign (wnegative to wpositive into point 21, line 22): refused unless asked
    for; asked for, joint 4 stays continuous through the singularity (paper 004)."""
    q, poses = _singular_path(profile_path)
    src, out = tmp_path / "scan.csv", tmp_path / "joints.csv"
    src.write_text("X,Y,Z,RX,RY,RZ\n" + "\n".join(_csv(p) for p in poses) + "\n")
    args = ["path", str(profile_path), str(src), "-o", str(out), "--near", _csv(q[0])]
    r = ucal(*args)
    assert r.returncode == 4 and not out.exists()
    assert "point 21 (line 22)" in r.stderr and "wrist singularity" in r.stderr

    r = ucal(*args, "--allow-config-change", "--json")
    assert r.returncode == 0, r.stderr
    assert "warning:" in r.stderr and "point 21 (line 22)" in r.stderr
    data = json.loads(r.stdout)
    assert data["points"] == 41
    assert data["max_step_deg"] < 1.0
    assert [c["point"] for c in data["configuration_changes"]] == [21]
    assert data["configuration_changes"][0]["changed"] == ["wrist"]
    rows = list(csv.reader(out.read_text().splitlines()))
    assert rows[0] == ["J1", "J2", "J3", "J4", "J5", "J6", "shoulder", "elbow", "wrist"]
    joints = np.array([row[:6] for row in rows[1:]], float)
    np.testing.assert_allclose(joints, q, atol=1e-6)
    assert [row[8] for row in rows[1:]] == ["wnegative"] * 20 + ["wpositive"] * 21

    r = ucal(*args[:-2], "--allow-config-change")
    assert r.returncode == 0, r.stderr
    assert "largest joint step" in r.stdout


def test_path_bad_row_exit_2(profile_path: Path, tmp_path: Path) -> None:
    src, out = tmp_path / "bad.csv", tmp_path / "joints.csv"
    src.write_text("X,Y,Z,RX,RY,RZ\n600,0,500,180,0,0\n600,0,abc,180,0,0\n")
    r = ucal("path", str(profile_path), str(src), "-o", str(out))
    assert r.returncode == 2
    line = r.stderr.strip().splitlines()
    assert len(line) == 1 and str(src) in line[0] and "row 3" in line[0]
    assert not out.exists()
    src.write_text("600,0,500,180,0\n")
    r = ucal("path", str(profile_path), str(src), "-o", str(out))
    assert r.returncode == 2 and "row 1" in r.stderr and "Traceback" not in r.stderr


def test_path_unreachable_exit_4_writes_nothing(profile_path: Path, tmp_path: Path) -> None:
    _, poses = _singular_path(profile_path)
    poses[5, :3] = [4000.0, 0.0, 0.0]
    src, out = tmp_path / "scan.csv", tmp_path / "joints.csv"
    src.write_text("\n".join(_csv(p) for p in poses) + "\n")
    r = ucal("path", str(profile_path), str(src), "-o", str(out))
    assert r.returncode == 4
    assert "path point 6" in r.stderr and "Traceback" not in r.stderr
    assert not out.exists()


CALIBRATED_DH = [
    {"theta_offset_deg": 0.0, "d_mm": 0.0, "a_mm": 50.21, "alpha_deg": -90.03},
    {"theta_offset_deg": -90.0, "d_mm": 49.83, "a_mm": 500.34, "alpha_deg": 0.02, "beta_deg": 0.04},
    {"theta_offset_deg": 90.0, "d_mm": 0.0, "a_mm": 0.12, "alpha_deg": 90.04},
    {"theta_offset_deg": 0.0, "d_mm": 549.61, "a_mm": 0.0, "alpha_deg": -89.97},
    {"theta_offset_deg": 0.0, "d_mm": 0.0, "a_mm": 0.0, "alpha_deg": 90.02},
    {"theta_offset_deg": 0.0, "d_mm": 100.0, "a_mm": 0.0, "alpha_deg": 0.0},
]


def test_ik_and_path_on_a_calibrated_table_agree_with_fk(
    profile_path: Path, tmp_path: Path
) -> None:
    """``[calibration] dh`` (twists off ±90°, Hayati β₂) replaces the table; the closed form
    seeds, the refinement lands every branch on the calibrated model's pose to 1e-6 mm."""
    write_profile(profile_path, {"calibration": {"dh": CALIBRATED_DH}}, reason="test")
    p = load_profile(profile_path)
    assert p.model.beta_deg[1] == 0.04 and p.model.dh[1, 2] == 500.34
    q = np.array([25.0, 30.0, 100.0, 15.0, 40.0, 20.0])
    pose = _tool_pose(profile_path, q)
    r = ucal("ik", str(profile_path), "--pose", _csv(pose), "--all", "--json")
    assert r.returncode == 0, r.stderr
    sols = np.array(json.loads(r.stdout)["solutions"])
    assert len(sols) >= 4
    np.testing.assert_allclose(sols[0], q, atol=1e-7)
    target = pose_to_matrix(pose)
    for s in sols:
        got = fk(p.model, s, p.tool_matrix, p.joint_offsets_deg)
        assert np.linalg.norm(got[:3, 3] - target[:3, 3]) < 1e-6
    path_in = tmp_path / "in.csv"
    qs = q + np.linspace(0.0, 5.0, 4)[:, None]
    path_in.write_text("\n".join(_csv(_tool_pose(profile_path, x)) for x in qs) + "\n")
    r = ucal("path", str(profile_path), str(path_in), "-o", str(tmp_path / "out.csv"))
    assert r.returncode == 0, r.stderr
    rows = np.array(
        [
            [float(v) for v in row[:6]]
            for row in csv.reader((tmp_path / "out.csv").open())
            if row and not row[0].startswith(("#", "J", "j"))
        ]
    )
    got = fk(p.model, rows, p.tool_matrix, p.joint_offsets_deg)[:, :3, 3]
    want = np.array([pose_to_matrix(_tool_pose(profile_path, x))[:3, 3] for x in qs])
    assert np.max(np.linalg.norm(got - want, axis=1)) < 1e-6


def test_path_for_controller_lands_the_calibrated_robot(profile_path: Path, tmp_path: Path) -> None:
    """Targets for the nominal arm (shipped table, zero offsets, the profile's tool): solved by
    the nominal model continuously from the same start, as the controller does, they put the
    calibrated robot (identified table, offsets up to 0.5°) within 0.01 mm / 0.001° of the
    poses asked for; the same file without the flag still gives joint readings."""
    write_profile(profile_path, {"calibration": {"dh": CALIBRATED_DH}}, reason="test")
    p = load_profile(profile_path)
    rng = np.random.default_rng(24)
    q = [np.array([25.0, 30.0, 100.0, 15.0, 40.0, 20.0])]
    while len(q) < 30:
        nxt = q[-1] + rng.uniform(-3.0, 3.0, 6)
        if p.model.within_limits(nxt) and 15.0 < nxt[4] < 120.0:
            q.append(nxt)
    poses = _tool_pose(profile_path, np.array(q))
    src, out = tmp_path / "scan.csv", tmp_path / "targets.csv"
    src.write_text("X,Y,Z,RX,RY,RZ\n" + "\n".join(_csv(x) for x in poses) + "\n")

    r = ucal(
        "path", str(profile_path), str(src), "-o", str(out), "--near", _csv(q[0]),
        "--for-controller", "--json",
    )  # fmt: skip
    assert r.returncode == 0, r.stderr
    data = json.loads(r.stdout)
    assert data["for_controller"] is True and data["nominal_model"] == "tx90l"
    assert data["points"] == 30 and data["max_correction_mm"] > 1.0
    rows = list(csv.reader(out.read_text().splitlines()))
    assert rows[0] == ["X", "Y", "Z", "RX", "RY", "RZ", "shoulder", "elbow", "wrist"]
    targets = np.array([row[:6] for row in rows[1:]], float)
    assert {tuple(row[6:]) for row in rows[1:]} == {("lefty", "epositive", "wpositive")}

    nominal = load_model("tx90l")
    path = plan_joint_path(nominal, targets, p.tool_matrix, start_deg=q[0])
    readings = path.joints_deg
    reached = fk(p.model, readings, p.tool_matrix, p.joint_offsets_deg)
    want = pose_to_matrix(poses)
    mm = np.linalg.norm(reached[:, :3, 3] - want[:, :3, 3], axis=-1)
    deg = rotation_angle_deg(want[:, :3, :3], reached[:, :3, :3])
    assert np.max(mm) < 0.01 and np.max(deg) < 0.001, (np.max(mm), np.max(deg))

    r = ucal("path", str(profile_path), str(src), "-o", str(out), "--for-controller")
    assert r.returncode == 0, r.stderr
    assert "controller targets" in r.stdout and "largest correction" in r.stdout
    r = ucal("path", str(profile_path), str(src), "-o", str(out), "--near", _csv(q[0]))
    assert r.returncode == 0, r.stderr
    joints = np.array(
        [row[:6] for row in list(csv.reader(out.read_text().splitlines()))[1:]], float
    )
    np.testing.assert_allclose(joints, np.array(q), atol=1e-6)


def test_path_for_controller_needs_a_shipped_model(profile_path: Path, tmp_path: Path) -> None:
    text = profile_path.read_text().replace('model = "tx90l"', 'model = "my_arm"')
    profile_path.write_text(text)
    src, out = tmp_path / "scan.csv", tmp_path / "targets.csv"
    src.write_text("600,0,300,180,0,0\n")
    r = ucal("path", str(profile_path), str(src), "-o", str(out), "--for-controller")
    assert r.returncode == 2 and "robot.model" in r.stderr and str(profile_path) in r.stderr
    assert not out.exists()
