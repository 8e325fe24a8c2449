"""verify reads the tank again at calibrate's readings: the sound speed now and its drift
within the run from the ratio of the water paths, a block that moved told from the water, each
water path converted at the speed of its time, and the readings calibrate keeps for it."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest
import tomlkit

from ucal.acoustics import sound_speed_m_s
from ucal.devices.record import measured_from_lines, measurement_lines
from ucal.model.geometry import FaceMeasurement
from ucal.model.readings import CalibrationReadings, readings_path, write_readings
from ucal.procedure import RunOptions
from ucal.profile import (
    create_profile,
    default_profile_text,
    load_profile,
    profile_from_data,
    write_profile,
)
from ucal.verify.inputs import BeforeProfile, SoundSpeed, repeated_faces, tank_reference
from ucal.verify.measure import PointResult, VerifyResult, tank_corrected
from ucal.verify.plan import WALL_PATH_MM, plan_summary, plan_verify, with_tank
from ucal.verify.procedure import VerifyJob
from ucal.verify.result import VerifySolved, water_note
from ucal.verify.tank import REPEAT_STD_MM, estimate_tank

#: Marczak's at 20 °C: what calibrate converted its times of flight with
C0 = float(sound_speed_m_s(20.0))
#: the speed calibrate's fit found (m/s), at its readings' mean time, and its drift (m/s/min)
C_CAL = C0 + 0.6
DRIFT_CAL = 0.05
T_REF = 2.0
#: the true water paths of the calibration pose's faces (mm), read at times (min)
PATHS_MM = np.array([83.2, 102.3, 134.1])
TIMES_MIN = (0.1, 0.4, 0.7)


def reading(face: int, path_mm: float, time_min: float, config: str = "base", sign: float = 1):
    return FaceMeasurement(
        config,
        face,
        np.array([0.0, 10.0, 80.0, 0.0, 60.0 + 10 * face, 0.0]),
        path_mm,
        distance_std_mm=0.001,
        gain_db=20.0,
        time_min=time_min,
        approach=np.full(6, sign),
    )


def calibration() -> CalibrationReadings:
    """calibrate's three readings: the true paths read at its speed of their time, converted
    at C0."""
    faces = []
    for k, (path, t) in enumerate(zip(PATHS_MM, TIMES_MIN, strict=True)):
        c = C_CAL + DRIFT_CAL * (t - T_REF)
        faces.append(reading(k, path * C0 / c, t))
    return CalibrationReadings(tuple(faces), C0, C_CAL, 0.3, DRIFT_CAL, 0.004, T_REF, "entry 1")


def again(speed_m_s: float, time_min: float, moved_mm=(0.0, 0.0, 0.0)) -> list[FaceMeasurement]:
    """The three paths read again at the tank's ``speed_m_s``, converted at C_CAL (verify's),
    the block moved ``moved_mm`` towards the tool along each face's normal."""
    paths = (PATHS_MM - np.asarray(moved_mm)) * C_CAL / speed_m_s
    return [reading(k, float(p), time_min, "tank") for k, p in enumerate(paths)]


def test_a_sound_speed_change_and_its_drift_are_recovered() -> None:
    """The tank 1.5 m/s faster than calibrate's speed at the start, drifting 0.1 m/s a
    minute over the 9 minutes of the run: both recovered from the paths' ratio, each reading
    taken as the water's."""
    start_c, end_c = C_CAL + 1.5, C_CAL + 1.5 + 0.9
    tank = estimate_tank(calibration(), tuple(again(start_c, 0.5) + again(end_c, 9.5)), C_CAL, 0.15)
    assert tank.used and tank.seen == "sound speed"
    assert tank.start.m_s == pytest.approx(start_c, abs=1e-6)
    assert tank.end is not None and tank.end.m_s == pytest.approx(end_c, abs=1e-6)
    assert tank.drift_m_s_per_min == pytest.approx(0.1, abs=1e-7)
    assert tank.speed_at(5.0) == pytest.approx(start_c + 0.45, abs=1e-6)
    assert tank.extra_moves == 6
    # relative to calibrate's speed at its readings' mean time
    assert tank.then_time_min == pytest.approx(np.mean(TIMES_MIN))
    assert tank.then_m_s == pytest.approx(C_CAL + DRIFT_CAL * (np.mean(TIMES_MIN) - T_REF))
    # one sigma: the readings' noise and the arm's repeatability over the three paths
    sigma = np.sqrt(0.001**2 + REPEAT_STD_MM**2)
    assert tank.start.std_m_s == pytest.approx(start_c * sigma / np.linalg.norm(PATHS_MM), 1e-2)
    # with the drift's curvature over the run (0.15·9/8) and calibrate's drift at its readings
    assert tank.curvature_std_m_s == pytest.approx(0.15 * 9.0 / 8.0)
    assert tank.std_m_s > tank.curvature_std_m_s > tank.start.std_m_s


