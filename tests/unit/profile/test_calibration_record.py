"""``[calibration]`` read back as a typed record: what calibrate wrote reaches verify unchanged,
and a key of the wrong shape stops every command at load time, the file and key named (exit 2),
where it was once taken as absent."""

from __future__ import annotations

from pathlib import Path

import pytest
import tomlkit

from ucal.errors import ProfileError
from ucal.profile import create_profile, load_profile, write_profile
from ucal.profile.calibration import CalibrationRecord, WrittenCalibration, calibration_record
from ucal.verify.inputs import calibration_gauge, sound_speed_for_verify, written_budget

from doubles import exit_code


@pytest.fixture
def profile(tmp_path: Path) -> Path:
    path = tmp_path / "cell.toml"
    create_profile(path, "tx90l")
    return path


def test_a_profile_never_calibrated_has_an_empty_record(profile: Path) -> None:
    assert calibration_record(profile) == CalibrationRecord()
    assert written_budget(profile) is None
    assert calibration_gauge(load_profile(profile), profile).j1 is None


def test_what_calibrate_wrote_is_what_verify_reads(profile: Path) -> None:
    keys = {
        "gauge": "block",
        "sound_speed_m_s": 1482.375,
        "unidentified_tcp_mm": [0.0572, 0.0978],
        "date": "2026-12-06T08:00:00+00:00",
    }
    write_profile(profile, {"calibration": keys}, "calibrate (test)")
    record = calibration_record(profile)
    assert record == CalibrationRecord("block", 1482.375, (0.0572, 0.0978), keys["date"])
    assert written_budget(profile) == (0.0572, 0.0978)
    cell = load_profile(profile)
    assert calibration_gauge(cell, profile).j1 == "block"
    sound = sound_speed_for_verify(cell, profile)
    assert sound.m_s == 1482.375
    assert "[calibration] sound_speed_m_s" in sound.source


@pytest.mark.parametrize(
    ("key", "value", "message"),
    [
        ("gauge", "flange", 'must be "block" or "base"'),
        ("sound_speed_m_s", "1482", "must be a finite number"),
        ("sound_speed_m_s", 340.0, "must be >= 1300 m/s"),
        ("unidentified_tcp_mm", [0.05], "must have 2 values"),
        ("unidentified_tcp_mm", [-0.1, 0.2], "must be >= 0 mm"),
        ("date", "yesterday", "must be an ISO 8601 time"),
    ],
)
def test_a_bad_key_is_refused_where_the_profile_is_read(
    profile: Path, key: str, value: object, message: str
) -> None:
    doc = tomlkit.parse(profile.read_text(encoding="utf-8"))
    doc.setdefault("calibration", tomlkit.table())[key] = value
    profile.write_text(tomlkit.dumps(doc), encoding="utf-8")
    for read in (load_profile, calibration_record):
        with pytest.raises(ProfileError) as e:
            read(profile)
        assert str(e.value).startswith(f"{profile}: calibration.{key}: {message}")
    # verify stops before the simulated cell is opened, exit 2
    assert exit_code(["verify", str(profile), "--sim", "--yes", "--points", "1"]) == 2


def test_the_written_table_rounds_marks_the_undetermined_and_leaves_out_what_was_not_found(
    profile: Path,
) -> None:
    nan = float("nan")
    written = WrittenCalibration(
        level="offsets",
        joint_offsets_deg=[0.12345678, 0, 0, 0, 0, 0],
        std_deg=[0.0012345678, nan, 0.001, 0.001, 0.001, nan],
        unobservable_joints=[2, 6],
        method="exact",
        approach="positive",
        sound_speed_m_s=1482.12345,
        fit_verdict="ok",
        chi2_reduced=1.23456,
        date="2026-12-06T08:00:00+00:00",
        unidentified_tcp_mm=(0.057234, 0.09781),
    )
    table = written.table()
    assert table["joint_offsets_deg"][0] == 0.123457
    assert table["std_deg"] == [0.001235, -1.0, 0.001, 0.001, 0.001, -1.0]
    assert table["sound_speed_m_s"] == 1482.123 and table["chi2_reduced"] == 1.2346
    assert table["unidentified_tcp_mm"] == [0.0572, 0.0978]
    assert not {"gauge", "backlash_deg", "dh", "condition_number"} & table.keys()
    write_profile(profile, {"calibration": table}, "calibrate (test)")
    assert load_profile(profile).unobservable_joints == (2, 6)
    assert calibration_record(profile).unidentified_tcp_mm == (0.0572, 0.0978)
