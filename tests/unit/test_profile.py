"""Profile loading, validation, the default profile, comment-preserving atomic writes, undo."""

from __future__ import annotations

import difflib
import json
import os
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
import tomlkit

import ucal.profile as profile_mod
from ucal.cell import PAPER_CALIBRATION_POSE_DEG
from ucal.cli import main
from ucal.errors import ProfileError
from ucal.kinematics.dh import fk, wrist_centre
from ucal.profile import (
    EXAMPLE_HEADER,
    EXAMPLE_MODEL,
    create_profile,
    default_profile_text,
    example_profile_text,
    history_dir,
    load_profile,
    profile_history,
    undo_profile,
    write_profile,
)
from ucal.profile.models import KNOWN_MODELS, load_model

from doubles import exit_code

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture
def cell(tmp_path: Path) -> Path:
    """A fresh tx90l profile with a few hand-written comments added by the technician."""
    p = tmp_path / "cell.toml"
    text = default_profile_text("tx90l")
    text = text.replace("[calibration]\n", "[calibration]  # last done by J. Doe\n")
    text = text.replace("[water]\n", "# tank filled with demineralised water\n[water]\n")
    text = text.replace("temperature_c = 20.0", "temperature_c = 20.0  # checked weekly")
    p.write_text(text, encoding="utf-8")
    return p


def _comments(text: str) -> list[str]:
    return [line[line.index("#") :] for line in text.splitlines() if "#" in line]


def _keys_in_order(text: str) -> list[str]:
    doc = tomlkit.parse(text)
    out = []
    for tname, table in doc.items():
        out.append(tname)
        if hasattr(table, "keys"):
            out.extend(f"{tname}.{k}" for k in table)
    return out


# ------------------------------------------------------------------------------ default profile


@pytest.mark.parametrize("model", KNOWN_MODELS)
def test_default_profile_is_valid_and_consistent_with_the_calibration_pose(
    model: str, tmp_path: Path
) -> None:
    path = tmp_path / f"{model}.toml"
    create_profile(path, model)
    prof = load_profile(path)
    shipped = load_model(model)
    np.testing.assert_array_equal(prof.model.dh, shipped.dh)
    np.testing.assert_array_equal(prof.model.joint_min_deg, shipped.joint_min_deg)
    np.testing.assert_allclose(prof.procedure.calibration_pose_deg, PAPER_CALIBRATION_POSE_DEG)
    assert prof.water_temperature_c == 20.0
    assert (prof.frequency_mhz, prof.element_diameter_mm) == (25.0, 6.0)
    np.testing.assert_array_equal(prof.joint_offsets_deg, np.zeros(6))
    assert prof.unobservable_joints == ()

    water = prof.procedure.water_path_mm
    w = wrist_centre(prof.model, PAPER_CALIBRATION_POSE_DEG)
    s = 100.0 + 80.0 + water
    np.testing.assert_allclose(prof.sample_position_mm, w - s, atol=1e-3)
    # At the calibration pose the beam (tool +z) points straight down and the TCP stands one
    # water path above the block's XY face, over the face.
    tcp = fk(prof.model, PAPER_CALIBRATION_POSE_DEG, tool=prof.tool_matrix)
    np.testing.assert_allclose(tcp[:3, 2], [0, 0, -1], atol=1e-3)
    assert tcp[2, 3] - prof.sample_position_mm[2] == pytest.approx(water, abs=1e-3)
    rel = tcp[:2, 3] - prof.sample_position_mm[:2]
    assert np.all(rel > 0) and np.all(rel < prof.sample_face_size_mm)
    # The reflector plate is horizontal, at the XY face's height, outside the block footprint.
    pts = prof.reflector_points_mm
    assert pts.shape == (3, 3)
    np.testing.assert_allclose(pts[:, 2], prof.sample_position_mm[2])
    inside_y = pts[:, 1] > prof.sample_position_mm[1]
    assert not inside_y.any()


def test_default_profile_keeps_its_comments() -> None:
    text = default_profile_text("tx90xl")
    assert "# Paper 000, section 5.1" in text
    assert 'model = "tx90xl"' in text
    assert text.count("theta_offset_deg =") == 6


def test_init_refuses_to_overwrite_without_force(cell: Path) -> None:
    before = cell.read_bytes()
    with pytest.raises(ProfileError, match="already exists"):
        create_profile(cell, "tx90")
    assert cell.read_bytes() == before
    create_profile(cell, "tx90", force=True)
    assert load_profile(cell).model.name == "tx90"
    undo_profile(cell)
    assert cell.read_bytes() == before


