"""``ucal export val3``: the VAL3 data hold the profile's tool and block frame to 0.001 mm /
0.001° (read back with xml.etree, as a VAL3 project file)."""

from __future__ import annotations

import json
import os
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from ucal.errors import EXIT_USAGE
from ucal.kinematics.dh import fk, transform
from ucal.kinematics.rotations import rotation_angle_deg
from ucal.profile import create_profile, load_profile, profile_history, undo_profile, write_profile
from ucal.profile.models import KNOWN_MODELS, load_model, model_sheet

from doubles import exit_code

NS = {"d": "http://www.staubli.com/robotics/VAL3/Data/2"}
XSI_TYPE = "{http://www.w3.org/2001/XMLSchema-instance}type"
TOOL = {"position_mm": [2.345678, -1.5, 85.25], "rotation_deg": [1.234567, -3.5, 178.9]}
BLOCK = {"position_mm": [260.912345, 97.043, -277.339], "rotation_deg": [0.3, -0.2, 91.7]}
#: The issue's bound on the data: 0.001 mm and 0.001°.
BOUND_MM = 0.001
BOUND_DEG = 0.001


@pytest.fixture
def profile_path(tmp_path: Path) -> Path:
    """A calibrated TX90L profile: a measured tool, a placed block, offsets in its history."""
    path = tmp_path / "cell.toml"
    create_profile(path, "tx90l")
    write_profile(path, {"sample": BLOCK}, reason="block placed")
    write_profile(path, {"tool": TOOL}, reason="tool-frame (exact)")
    write_profile(
        path,
        {"calibration": {"joint_offsets_deg": [0.0, 0.4, -0.3, 0.2, 0.5, 0.0]}},
        reason="calibrate: fit ok (χ²ᵣ 0.9)",
    )
    return path


def read_dtx(path: Path) -> dict[str, ET.Element]:
    """The ``Data`` elements of a ``.dtx`` file by name."""
    root = ET.parse(path).getroot()
    assert root.tag == f"{{{NS['d']}}}Database"
    return {d.attrib["name"]: d for d in root.iterfind("d:Datas/d:Data", NS)}


def value_matrix(data: ET.Element) -> np.ndarray:
    """The transform (4, 4) of a datum's single ``Value``: x, y, z (mm), VAL3 angles (deg)."""
    (value,) = data.iterfind("d:Value", NS)
    assert value.attrib["key"] == "0"
    v = [float(value.attrib[k]) for k in ("x", "y", "z", "rx", "ry", "rz")]
    # VAL3: Rot(x, rx)·Rot(y, ry)·Rot(z, rz) about the moving axes = scipy's intrinsic "XYZ"
    return transform(v[:3], Rotation.from_euler("XYZ", v[3:], degrees=True).as_matrix())


def errors(a: np.ndarray, b: np.ndarray) -> tuple[float, float]:
    mm = float(np.linalg.norm(a[:3, 3] - b[:3, 3]))
    return mm, float(rotation_angle_deg(a[:3, :3], b[:3, :3]))


def test_dtx_holds_the_tool_and_block_frames(profile_path: Path, tmp_path: Path) -> None:
    out = tmp_path / "val3"
    assert exit_code(["export", "val3", str(profile_path), "-o", str(out)]) == 0
    data = read_dtx(out / "ucalCell" / "ucalCell.dtx")
    profile = load_profile(profile_path)

    expected = {
        "tUcalTool": ("tool", "flange[0]", profile.tool_matrix),
        "fUcalBlock": ("frame", "world[0]", profile.sample_matrix),
        "trUcalTool": ("trsf", None, profile.tool_matrix),
        "trUcalBlock": ("trsf", None, profile.sample_matrix),
    }
    assert set(data) == set(expected)
    for name, (val3_type, father, want) in expected.items():
        d = data[name]
        assert d.attrib["type"] == val3_type and d.attrib[XSI_TYPE] == "array"
        assert d.attrib["access"] == "public" and d.attrib["size"] == "1"
        assert d.find("d:Value", NS).attrib.get("fatherId") == father  # type: ignore[union-attr]
        mm, deg = errors(value_matrix(d), want)
        assert mm < BOUND_MM and deg < BOUND_DEG, (name, mm, deg)
        assert mm < 1e-5 and deg < 1e-5, (name, mm, deg)  # 6 decimals: a micrometre's hundredth


