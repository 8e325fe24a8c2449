"""World files: every key optional, overrides over the profile's nominal world, validation."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
import tomlkit

from ucal.cell import DEFAULT_PULSER_DELAY_NS, CellProfile, PulserTruth, WorldTruth
from ucal.errors import ProfileError
from ucal.profile import (
    default_profile_text,
    description_keys,
    history_dir,
    load_profile,
    write_profile,
)
from ucal.profile.models import load_model
from ucal.profile.validation import DH_KEYS
from ucal.sim.cell import SimulatedCell
from ucal.world import load_world, world_warnings


@pytest.fixture
def profile(tmp_path: Path) -> CellProfile:
    path = tmp_path / "cell.toml"
    path.write_text(default_profile_text("tx90l"))
    return load_profile(path)


def _world(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "world.toml"
    path.write_text(text)
    return path


def _assert_same(a: WorldTruth, b: WorldTruth) -> None:
    np.testing.assert_array_equal(a.model.dh, b.model.dh)
    for name in (
        "joint_offsets_deg",
        "tool_position_mm",
        "tool_rotation_deg",
        "sample_position_mm",
        "sample_rotation_deg",
        "initial_joints_deg",
    ):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    for name in (
        "sample_face_size_mm",
        "water_temperature_c",
        "frequency_mhz",
        "element_diameter_mm",
        "noise",
    ):
        assert getattr(a, name) == getattr(b, name), name
    np.testing.assert_allclose(a.reflector.point_mm, b.reflector.point_mm)
    np.testing.assert_allclose(a.reflector.normal, b.reflector.normal)


def test_no_world_and_empty_world_are_nominal(profile: CellProfile, tmp_path: Path) -> None:
    nominal = WorldTruth.nominal(profile)
    _assert_same(load_world(None, profile), nominal)
    _assert_same(load_world(_world(tmp_path, "# nothing hidden\n"), profile), nominal)
    np.testing.assert_array_equal(nominal.joint_offsets_deg, np.zeros(6))
    assert nominal.noise.tof_ns == 0.0


def test_world_overrides(profile: CellProfile, tmp_path: Path) -> None:
    path = _world(
        tmp_path,
        """
