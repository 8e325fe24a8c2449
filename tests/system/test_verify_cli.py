"""``ucal verify`` as a process against the loopback simulated cell (paper 000, §5.2)."""

from __future__ import annotations

import json
import re
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import tomlkit

from ucal.acoustics import sound_speed_m_s
from ucal.profile import create_profile, write_profile

from doubles import counting_moves, ucal_here

pytestmark = pytest.mark.system

TRUE_OFFSETS_DEG = [0.4, -0.5, 0.6, -0.7, 0.5, 0.3]
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def run_ucal(*args: str) -> subprocess.CompletedProcess:
    """``ucal ARGS`` in this process (``doubles.ucal_here``: the same command line without a
    new interpreter's imports); the tests that read a logged warning run a process."""
    return ucal_here(*args)


@pytest.fixture
def world(tmp_path: Path) -> Path:
    """Hidden joint offsets, everything else nominal, no noise."""
    path = tmp_path / "world.toml"
    path.write_text(
        "[robot]\njoint_offsets_deg = [" + ", ".join(map(str, TRUE_OFFSETS_DEG)) + "]\n",
        encoding="utf-8",
    )
    return path


def make_profile(tmp_path: Path, name: str, offsets_deg: list[float] | None) -> Path:
    path = create_profile(tmp_path / name, "tx90l")
    # a doweled, levelled block: with a hand-placed block's yaw tolerance joint 1 cannot be
    # calibrated (one rotation about the base axis with the block's yaw)
    write_profile(
        path,
        {"sample": {"position_std_mm": 0.5, "rotation_std_deg": [0.01, 0.01, 0.01]}},
        "fixtured block",
    )
    if offsets_deg is not None:
        # as `ucal calibrate` would have written it, the sound speed of the tank measured
        cal = {
            "joint_offsets_deg": offsets_deg,
            "unidentified_tcp_mm": [0.12, 0.25],
            "sound_speed_m_s": round(float(sound_speed_m_s(20.0)), 3),
        }
        write_profile(path, {"calibration": cal}, "calibrate")
    return path


def check_shape(out: dict, points: int) -> None:
    assert out["points"] == points
    for key in ("before_mm", "after_mm"):
        for stat in ("mean", "max", "std"):
            assert len(out[key][stat]) == 3
            assert all(isinstance(v, float) and np.isfinite(v) for v in out[key][stat])
    for p in ("before", "after"):
        dev = np.array(out["deviations_mm"][p])
        assert dev.shape == (points, 3)
        st = out[f"{p}_mm"]
        assert st["mean"] == pytest.approx(np.abs(dev).mean(0).tolist())
        assert st["max"] == pytest.approx(np.abs(dev).max(0).tolist())
        assert st["std"] == pytest.approx(np.abs(dev).std(0).tolist())
    assert out["moves"] > 0 and out["pulser_reads"] > 0