def test_dtx_names_the_profile_and_its_last_calibration(profile_path: Path, tmp_path: Path) -> None:
    out = tmp_path / "val3"
    assert exit_code(["export", "val3", str(profile_path), "-o", str(out)]) == 0
    raw = (out / "ucalCell" / "ucalCell.dtx").read_bytes()
    assert raw.startswith(b"\xef\xbb\xbf<?xml")  # as VAL3 files: a BOM, then the declaration
    parser = ET.XMLParser(target=ET.TreeBuilder(insert_comments=True))
    root = ET.fromstring(raw, parser=parser)
    comments = " ".join(c.text or "" for c in root.iter() if c.tag is ET.Comment)
    last = profile_history(profile_path)[-1]
    assert str(profile_path.resolve()) in comments
    assert last.time in comments and "calibrate" in comments


def test_project_declares_the_data_file(profile_path: Path, tmp_path: Path) -> None:
    out = tmp_path / "val3"
    assert exit_code(["export", "val3", str(profile_path), "-o", str(out)]) == 0
    app = out / "ucalCell"
    assert sorted(p.name for p in app.iterdir()) == [
        "start.pgx",
        "stop.pgx",
        "ucalCell.dtx",
        "ucalCell.pjx",
    ]
    ns = {"p": "http://www.staubli.com/robotics/VAL3/Project/3"}
    project = ET.parse(app / "ucalCell.pjx").getroot()
    assert [d.attrib["file"] for d in project.iterfind("p:Database/p:Data", ns)] == ["ucalCell.dtx"]
    assert project.find("p:Parameters", ns).attrib["millimeterUnit"] == "true"  # type: ignore[union-attr]
    programs = {p.attrib["file"] for p in project.iterfind("p:Programs/p:Program", ns)}
    assert programs == {"start.pgx", "stop.pgx"}
    for name in ("start", "stop"):
        pgx = ET.parse(app / f"{name}.pgx").getroot()
        (program,) = pgx
        assert program.attrib["name"] == name