[robot]
joint_offsets_deg = [0.5, -0.3, 0.25, 0.1, -0.4, 0.2]
initial_joints_deg = [0, 10, 90, 0, 45, 0]
[tool]
position_mm = [0.4, -0.2, 81.5]
[sample]
rotation_deg = [0.5, -0.25, 1.0]
face_size_mm = 400
[reflector]
point_mm = [500, -100, -300]
normal = [0, 0.1, 2]
size_mm = [150, 250]
[water]
temperature_c = 23.5
[transducer]
frequency_mhz = 10
[noise]
tof_ns = 0.5
amplitude = 0.02
seed = 7
""",
    )
    w = load_world(path, profile)
    np.testing.assert_array_equal(w.joint_offsets_deg, [0.5, -0.3, 0.25, 0.1, -0.4, 0.2])
    np.testing.assert_array_equal(w.initial_joints_deg, [0, 10, 90, 0, 45, 0])
    np.testing.assert_array_equal(w.tool_position_mm, [0.4, -0.2, 81.5])
    np.testing.assert_array_equal(w.tool_rotation_deg, profile.tool_rotation_deg)  # not given
    np.testing.assert_array_equal(w.sample_position_mm, profile.sample_position_mm)
    np.testing.assert_array_equal(w.sample_rotation_deg, [0.5, -0.25, 1.0])
    assert w.sample_face_size_mm == 400.0
    np.testing.assert_array_equal(w.reflector.point_mm, [500, -100, -300])
    np.testing.assert_allclose(w.reflector.normal, np.array([0, 0.1, 2]) / np.hypot(0.1, 2))
    np.testing.assert_array_equal(w.reflector.size_mm, [150, 250])
    assert w.water_temperature_c == 23.5
    assert w.frequency_mhz == 10.0
    assert w.element_diameter_mm == profile.element_diameter_mm
    assert (w.noise.tof_ns, w.noise.amplitude, w.noise.seed) == (0.5, 0.02, 7)
    np.testing.assert_array_equal(w.model.dh, profile.model.dh)


def test_world_partial_reflector_keeps_the_profile_plate(
    profile: CellProfile, tmp_path: Path
) -> None:
    w = load_world(_world(tmp_path, "[reflector]\nnormal = [0.01, 0, 1]\n"), profile)
    np.testing.assert_allclose(w.reflector.point_mm, profile.reflector_points_mm.mean(0))
    assert w.reflector.normal[0] == pytest.approx(0.01 / np.hypot(0.01, 1))


def test_world_model_and_dh(profile: CellProfile, tmp_path: Path) -> None:
    w = load_world(_world(tmp_path, '[robot]\nmodel = "tx90xl"\n'), profile)
    np.testing.assert_array_equal(w.model.dh, load_model("tx90xl").dh)
    np.testing.assert_array_equal(w.model.joint_min_deg, profile.model.joint_min_deg)

    dh = profile.model.dh.copy()
    dh[1, 2] += 0.8  # upper arm 0.8 mm longer than nominal
    doc = tomlkit.document()
    robot = tomlkit.table()
    robot["dh"] = [dict(zip(DH_KEYS, map(float, row), strict=True)) for row in dh]
    doc["robot"] = robot
    w = load_world(_world(tmp_path, tomlkit.dumps(doc)), profile)
    np.testing.assert_array_equal(w.model.dh, dh)
    np.testing.assert_array_equal(w.tool_position_mm, profile.tool_position_mm)


def test_world_needs_a_plate_if_the_profile_has_none(profile: CellProfile, tmp_path: Path) -> None:
    bare = profile.replace(reflector_points_mm=None)
    with pytest.raises(ProfileError) as err:
        load_world(_world(tmp_path, "[reflector]\npoint_mm = [0, 0, 0]\n"), bare)
    assert err.value.key == "reflector.normal"
    w = load_world(
        _world(tmp_path, "[reflector]\npoint_mm = [1, 2, 3]\nnormal = [0, 0, 1]\n"), bare
    )
    np.testing.assert_array_equal(w.reflector.point_mm, [1, 2, 3])


_ROW2 = "{theta_offset_deg = -90, d_mm = 50, a_mm = 500, alpha_deg = 0"


def _dh_world(row: str) -> str:
    """A world whose ``[robot] dh`` has ``row`` first or second, the other rows TX90L's."""
    rest = "[90, 0, 0, 90], [0, 550, 0, -90], [0, 0, 0, 90], [0, 100, 0, 0]"
    rows = f"{row}, [-90, 50, 500, 0]" if row.startswith("[") else f"[0, 0, 50, -90], {row}"
    return f"[robot]\ndh = [{rows}, {rest}]\n"