@pytest.mark.timeout(300)
def test_calibrated_profile_verifies_far_better_after(tmp_path: Path, world: Path) -> None:
    profile = make_profile(tmp_path, "cell.toml", TRUE_OFFSETS_DEG)
    before_bytes = profile.read_bytes()
    plot = tmp_path / "report.png"
    r = run_ucal(
        "verify",
        str(profile),
        "--sim",
        str(world),
        "--points",
        "4",
        "--plot",
        str(plot),
        "--yes",
        "--json",
    )
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout)
    check_shape(out, 4)
    # stderr is not a terminal: a plain progress line per point and pass, --json or not
    steps = re.findall(r"^verify \[(\d+)/12\] (?:before|after) point", r.stderr, re.MULTILINE)
    assert steps == [str(i) for i in range(8)]  # then the four edge scans of the tool check
    assert "verify [10/12] tool check along block X, tool turned" in r.stderr
    assert re.search(r"^verify \[12/12\] solving \(\d+ moves, \d+ reads, about ", r.stderr, re.M)
    # points in three orientations, the tilted ones over a patch of their own
    groups = {g["name"]: g for g in out["groups"]}
    assert [groups[n]["points"] for n in ("down", "turned", "tilted")] == [[1, 2], [3], [4]]
    assert groups["tilted"]["height_mm"] == 60.0 and groups["down"]["height_mm"] == 30.0
    assert all(max(g["after_max_mm"]) < 0.05 for g in out["groups"])
    assert out["passed"] is True and out["tolerance_mm"] == 0.5  # [procedure] default
    assert out["before_source"].startswith("history entry")
    before = np.array(out["before_mm"]["mean"])
    after_max = np.array(out["after_mm"]["max"])
    # hidden offsets of about half a degree: millimetres off before, micrometres after
    assert np.max(before) > 1.0
    assert np.all(after_max < 0.05), out["after_mm"]
    assert np.linalg.norm(before) > 50 * np.linalg.norm(out["after_mm"]["mean"])
    # the measured reached points agree with the simulator's truth
    assert np.all(np.array(out["truth"]["measurement_error_max_mm"]) < 0.01), out["truth"]
    # the right tool: the edges find the real TCP where the profile's is (up to the 8 ns
    # electronic delay, 6 µm of water path)
    tool = out["tool_check"]
    assert [(e["axis"], e["tool"]) for e in tool["edges"]] == [
        ("X", "down"),
        ("Y", "down"),
        ("X", "turned"),
        ("Y", "turned"),
    ]
    assert np.max(np.abs(tool["offset_mm"])) < 0.01, tool
    assert tool["separated"] is True and abs(tool["along_beam_mm"]) < 0.01
    assert np.max(np.abs(tool["across_beam_flange_mm"])) < 0.01
    assert plot.read_bytes()[:8] == PNG_MAGIC
    assert profile.read_bytes() == before_bytes  # verify never writes the profile


def verify_with_true_tool(
    tmp_path: Path,
    position_mm: list[float],
    points: int,
    *extra: str,
    rotation_deg: tuple[float, float, float] = (0.0, 0.0, 0.0),
) -> dict:
    """verify --json of a profile with the right offsets and its drawing's tool (0, 0, 80 mm in
    the flange frame, not turned) on a cell whose tool is at ``position_mm`` turned
    ``rotation_deg``: exit 1; its JSON object."""
    world = tmp_path / "world.toml"
    world.write_text(
        "[robot]\njoint_offsets_deg = [" + ", ".join(map(str, TRUE_OFFSETS_DEG)) + "]\n"
        f"[tool]\nposition_mm = {position_mm}\nrotation_deg = {list(rotation_deg)}\n",
        encoding="utf-8",
    )
    profile = make_profile(tmp_path, "cell.toml", TRUE_OFFSETS_DEG)
    r = run_ucal(
        "verify",
        str(profile),
        "--sim",
        str(world),
        "--points",
        str(points),
        "--yes",
        "--json",
        "-q",
        *extra,
    )
    assert r.returncode == 1, r.stderr
    return json.loads(r.stdout)


@pytest.mark.timeout(120)
def test_tool_off_across_the_beam_fails(tmp_path: Path) -> None:
    """The real tool 1 mm off the profile's across the beam (flange x; the beam is flange z):
    water paths at normal incidence cannot see it, the edges of the XY face do: ~1 mm after
    calibration on one block axis, as the truth has it, above the tolerance: exit 1."""
    out = verify_with_true_tool(tmp_path, [1.0, 0.0, 80.0], 1, "--tolerance-mm", "0.98")
    assert out["passed"] is False and "above the tolerance of 0.98 mm" in out["error"]
    assert out["marginal"] is True  # 1 mm against 0.98: closer than what verify measures to
    after = np.abs(np.array(out["deviations_mm"]["after"][0]))
    true_after = np.abs(
        np.array(out["truth"]["reached_mm"]["after"][0]) - np.array(out["nominal_mm"][0])
    )
    # the tool's millimetre shows on one axis across the beam, none on the others
    assert sorted(after) == pytest.approx([0.0, 0.0, 1.0], abs=0.02), after
    assert np.max(np.abs(out["tool_check"]["offset_mm"])) == pytest.approx(1.0, abs=0.02)
    # and agrees with the truth of the same point
    assert after == pytest.approx(true_after, abs=0.01)
    assert np.all(np.array(out["truth"]["after_error_max_mm"]) < 0.01), out["truth"]