def test_a_block_translation_is_not_taken_for_a_sound_speed_change() -> None:
    """The block moved 0.1 mm along X since calibrate, the water as it was: the paths changed
    unlike a sound speed change (one face's only), so the speed is not used and verify keeps
    the promise of its age, and says why."""
    tank = estimate_tank(
        calibration(),
        tuple(again(C_CAL, 0.5, (0.1, 0.0, 0.0)) + again(C_CAL, 9.5, (0.1, 0.0, 0.0))),
        C_CAL,
    )
    assert tank.start.moved and not tank.used and tank.seen == "moved"
    assert max(abs(v) for v in tank.start.misfit_mm) > 0.05
    profile = profile_from_data(tomlkit.parse(default_profile_text("tx90l")), "cell.toml")
    plan = plan_verify(profile, 1)
    sound = SoundSpeed(C_CAL, 20.2, "calibrate", 1.5, 60.0)
    solved = VerifySolved(
        VerifyResult(plan, [], 0, 0), BeforeProfile(np.zeros(6), ""), sound, 0.5, 0.0, tank=tank
    )
    assert solved.tank_used is None
    assert solved.water_std_mm == pytest.approx(max(WALL_PATH_MM) * 1.5 / C_CAL)
    (note,) = water_note(solved)
    assert "the block or the arm moved" in note and "60 min ago" in note
    # the same 0.1 mm on every face, in proportion to nothing: moved too
    uniform = estimate_tank(calibration(), tuple(again(C_CAL, 0.5, (0.2, 0.2, 0.2))), C_CAL)
    assert uniform.start.moved


def test_a_run_with_the_tank_read_again_promises_its_sound_speed() -> None:
    """The tank's speed read within the run replaces the age's in the promise."""
    tank = estimate_tank(calibration(), tuple(again(C_CAL, 0.5) + again(C_CAL, 9.5)), C_CAL)
    profile = profile_from_data(tomlkit.parse(default_profile_text("tx90l")), "cell.toml")
    sound = SoundSpeed(C_CAL, 20.2, "calibrate", 1.5, 60.0)
    solved = VerifySolved(
        VerifyResult(plan_verify(profile, 1), [], 0, 0),
        BeforeProfile(np.zeros(6), ""),
        sound,
        0.5,
        0.0,
        tank=tank,
    )
    assert solved.tank_used is tank
    # what the water did since calibrate: its own std of the speed is in MEASURED_WITHIN_MM
    assert solved.water_std_mm == pytest.approx(max(WALL_PATH_MM) * tank.change_std_m_s / C_CAL)
    assert solved.water_std_mm < 0.02
    # as a sound speed, the calibration's std of its own (0.3 m/s) is in the speed's
    assert tank.std_m_s == pytest.approx(np.hypot(tank.change_std_m_s, 0.3), rel=1e-6)
    (note,) = water_note(solved)
    assert "read again" in note and f"{tank.m_s:.2f}" in note


def test_each_water_path_is_converted_at_the_speed_of_its_time() -> None:
    """The tank 0.2 % faster at the end of a 10 min run than at its start: a point read at 5
    min moves by 0.1 % of each of its paths (mm), on the axis of that path's face."""
    profile = profile_from_data(tomlkit.parse(default_profile_text("tx90l")), "cell.toml")
    plan = plan_verify(profile, 1)
    paths = (150.0, 50.0, 30.0)
    point = PointResult(
        "after",
        0,
        plan.nominal_mm[0],
        plan.targets[-1].joints_deg,
        tuple(reading(k, p, 5.0) for k, p in enumerate(paths)),
        np.array([10.0, 20.0, 30.0]),
        plan.nominal_mm[0] + 0.01,
        0.0,
    )
    result = VerifyResult(plan, [point], 0, 0)
    tank = estimate_tank(
        calibration(),
        tuple(again(C_CAL, 0.0) + again(C_CAL * 1.002, 10.0)),
        C_CAL,
    )
    (moved,) = tank_corrected(result, tank, C_CAL).points
    shift = np.array(paths) * 1e-3
    np.testing.assert_allclose(moved.reached_mm - point.reached_mm, shift, atol=1e-9)
    np.testing.assert_allclose(moved.wrist_centre_mm - point.wrist_centre_mm, shift, atol=1e-9)
    assert [m.distance_mm for m in moved.faces] == pytest.approx(np.array(paths) * 1.001)


