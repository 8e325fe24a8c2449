"""``ucal path PROFILE IN.csv -o OUT.csv``: one arm configuration per path, written per row in
the controller's words; a configuration change or a joint jump refused (exit 4) unless
``--allow-config-change``, then warned on stderr naming the point."""

from __future__ import annotations

import csv
import json
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from ucal.errors import EXIT_SAFETY
from ucal.kinematics.dh import fk, wrist_centre
from ucal.kinematics.rotations import matrix_to_pose
from ucal.profile import load_profile

RunMain = Callable[[list[str]], tuple[int, str, str]]
HEADER = ["J1", "J2", "J3", "J4", "J5", "J6", "shoulder", "elbow", "wrist"]
#: Readings of a scan whose elbow (J3) runs into its 145° limit on row 34: past it, the only
#: solutions inside the ranges have the other shoulder (J1 from 30° to about -134°).
SWING = np.tile([30.0, 20.0, 120.0, 0.0, 40.0, 0.0], (41, 1))
SWING[:, 2] = np.linspace(125.0, 150.0, 41)
NEAR = "30,20,125,0,40,0"


def scan(path: Path, profile: Path, joints: np.ndarray) -> Path:
    """Write the tool poses of ``joints`` as IN.csv: a comment and a header line first, so the
    pose of point k is on line k + 2."""
    p = load_profile(profile)
    poses = matrix_to_pose(fk(p.model, joints, p.tool_matrix, p.joint_offsets_deg))
    rows = "\n".join(",".join(repr(float(v)) for v in pose) for pose in poses)
    path.write_text(f"# a scan\nX,Y,Z,RX,RY,RZ\n{rows}\n", encoding="utf-8")
    return path


def read_rows(path: Path) -> tuple[list[str], np.ndarray, list[tuple[str, ...]]]:
    """OUT.csv → (header, the six numbers of each row, the configuration words of each row)."""
    rows = list(csv.reader(path.read_text(encoding="utf-8").splitlines()))
    return rows[0], np.array([r[:6] for r in rows[1:]], float), [tuple(r[6:]) for r in rows[1:]]


def words_from_joints(profile: Path, joints: np.ndarray) -> list[tuple[str, ...]]:
    """The configuration of each row from its readings, read off the arm: the wrist centre in
    front of axis 1 (lefty) or behind it, the signs of J3 and J5."""
    model = load_profile(profile).model
    out = []
    for q in joints:
        w = wrist_centre(model, q)
        front = w[0] * np.cos(np.radians(q[0])) + w[1] * np.sin(np.radians(q[0])) >= 0.0
        out.append(
            (
                "lefty" if front else "righty",
                "epositive" if q[2] >= 0.0 else "enegative",
                "wpositive" if q[4] >= 0.0 else "wnegative",
            )
        )
    return out


def test_a_path_that_swings_round_the_back_is_refused(
    profile: Path, tmp_path: Path, run_main: RunMain
) -> None:
    src, out = scan(tmp_path / "scan.csv", profile, SWING), tmp_path / "joints.csv"
    code, stdout, err = run_main(["path", str(profile), str(src), "-o", str(out), "--near", NEAR])
    assert code == EXIT_SAFETY and not out.exists() and stdout == ""
    (line,) = err.strip().splitlines()
    assert line.startswith(f"error: {src} point 34 (line 36): ")
    assert "the shoulder from lefty to righty (J1 30.00 to -134.08 deg" in line
    assert "round the back" in line and "--allow-config-change" in line

    code, stdout, _ = run_main(
        ["path", str(profile), str(src), "-o", str(out), "--near", NEAR, "--json"]
    )
    data = json.loads(stdout)
    assert code == data["exit_code"] == EXIT_SAFETY and "point 34 (line 36)" in data["error"]
    assert not out.exists()


def test_asked_for_the_swing_is_written_with_a_warning(
    profile: Path, tmp_path: Path, run_main: RunMain
) -> None:
    src, out = scan(tmp_path / "scan.csv", profile, SWING), tmp_path / "joints.csv"
    args = ["path", str(profile), str(src), "-o", str(out), "--near", NEAR]
    code, stdout, err = run_main([*args, "--allow-config-change"])
    assert code == 0, err
    (warning,) = err.strip().splitlines()
    assert warning.startswith(f"warning: {src} point 34 (line 36): the configuration changes")
    assert "changed or jumped into point(s) 34" in stdout
    header, joints, words = read_rows(out)
    assert header == HEADER
    assert words == words_from_joints(profile, joints)
    assert words[:33] == [("lefty", "epositive", "wpositive")] * 33
    assert words[33:] == [("righty", "enegative", "wnegative")] * 8
    assert joints[33, 0] == pytest.approx(-134.08, abs=0.01)

    code, stdout, _ = run_main([*args, "--allow-config-change", "--json"])
    data = json.loads(stdout)
    assert code == 0 and data["points"] == 41 and data["step_limit_deg"] == 30.0
    assert [c["shoulder"] for c in data["configurations"]] == ["lefty"] * 33 + ["righty"] * 8
    (change,) = data["configuration_changes"]
    assert (change["point"], change["line"], change["joint"]) == (34, 36, 3)
    assert change["changed"] == ["shoulder", "elbow", "wrist"]
    assert change["from"] == {"shoulder": "lefty", "elbow": "epositive", "wrist": "wpositive"}
    assert change["joints_before_deg"][0] == pytest.approx(30.0)
    assert change["kept_step_deg"] is None