@pytest.mark.timeout(120)
def test_tool_off_along_and_across_the_beam_shows_in_every_orientation(tmp_path: Path) -> None:
    """A tool 1 mm longer and 0.8 / −0.5 mm off across the beam than the profile says: the
    edge scans in both senses about the beam split the two, and every point — straight down,
    turned, tilted 15° over its own patch — carries what the real TCP does there, as the
    simulator's truth of the same points says."""
    out = verify_with_true_tool(tmp_path, [0.8, -0.5, 81.0], points=3)
    assert out["marginal"] is False  # over 1 mm against 0.5
    assert out["tool_check"]["misfit_mm"] < 0.02  # the beam where the profile says: consistent
    assert not any("disagree" in n for n in out["notes"])
    tool = out["tool_check"]
    assert tool["separated"] is True
    assert tool["along_beam_mm"] == pytest.approx(1.0, abs=0.01)
    assert tool["across_beam_flange_mm"] == pytest.approx([0.8, -0.5, 0.0], abs=0.01)
    nominal = np.array(out["nominal_mm"])
    after = np.array(out["deviations_mm"]["after"])
    true_after = np.array(out["truth"]["reached_mm"]["after"]) - nominal
    assert after == pytest.approx(true_after, abs=0.01)
    # each orientation puts the error elsewhere: the tilted point is not the down point
    assert np.max(np.abs(after[2] - after[0])) > 0.2
    assert [g["name"] for g in out["groups"]] == ["down", "turned", "tilted"]


@pytest.mark.timeout(300)
def test_uncalibrated_profile_before_equals_after_and_fails(tmp_path: Path, world: Path) -> None:
    """Half a degree of offsets the profile does not know: millimetres off after calibration
    too, above the tolerance: a result (the full object with the error fields), exit 1."""
    profile = make_profile(tmp_path, "cell.toml", None)
    r = run_ucal(
        "verify",
        str(profile),
        "--sim",
        str(world),
        "--points",
        "2",
        "--yes",
        "--json",
        "-q",
        "--tolerance-mm",
        "0.8",
    )
    assert r.returncode == 1, r.stderr
    assert "verify [" not in r.stderr and "passes" not in r.stderr  # -q: no progress, no plan
    out = json.loads(r.stdout)
    check_shape(out, 2)
    assert out["passed"] is False and out["tolerance_mm"] == 0.8
    assert out["exit_code"] == 1 and "above the tolerance of 0.8 mm" in out["error"]
    assert "no calibration in the profile's history" in out["before_source"]
    before = np.array(out["deviations_mm"]["before"])
    after = np.array(out["deviations_mm"]["after"])
    assert np.max(np.abs(before)) > 1.0
    assert after == pytest.approx(before, abs=0.02)
    # default picture next to the profile
    assert (tmp_path / "cell.verify.png").read_bytes()[:8] == PNG_MAGIC


@pytest.mark.timeout(60)
def test_table_output_and_refusals(tmp_path: Path, world: Path) -> None:
    profile = make_profile(tmp_path, "cell.toml", TRUE_OFFSETS_DEG)
    # neither --sim nor URLs: usage error
    r = run_ucal("verify", str(profile), "--yes")
    assert r.returncode == 2 and "--sim" in r.stderr and "Traceback" not in r.stderr
    # no terminal and no --yes: refused before moving
    r = run_ucal("verify", str(profile), "--sim", str(world), "--points", "1")
    assert r.returncode == 2 and "--yes" in r.stderr
    # unknown picture format
    r = run_ucal(
        "verify", str(profile), "--sim", str(world), "--plot", str(tmp_path / "x.xyz"), "--yes"
    )
    assert r.returncode == 2 and "x.xyz" in r.stderr


