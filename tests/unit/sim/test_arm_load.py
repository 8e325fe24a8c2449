"""The simulated arm bends under gravity and grows as it warms (``ucal.sim.arm``): its sag
against a planar elastostatic calculation written here, its growth against the model's reach,
the world keys that state them, and one truth for a served and an in-process cell."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.controller.client import SimpleMessageController
from ucal.cell import PAPER_CALIBRATION_POSE_DEG, CellProfile, WorldTruth
from ucal.errors import ProfileError
from ucal.kinematics.rotations import matrix_to_pose
from ucal.profile import default_profile_text, load_profile
from ucal.profile.models import model_sheet
from ucal.sim.cell import SimulatedCell
from ucal.sim.serve import SimulatedCellServer
from ucal.world import load_world, world_from_data

G = 9.80665
#: The transducer holder of paper 000's cell: 80 mm long, about 1 kg, its centre halfway.
HOLDER = {"mass_kg": 1.0, "centre_of_mass_mm": [0.0, 0.0, 40.0]}


@pytest.fixture(scope="module")
def profile(tmp_path_factory: pytest.TempPathFactory) -> CellProfile:
    path = tmp_path_factory.mktemp("arm") / "cell.toml"
    path.write_text(default_profile_text("tx90l"))
    return load_profile(path)


def _world(profile: CellProfile, data: dict) -> WorldTruth:
    return world_from_data(data, Path("world.toml"), profile)


def _bent(profile: CellProfile, k2: float, k3: float) -> WorldTruth:
    return _world(
        profile, {"robot": {"stiffness_nm_per_rad": [0, k2, k3, 0, 0, 0]}, "tool": HOLDER}
    )


def _ry(phi: float) -> np.ndarray:
    c, s = math.cos(phi), math.sin(phi)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def _rz(phi: float) -> np.ndarray:
    c, s = math.cos(phi), math.sin(phi)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def planar_sag_mm(q_deg: np.ndarray, k2: float, k3: float) -> np.ndarray:
    """The TX90L's flange displacement (mm, base frame) under gravity with springs on J2 and
    J3 alone, J4 = 0: the arm is a chain in the vertical plane of J1, its joints turning about
    the plane's normal (+y of the URDF, J1 turned): each link's centre of mass placed by the
    joint angles summed from the vertical, the torque about each axis g·Σ m·(x − x_axis) of
    what lies beyond it, the flange moved by each small turn, to first order."""
    sheet = model_sheet("tx90l")
    m, c0 = sheet.link_mass_kg, sheet.link_centre_of_mass_mm
    l2, l3 = sheet.upper_arm_mm, sheet.forearm_mm
    q = np.radians(q_deg)
    phi2, phi3, phi5 = q[1], q[1] + q[2], q[1] + q[2] + q[4]
    p2 = np.array([50.0, 0.0, 0.0])  # joint origins at the zero pose (URDF)
    p3_0, p5_0 = np.array([50.0, 50.0, l2]), np.array([50.0, 50.0, l2 + l3])
    flange_0 = p5_0 + [0.0, 0.0, 100.0]
    p3 = p2 + _ry(phi2) @ (p3_0 - p2)
    p5 = p3 + _ry(phi3) @ (p5_0 - p3_0)
    rz6 = _rz(q[5])
    bodies = [
        (m[1], p2 + _ry(phi2) @ (c0[1] - p2)),
        (m[2], p3 + _ry(phi3) @ (c0[2] - p3_0)),
        (m[3], p3 + _ry(phi3) @ (c0[3] - p3_0)),
        (m[4], p5 + _ry(phi5) @ (c0[4] - p5_0)),
        (m[5], p5 + _ry(phi5) @ (flange_0 - p5_0 + rz6 @ (c0[5] - flange_0))),
        (HOLDER["mass_kg"], p5 + _ry(phi5) @ [0.0, 0.0, 100.0 + 40.0]),
    ]
    flange = p5 + _ry(phi5) @ [0.0, 0.0, 100.0]
    torque2 = G * sum(mass * (x[0] - p2[0]) for mass, x in bodies) * 1e-3
    torque3 = G * sum(mass * (x[0] - p3[0]) for mass, x in bodies[1:]) * 1e-3
    move = np.zeros(3)
    for turn, axis_point in ((torque2 / k2, p2), (torque3 / k3, p3)):
        r = flange - axis_point
        move += turn * np.array([r[2], 0.0, -r[0]])  # d/dφ of R_y(φ)·r
    return _rz(q[0]) @ move


def _sag(world: WorldTruth, rigid: WorldTruth, q: np.ndarray) -> np.ndarray:
    return SimulatedCell(world).true_flange(q)[:3, 3] - SimulatedCell(rigid).true_flange(q)[:3, 3]


@pytest.mark.parametrize("k", [1e5, 1e6])
def test_the_flange_sags_at_the_calibration_pose_as_a_planar_calculation(
    profile: CellProfile, k: float
) -> None:
    """Paper 000's pose on a TX90L with its published link masses and an 80 mm, 1 kg holder:
    553 µm at 1e5 N·m/rad on J2 and J3, 55 µm at 1e6, within 1 % of the planar calculation."""
    q = PAPER_CALIBRATION_POSE_DEG
    sag = _sag(_bent(profile, k, k), _world(profile, {}), q)
    expected = planar_sag_mm(q, k, k)
    assert np.linalg.norm(sag - expected) <= 0.01 * np.linalg.norm(expected)
    assert sag[2] < 0.0  # it goes down
    assert np.linalg.norm(sag) == pytest.approx(0.553e5 / k, rel=0.01)


@settings(max_examples=25, deadline=None)
@given(
    k2=st.floats(1e5, 1e7),
    k3=st.floats(1e5, 1e7),
    q2=st.floats(-30.0, 90.0),
    q3=st.floats(0.0, 120.0),
)
def test_sag_follows_the_planar_calculation_and_scales_as_one_over_k(
    profile: CellProfile, k2: float, k3: float, q2: float, q3: float
) -> None:
    q = np.array([10.0, q2, q3, 0.0, 20.0, 0.0])
    rigid = _world(profile, {})
    sag = _sag(_bent(profile, k2, k3), rigid, q)
    expected = planar_sag_mm(q, k2, k3)
    assert np.linalg.norm(sag - expected) <= 0.01 * np.linalg.norm(expected) + 1e-6
    stiffer = _sag(_bent(profile, 10.0 * k2, 10.0 * k3), rigid, q)
    # as one over k to first order: the rest is the sag's own effect on the posture's torque,
    # a thousandth of it, seen against the whole sag (a small component alone is not a scale)
    assert np.linalg.norm(stiffer - sag / 10.0) <= 0.01 * np.linalg.norm(sag / 10.0) + 1e-6


def test_an_outstretched_arm_sags_down(profile: CellProfile) -> None:
    """J2 at 90°: the arm horizontal, 1.2 m out; its flange goes down, 1.8 mm at 1e5."""
    q = np.array([0.0, 90.0, 0.0, 0.0, 0.0, 0.0])
    sag = _sag(_bent(profile, 1e5, 1e5), _world(profile, {}), q)
    assert sag[2] < -1.5 and abs(sag[1]) < 1e-9


def test_a_world_without_stiffness_or_warmth_is_rigid_bit_for_bit(profile: CellProfile) -> None:
    rigid = SimulatedCell(_world(profile, {}))
    still = [
        {"robot": {"stiffness_nm_per_rad": [0, 0, 0, 0, 0, 0]}, "tool": HOLDER},
        {"robot": {"link_mass_kg": [1, 2, 3, 4, 5, 6]}, "arm": {"offset_k": 0.0}},
        {"arm": {"offset_k": 5.0, "expansion_per_k": 0.0}},
    ]
    rng = np.random.default_rng(36)
    for data in still:
        cell = SimulatedCell(_world(profile, data))
        for q in rng.uniform(-60, 60, (5, 6)):
            np.testing.assert_array_equal(cell.true_tcp(q, np.ones(6), 600.0), rigid.true_tcp(q))


@settings(max_examples=25, deadline=None)
@given(dt=st.floats(0.5, 20.0), q=st.lists(st.floats(-90.0, 90.0), min_size=6, max_size=6))
def test_a_warm_arm_grows_by_alpha_dt_over_its_reach(
    profile: CellProfile, dt: float, q: list[float]
) -> None:
    """Every length grows by α·ΔT, so the flange moves out from the base by α·ΔT of its
    distance from it, whatever the posture."""
    rigid = SimulatedCell(_world(profile, {})).true_flange(np.array(q))[:3, 3]
    warm = SimulatedCell(_world(profile, {"arm": {"offset_k": dt}})).true_flange(np.array(q))
    np.testing.assert_allclose(warm[:3, 3], rigid * (1.0 + 23e-6 * dt), rtol=1e-12, atol=1e-9)


@pytest.mark.parametrize("dt, growth_um", [(2.0, 55.2), (5.0, 138.0), (10.0, 276.0)])
def test_the_reach_grows_with_the_warm_up(
    profile: CellProfile, dt: float, growth_um: float
) -> None:
    """The TX90L outstretched (J2 at 90°): 50 + 500 + 550 + 100 = 1200 mm of reach from J1's
    axis, 23 ppm/K longer; the warm-up reaches 1 − 1/e of its rise after one time constant."""
    sheet = model_sheet("tx90l")
    reach = 50.0 + sheet.upper_arm_mm + sheet.forearm_mm + 100.0
    q = np.array([0.0, 90.0, 0.0, 0.0, 0.0, 0.0])
    cold = SimulatedCell(_world(profile, {})).true_flange(q)[0, 3]
    world = _world(profile, {"arm": {"warmup_k": dt, "warmup_time_constant_min": 20.0}})
    cell = SimulatedCell(world)
    assert cold == pytest.approx(reach)
    assert (cell.true_flange(q, t_s=1e9)[0, 3] - cold) * 1e3 == pytest.approx(growth_um, rel=1e-6)
    assert cell.true_flange(q, t_s=0.0)[0, 3] == cold
    after_tau = (cell.true_flange(q, t_s=1200.0)[0, 3] - cold) * 1e3
    assert after_tau == pytest.approx(growth_um * (1.0 - math.exp(-1.0)), rel=1e-6)


def test_a_world_with_stiffness_alone_takes_its_model_tables_masses(profile: CellProfile) -> None:
    world = _world(profile, {"robot": {"stiffness_nm_per_rad": [0, 1e5, 1e5, 0, 0, 0]}})
    sheet = model_sheet("tx90l")
    np.testing.assert_array_equal(world.arm.link_mass_kg, sheet.link_mass_kg)
    np.testing.assert_array_equal(world.arm.link_centre_of_mass_mm, sheet.link_centre_of_mass_mm)
    assert world.arm.tool_mass_kg == 0.0
    # gravity turned to +z lifts the arm: the sag changes sign
    up = _world(
        profile,
        {"robot": {"stiffness_nm_per_rad": [0, 1e5, 1e5, 0, 0, 0], "gravity_m_s2": [0, 0, G]}},
    )
    q = PAPER_CALIBRATION_POSE_DEG
    rigid = _world(profile, {})
    np.testing.assert_allclose(_sag(up, rigid, q), -_sag(world, rigid, q), rtol=0.01)


def test_spec_s_warm_arm_keys_are_the_arm_table_s(profile: CellProfile) -> None:
    """SPEC.md's ``[robot] temperature_rise_k``, ``warm_up_time_constant_min`` and
    ``expansion_ppm_per_k`` give the arm ``[arm]``'s keys give: a rise that holds for the run
    (no time constant) or grows during it, the links' expansion in ppm."""
    q = np.array([0.0, 90.0, 0.0, 0.0, 0.0, 0.0])

    def x_mm(data: dict, t_s: float) -> float:
        return float(SimulatedCell(_world(profile, data)).true_flange(q, t_s=t_s)[0, 3])

    held = {"robot": {"temperature_rise_k": 5.0, "expansion_ppm_per_k": 20.0}}
    same = {"arm": {"offset_k": 5.0, "expansion_per_k": 20e-6}}
    assert x_mm(held, 0.0) == pytest.approx(x_mm(same, 0.0), abs=1e-9)
    assert x_mm(held, 0.0) > x_mm({}, 0.0) + 0.1  # 100 ppm of 1.2 m
    growing = {"robot": {"temperature_rise_k": 5.0, "warm_up_time_constant_min": 20.0}}
    warmup = {"arm": {"warmup_k": 5.0, "warmup_time_constant_min": 20.0}}
    assert x_mm(growing, 0.0) == x_mm({}, 0.0)
    assert x_mm(growing, 1200.0) == pytest.approx(x_mm(warmup, 1200.0), abs=1e-9)