def test_json_holds_the_same(
    profile_path: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "val3"
    assert exit_code(["export", "val3", str(profile_path), "-o", str(out), "--json"]) == 0
    printed = json.loads(capsys.readouterr().out)
    written = json.loads((out / "ucal_cell.json").read_text(encoding="utf-8"))
    assert {k: v for k, v in printed.items() if k != "files"} == written
    assert len(printed["files"]) == 5
    profile = load_profile(profile_path)
    data = read_dtx(out / "ucalCell" / "ucalCell.dtx")
    for key, name, want in (
        ("tool", "tUcalTool", profile.tool_matrix),
        ("block", "fUcalBlock", profile.sample_matrix),
    ):
        t = written[key]
        got = transform(
            t["position_mm"],
            Rotation.from_euler("XYZ", t["rotation_deg"], degrees=True).as_matrix(),
        )
        mm, deg = errors(got, want)
        assert mm < BOUND_MM and deg < BOUND_DEG
        np.testing.assert_array_equal(got, value_matrix(data[name]))
    assert written["calibration"]["reason"].startswith("calibrate")
    assert written["joint_offsets_deg"] == [0.0, 0.4, -0.3, 0.2, 0.5, 0.0]


@pytest.mark.parametrize(
    "rotation_deg", [[170.0, 100.0, -30.0], [10.0, 90.0, 20.0], [-179.9999, -89.9999, 179.9999]]
)
def test_any_angles_are_written_as_the_controller_shows_them(
    rotation_deg: list[float], tmp_path: Path
) -> None:
    """Angles outside VAL3's ranges (ry beyond ±90°), at and near gimbal lock: written with
    |ry| <= 90°, |rx|, |rz| <= 180°, the same frame."""
    path = tmp_path / "cell.toml"
    create_profile(path, "tx90")
    write_profile(
        path, {"tool": {"position_mm": [0.0, 10.0, 80.0], "rotation_deg": rotation_deg}}, "test"
    )
    out = tmp_path / "val3"
    assert exit_code(["export", "val3", str(path), "-o", str(out)]) == 0
    d = read_dtx(out / "ucalCell" / "ucalCell.dtx")["tUcalTool"]
    value = d.find("d:Value", NS).attrib  # type: ignore[union-attr]
    assert abs(float(value["ry"])) <= 90.0
    assert abs(float(value["rx"])) <= 180.0 and abs(float(value["rz"])) <= 180.0
    mm, deg = errors(value_matrix(d), load_profile(path).tool_matrix)
    assert mm < BOUND_MM and deg < BOUND_DEG, (mm, deg)


def test_an_undone_calibration_is_not_named(profile_path: Path, tmp_path: Path) -> None:
    undo_profile(profile_path)  # the calibrate write
    out = tmp_path / "val3"
    assert exit_code(["export", "val3", str(profile_path), "-o", str(out), "--json"]) == 0
    written = json.loads((out / "ucal_cell.json").read_text(encoding="utf-8"))
    assert written["calibration"]["reason"].startswith("tool-frame")


@pytest.mark.parametrize("name", KNOWN_MODELS)
def test_the_model_flange_is_the_controllers(name: str) -> None:
    """The joint-6 frame of the shipped tables is the controller's flange (the URDF's
    all-zeros tool frame ``tool0``): at zero readings on the joint-6 axis, 100 mm beyond the
    wrist centre, axes parallel to the base frame; joint 6 turns it about its own z."""
    model = load_model(name)
    length = model_sheet(name).upper_arm_mm + model_sheet(name).forearm_mm
    np.testing.assert_allclose(
        fk(model, np.zeros(6)), transform([50, 50, length + 100], np.eye(3)), atol=1e-9
    )
    q = np.array([20.0, -30.0, 70.0, 15.0, 50.0, 0.0])
    turned = q + [0, 0, 0, 0, 0, 35.0]
    rz = transform(np.zeros(3), Rotation.from_euler("z", 35.0, degrees=True).as_matrix())
    np.testing.assert_allclose(fk(model, turned), fk(model, q) @ rz, atol=1e-9)


def test_unwritable_directory_exit_2_naming_it(
    profile_path: Path,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    locked = tmp_path / "read-only"
    locked.mkdir()
    real_access = os.access
    monkeypatch.setattr(
        os,
        "access",
        lambda p, mode: False if Path(p) == locked and mode & os.W_OK else real_access(p, mode),
    )
    assert exit_code(["export", "val3", str(profile_path), "-o", str(locked)]) == EXIT_USAGE
    err = capsys.readouterr().err
    assert err.startswith(f"error: {locked}: cannot write") and "Traceback" not in err
    assert list(locked.iterdir()) == []


def test_directory_that_is_a_file_exit_2(
    profile_path: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    blocker = tmp_path / "file"
    blocker.write_text("x")
    code = exit_code(["export", "val3", str(profile_path), "-o", str(blocker / "val3"), "--json"])
    assert code == EXIT_USAGE
    printed = json.loads(capsys.readouterr().out)
    assert printed["exit_code"] == EXIT_USAGE and str(blocker / "val3") in printed["error"]


def test_missing_directory_is_created(profile_path: Path, tmp_path: Path) -> None:
    out = tmp_path / "a" / "b"
    assert exit_code(["export", "val3", str(profile_path), "-o", str(out)]) == 0
    assert (out / "ucalCell" / "ucalCell.dtx").is_file() and (out / "ucal_cell.json").is_file()