def test_example_cell_profile_is_valid() -> None:
    prof = load_profile(REPO / "profiles" / "example_cell.toml")
    assert prof.model.name == "tx90l"
    assert prof.reflector_points_mm is not None


def test_example_cell_profile_is_what_profile_init_writes(tmp_path: Path) -> None:
    """One source: the shipped example is the init template under its header (regenerate with
    ``python -c "from ucal.profile import *; print(example_profile_text(), end='')"``)."""
    shipped = (REPO / "profiles" / "example_cell.toml").read_text()
    assert shipped == example_profile_text()
    created = create_profile(tmp_path / "cell.toml", EXAMPLE_MODEL).read_text()
    assert shipped.endswith(created) and shipped.startswith(EXAMPLE_HEADER)
    a = load_profile(REPO / "profiles" / "example_cell.toml")
    b = load_profile(tmp_path / "cell.toml")
    np.testing.assert_array_equal(a.reflector_points_mm, b.reflector_points_mm)
    np.testing.assert_array_equal(a.sample_position_mm, b.sample_position_mm)


# ------------------------------------------------------------------------------ loading


def test_custom_dh_table_without_known_model(tmp_path: Path) -> None:
    doc = tomlkit.parse(default_profile_text("tx90l"))
    doc["robot"]["model"] = "my-cell-robot"
    doc["robot"]["dh"][1]["a_mm"] = 501.5
    path = tmp_path / "c.toml"
    path.write_text(tomlkit.dumps(doc))
    prof = load_profile(path)
    assert prof.model.name == "my-cell-robot"
    assert prof.model.dh[1, 2] == 501.5


def test_dh_table_absent_takes_the_shipped_table_and_ranges(tmp_path: Path) -> None:
    doc = tomlkit.parse(default_profile_text("tx90xl"))
    for key in ("dh", "joint_min_deg", "joint_max_deg"):
        del doc["robot"][key]
    path = tmp_path / "c.toml"
    path.write_text(tomlkit.dumps(doc))
    prof = load_profile(path)
    np.testing.assert_array_equal(prof.model.dh, load_model("tx90xl").dh)
    np.testing.assert_array_equal(prof.model.joint_max_deg, load_model("tx90xl").joint_max_deg)


def test_optional_tables_default(tmp_path: Path) -> None:
    doc = tomlkit.parse(default_profile_text("tx90l"))
    for t in ("procedure", "calibration", "reflector"):
        del doc[t]
    del doc["sample"]["face_size_mm"]
    path = tmp_path / "c.toml"
    path.write_text(tomlkit.dumps(doc))
    prof = load_profile(path)
    assert prof.reflector_points_mm is None
    assert prof.procedure.calibration_pose_deg is None
    assert prof.sample_face_size_mm == profile_mod.DEFAULT_FACE_MM
    np.testing.assert_array_equal(prof.joint_offsets_deg, np.zeros(6))


def test_drift_and_lost_motion_tolerances(tmp_path: Path) -> None:
    doc = tomlkit.parse(default_profile_text("tx90l"))
    path = tmp_path / "c.toml"
    path.write_text(tomlkit.dumps(doc))
    prof = load_profile(path)  # the template's: the defaults
    assert prof.drift_std_c_per_min == 0.05
    np.testing.assert_array_equal(prof.backlash_std_deg, np.full(6, 0.01))
    doc["water"]["drift_std_c_per_min"] = 0.2
    doc["robot"]["backlash_std_deg"] = [0.01, 0.02, 0.03, 0.004, 0.005, 0.006]
    path.write_text(tomlkit.dumps(doc))
    prof = load_profile(path)
    assert prof.drift_std_c_per_min == 0.2
    np.testing.assert_array_equal(prof.backlash_std_deg, [0.01, 0.02, 0.03, 0.004, 0.005, 0.006])
    del doc["water"]["drift_std_c_per_min"]
    doc["robot"]["backlash_std_deg"] = 0.03
    path.write_text(tomlkit.dumps(doc))
    prof = load_profile(path)
    assert prof.drift_std_c_per_min == 0.05
    np.testing.assert_array_equal(prof.backlash_std_deg, np.full(6, 0.03))
    doc["robot"]["backlash_std_deg"] = [0.01, 0.02]
    path.write_text(tomlkit.dumps(doc))
    with pytest.raises(ProfileError) as err:
        load_profile(path)
    assert err.value.key == "robot.backlash_std_deg"


