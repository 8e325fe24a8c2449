"""``ucal export ros2``: the exported URDF, read by an independent URDF library (yourdfpy) with
the exported offsets applied to the readings, is ``ucal fk`` to 1 µm and 1 µrad; the xacro
(rendered by xacro itself) is the same URDF; the YAML files carry the profile's hash, the
offsets' sign and the covariance of what they hold."""

from __future__ import annotations

import hashlib
import json
import os
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import pytest
import xacro
import yaml
import yourdfpy

from ucal.cli.fk import tool_pose
from ucal.errors import EXIT_USAGE
from ucal.kinematics.rotations import pose_to_matrix, rotation_angle_deg
from ucal.profile import create_profile, load_profile, pose_digest, write_profile
from ucal.profile.models import load_model
from ucal.ros2 import ros2_arm, write_ros2
from ucal.ros2_description import JOINTS

from doubles import exit_code

#: The issue's bounds: 1 µm (in mm) and 1 µrad.
BOUND_MM = 1e-3
BOUND_RAD = 1e-6
#: Random joint vectors of the done-when check.
N_POSTURES = 1000

OFFSETS_DEG = [0.12, -0.31, 0.27, 0.05, -0.44, 0.23]
#: A measured tool, off its axis and turned (Stäubli angles).
TOOL = {"position_mm": [2.345678, -1.5, 85.25], "rotation_deg": [1.234567, -3.5, 178.9]}
#: What ``calibrate`` writes with the offsets: one sigma, joint 4 not determined.
CALIBRATED = {
    "joint_offsets_deg": OFFSETS_DEG,
    "std_deg": [0.004, 0.002, 0.003, -1.0, 0.006, 0.02],
    "unobservable_joints": [4],
}


def identified_table() -> tuple[list[dict[str, float]], list[dict[str, float]]]:
    """A ``[calibration] dh`` as ``calibrate --level full`` writes it (every length and twist
    moved, a Hayati twist on row 2) and its ``dh_std`` (−1: not determined)."""
    nominal = load_model("tx90l").dh
    rows = []
    for i, (theta, d, a, alpha) in enumerate(nominal):
        rows.append(
            {
                "theta_offset_deg": float(theta),
                "d_mm": float(d) + 0.11 * (i + 1) - 0.3,
                "a_mm": float(a) + 0.07 * (-1) ** i,
                "alpha_deg": float(alpha) + 0.013 * (i - 2.5),
            }
        )
    rows[1]["beta_deg"] = 0.047
    stds = [{"d_mm": 0.02, "a_mm": 0.03, "alpha_deg": 0.001, "beta_deg": -1.0} for _ in range(6)]
    stds[1]["beta_deg"] = 0.002
    stds[0]["d_mm"] = -1.0  # not identifiable: the [robot] tolerance stands
    return rows, stds


def make_profile(path: Path, level: str) -> Path:
    """A TX90L cell calibrated at ``level`` (``offsets``: offsets on the shipped table;
    ``full``: the identified table too), with a measured tool."""
    create_profile(path, "tx90l")
    measured = {  # as tool-frame writes it: the tool as drawn kept beside the measured one
        **TOOL,
        "drawn_position_mm": [0.0, 0.0, 80.0],
        "drawn_rotation_deg": [0.0, 0.0, 0.0],
        "measured_sha256": pose_digest(TOOL["position_mm"], TOOL["rotation_deg"]),
    }
    write_profile(path, {"tool": measured}, reason="tool-frame (exact)")
    calibration: dict[str, Any] = dict(CALIBRATED)
    if level == "full":
        calibration["dh"], calibration["dh_std"] = identified_table()
    write_profile(path, {"calibration": calibration}, reason=f"calibrate --level {level}")
    return path


class Exported(NamedTuple):
    level: str
    profile: Path
    written: dict[str, Path]