BAD_WORLDS = [
    ("[robot]\njoint_offsets_deg = [0, 0, 0]\n", "robot.joint_offsets_deg", "must have 6"),
    ("[robot]\njoint_offsets_deg = [0, nan, 0, 0, 0, 0]\n", "robot.joint_offsets_deg[1]", "finite"),
    ('[robot]\nmodel = "kr16"\n', "robot.model", "unknown robot model"),
    (
        "[robot]\ninitial_joints_deg = [0, 0, 0, 0, 200, 0]\n",
        "robot.initial_joints_deg[4]",
        "outside its range",
    ),
    ('[tool]\nposition_mm = [0, 0, "80"]\n', "tool.position_mm[2]", "got '80'"),
    ("[noise]\ntof_ns = -1\n", "noise.tof_ns", ">= 0"),
    ("[noise]\nseed = 1.5\n", "noise.seed", "integer"),
    ("[water]\ntemperature_c = -5\n", "water.temperature_c", ">= 0"),
    ("[transducer]\nelement_diameter_mm = 0\n", "transducer.element_diameter_mm", "> 0"),
    ("[reflector]\nnormal = [0, 0, 0]\n", "reflector.normal", "non-zero"),
    (
        "[reflector]\nnormal = [0, 0, 1]\nedge_direction = [0, 0, 2]\n",
        "reflector.edge_direction",
        "parallel",
    ),
    ("[reflector]\nsize_mm = [100, -1]\n", "reflector.size_mm[1]", "> 0"),
    ("[sample]\nface_size_mm = 0\n", "sample.face_size_mm", "> 0"),
    ("noise = 3\n", "noise", "must be a table"),
    ("[robot]\nbacklash_deg = [0, 0, -0.1, 0, 0, 0]\n", "robot.backlash_deg[2]", ">= 0"),
    ("[robot]\nbacklash_deg = [0, 0, 0]\n", "robot.backlash_deg", "must have 6"),
    ("[robot]\nbacklash_deg = [0, 0, 0, 0, 0, 9]\n", "robot.backlash_deg[5]", "<= 5"),
    ("[water]\ndrift_c_per_min = 11\n", "water.drift_c_per_min", "<= 10"),
    ('[water]\ndrift_c_per_min = "warm"\n', "water.drift_c_per_min", "finite"),
    ("[pulser]\namplitude_bits = 8.0\n", "pulser.amplitude_bits", "integer"),
    ("[pulser]\namplitude_bits = 25\n", "pulser.amplitude_bits", "<= 24"),
    ("[pulser]\ngain_error_db = -0.1\n", "pulser.gain_error_db", ">= 0"),
    ("[pulser]\ndelay_ns = inf\n", "pulser.delay_ns", "finite"),
    ("[pulser]\ndelay_ns = 20000\n", "pulser.delay_ns", "<= 10000"),
    ("pulser = 1\n", "pulser", "must be a table"),
    ("[reflector]\nedge_radius_mm = -1\n", "reflector.edge_radius_mm", ">= 0"),
    (
        "[reflector]\nsize_mm = [30, 30]\nedge_radius_mm = 15\n",
        "reflector.edge_radius_mm",
        "no flat plate",
    ),
    ("[reflector]\nflatness_mm = 6\n", "reflector.flatness_mm", "<= 5"),
    ("[transducer]\nsquint_deg = 6\n", "transducer.squint_deg", "<= 5"),
    ("[transducer]\nnear_field = 1\n", "transducer.near_field", "true or false"),
    ('[controller]\nserver = "val4"\n', "controller.server", "unknown server 'val4'"),
    ("[controller]\nstartup_silence_s = -1\n", "controller.startup_silence_s", ">= 0"),
    (_dh_world("[0, 0, 50, -90, 31]"), "robot.dh[0][4]", "<= 30"),
    (_dh_world(_ROW2 + ', beta_deg = "x"}'), "robot.dh[1].beta_deg", "finite"),
    (_dh_world(_ROW2 + ", gamma_deg = 1}"), "robot.dh[1].gamma_deg", "unknown DH column"),
    # a misspelt key would be ignored and the truth silently nominal: refused, with the cure
    ("[noise]\ntof_n = 1.0\n", "noise.tof_n", "unknown key; did you mean tof_ns?"),
    ("[reflector]\npoints_mm = [0, 0, 0]\n", "reflector.points_mm", "did you mean point_mm?"),
    ("[nosie]\nseed = 1\n", "nosie", "unknown table; did you mean [noise]?"),
]


@pytest.mark.parametrize("text, key, message", BAD_WORLDS, ids=[b[1] for b in BAD_WORLDS])
def test_bad_world_names_file_and_key(
    text: str, key: str, message: str, profile: CellProfile, tmp_path: Path
) -> None:
    path = _world(tmp_path, text)
    with pytest.raises(ProfileError) as err:
        load_world(path, profile)
    assert err.value.key == key
    assert str(err.value).startswith(f"{path}: {key}: ")
    assert message in str(err.value)
    assert err.value.exit_code == 2


def test_world_unknown_keys_are_reported(tmp_path: Path) -> None:
    path = _world(tmp_path, "[noise]\ntof_ns = 1.0\nsigma = 2\n[wind]\nspeed = 1\n")
    assert world_warnings(path) == [
        "unknown key noise.sigma (ignored)",
        "unknown key wind (ignored)",
    ]


