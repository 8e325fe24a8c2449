"""The shipped robot models: one data file each (``profiles/<model>.toml``), read by
``ucal.profile.models``; their speeds are what the plan's estimate, the rig and the simulated
controller take."""

from __future__ import annotations

import numpy as np
import pytest

from ucal.calibration.procedure import OffsetsCalibration
from ucal.kinematics.ik import check_structure
from ucal.model.targets import plan_calibration
from ucal.profile import create_profile, load_profile
from ucal.profile.models import KNOWN_MODELS, joint_speeds_deg_s, load_model, model_sheet
from ucal.sim.serve import SimulatedCellServer
from ucal.timing import APPROACH_DEG, estimate_run

TX2 = ("tx2-90", "tx2-90l", "tx2-90xl")
#: The joints' speeds the TX90 family has always been planned with (deg/s).
TX90_PLAN_SPEEDS = (250.0, 200.0, 250.0, 400.0, 400.0, 600.0)


def test_todays_arms_are_shipped_beside_the_tx90_family() -> None:
    assert set(KNOWN_MODELS) == {"tx90", "tx90l", "tx90xl", *TX2}


@pytest.mark.parametrize("name", KNOWN_MODELS)
def test_a_model_file_reads_whole_and_names_itself(name: str) -> None:
    sheet = model_sheet(name)
    assert sheet.robot.name == name
    assert sheet.robot.speed_deg_s is not None and np.all(sheet.robot.speed_deg_s > 0)
    assert np.all(sheet.robot.speed_deg_s <= sheet.max_speed_deg_s)
    assert sheet.base_height_mm == 478.0
    check_structure(sheet.robot)


def test_the_tx90_family_plans_at_the_speeds_it_always_had() -> None:
    for name in ("tx90", "tx90l", "tx90xl"):
        np.testing.assert_array_equal(load_model(name).speed_deg_s, TX90_PLAN_SPEEDS)
    np.testing.assert_array_equal(joint_speeds_deg_s(None), TX90_PLAN_SPEEDS)


def test_the_tx2_arms_are_the_tx90_familys_geometry_at_the_ros_industrial_speeds() -> None:
    for tx2, tx90 in zip(TX2, ("tx90", "tx90l", "tx90xl"), strict=True):
        np.testing.assert_array_equal(load_model(tx2).dh, load_model(tx90).dh)
        np.testing.assert_array_equal(
            load_model(tx2).speed_deg_s, (400.0, 390.0, 420.0, 540.0, 475.0, 760.0)
        )


def test_the_estimate_follows_the_model_files_speeds(tmp_path) -> None:
    """The same plan on a TX90L and a TX2-90L (same geometry, faster joints): the moves take
    less time on the TX2, the reads as long."""
    estimates = {}
    for name in ("tx90l", "tx2-90l"):
        create_profile(tmp_path / f"{name}.toml", name)
        profile = load_profile(tmp_path / f"{name}.toml")
        job = OffsetsCalibration(profile, tmp_path / f"{name}.toml")
        estimates[name] = job.estimate(plan_calibration(profile))
    slow, fast = estimates["tx90l"], estimates["tx2-90l"]
    assert (slow.moves, slow.reads) == (fast.moves, fast.reads)
    assert fast.motion_s < slow.motion_s and fast.tcp_s < slow.tcp_s


def test_a_profiles_own_speeds_reach_the_estimate_and_the_controller(tmp_path) -> None:
    path = tmp_path / "cell.toml"
    create_profile(path, "tx90l")
    text = path.read_text().replace(
        "backlash_std_deg",
        "speed_deg_s = [125.0, 100.0, 125.0, 200.0, 200.0, 300.0]\nbacklash_std_deg",
    )
    path.write_text(text)
    profile = load_profile(path)
    np.testing.assert_array_equal(joint_speeds_deg_s(profile.model), np.array(TX90_PLAN_SPEEDS) / 2)
    start, target = np.zeros(6), np.array([0.0, 30.0, 0.0, 0.0, 0.0, 0.0])
    halved = estimate_run([target], start, 0.5, speeds_deg_s=joint_speeds_deg_s(profile.model))
    full = estimate_run([target], start, 0.5, speeds_deg_s=np.array(TX90_PLAN_SPEEDS))
    # the trapezoid to the pre-point 0.05 deg short, d/v + v/a at 1000 deg/s², at v = 50 and 100
    # deg/s (the last 0.05 deg is acceleration-bound, the same at either speed)
    d = 30.0 - APPROACH_DEG
    expected = (d / 50.0 + 50.0 / 1000.0) - (d / 100.0 + 100.0 / 1000.0)
    assert halved.motion_s - full.motion_s == pytest.approx(expected)
    server = SimulatedCellServer(None, profile)
    try:
        server.start()
        np.testing.assert_array_equal(
            server.controller.max_speed_deg_s, np.array(TX90_PLAN_SPEEDS) / 2
        )
    finally:
        server.stop()


@pytest.mark.parametrize("name", TX2)
def test_a_new_tx2_profile_plans_a_calibration(tmp_path, name: str) -> None:
    """A new profile of each TX2 arm plans its calibration (tx2-90l runs it whole:
    tests/system/test_profile_models_cli.py)."""
    create_profile(tmp_path / "cell.toml", name)
    profile = load_profile(tmp_path / "cell.toml")
    plan = plan_calibration(profile)
    assert plan.targets
    assert profile.model.name == name