BAD_ARMS = [
    ("[robot]\nstiffness_nm_per_rad = [0, 1e5, 1e5]\n", "robot.stiffness_nm_per_rad", "6 values"),
    (
        "[robot]\nstiffness_nm_per_rad = [0, 50, 1e5, 0, 0, 0]\n",
        "robot.stiffness_nm_per_rad[1]",
        "0 (rigid) or >= 10000",
    ),
    (
        "[robot]\nstifness_nm_per_rad = [0, 1e5, 1e5, 0, 0, 0]\n",
        "robot.stifness_nm_per_rad",
        "did you mean stiffness_nm_per_rad?",
    ),
    ("[robot]\nlink_mass_kg = [1, 2, 3, 4, 5, -1]\n", "robot.link_mass_kg[5]", ">= 0"),
    ("[robot]\nlink_centre_of_mass_mm = [[0, 0, 0]]\n", "robot.link_centre_of_mass_mm", "6 values"),
    ("[robot]\ngravity_m_s2 = [0, 0, -98]\n", "robot.gravity_m_s2[2]", ">= -50"),
    ("[tool]\nmass_kg = -1.0\n", "tool.mass_kg", ">= 0"),
    ("[tool]\ncentre_of_mass = [0, 0, 40]\n", "tool.centre_of_mass", "did you mean"),
    ("[arm]\nwarmup_k = 80\n", "arm.warmup_k", "<= 50"),
    ("[arm]\nwarmup_time_constant_min = 0\n", "arm.warmup_time_constant_min", ">= 0.1"),
    ("[arm]\nexpansion_per_k = 0.01\n", "arm.expansion_per_k", "<= 0.0001"),
    ("[arm]\nwarmupk = 5\n", "arm.warmupk", "did you mean warmup_k?"),
    ("[robot]\ntemperature_rise_k = 60\n", "robot.temperature_rise_k", "<= 50"),
    (
        "[robot]\ntemperature_rise_k = 5\nwarm_up_time_constant_min = 0.05\n",
        "robot.warm_up_time_constant_min",
        ">= 0.1 min",
    ),
    (
        "[robot]\ntemperature_rise_k = 5\n[arm]\noffset_k = 5\n",
        "robot.temperature_rise_k",
        "given twice",
    ),
    ('[arm]\nwarmup_k = 5\n[robot]\nmodel = "tx90l"\n', None, None),
]