def test_new_effects_default_to_zero(profile: CellProfile, tmp_path: Path) -> None:
    for w in (WorldTruth.nominal(profile), load_world(_world(tmp_path, "[pulser]\n"), profile)):
        np.testing.assert_array_equal(w.backlash_deg, np.zeros(6))
        np.testing.assert_array_equal(w.dh_beta_deg, np.zeros(6))
        assert w.water_drift_c_per_min == 0.0
        assert w.pulser == PulserTruth()
        assert (w.pulser.amplitude_bits, w.pulser.gain_error_db) == (0, 0.0)
        # what a real instrument does is always on: a fixed electronic delay
        assert w.pulser.delay_ns == DEFAULT_PULSER_DELAY_NS > 0.0


def test_world_effect_keys(profile: CellProfile, tmp_path: Path) -> None:
    path = _world(
        tmp_path,
        """
[robot]
backlash_deg = [0.01, 0.02, 0.02, 0.03, 0.03, 0.04]
[water]
temperature_c = 21.0
drift_c_per_min = -0.25
[pulser]
amplitude_bits = 8
gain_error_db = 0.2
delay_ns = 35.5
[controller]
server = "val3-feedback"
startup_silence_s = 2.5
""",
    )
    w = load_world(path, profile)
    assert (w.controller_server, w.controller_silence_s) == ("val3-feedback", 2.5)
    np.testing.assert_array_equal(w.backlash_deg, [0.01, 0.02, 0.02, 0.03, 0.03, 0.04])
    assert (w.water_temperature_c, w.water_drift_c_per_min) == (21.0, -0.25)
    assert w.pulser == PulserTruth(amplitude_bits=8, gain_error_db=0.2, delay_ns=35.5)
    np.testing.assert_array_equal(w.model.dh, profile.model.dh)  # no dh: the profile's
    np.testing.assert_array_equal(w.dh_beta_deg, np.zeros(6))
    assert world_warnings(path) == []
    # a partial [pulser] keeps the other defaults
    w = load_world(_world(tmp_path, "[pulser]\namplitude_bits = 12\n"), profile)
    assert w.pulser == PulserTruth(amplitude_bits=12)


def test_plate_and_beam_keys(profile: CellProfile, tmp_path: Path) -> None:
    path = _world(
        tmp_path,
        """
[reflector]
edge_radius_mm = 1.5
flatness_mm = 0.05
[transducer]
squint_deg = 0.8
squint_azimuth_deg = 120
near_field = true
""",
    )
    w = load_world(path, profile)
    assert (w.reflector.edge_radius_mm, w.reflector.flatness_mm) == (1.5, 0.05)
    assert (w.beam_squint_deg, w.beam_squint_azimuth_deg, w.near_field) == (0.8, 120.0, True)
    assert world_warnings(path) == []
    nominal = WorldTruth.nominal(profile)
    assert (nominal.beam_squint_deg, nominal.near_field) == (0.0, False)
    assert (nominal.reflector.edge_radius_mm, nominal.reflector.flatness_mm) == (0.0, 0.0)


def test_world_dh_accepts_hayati_beta(profile: CellProfile, tmp_path: Path) -> None:
    dh = profile.model.dh.copy()
    rows = [dict(zip(DH_KEYS, map(float, row), strict=True)) for row in dh]
    rows[1]["beta_deg"] = 0.05  # joints 2 and 3 nearly parallel: Hayati's twist
    doc = tomlkit.document()
    robot = tomlkit.table()
    arr = tomlkit.array()
    arr.extend(rows[:2])
    arr.append([float(v) for v in dh[2]] + [-0.02])  # an array row: beta as a fifth number
    arr.extend(rows[3:])
    robot["dh"] = arr
    doc["robot"] = robot
    path = _world(tmp_path, tomlkit.dumps(doc))
    w = load_world(path, profile)
    np.testing.assert_array_equal(w.model.dh, dh)
    np.testing.assert_array_equal(w.dh_beta_deg, [0.0, 0.05, -0.02, 0.0, 0.0, 0.0])
    assert world_warnings(path) == []


