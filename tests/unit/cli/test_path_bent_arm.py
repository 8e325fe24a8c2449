"""``ucal path --for-controller`` on an arm that bends under gravity: each target makes up for
the sag of its own posture, so the simulated bent arm (``ucal.sim.arm``) lands on the poses
asked for; a profile that states a rigid arm, or no load posture, gives the targets as before
and says why."""

from __future__ import annotations

import csv
import json
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from ucal.cell import PAPER_CALIBRATION_POSE_DEG, WorldTruth
from ucal.errors import UnreachableError
from ucal.kinematics.dh import fk
from ucal.kinematics.filtering import controller_targets
from ucal.kinematics.path import plan_joint_path
from ucal.kinematics.rotations import matrix_to_pose, pose_to_matrix, rotation_angle_deg
from ucal.model.kinematic import SCAN_HALF_RANGE_DEG
from ucal.profile import load_profile, write_profile
from ucal.profile.models import controller_model, load_model
from ucal.sim.cell import SimulatedCell
from ucal.world import world_from_data

RunMain = Callable[[list[str]], tuple[int, str, str]]
#: The issue's bound on where the bent arm lands over the scanning region (mm).
LANDING_MM = 0.02
#: The softest arm of the published range on the shoulder and elbow, the other joints in
#: proportion to the TX90L table's nominal stiffness (J6 at the smallest a world may state).
STIFFNESS = [2.46e5, 1e5, 1e5, 2.6e4, 2.2e4, 1e4]
#: A 1.5 kg transducer holder whose centre lies 40 mm out on the flange's axis, and its frame.
TOOL = {
    "position_mm": [0.3, -0.2, 80.4],
    "rotation_deg": [0.2, -0.22, 0.0],
    "mass_kg": 1.5,
    "centre_of_mass_mm": [0.0, 0.0, 40.0],
}
OFFSETS = [0.8, -1.2, 1.5, -2.0, 1.1, 0.6]
LOAD_POSTURE = PAPER_CALIBRATION_POSE_DEG


def true_table() -> list[dict[str, float]]:
    """The TX90L's table with errors as the full level identifies them: lengths off by tenths
    of a millimetre, twists by hundredths of a degree, a Hayati β₂."""
    dh = load_model("tx90l").dh
    errors = [(0.0, 0.21, -0.03), (-0.17, 0.34, 0.02), (0.0, 0.12, 0.04)]
    errors += [(-0.39, 0.0, 0.03), (0.0, 0.0, 0.02), (0.0, 0.0, 0.0)]
    rows = []
    for (theta, d, a, alpha), (dd, da, dalpha) in zip(dh, errors, strict=True):
        rows.append(
            {
                "theta_offset_deg": float(theta),
                "d_mm": float(d + dd),
                "a_mm": float(a + da),
                "alpha_deg": float(alpha + dalpha),
            }
        )
    rows[1]["beta_deg"] = 0.04
    return rows


def sweep(n: int) -> np.ndarray:
    """Joint readings (n, 6) of a scan that sweeps the scanning region about the load posture
    (±20° of the arm, ±90/30/90° of the wrist), every joint at its own frequency."""
    t = np.linspace(0.0, 1.0, n)[:, None]
    freq = np.array([1.0, 2.0, 3.0, 5.0, 4.0, 7.0])
    phase = np.array([0.3, 1.1, 0.7, 0.2, 1.9, 0.4])
    return np.asarray(LOAD_POSTURE + SCAN_HALF_RANGE_DEG * np.sin(2 * np.pi * freq * t + phase))


@pytest.fixture
def bent_cell(profile: Path) -> tuple[Path, WorldTruth]:
    """A world whose arm bends, and the profile of that cell after the full level: its true
    table, the offsets the calibration sees at the load posture (the encoders' plus the sag
    there), the joints' stiffness, the tool's mass and the load posture."""
    table = true_table()
    world = world_from_data(
        {
            "robot": {
                "model": "tx90l",
                "dh": table,
                "joint_offsets_deg": OFFSETS,
                "stiffness_nm_per_rad": STIFFNESS,
            },
            "tool": TOOL,
        },
        profile.parent / "world.toml",
        load_profile(profile),
    )
    sag = SimulatedCell(world).sag_deg(LOAD_POSTURE)
    assert np.max(np.abs(sag)) > 0.01  # the load posture itself sags
    write_profile(
        profile,
        {
            "robot": {"stiffness_nm_per_rad": STIFFNESS},
            "tool": TOOL,
            "calibration": {
                "joint_offsets_deg": (np.asarray(OFFSETS) + sag).tolist(),
                "dh": table,
                "load_posture_deg": LOAD_POSTURE.tolist(),
            },
        },
        "the cell's truth",
    )
    return profile, world


def scan_file(path: Path, world: WorldTruth, joints: np.ndarray) -> tuple[Path, np.ndarray]:
    """IN.csv of the poses the bent arm reaches at ``joints``: reachable poses over the region."""
    cell = SimulatedCell(world)
    poses = np.array([matrix_to_pose(cell.true_tcp(q)) for q in joints])
    rows = "\n".join(",".join(repr(float(v)) for v in pose) for pose in poses)
    path.write_text(f"X,Y,Z,RX,RY,RZ\n{rows}\n", encoding="utf-8")
    return path, poses


def read_targets(path: Path) -> tuple[list[str], np.ndarray, list[list[str]]]:
    rows = list(csv.reader(path.read_text(encoding="utf-8").splitlines()))
    return rows[0], np.array([r[:6] for r in rows[1:]], float), rows[1:]