@pytest.mark.parametrize("text, key, message", BAD_ARMS, ids=[str(b[1]) for b in BAD_ARMS])
def test_arm_keys_are_validated_naming_the_key(
    text: str, key: str | None, message: str | None, profile: CellProfile, tmp_path: Path
) -> None:
    path = tmp_path / "world.toml"
    path.write_text(text)
    if key is None:
        assert load_world(path, profile).arm.warmup_k == 5.0
        return
    with pytest.raises(ProfileError) as err:
        load_world(path, profile)
    assert err.value.key == key
    assert message in str(err.value)
    assert err.value.exit_code == 2


def test_a_bad_arm_key_stops_the_command_with_exit_2(tmp_path: Path) -> None:
    (tmp_path / "cell.toml").write_text(default_profile_text("tx90l"))
    (tmp_path / "world.toml").write_text("[arm]\nwarmup_k = 80\n")
    run = subprocess.run(
        [sys.executable, "-m", "ucal", "calibrate", "cell.toml", "--sim", "world.toml", "--yes"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert run.returncode == 2
    assert "arm.warmup_k" in run.stderr


def test_a_served_cell_and_the_in_process_one_hold_the_same_true_pose(
    profile: CellProfile, tmp_path: Path
) -> None:
    """On the host clock (``sim serve``) the arm warms over the cell's seconds as it does in
    process: the pose the served cell logs after a move is the in-process cell's at that
    time, a bent and warming arm."""
    world = _world(
        profile,
        {
            "robot": {"stiffness_nm_per_rad": [2e5, 1e5, 1e5, 5e4, 5e4, 5e4]},
            "tool": HOLDER,
            "arm": {"warmup_k": 10.0, "warmup_time_constant_min": 0.1},
        },
    )
    log_path = tmp_path / "motions.jsonl"
    target = np.array([20.0, 40.0, 100.0, 10.0, 30.0, 5.0])
    with (
        SimulatedCellServer(world, profile, log_path=log_path, time_scale=0.0) as server,
        SimpleMessageController.from_url(server.urls["controller"]) as ctl,
    ):
        ctl.start_move(target, 0.5)
        ctl.wait_settled(target, timeout_s=10.0)
    record = json.loads(log_path.read_text().splitlines()[-1])
    cell = SimulatedCell(world)
    expected = cell.true_tcp(np.array(record["end_deg"]), np.sign(target), record["t_cell_s"])
    np.testing.assert_allclose(
        record["true_tcp_pose"], matrix_to_pose(expected), rtol=0.0, atol=1e-9
    )
    cold = matrix_to_pose(cell.true_tcp(target, np.sign(target), 0.0))
    assert record["t_cell_s"] > 0.0
    # the arm warmed (and bent) between the start and the log: the pose is not the cold one
    assert np.max(np.abs(np.array(record["true_tcp_pose"][:3]) - cold[:3])) > 1e-4


@pytest.mark.parametrize(
    "tx2, tx90", [("tx2-90", "tx90"), ("tx2-90l", "tx90l"), ("tx2-90xl", "tx90xl")]
)
def test_every_model_table_carries_its_links_masses(tx2: str, tx90: str) -> None:
    """The TX90 tables hold the URDF's masses (the arm's moving links: 46 kg on a TX90L); a
    TX2 table, whose description has none, its TX90 sibling's; the wrist's centres lie on the
    J4/J6 axis, 50 mm across from J1's."""
    sheet = model_sheet(tx90)
    np.testing.assert_array_equal(model_sheet(tx2).link_mass_kg, sheet.link_mass_kg)
    np.testing.assert_array_equal(
        model_sheet(tx2).link_centre_of_mass_mm, sheet.link_centre_of_mass_mm
    )
    assert 40.0 < sheet.link_mass_kg.sum() < 55.0
    np.testing.assert_allclose(sheet.link_centre_of_mass_mm[3:, :2], 50.0, atol=2.6)