@pytest.fixture(scope="module", params=["offsets", "full"])
def exported(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> Exported:
    """A profile of each level and the files exported from it, once."""
    level = request.param
    base = tmp_path_factory.mktemp(level)
    profile = make_profile(base / "cell.toml", level)
    return Exported(level, profile, write_ros2(ros2_arm(profile), base / "ros2"))


def load_urdf(path: Path) -> yourdfpy.URDF:
    return yourdfpy.URDF.load(str(path), load_meshes=False, build_collision_scene_graph=False)


def fk_errors(
    urdf: yourdfpy.URDF, profile_path: Path, readings_deg: np.ndarray, add_offsets: bool
) -> tuple[float, float]:
    """Largest position (mm) and rotation (rad) difference between the URDF's ``ucal_tcp`` in
    ``base`` and ``ucal fk``'s pose, over the joint readings (n, 6)."""
    profile = load_profile(profile_path)
    worst_mm = worst_rad = 0.0
    for reading in readings_deg:
        joints = reading + profile.joint_offsets_deg if add_offsets else reading
        urdf.update_cfg(dict(zip(JOINTS, np.radians(joints), strict=True)))
        got = urdf.get_transform("ucal_tcp", "base")
        want = pose_to_matrix(tool_pose(profile, reading))  # the `ucal fk` code path
        worst_mm = max(worst_mm, float(np.linalg.norm(got[:3, 3] * 1000.0 - want[:3, 3])))
        angle = float(np.radians(rotation_angle_deg(got[:3, :3], want[:3, :3])))
        worst_rad = max(worst_rad, angle)
    return worst_mm, worst_rad


def random_readings(profile_path: Path, n: int, seed: int) -> np.ndarray:
    model = load_profile(profile_path).model
    rng = np.random.default_rng(seed)
    return rng.uniform(model.joint_min_deg, model.joint_max_deg, (n, 6))


def test_urdf_with_the_offsets_applied_is_ucal_fk(exported: Exported) -> None:
    """The done-when check: 1,000 random readings within the joint ranges, offsets added."""
    _, profile, written = exported
    model = load_profile(profile).model
    if exported.level == "full":  # the identified table, twist and all, is what ucal fk uses
        assert model.dh_source == "[calibration] dh" and model.has_twists
    else:
        assert model.dh_source != "[calibration] dh"
    readings = random_readings(profile, N_POSTURES, seed=38)
    mm, rad = fk_errors(load_urdf(written["urdf"]), profile, readings, add_offsets=True)
    print(f"{exported.level}: max {mm * 1e3:.3g} µm, {rad * 1e6:.3g} µrad")
    assert mm < BOUND_MM and rad < BOUND_RAD, (mm, rad)
    assert mm < 1e-6 and rad < 1e-9  # numbers written in full: rounding leaves nothing


def test_urdf_with_offsets_folded_in_takes_the_readings(exported: Exported) -> None:
    _, profile, written = exported
    readings = random_readings(profile, 200, seed=39)
    urdf = load_urdf(written["urdf_offsets_in_urdf"])
    mm, rad = fk_errors(urdf, profile, readings, add_offsets=False)
    assert mm < BOUND_MM and rad < BOUND_RAD, (mm, rad)


def test_the_cli_pose_is_the_urdf_pose(
    exported: Exported, capsys: pytest.CaptureFixture[str]
) -> None:
    _, profile, written = exported
    reading = np.array([30.53, 31.15, 109.49, 0.0, 39.36, 30.54])
    joints = ",".join(map(str, reading))
    assert exit_code(["fk", str(profile), "--joints", joints, "--json"]) == 0
    want = pose_to_matrix(json.loads(capsys.readouterr().out)["pose"])
    urdf = load_urdf(written["urdf"])
    offsets = load_profile(profile).joint_offsets_deg
    urdf.update_cfg(dict(zip(JOINTS, np.radians(reading + offsets), strict=True)))
    got = urdf.get_transform("ucal_tcp", "base")
    np.testing.assert_allclose(got[:3, 3] * 1000.0, want[:3, 3], atol=1e-6)
    assert rotation_angle_deg(got[:3, :3], want[:3, :3]) < 1e-7


def test_the_urdf_names_ros_industrial_frames(exported: Exported) -> None:
    _, _, written = exported
    urdf = load_urdf(written["urdf"])
    assert urdf.actuated_joint_names == list(JOINTS)
    names = set(urdf.link_map)
    expected = {"world", "base_link", "base", "flange", "tool0", "ucal_tcp"}
    assert expected | {f"link_{i}" for i in range(1, 7)} == names
    np.testing.assert_allclose(urdf.get_transform("base", "base_link")[:3, 3], [0, 0, 0.478])


def joint_table(urdf: yourdfpy.URDF) -> dict[str, tuple[Any, ...]]:
    """Each joint's type, parent, child, origin, axis and limits, for comparing two URDFs."""
    out = {}
    for j in urdf.robot.joints:
        limit = None if j.limit is None else (j.limit.lower, j.limit.upper, j.limit.velocity)
        axis = None if j.type == "fixed" else tuple(j.axis)
        out[j.name] = (j.type, j.parent, j.child, j.origin, axis, limit)
    return out


def assert_same_urdf(a: yourdfpy.URDF, b: yourdfpy.URDF) -> None:
    ta, tb = joint_table(a), joint_table(b)
    assert list(ta) == list(tb)
    for name, (kind, parent, child, origin, axis, limit) in ta.items():
        kind_b, parent_b, child_b, origin_b, axis_b, limit_b = tb[name]
        assert (kind, parent, child, axis) == (kind_b, parent_b, child_b, axis_b), name
        np.testing.assert_allclose(origin, origin_b, atol=1e-15, err_msg=name)
        assert (limit is None) == (limit_b is None), name
        if limit is not None:
            np.testing.assert_allclose(limit, limit_b, rtol=1e-15, err_msg=name)


def render_xacro(path: Path, **args: str) -> str:
    return xacro.process_file(str(path), mappings=args).toprettyxml(indent="  ")


def from_text(text: str, directory: Path, name: str) -> yourdfpy.URDF:
    path = directory / name
    path.write_text(text, encoding="utf-8")
    return load_urdf(path)


@pytest.mark.parametrize("offsets_in_urdf", [False, True])
def test_xacro_renders_the_exported_urdf(
    exported: Exported, offsets_in_urdf: bool, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The xacro, rendered by xacro from another directory with its default YAML paths, is
    the plain URDF it was exported with."""
    _, _, written = exported
    monkeypatch.chdir(tmp_path)
    text = render_xacro(written["xacro"], offsets_in_urdf=str(offsets_in_urdf).lower())
    assert "<ros2_control" not in text
    rendered = from_text(text, tmp_path, "rendered.urdf")
    plain = written["urdf_offsets_in_urdf" if offsets_in_urdf else "urdf"]
    assert_same_urdf(rendered, load_urdf(plain))


def test_xacro_prefix_and_ros2_control_transmissions(exported: Exported, tmp_path: Path) -> None:
    _, profile, written = exported
    offsets_rad = np.radians(load_profile(profile).joint_offsets_deg)
    for baked, expected in (("false", offsets_rad), ("true", np.zeros(6))):
        text = render_xacro(
            written["xacro"],
            prefix="arm_",
            offsets_in_urdf=baked,
            ros2_control_plugin="mock_components/GenericSystem",
        )
        urdf = from_text(text, tmp_path, f"control_{baked}.urdf")
        assert urdf.actuated_joint_names == [f"arm_{j}" for j in JOINTS]
        assert "arm_ucal_tcp" in urdf.link_map
        root = ET.fromstring(text)
        (control,) = root.findall("ros2_control")
        assert control.findtext("hardware/plugin") == "mock_components/GenericSystem"
        got = [float(t.findtext("joint/offset", "")) for t in control.findall("transmission")]
        plugins = {t.findtext("plugin") for t in control.findall("transmission")}
        assert plugins == {"transmission_interface/SimpleTransmission"}
        np.testing.assert_array_equal(got, expected)


def test_xacro_refuses_offsets_of_another_profile(exported: Exported) -> None:
    _, _, written = exported
    offsets = written["joint_offsets"]
    other = offsets.read_text(encoding="utf-8").replace('hash: "sha256:', 'hash: "sha256:0', 1)
    stale = offsets.with_name("stale_joint_offsets.yaml")
    stale.write_text(other, encoding="utf-8")
    with pytest.raises(xacro.XacroException, match="different profiles"):
        render_xacro(written["xacro"], joint_offsets_params=str(stale))


def read_yaml(path: Path) -> Any:
    return yaml.safe_load(path.read_text(encoding="utf-8"))


def test_yaml_files_carry_the_profile_hash(exported: Exported) -> None:
    _, profile, written = exported
    digest = hashlib.sha256(profile.read_bytes()).hexdigest()
    kinematics = read_yaml(written["kinematics"])
    assert kinematics["kinematics"]["hash"] == f"sha256:{digest}"
    assert kinematics["kinematics_offsets_in_urdf"]["hash"] == f"sha256:{digest}"
    assert kinematics["source"]["sha256"] == digest
    assert kinematics["source"]["profile"] == str(profile.resolve())
    assert kinematics["source"]["ucal_version"] and kinematics["source"]["date"]
    for kind in ("joint_offsets", "covariance"):
        assert read_yaml(written[kind])["hash"] == f"sha256:{digest}"


def test_an_edited_profile_has_another_hash(tmp_path: Path) -> None:
    profile = make_profile(tmp_path / "cell.toml", "offsets")
    first = ros2_arm(profile).hash
    profile.write_text(profile.read_text(encoding="utf-8") + "\n# remounted\n", encoding="utf-8")
    assert ros2_arm(profile).hash != first


def test_kinematics_yaml_is_ur_description_style(exported: Exported) -> None:
    """Each origin has UR's six keys, in m and rad, as the URDF's origins hold them."""
    _, _, written = exported
    kin = read_yaml(written["kinematics"])["kinematics"]
    urdf = load_urdf(written["urdf"])
    for name in (*JOINTS, "flange", "tcp"):
        assert set(kin[name]) == {"x", "y", "z", "roll", "pitch", "yaw"}
        joint = {"flange": "joint_6-flange", "tcp": "tool0-ucal_tcp"}.get(name, name)
        origin = urdf.joint_map[joint].origin
        np.testing.assert_allclose(origin[:3, 3], [kin[name][k] for k in "xyz"], atol=1e-15)


def test_joint_offsets_yaml_states_the_sign(exported: Exported) -> None:
    _, _, written = exported
    offsets = read_yaml(written["joint_offsets"])
    assert offsets["sign"] == "position = reading + offset"
    np.testing.assert_allclose(list(offsets["joint_offsets"].values()), np.radians(OFFSETS_DEG))
    assert list(offsets["joint_offsets_deg"].values()) == OFFSETS_DEG
    std = offsets["std"]
    assert std["joint_4"] is None and offsets["unobservable_joints"] == ["joint_4"]
    assert std["joint_1"] == pytest.approx(np.radians(0.004))


def test_covariance_names_what_is_determined(exported: Exported) -> None:
    _, _, written = exported
    cov = read_yaml(written["covariance"])
    assert cov["joint_offsets"]["joint_1"]["status"] == "calibrated"
    assert cov["joint_offsets"]["joint_4"]["std"] is None
    assert cov["joint_offsets"]["joint_4"]["status"].startswith("not determined")
    assert cov["tool"]["x"]["status"] == "measured (tool-frame)"
    dh = cov["dh"]
    if exported.level == "full":
        assert dh["row_2"]["a"]["status"] == "identified"
        assert dh["row_2"]["a"]["std"] == pytest.approx(0.03e-3)
        assert dh["row_2"]["beta"]["std"] == pytest.approx(np.radians(0.002))
        assert dh["row_1"]["d"]["status"].startswith("tolerance")
    else:
        assert all(p["status"].startswith("tolerance") for r in dh.values() for p in r.values())
    assert "beta" in dh["row_2"] and "beta" not in dh["row_3"]
    for name, flat in cov["origin_covariance"].items():
        c = np.array(flat).reshape(6, 6)
        np.testing.assert_allclose(c, c.T, atol=1e-18, err_msg=name)
        assert np.linalg.eigvalsh(c).min() > -1e-15, name


def test_origin_covariance_is_the_parameters(exported: Exported) -> None:
    """joint_3's origin is row 2's ``Tz(d)·Tx(a)·Rx(α)·Ry(β)``: x carries a's variance, z d's,
    the rotation about x α's; and the tcp carries [tool]'s position stds."""
    _, _, written = exported
    cov = read_yaml(written["covariance"])
    row = cov["dh"]["row_2"]
    c = np.array(cov["origin_covariance"]["joint_3"]).reshape(6, 6)
    assert c[0, 0] == pytest.approx(row["a"]["variance"], rel=1e-6)
    assert c[2, 2] == pytest.approx(row["d"]["variance"], rel=1e-6)
    assert c[1, 1] == pytest.approx(0.0, abs=1e-20)
    assert c[3, 3] == pytest.approx(row["alpha"]["variance"], rel=1e-6)
    assert np.trace(c[3:, 3:]) == pytest.approx(
        row["alpha"]["variance"] + row["beta"]["variance"], rel=1e-6
    )
    tcp = np.array(cov["origin_covariance"]["tcp"]).reshape(6, 6)
    np.testing.assert_allclose(np.diag(tcp)[:3], np.full(3, 1e-3) ** 2, rtol=1e-6)
    assert np.all(np.array(cov["origin_covariance"]["joint_1"]) == 0.0)


def test_json_lists_the_files(
    exported: Exported, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    _, profile, _ = exported
    out = tmp_path / "ros2"
    args = ["export", "ros2", str(profile), "-o", str(out), "--json", "--prefix", "arm_"]
    assert exit_code(args) == 0
    printed = json.loads(capsys.readouterr().out)
    files = [Path(p) for p in printed["files"].values()]
    assert sorted(p.name for p in files) == sorted(p.name for p in out.iterdir())
    assert len(files) == 7 and all(p.is_file() and p.parent == out for p in files)
    assert printed["profile_sha256"] == hashlib.sha256(profile.read_bytes()).hexdigest()
    assert printed["prefix"] == "arm_" and printed["tcp_link"] == "arm_ucal_tcp"
    assert printed["joint_offsets_deg"] == OFFSETS_DEG
    urdf = load_urdf(Path(printed["files"]["urdf"]))
    assert urdf.actuated_joint_names == [f"arm_{j}" for j in JOINTS]


@pytest.fixture
def locked(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A directory this process may not write into (as os.access has it: root writes anywhere)."""
    directory = tmp_path / "read-only"
    directory.mkdir()
    access = os.access

    def denied(path: Any, mode: int) -> bool:
        return not (Path(path) == directory and mode & os.W_OK) and access(path, mode)

    monkeypatch.setattr(os, "access", denied)
    return directory


def test_unwritable_directory_exit_2_naming_it(
    locked: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    profile = make_profile(tmp_path / "cell.toml", "offsets")
    assert exit_code(["export", "ros2", str(profile), "-o", str(locked)]) == EXIT_USAGE
    err = capsys.readouterr().err
    assert err.startswith(f"error: {locked}: cannot write"), err
    assert "Traceback" not in err and not any(locked.iterdir())


@pytest.mark.parametrize("case", ["directory under a file", "bad prefix"])
def test_input_errors_exit_2_naming_what(
    case: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    profile = make_profile(tmp_path / "cell.toml", "offsets")
    blocker = tmp_path / "file"
    blocker.write_text("x")
    out, options, named = {
        "directory under a file": (blocker / "ros2", [], str(blocker / "ros2")),
        "bad prefix": (tmp_path / "ros2", ["--prefix", "a b"], "--prefix"),
    }[case]
    code = exit_code(["export", "ros2", str(profile), "-o", str(out), "--json", *options])
    printed = json.loads(capsys.readouterr().out)
    assert code == printed["exit_code"] == EXIT_USAGE and named in printed["error"]
    assert not (tmp_path / "ros2").exists()