@pytest.mark.timeout(60)
def test_unreachable_points_refused_without_motion(tmp_path: Path) -> None:
    profile = make_profile(tmp_path, "cell.toml", None)
    # move the block 1.5 m away: no point can be reached; refused while planning
    doc = tomlkit.parse(profile.read_text(encoding="utf-8"))
    pos = [float(v) for v in doc["sample"]["position_mm"]]
    write_profile(profile, {"sample": {"position_mm": [pos[0] + 1500.0, pos[1], pos[2]]}}, "test")
    r = run_ucal("verify", str(profile), "--sim", "--points", "4", "--yes", "--json")
    assert r.returncode == 4, r.stderr
    assert "plan" in r.stderr
    assert json.loads(r.stdout) == {
        "error": r.stderr.strip().removeprefix("error: "),
        "exit_code": 4,
    }
    assert not (tmp_path / "cell.verify.png").exists()


@pytest.mark.timeout(400)
def test_calibrate_then_verify(tmp_path: Path, world: Path) -> None:
    pytest.importorskip("ucal.cli.calibrate", reason="`ucal calibrate` not available")
    profile = make_profile(tmp_path, "cell.toml", None)
    r = run_ucal("calibrate", str(profile), "--sim", str(world), "--yes", "--json")
    assert r.returncode == 0, r.stderr
    r = run_ucal("verify", str(profile), "--sim", str(world), "--points", "2", "--yes", "--json")
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout)
    check_shape(out, 2)
    assert np.max(out["before_mm"]["mean"]) > 1.0
    assert np.max(out["after_mm"]["max"]) < 0.1, out["after_mm"]
    # calibrate kept its readings beside its write; verify read the calibration pose's three
    # faces again at its start and end (six moves): the tank as it was, 20 °C, still
    assert (profile.parent / "cell.toml.history" / "0002-readings.json").exists()
    tank = out["tank"]
    assert tank["seen"] == "sound speed" and tank["used"] and tank["extra_moves"] == 6
    assert [tank[k]["dof"] for k in ("start", "end")] == [2, 2]
    # the speed as calibrate measured it (±0.4 m/s), changed by nothing since
    c_now, c_std = out["sound_speed_now_m_s"], out["sound_speed_now_std_m_s"]
    assert abs(c_now - float(sound_speed_m_s(20.0))) < 3 * c_std < 1.5
    assert abs(c_now - out["sound_speed_m_s"]) < 3 * tank["change_std_m_s"] < 0.3
    assert abs(out["sound_speed_run_drift_m_s_per_min"]) < 3 * tank["drift_std_m_s_per_min"]
    assert any("read again" in n for n in out["notes"])


@pytest.mark.timeout(120)
def test_ctrl_c_stops_and_exits_130(tmp_path: Path, world: Path) -> None:
    profile = make_profile(tmp_path, "cell.toml", TRUE_OFFSETS_DEG)
    before_bytes = profile.read_bytes()
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "ucal",
            "verify",
            str(profile),
            "--sim",
            str(world),
            "--points",
            "4",
            "--yes",
        ],
        stdin=subprocess.DEVNULL,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        # the second point's progress line shows the robot is measuring
        line = ""
        while "[1/12]" not in line:
            line = proc.stderr.readline()
            assert line, "verify ended before measuring a point"
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 130, err
    assert "interrupted" in err and "Traceback" not in err
    assert not (tmp_path / "cell.verify.png").exists()
    assert profile.read_bytes() == before_bytes