def test_step_in_the_profile_and_the_world_and_its_echo(tmp_path: Path) -> None:
    path = tmp_path / "cell.toml"
    text = default_profile_text("tx90l")
    path.write_text(
        text + "\n[step]\nheight_mm = 40.0\ncentre_mm = [250.0, 250.0]\nsize_mm = 60.0\n"
    )
    with pytest.raises(ProfileError, match=r"step\.height_std_mm"):  # the certificate's sigma
        load_profile(path)
    path.write_text(
        text + "\n[step]\nheight_mm = 40.0\nheight_std_mm = 0.002\n"
        "centre_mm = [250.0, 250.0]\nsize_mm = 60.0\n"
    )
    profile = load_profile(path)
    assert profile.step is not None and profile.step.height_std_mm == 0.002
    assert load_world(None, profile).step == profile.step  # nominal: as the profile says
    world = load_world(
        _world(tmp_path, "[step]\nheight_mm = 40.003\ntilt_deg = [0.002, -0.001]\n"), profile
    )
    assert world.step.height_mm == 40.003 and world.step.size_mm == 60.0
    np.testing.assert_array_equal(world.step.centre_mm, [250.0, 250.0])
    with pytest.raises(ProfileError, match=r"step\.centre_mm"):  # its top off the face
        load_world(_world(tmp_path, "[step]\ncentre_mm = [480.0, 250.0]\n"), profile)
    # beam straight down over the step's centre: the echo comes from its top, 40 mm up
    sim = SimulatedCell(world)
    top = profile.sample_matrix @ np.array([250.0, 250.0, 40.003 + 100.0, 1.0])
    down = np.array([0.0, 0.0, -1.0]) @ profile.sample_matrix[:3, :3].T
    hit = sim._echoing_hit(top[:3], down)
    assert hit is not None and hit[0].face.name == "step"
    assert hit[0].distance_mm == pytest.approx(100.0, abs=0.01)
    beside = profile.sample_matrix @ np.array([150.0, 250.0, 140.0, 1.0])
    assert sim._echoing_hit(beside[:3], down)[0].face.name == "z"


def test_missing_keys_are_the_cell_as_described(tmp_path: Path) -> None:
    """A world without [tool] is the tool the profile described (a hand edit included), not
    what tool-frame wrote into it later, whatever became of the history: the simulated cell
    does not move with the estimates."""
    path = tmp_path / "cell.toml"
    path.write_text(default_profile_text("tx90l"))
    world = _world(tmp_path, "[robot]\njoint_offsets_deg = [0.1, 0, 0, 0, 0, 0]\n")
    write_profile(path, {"tool": {"position_mm": [0.0, 0.0, 95.0]}}, "the drawing, revised")
    drawn = load_world(world, load_profile(path))
    assert drawn.tool_position_mm[2] == pytest.approx(95.0)  # the technician's description
    tool = {"position_mm": [0.5, 0.5, 96.0], "rotation_deg": [0.0, 0.0, 0.0]}
    tool |= description_keys(load_profile(path), "tool", **tool)  # as tool-frame writes it
    write_profile(path, {"tool": tool}, "tool-frame (exact)")
    shutil.rmtree(history_dir(path))
    measured = load_profile(path)
    assert measured.tool_position_mm[2] == pytest.approx(96.0)
    truth = load_world(world, measured)
    np.testing.assert_array_equal(truth.tool_position_mm, drawn.tool_position_mm)


def test_water_absorption_and_the_baseline_offset_are_world_keys(tmp_path: Path) -> None:
    profile = CellProfile(model=load_model("tx90l"))
    path = tmp_path / "w.toml"
    path.write_text("[water]\nabsorption = true\n[pulser]\nbaseline_offset = -0.03\n")
    world = load_world(path, profile)
    assert world.water_absorption is True and world.pulser.baseline_offset == -0.03
    nominal = load_world(None, profile)
    assert nominal.water_absorption is False and nominal.pulser.baseline_offset == 0.0
    for text, key in [
        ("[water]\nabsorption = 1\n", "water.absorption"),
        ("[pulser]\nbaseline_offset = 0.7\n", "pulser.baseline_offset"),
        ("[water]\nabsorbtion = true\n", "absorption"),
    ]:
        path.write_text(text)
        with pytest.raises(ProfileError, match=key):
            load_world(path, profile)
