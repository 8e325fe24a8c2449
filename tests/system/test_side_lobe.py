"""The peak search on a side lobe: a wall predicted 2° off its normal (the block turned 2° about
its vertical, the profile says 0), measured after the floor, in the simulated cell (in process,
simulated time)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from ucal.acoustics import water_absorption_np_per_mm
from ucal.devices.session import open_cell
from ucal.errors import EXIT_HARDWARE, HardwareError
from ucal.measure.acquire import acquisition_gain
from ucal.measure.approach import FinalApproachRig
from ucal.measure.face import FaceRequest, FaceSetup, SearchMode, measure
from ucal.measure.lobe import MainLobe
from ucal.measure.search import PeakSearch, ka_of
from ucal.model.geometry import Face
from ucal.model.targets import calibration_pose, geometry
from ucal.profile import create_profile, load_profile
from ucal.sim.cell import SimulatedCell
from ucal.world import load_world

pytestmark = pytest.mark.system

YAW_DEG = 2.0  # the block's turn the profile does not know


def _true_tilt_deg(truth: SimulatedCell, joints_deg: np.ndarray, face: Face) -> float:
    _, beam = truth.true_beam(joints_deg)
    normal = truth.world.sample_matrix[:3, int(face)]
    return float(np.degrees(np.arccos(np.clip(-beam @ normal, -1.0, 1.0))))


def _wall(tmp_path: Path, reference: str) -> tuple[float | str, MainLobe]:
    """Measure the floor (when ``reference`` is not "none"), then the YZ wall from the profile's
    prediction; the wall's true tilt off normal (or the error), and the heights kept."""
    path = tmp_path / "cell.toml"
    create_profile(path, "tx90l")
    profile = load_profile(path)
    rot = (np.asarray(profile.sample_rotation_deg) + [0.0, 0.0, YAW_DEG]).tolist()
    world = tmp_path / "world.toml"
    world.write_text(
        f"[sample]\nrotation_deg = {rot!r}\n[noise]\ntof_ns = 0.5\namplitude = 0.01\nseed = 3\n"
    )
    truth = SimulatedCell(load_world(world, profile))
    geom, pose, est = geometry(profile), calibration_pose(profile), np.zeros(6)
    with open_cell(profile, str(world), None, None) as cell:
        rig = FinalApproachRig(cell.rig)
        ka = ka_of(profile.frequency_mhz, profile.element_diameter_mm, 20.0)
        away = pose.copy()
        away[4] -= 25.0
        setup = FaceSetup(profile, ka, acquisition_gain(rig, away))
        if reference != "none":
            floor = FaceRequest(Face.XY, pose, geom, est, "face XY (base)", "base")
            found = measure(rig, setup, floor)
            assert _true_tilt_deg(truth, found.measurement.joints_deg, Face.XY) < 0.01
            # its water path read at a posture reached from below on every joint, some time
            # after the run's first reading (the noise floor's)
            approach, minutes = found.measurement.approach, found.measurement.time_min
            assert approach is not None and approach.tolist() == [1.0] * 6
            assert minutes is not None and 0.0 < minutes == pytest.approx(rig.minutes(), abs=1.0)
            if reference == "30 dB too strong":  # as if another reflector had given it
                setup.main_lobe.peaks[:] = [(a * 10**1.5, p) for a, p in setup.main_lobe.peaks]
        wall = FaceRequest(
            Face.YZ, pose, geom, est, "face YZ (base)", "base", SearchMode.QUICK, 8.0
        )
        try:
            result = measure(rig, setup, wall)
        except HardwareError as err:
            assert err.exit_code == EXIT_HARDWARE
            return str(err), setup.main_lobe
        return _true_tilt_deg(truth, result.measurement.joints_deg, Face.YZ), setup.main_lobe


def test_without_a_main_lobe_height_the_search_fits_a_side_lobe(tmp_path: Path) -> None:
    # the situation the height is for: from this start the search alone stays 2° off normal
    tilt, heights = _wall(tmp_path, "none")
    assert isinstance(tilt, float) and 1.5 < tilt < 3.0
    assert heights.peaks == []  # a side lobe's fit is not kept as a height


def test_the_floor_s_height_takes_the_wall_search_to_its_main_lobe(tmp_path: Path) -> None:
    tilt, heights = _wall(tmp_path, "floor")
    assert isinstance(tilt, float) and tilt < 0.01
    # both faces' main lobes kept, at their water paths (the floor's 100 mm below the pose)
    assert len(heights.peaks) == 2
    floor, (wall_a, wall_l) = heights.peaks
    assert floor[1] == pytest.approx(100.0, abs=2.0) and 60.0 < wall_l < 140.0
    # one reflector: the wall's main lobe is the floor's, carried to its path, within 2 dB
    carried = MainLobe([floor]).expected(wall_l, water_absorption_np_per_mm(25.0))
    assert carried is not None and abs(20 * np.log10(wall_a / carried)) < 2.0


def test_a_main_lobe_far_weaker_than_expected_is_named_not_fitted(tmp_path: Path) -> None:
    message, _ = _wall(tmp_path, "30 dB too strong")
    assert isinstance(message, str)
    assert message.startswith("pulser at ") and "face YZ (base): the peak found" in message
    assert "dB below the main lobe that the faces measured so far give" in message
    assert "a side lobe, and no main lobe found" in message


def test_main_lobe_height_is_carried_by_absorption_and_the_strongest_counts() -> None:
    lobe = MainLobe()
    assert lobe.expected(100.0, 0.0158) is None
    lobe.add(0.02, 100.0)
    lobe.add(0.5, float("nan"))  # no water path: not kept
    assert len(lobe.peaks) == 1
    assert lobe.expected(100.0, 0.0158) == pytest.approx(0.02)
    # 40 mm shorter: 2·0.0158·40 Np = 10.98 dB more (one height: the profile's absorption)
    assert lobe.expected(60.0, 0.0158) == pytest.approx(0.02 * np.exp(2 * 0.0158 * 40))
    # a side lobe's height must not lower the expectation: the echo at a shorter path is at
    # least as strong as the main lobe at a longer one
    lobe.add(0.001, 60.0)
    assert lobe.expected(60.0, 0.0158) >= 0.02
    assert lobe.expected(100.0, 0.0158) == pytest.approx(0.02)


def test_a_peak_12_db_or_more_below_the_expected_main_lobe_is_a_side_lobe() -> None:
    lobe = MainLobe([(0.02, 100.0)])
    search = PeakSearch(
        None,  # type: ignore[arg-type]  # judging needs no rig
        300.0,
        (3, 4),
        np.eye(2),
        20.0,
        absorption_np_per_mm=0.0158,
        main_lobe=lobe,
    )
    assert search.side_lobe_db((0.02 * 10 ** (-11 / 20), 100.0)) is None
    assert search.side_lobe_db((0.02 * 10 ** (-13 / 20), 100.0)) == pytest.approx(13.0)
    # the same height 40 mm closer, where the main lobe is 11 dB stronger: 24 dB below it
    assert search.side_lobe_db((0.02 * 10 ** (-13 / 20), 60.0)) == pytest.approx(
        13.0 + 20 * np.log10(np.exp(2 * 0.0158 * 40))
    )
    without = PeakSearch(None, 300.0, (3, 4), np.eye(2), 20.0)  # type: ignore[arg-type]
    assert without.side_lobe_db((1e-9, 100.0)) is None  # no height to expect: nothing judged