def test_the_faces_read_again_are_one_posture_of_calibrates_from_below(tmp_path) -> None:
    """The calibration pose's three faces, not a reading from above nor another posture's;
    without a posture of all three, each face's longest path; none without every face. The
    readings are kept beside calibrate's history entry and read back by verify."""
    cal = calibration()
    above = replace(reading(0, 90.0, 3.0, "base-above", -1.0))
    other = [reading(k, 120.0 + k, 1.0, "j2") for k in (2, 0)]
    faces = (*other, above, *cal.faces)
    assert repeated_faces(faces) == cal.faces
    single = tuple(reading(k % 3, 60.0 + k, k, f"p{k}") for k in range(6))
    assert [m.distance_mm for m in repeated_faces(single) or ()] == [63.0, 64.0, 65.0]
    assert repeated_faces(single[:2] + single[3:5]) is None
    path = create_profile(tmp_path / "cell.toml", "tx90l")
    entry = write_profile(path, {"calibration": {"sound_speed_m_s": C_CAL}}, "calibrate")
    assert entry is not None
    assert tank_reference(path) is None  # a calibration that kept no readings
    write_readings(path, entry, replace(cal, faces=faces))
    back = tank_reference(path)
    assert back is not None and back.source.startswith(f"history entry {entry.id}")
    assert [(m.config, int(m.face)) for m in back.faces] == [("base", 0), ("base", 1), ("base", 2)]
    assert back.path_mm(back.faces[1]) == pytest.approx(PATHS_MM[1])
    data = json.loads((path.parent / "cell.toml.history" / "0001-readings.json").read_text())
    assert len(data["faces"]) == len(faces) and data["sound_speed_m_s"] == C_CAL


def test_a_replay_reads_the_tank_as_the_run_did(tmp_path) -> None:
    """The readings verify read again are in its record's inputs (the history may move on)
    and its measurement lines: a replay solves the same tank."""
    path = create_profile(tmp_path / "cell.toml", "tx90l")
    entry = write_profile(path, {"calibration": {"sound_speed_m_s": C_CAL}}, "calibrate")
    assert entry is not None
    write_readings(path, entry, calibration())
    run = VerifyJob(load_profile(path), path)
    run.check(RunOptions(None, dry_run=True))
    inputs = json.loads(json.dumps(run.record_header(None)["inputs"]))
    readings_path(path, entry).unlink()
    replay = VerifyJob(load_profile(path), path, recorded_inputs=inputs)
    replay.check(RunOptions(None, dry_run=True))
    assert run.tank is not None and replay.tank is not None
    assert [m.distance_mm for m in replay.tank.faces] == [m.distance_mm for m in run.tank.faces]
    assert replay.tank.speed_at(1.0) == run.tank.speed_at(1.0)
    plan = plan_verify(load_profile(path), 1)
    result = VerifyResult(plan, [], 0, 0, tank_readings=tuple(again(C_CAL + 1.0, 0.5)))
    lines = json.loads(json.dumps(measurement_lines(result, given=("plan",))))
    back = measured_from_lines(lines, plan=plan)
    assert [m.time_min for m in back.tank_readings] == [0.5] * 3
    assert [m.distance_mm for m in back.tank_readings] == [
        m.distance_mm for m in result.tank_readings
    ]


def test_the_plan_says_the_six_moves_it_adds(tmp_path) -> None:
    """The three postures are checked before motion and the plan and its estimate count the
    six moves and their readings; a posture outside the joint ranges keeps the plan without."""
    profile = profile_from_data(tomlkit.parse(default_profile_text("tx90l")), "cell.toml")
    plan = plan_verify(profile, 1)
    cal = calibration()
    faces = cal.faces
    tanked = with_tank(plan, profile, cal)
    assert tanked.tank_faces == faces
    job = VerifyJob(profile, tmp_path / "cell.toml")
    extra = job.estimate(tanked).moves - job.estimate(plan).moves
    assert extra == 6
    assert job.estimate(tanked).reads - job.estimate(plan).reads == 6 * 8
    assert "(6 moves more)" in plan_summary(tanked, tmp_path / "cell.toml")
    out_of_range = replace(faces[0], joints_deg=np.array([0.0, 10.0, 80.0, 0.0, 170.0, 0.0]))
    kept = with_tank(plan, profile, replace(cal, faces=(out_of_range, *faces[1:])))
    assert kept.tank_faces == ()