def test_dh_rows_as_plain_arrays(tmp_path: Path) -> None:
    doc = tomlkit.parse(default_profile_text("tx90l"))
    doc["robot"]["dh"] = [[float(v) for v in row] for row in load_model("tx90l").dh]
    path = tmp_path / "c.toml"
    path.write_text(tomlkit.dumps(doc))
    np.testing.assert_array_equal(load_profile(path).model.dh, load_model("tx90l").dh)


def test_invalid_toml_names_the_file(tmp_path: Path) -> None:
    path = tmp_path / "broken.toml"
    path.write_text("schema = 1\n[robot\nmodel = 'tx90'\n")
    with pytest.raises(ProfileError, match=r"broken\.toml: not valid TOML.*line 2"):
        load_profile(path)


def test_missing_file_names_the_file(tmp_path: Path) -> None:
    with pytest.raises(ProfileError, match=r"nope\.toml: cannot read"):
        load_profile(tmp_path / "nope.toml")


Mutation = Callable[[tomlkit.TOMLDocument], None]


def _set(table: str, key: str, value: object) -> Mutation:
    def f(doc: tomlkit.TOMLDocument) -> None:
        doc[table][key] = value

    return f


def _del(table: str, key: str | None = None) -> Mutation:
    def f(doc: tomlkit.TOMLDocument) -> None:
        if key is None:
            del doc[table]
        else:
            del doc[table][key]

    return f


def _dh(row: int, col: str, value: object) -> Mutation:
    def f(doc: tomlkit.TOMLDocument) -> None:
        doc["robot"]["dh"][row][col] = value

    return f


def _rename(table: str | None, old: str, new: str) -> Mutation:
    """A key (or, with ``table`` None, a table) misspelt: ``old`` written as ``new``."""

    def f(doc: tomlkit.TOMLDocument) -> None:
        where = doc if table is None else doc[table]
        value = where[old]
        del where[old]
        where[new] = value

    return f


def _dh_column(row: int, old: str, new: str) -> Mutation:
    def f(doc: tomlkit.TOMLDocument) -> None:
        cells = doc["robot"]["dh"][row]
        cells[new] = cells.pop(old)

    return f


def _unknown_model(doc: tomlkit.TOMLDocument) -> None:
    doc["robot"]["model"] = "tx200"
    del doc["robot"]["dh"]


def _schema(doc: tomlkit.TOMLDocument) -> None:
    doc["schema"] = 2