@pytest.mark.timeout(120)
def test_region_check_passes_the_right_model_and_fails_the_wrong_one(
    tmp_path: Path, world: Path
) -> None:
    """``verify --region``: the right offsets pass; offsets the profile does not know tilt the
    beam off normal at postures spread over the block, a misfit: exit 1 with the result."""
    good = make_profile(tmp_path, "good.toml", TRUE_OFFSETS_DEG)
    r = run_ucal("verify", str(good), "--sim", str(world), "--region", "4", "--yes", "--json")
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout)
    assert out["passed"] is True and out["region"]["verdict"] == "ok"
    assert out["region"]["postures"] == 4 and out["region"]["max_tilt_deg"] < 0.001
    # what the calibration could not see is said beside what the region measured
    assert out["region"]["unidentified_tcp_mm"] == {"mean": 0.12, "max": 0.25, "quantities": []}
    assert out["moves"] > 0 and out["pulser_reads"] > 0
    # the procedure's plan and progress on stderr
    assert "Region check of" in r.stderr and "Estimated time on a real cell" in r.stderr
    assert "verify [4/4] solving" in r.stderr

    bad = make_profile(tmp_path, "bad.toml", None)
    before = bad.read_bytes()
    r = run_ucal("verify", str(bad), "--sim", str(world), "--region", "4", "--yes", "--json")
    assert r.returncode == 1, r.stderr
    out = json.loads(r.stdout)
    assert out["passed"] is False and out["region"]["verdict"] == "misfit"
    assert out["exit_code"] == 1 and out["error"].startswith("region check failed")
    assert out["region"]["max_tilt_deg"] > 0.3
    assert out["region"]["unidentified_tcp_mm"] is None  # never calibrated: none stated
    assert bad.read_bytes() == before  # never written


@pytest.mark.timeout(120)
def test_a_beam_off_the_profiles_is_said_not_hidden(tmp_path: Path) -> None:
    """A tool turned 0.3° off its drawing (its beam 0.3° off the profile's, as before
    ``tool-frame``): the flange orientation the postures give is off by as much, differently in
    each sense about the beam, so the 'after' figures are off by tenths of a millimetre. The
    four edge scans disagree by about that much, and verify says so, with the verdict
    marginal within it."""
    out = verify_with_true_tool(
        tmp_path, [0.0, 0.0, 80.0], 2, "--tolerance-mm", "0.3", rotation_deg=(0.3, 0.0, 0.0)
    )
    misfit = out["tool_check"]["misfit_mm"]
    off = np.max(out["truth"]["after_error_max_mm"])  # measured minus true, worst axis
    assert off > 0.1 and misfit > 0.1  # a real effect, and seen
    assert misfit == pytest.approx(off, rel=0.5)  # of the size it says
    [note] = [n for n in out["notes"] if "disagree" in n]
    assert "run `ucal tool-frame`" in note


def test_offsets_calibrate_left_undetermined_refuse_before_the_first_motion(tmp_path, monkeypatch):
    """A tx90xl calibrated with joints 2 and 3 left undetermined: with the cell's true ones
    2.1° and −0.6° off, its "after" points stood 25 mm lower than the profile put them, and
    verify refused after 175 moves, the tool predicted 5 mm from the XY face. The plan keeps
    the room those offsets can take; where no choice of the points keeps it, verify refuses
    before the first motion and names them."""
    profile = tmp_path / "cell.toml"
    create_profile(profile, "tx90xl")
    write_profile(
        profile,
        {
            "tool": {
                "position_mm": [-2.238, -0.131, 138.199],
                "rotation_deg": [0.548, -0.529, 0.0],
                "position_std_mm": [0.026, 0.014, 0.848],
                "rotation_std_deg": [0.000642, 0.000649, 0.5],
            },
            "sample": {
                "position_mm": [375.008, 170.517, -223.411],
                "rotation_deg": [0.705, 0.868, 0.0],
            },
            "calibration": {
                "joint_offsets_deg": [-0.890844, 0.0, 0.0, 2.260006, -1.443715, 0.0],
                "std_deg": [0.500038, -1.0, -1.0, 0.005609, 0.000672, -1.0],
                "unobservable_joints": [2, 3, 6],
            },
        },
        "calibrated with joints 2, 3 and 6 undetermined",
    )
    moves = counting_moves(monkeypatch)
    out = run_ucal("verify", str(profile), "--sim", "--yes", "--json", "-q", "--points", "3")
    assert out.returncode == 4, out.stderr
    assert moves["n"] == 0
    error = json.loads(out.stdout)["error"]
    assert "joint(s) 2, 3 (not determined by the last calibration" in error
    assert "a calibration that determines joint 2's offset would lift it" in error