def test_a_joint_step_beyond_the_limit_is_refused(
    profile: Path, tmp_path: Path, run_main: RunMain
) -> None:
    q = np.tile([0.0, 20.0, 90.0, 0.0, 60.0, 0.0], (5, 1))
    q[:, 0] = [0.0, 2.0, 4.0, 12.0, 14.0]
    src, out = scan(tmp_path / "scan.csv", profile, q), tmp_path / "joints.csv"
    args = ["path", str(profile), str(src), "-o", str(out), "--near", "0,20,90,0,60,0"]
    assert run_main(args)[0] == 0
    code, _, err = run_main([*args, "--max-step-deg", "5"])
    assert code == EXIT_SAFETY
    assert "point 4 (line 6): J1 by +8.00 deg (4.00 to 12.00), more than the 5 deg" in err
    code, _, err = run_main([*args, "--max-step-deg", "5", "--allow-config-change"])
    assert code == 0 and "warning:" in err and "point 4 (line 6)" in err
    assert run_main([*args, "--max-step-deg", "0"])[0] == 2


@settings(max_examples=15, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    seed=st.integers(0, 2**32 - 1),
    start=st.sampled_from(
        [[0.0, 30.0, 100.0, 10.0, 50.0, 0.0], [20.0, 10.0, -60.0, 0.0, -40.0, 5.0]]
    ),
)
def test_hypothesis_each_row_carries_the_configuration_of_its_joints(
    profile: Path, tmp_path: Path, run_main: RunMain, seed: int, start: list[float]
) -> None:
    """Random walks (steps up to 3° per joint) inside the ranges and inside one configuration,
    clear of its boundaries (the wrist centre 50 mm or more from the plane of axis 1, J3 and J5
    5° or more from 0: a walk across one is a change the path refuses), from starts in two
    configurations: the path is the walk, and every written row names the configuration its
    readings are in."""
    model = load_profile(profile).model
    rng = np.random.default_rng(seed)
    q = [np.array(start)]
    first = words_from_joints(profile, np.array(q))[0]

    def clear(joints: np.ndarray) -> bool:
        w = wrist_centre(model, joints)
        side = w[0] * np.cos(np.radians(joints[0])) + w[1] * np.sin(np.radians(joints[0]))
        same = words_from_joints(profile, joints[None])[0] == first
        return same and abs(side) > 50.0 and abs(joints[2]) > 5.0 and abs(joints[4]) > 5.0

    while len(q) < 25:
        nxt = q[-1] + rng.uniform(-3.0, 3.0, 6)
        if model.within_limits(nxt) and clear(nxt):
            q.append(nxt)
    walk = np.array(q)
    src, out = scan(tmp_path / "walk.csv", profile, walk), tmp_path / "walk_joints.csv"
    args = ["path", str(profile), str(src), "-o", str(out), "--near", ",".join(map(str, start))]
    code, _, err = run_main(args)
    assert code == 0 and err == "", err
    _, joints, words = read_rows(out)
    np.testing.assert_allclose(joints, walk, atol=1e-6)
    assert words == words_from_joints(profile, joints)


def test_for_controller_rows_carry_the_configuration(
    profile: Path, tmp_path: Path, run_main: RunMain
) -> None:
    q = np.tile([25.0, 30.0, 100.0, 15.0, 40.0, 20.0], (5, 1)) + np.arange(5)[:, None]
    src, out = scan(tmp_path / "scan.csv", profile, q), tmp_path / "targets.csv"
    args = ["path", str(profile), str(src), "-o", str(out), "--for-controller"]
    code, _, err = run_main([*args, "--near", "25,30,100,15,40,20"])
    assert code == 0, err
    header, _, words = read_rows(out)
    assert header == ["X", "Y", "Z", "RX", "RY", "RZ", "shoulder", "elbow", "wrist"]
    assert words == [("lefty", "epositive", "wpositive")] * 5


def test_help_documents_the_columns_and_the_refusal(run_main: RunMain) -> None:
    code, out, _ = run_main(["path", "--help"])
    assert code == 0
    for word in ("X, Y, Z", "RX, RY, RZ", "mm", "deg", "base frame", "Rot(x,RX)", "J1..J6"):
        assert word in out, word
    for word in ("shoulder", "lefty", "righty", "epositive", "wnegative", "VAL3 config"):
        assert word in out, word
    assert "--allow-config-change" in out and "--max-step-deg" in out and "exit 4" in out
    assert "examples/scan.csv" in out and "Examples:" in out