MALFORMED: list[tuple[str, Mutation, str, str]] = [
    ("missing key", _del("tool", "position_mm"), "tool.position_mm", "missing key"),
    ("missing table", _del("water"), "water", "missing table"),
    (
        "missing model and dh",
        lambda d: (_del("robot", "model")(d), _del("robot", "dh")(d)),
        "robot.model",
        "missing key",
    ),
    (
        "wrong length",
        _set("tool", "position_mm", [0.0, 0.0]),
        "tool.position_mm",
        "must have 3 values, got 2",
    ),
    ("dh wrong length", lambda d: d["robot"]["dh"].pop(), "robot.dh", "must have 6 values"),
    (
        "nan",
        _set("sample", "position_mm", [float("nan"), 0.0, 0.0]),
        "sample.position_mm[0]",
        "must be a finite number, got nan",
    ),
    (
        "inf",
        _set("transducer", "element_diameter_mm", float("inf")),
        "transducer.element_diameter_mm",
        "finite",
    ),
    (
        "text for number",
        _dh(2, "a_mm", "abc"),
        "robot.dh[2].a_mm",
        "must be a finite number, got 'abc'",
    ),
    (
        "bool for number",
        _set("water", "temperature_c", True),
        "water.temperature_c",
        "must be a finite number",
    ),
    ("unknown model", _unknown_model, "robot.model", "unknown robot model 'tx200'"),
    ("schema", _schema, "schema", "must be 1"),
    ("hot water", _set("water", "temperature_c", 80.0), "water.temperature_c", "<= 60"),
    ("zero frequency", _set("transducer", "frequency_mhz", 0.0), "transducer.frequency_mhz", "> 0"),
    ("negative face", _set("sample", "face_size_mm", -1.0), "sample.face_size_mm", "> 0"),
    (
        "joint range",
        _set("robot", "joint_min_deg", [-180.0, -130.0, 150.0, -270.0, -115.0, -270.0]),
        "robot.joint_min_deg[2]",
        "must be below maximum",
    ),
    (
        "big offset",
        _set("calibration", "joint_offsets_deg", [0, 45, 0, 0, 0, 0]),
        "calibration.joint_offsets_deg[1]",
        "<= 30",
    ),
    (
        "joint number",
        _set("calibration", "unobservable_joints", [7]),
        "calibration.unobservable_joints[0]",
        "<= 6",
    ),
    (
        "joint number type",
        _set("calibration", "unobservable_joints", [1.0]),
        "calibration.unobservable_joints[0]",
        "must be an integer",
    ),
    (
        "two points",
        _set("reflector", "points_mm", [[0, 0, 0], [1, 0, 0]]),
        "reflector.points_mm",
        "at least 3",
    ),
    (
        "collinear",
        _set("reflector", "points_mm", [[0, 0, 0], [100, 0, 0], [200, 0, 0]]),
        "reflector.points_mm",
        "collinear",
    ),
    (
        "duplicate",
        _set("reflector", "points_mm", [[0, 0, 0], [100, 0, 0], [100, 0, 0]]),
        "reflector.points_mm[2]",
        "duplicates point 1",
    ),
    ("speed", _set("procedure", "speed", 1.5), "procedure.speed", "<= 1"),
    (
        "first-state timeout",
        _set("controller", "first_state_timeout_s", 0.0),
        "controller.first_state_timeout_s",
        "> 0",
    ),
    (
        "settle timeout",
        _set("controller", "settle_timeout_s", "long"),
        "controller.settle_timeout_s",
        "finite",
    ),
    (
        "averages",
        _set("procedure", "tof_averages", 2.5),
        "procedure.tof_averages",
        "must be an integer",
    ),
    (
        "pose out of range",
        _set("procedure", "calibration_pose_deg", [0, 150, 0, 0, 45, 0]),
        "procedure.calibration_pose_deg[1]",
        "outside its range",
    ),
    ("not a table", _set("tool", "position_mm", {"x": 1}), "tool.position_mm", "must be an array"),
    # a misspelt key is named as such, with the key it stands for, not as that key missing
    (
        "misspelt required key",
        _rename("transducer", "frequency_mhz", "frequncy_mhz"),
        "transducer.frequncy_mhz",
        "unknown key; did you mean frequency_mhz?",
    ),
    (
        "misspelt optional key",
        _rename("water", "temperature_std_c", "temperatur_std_c"),
        "water.temperatur_std_c",
        "unknown key; did you mean temperature_std_c?",
    ),
    (
        "misspelt table",
        _rename(None, "transducer", "transducr"),
        "transducr",
        "unknown table; did you mean [transducer]?",
    ),
    ("misspelt schema", _rename(None, "schema", "schem"), "schem", "did you mean schema?"),
    (
        "misspelt DH column",
        _dh_column(1, "a_mm", "a_m"),
        "robot.dh[1].a_m",
        "unknown DH column; did you mean a_mm?",
    ),
]