def landing(
    profile: Path, world: WorldTruth, targets: np.ndarray, asked: np.ndarray, start: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Where the bent arm puts the tool on each target (mm, deg from the asked pose): the
    controller solves the targets with its nominal model continuously from ``start`` and
    commands those readings; the world's arm bends under them."""
    p = load_profile(profile)
    readings = plan_joint_path(controller_model(p.model), targets, p.tool_matrix, start_deg=start)
    cell = SimulatedCell(world)
    reached = np.array([cell.true_tcp(q) for q in readings.joints_deg])
    want = pose_to_matrix(asked)
    mm = np.linalg.norm(reached[:, :3, 3] - want[:, :3, 3], axis=-1)
    return mm, rotation_angle_deg(want[:, :3, :3], reached[:, :3, :3])


def run_path(run_main: RunMain, profile: Path, src: Path, out: Path, near: np.ndarray) -> dict:
    near_s = ",".join(repr(float(v)) for v in near)
    args = ["path", str(profile), str(src), "-o", str(out), "--for-controller", "--near", near_s]
    code, stdout, err = run_main([*args, "--json"])
    assert code == 0, err
    data: dict = json.loads(stdout)
    return data


def test_the_bent_arm_lands_on_the_asked_poses_over_the_scanning_region(
    bent_cell: tuple[Path, WorldTruth], tmp_path: Path, run_main: RunMain
) -> None:
    """Stiffness 1e5 N·m/rad on J2 and J3, a 1.5 kg holder: the targets put the bent arm
    within 0.02 mm of every pose of a scan over the scanning region; the targets of the same
    cell stated rigid miss by the sag relative to the load posture (over 0.1 mm), which is
    what the deflection column says each target was moved by."""
    profile, world = bent_cell
    q = sweep(240)
    src, asked = scan_file(tmp_path / "scan.csv", world, q)
    out = tmp_path / "targets.csv"

    data = run_path(run_main, profile, src, out, q[0])
    assert data["gravity_corrected"] is True
    np.testing.assert_allclose(data["load_posture_deg"], LOAD_POSTURE)
    header, targets, rows = read_targets(out)
    assert header[-1] == "deflection_mm" and len(header) == 10
    assert {tuple(r[6:9]) for r in rows} == {("lefty", "epositive", "wpositive")}
    mm, deg = landing(profile, world, targets, asked, q[0])
    assert np.max(mm) < LANDING_MM and np.max(deg) < 0.001, (np.max(mm), np.max(deg))

    # the same cell stated rigid: today's targets, which the bent arm misses by its sag
    write_profile(profile, {"robot": {"stiffness_nm_per_rad": [0.0] * 6}}, "stated rigid")
    rigid_out = tmp_path / "rigid.csv"
    rigid = run_path(run_main, profile, src, rigid_out, q[0])
    assert rigid["gravity_corrected"] is False and "rigid arm" in rigid["gravity_note"]
    rigid_header, rigid_targets, _ = read_targets(rigid_out)
    assert rigid_header == header[:9]
    missed, _ = landing(profile, world, rigid_targets, asked, q[0])
    assert np.max(missed) > 0.1 and np.mean(missed) > 5 * LANDING_MM, np.max(missed)
    moved = np.array([float(r[9]) for r in rows])
    np.testing.assert_allclose(
        moved, np.linalg.norm(targets[:, :3] - rigid_targets[:, :3], axis=1), atol=2e-9
    )
    assert data["max_deflection_mm"] == pytest.approx(np.max(moved), abs=1e-9)
    # what the correction moves is what the uncorrected targets miss by, to a few per cent
    assert np.max(moved) == pytest.approx(np.max(missed), rel=0.05)


def test_offsets_without_a_load_posture_are_not_corrected_and_say_so(
    bent_cell: tuple[Path, WorldTruth], tmp_path: Path, run_main: RunMain
) -> None:
    """The arm gives, but the offsets state no posture whose load they hold (a calibration
    from before the key): the targets are the rigid ones, and the output names the key."""
    profile, world = bent_cell
    text = profile.read_text(encoding="utf-8")
    lines = [ln for ln in text.splitlines() if not ln.startswith("load_posture_deg")]
    profile.write_text("\n".join(lines) + "\n", encoding="utf-8")
    assert load_profile(profile).load_posture_deg is None
    q = sweep(240)[:12]
    src, _ = scan_file(tmp_path / "scan.csv", world, q)
    out = tmp_path / "targets.csv"
    data = run_path(run_main, profile, src, out, q[0])
    assert data["gravity_corrected"] is False
    assert "load_posture_deg" in data["gravity_note"] and "calibrate" in data["gravity_note"]
    assert read_targets(out)[0][-1] == "wrist"
    near = ",".join(repr(float(v)) for v in q[0])
    code, _, err = run_main(
        ["path", str(profile), str(src), "-o", str(out), "--for-controller", "--near", near]
    )
    assert code == 0 and err.startswith("warning: targets not corrected for the arm's sag")


def test_a_sag_that_takes_a_joint_out_of_range_names_the_point() -> None:
    """A target whose readings the deflection pushes past a joint's range is refused, naming
    the point, the joint and the sag, not handed to the controller."""
    model = load_model("tx90l")
    q = np.tile([10.0, 30.0, 100.0, 20.0, 40.0, 10.0], (2, 1))
    q[:, 2] = model.joint_max_deg[2] - [1.0, 0.01]
    tool = np.eye(4)
    poses = matrix_to_pose(fk(model, q, tool))

    def sag(joints: np.ndarray) -> np.ndarray:
        out = np.zeros_like(joints)
        out[:, 2] = -0.05  # the elbow gives 0.05° the way its reading falls
        return out

    with pytest.raises(UnreachableError, match=r"path point 2: J3 .*sag.*-0\.0500 deg"):
        controller_targets(model, controller_model(model), poses, tool, start_deg=q[0], sag_deg=sag)