@pytest.mark.parametrize("case, mutate, key, message", MALFORMED, ids=[c[0] for c in MALFORMED])
def test_malformed_profile_exits_2_naming_file_and_key(
    case: str,
    mutate: Mutation,
    key: str,
    message: str,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    doc = tomlkit.parse(default_profile_text("tx90l"))
    mutate(doc)
    path = tmp_path / "bad.toml"
    path.write_text(tomlkit.dumps(doc), encoding="utf-8")
    with pytest.raises(ProfileError) as err:
        load_profile(path)
    assert err.value.key == key
    for command in (["profile", "validate"], ["profile", "show"]):
        with pytest.raises(SystemExit) as exc:
            main([*command, str(path)])
        assert exc.value.code == 2
        out = capsys.readouterr()
        assert out.out == ""
        lines = out.err.strip().splitlines()
        assert len(lines) == 1, out.err
        assert lines[0].startswith(f"error: {path}: {key}: "), lines[0]
        assert message in lines[0]
        assert "Traceback" not in out.err


def test_fk_with_malformed_profile_exits_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    doc = tomlkit.parse(default_profile_text("tx90l"))
    doc["tool"]["rotation_deg"] = [0.0, "x", 0.0]
    path = tmp_path / "bad.toml"
    path.write_text(tomlkit.dumps(doc))
    with pytest.raises(SystemExit) as exc:
        main(["fk", str(path), "--joints", "0,0,0,0,0,0"])
    assert exc.value.code == 2
    assert (
        f"{path}: tool.rotation_deg[1]: must be a finite number, got 'x'" in capsys.readouterr().err
    )


def test_unknown_keys_are_warnings(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    doc = tomlkit.parse(default_profile_text("tx90l"))
    doc["water"]["temprature_c"] = 21.0  # beside temperature_c: allowed, but said
    doc["water"]["operator"] = "J. Doe"  # close to no known key: allowed
    path = tmp_path / "c.toml"
    path.write_text(tomlkit.dumps(doc))
    assert exit_code(["profile", "validate", str(path), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["valid"] is True
    assert out["warnings"] == [
        "unknown key water.temprature_c (ignored; did you mean temperature_c?)",
        "unknown key water.operator (ignored)",
    ]


# ------------------------------------------------------------------------------ writing


def test_write_keeps_comments_and_key_order(cell: Path) -> None:
    before = cell.read_text()
    offsets = np.array([0.12, -0.25, 0.5, 0.0, -1.75, 0.3])
    write_profile(
        cell,
        {
            "calibration": {
                "joint_offsets_deg": offsets,
                "unobservable_joints": np.array([4]),
                "method": "exact",
            },
            "tool": {"position_mm": np.array([0.5, -0.25, 81.0])},
            "reflector": {"plate": "steel"},
            "water": {"temperature_c": np.float64(21.5)},
        },
        reason="calibrate",
    )
    after = cell.read_text()
    assert _comments(after) == _comments(before)
    keys_before = _keys_in_order(before)
    keys_after = _keys_in_order(after)
    # Existing keys keep their order; the new key follows the last key of its table.
    assert [k for k in keys_after if k in keys_before] == keys_before
    i = keys_after.index("calibration.method")
    assert keys_after[i - 1] == "calibration.unobservable_joints"
    # ... and stays above the comment that introduces the next table
    assert after.index('plate = "steel"') < after.index("# tank filled")
    assert after.index("points_mm") < after.index('plate = "steel"')
    prof = load_profile(cell)
    np.testing.assert_array_equal(prof.joint_offsets_deg, offsets)
    assert prof.unobservable_joints == (4,)
    np.testing.assert_array_equal(prof.tool_position_mm, [0.5, -0.25, 81.0])
    assert prof.water_temperature_c == 21.5
    assert "temperature_c = 21.5  # checked weekly" in after
    assert "[calibration]  # last done by J. Doe" in after
    # numpy values are written as plain TOML numbers
    assert "joint_offsets_deg = [0.12, -0.25, 0.5, 0.0, -1.75, 0.3]" in after
    assert "np." not in after and "array" not in after
    # only the lines of the written keys differ
    diff = difflib.ndiff(before.splitlines(), after.splitlines())
    changed = {line[2:].split(" =")[0] for line in diff if line[:2] in ("- ", "+ ")}
    assert changed == {
        "joint_offsets_deg",
        "unobservable_joints",
        "method",
        "position_mm",
        "plate",
        "temperature_c",
    }


def test_write_adds_a_missing_table(cell: Path) -> None:
    doc = tomlkit.parse(cell.read_text())
    del doc["calibration"]
    cell.write_text(tomlkit.dumps(doc))
    write_profile(cell, {"calibration": {"joint_offsets_deg": [0.1] * 6}}, reason="calibrate")
    np.testing.assert_array_equal(load_profile(cell).joint_offsets_deg, [0.1] * 6)


def test_write_that_would_invalidate_the_profile_is_refused(cell: Path) -> None:
    before = cell.read_bytes()
    with pytest.raises(ProfileError) as err:
        write_profile(
            cell, {"calibration": {"joint_offsets_deg": [0, 0, 99.0, 0, 0, 0]}}, reason="calibrate"
        )
    assert err.value.key == "calibration.joint_offsets_deg[2]"
    assert cell.read_bytes() == before
    assert profile_history(cell) == []


def test_failed_replace_leaves_the_profile_unchanged(
    cell: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    before = cell.read_bytes()
    real_replace = os.replace

    def failing_replace(src: str, dst: str) -> None:
        if Path(dst) == cell:
            raise OSError(28, "No space left on device")
        real_replace(src, dst)

    monkeypatch.setattr(os, "replace", failing_replace)
    with pytest.raises(ProfileError, match="cannot write: No space left on device"):
        write_profile(cell, {"calibration": {"joint_offsets_deg": [0.5] * 6}}, reason="calibrate")
    assert cell.read_bytes() == before
    # no temporary file left behind, no history entry or copy for the failed write
    assert sorted(p.name for p in cell.parent.iterdir()) == ["cell.toml", "cell.toml.history"]
    assert profile_history(cell) == []
    assert not (history_dir(cell) / "0001-before.toml").exists()


def test_failed_temp_write_leaves_the_profile_unchanged(
    cell: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    before = cell.read_bytes()

    def failing_fsync(fd: int) -> None:
        raise OSError(5, "Input/output error")

    monkeypatch.setattr(os, "fsync", failing_fsync)
    with pytest.raises(ProfileError):
        write_profile(cell, {"calibration": {"joint_offsets_deg": [0.5] * 6}}, reason="calibrate")
    assert cell.read_bytes() == before
    assert not [p for p in cell.parent.iterdir() if p.name.endswith(".tmp")]


def test_unchanged_write_records_nothing(cell: Path) -> None:
    write_profile(cell, {"calibration": {"joint_offsets_deg": [0.0] * 6}}, reason="calibrate")
    assert profile_history(cell) == []


# ------------------------------------------------------------------------------ history, undo


def test_undo_restores_the_previous_bytes(cell: Path) -> None:
    v0 = cell.read_bytes()
    write_profile(cell, {"calibration": {"joint_offsets_deg": [0.1] * 6}}, reason="calibrate")
    v1 = cell.read_bytes()
    write_profile(cell, {"tool": {"position_mm": [0.0, 0.0, 81.0]}}, reason="tool-frame")
    v2 = cell.read_bytes()
    assert len({v0, v1, v2}) == 3
    entries = profile_history(cell)
    assert [(e.id, e.reason, e.undone) for e in entries] == [
        (1, "calibrate", False),
        (2, "tool-frame", False),
    ]

    undone = undo_profile(cell)
    assert undone.id == 2
    assert cell.read_bytes() == v1
    assert (history_dir(cell) / undone.after).read_bytes() == v2  # nothing is lost
    undo_profile(cell)
    assert cell.read_bytes() == v0
    with pytest.raises(ProfileError, match="nothing to undo"):
        undo_profile(cell)

    # a new write after undos starts from the restored version and is undoable again
    write_profile(cell, {"water": {"temperature_c": 22.0}}, reason="manual")
    undo_profile(cell)
    assert cell.read_bytes() == v0


def test_undo_refuses_after_a_hand_edit_unless_forced(cell: Path) -> None:
    v0 = cell.read_bytes()
    write_profile(cell, {"calibration": {"joint_offsets_deg": [0.1] * 6}}, reason="calibrate")
    cell.write_text(cell.read_text() + "# edited by hand\n")
    edited = cell.read_bytes()
    with pytest.raises(ProfileError, match="changed since write 1"):
        undo_profile(cell)
    assert cell.read_bytes() == edited
    undo_profile(cell, force=True)
    assert cell.read_bytes() == v0


def test_undo_via_cli(cell: Path, capsys: pytest.CaptureFixture[str]) -> None:
    v0 = cell.read_bytes()
    write_profile(cell, {"calibration": {"joint_offsets_deg": [0.2] * 6}}, reason="calibrate")
    assert exit_code(["profile", "undo", str(cell), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["undone"] == 1 and out["reason"] == "calibrate"
    assert cell.read_bytes() == v0
    with pytest.raises(SystemExit) as exc:
        main(["profile", "undo", str(cell)])
    assert exc.value.code == 2
    assert "nothing to undo" in capsys.readouterr().err


def test_failed_undo_leaves_the_profile_unchanged(
    cell: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    write_profile(cell, {"calibration": {"joint_offsets_deg": [0.1] * 6}}, reason="calibrate")
    v1 = cell.read_bytes()
    real_replace = os.replace

    def failing_replace(src: str, dst: str) -> None:
        if Path(dst) == cell:
            raise OSError(13, "Permission denied")
        real_replace(src, dst)

    monkeypatch.setattr(os, "replace", failing_replace)
    with pytest.raises(ProfileError):
        undo_profile(cell)
    assert cell.read_bytes() == v1
    assert not profile_history(cell)[0].undone
