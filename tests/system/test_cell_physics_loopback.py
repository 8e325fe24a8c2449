"""The simulated cell's physics read through the real drivers over loopback."""

from __future__ import annotations

import numpy as np
import pytest

from drivers.controller.client import SimpleMessageController
from drivers.pulser.base import PulserSettings
from drivers.pulser.modbus import ModbusPulser
from ucal.cell import PAPER_CALIBRATION_POSE_DEG, CellProfile, WorldTruth
from ucal.kinematics.dh import fk, wrist_centre
from ucal.kinematics.rotations import rpy_to_matrix
from ucal.model.geometry import CellGeometry
from ucal.model.wrist import aim_wrist
from ucal.profile.models import load_model
from ucal.sim.serve import SimulatedCellServer

pytestmark = pytest.mark.system


@pytest.fixture(params=["tcp", "rtu"])
def cell(request):
    """A nominal cell whose XY face lies 50 mm below the tool centre at the paper's pose."""
    model = load_model("tx90l")
    pose = PAPER_CALIBRATION_POSE_DEG
    tcp = (fk(model, pose) @ np.array([0.0, 0.0, 80.0, 1.0]))[:3]
    corner = tcp - np.array([200.0, 200.0, 50.0])
    profile = CellProfile(model=model, sample_position_mm=corner)
    world = WorldTruth.nominal(profile)
    with (
        SimulatedCellServer(world, profile, time_scale=0.0, pulser_framing=request.param) as srv,
        SimpleMessageController.from_url(srv.urls["controller"]) as ctl,
        ModbusPulser.from_url(srv.urls["pulser"]) as pulser,
    ):
        pulser.configure(PulserSettings(gain_db=20.0, averages=1))
        yield profile, ctl, pulser


def test_50_mm_water_path_at_20c_reads_67_46_us(cell):
    _profile, ctl, pulser = cell
    ctl.move_joints(PAPER_CALIBRATION_POSE_DEG, timeout_s=10)
    reading = pulser.read_gate(fresh=True)
    assert reading.has_echo
    assert abs(reading.tof_ns / 1000.0 - 67.46) < 0.01


def test_amplitude_at_0_2_degree_tilt_is_about_half(cell):
    profile, ctl, pulser = cell
    ctl.move_joints(PAPER_CALIBRATION_POSE_DEG, timeout_s=10)
    normal = pulser.read_gate(fresh=True).amplitude
    geom = CellGeometry(profile.model, profile.tool_matrix, rpy_to_matrix(np.zeros(3)))
    tilted_dir = rpy_to_matrix(np.array([0.2, 0.0, 0.0])) @ np.array([0.0, 0.0, -1.0])
    q = aim_wrist(geom, PAPER_CALIBRATION_POSE_DEG, tilted_dir, np.zeros(6))
    np.testing.assert_allclose(
        wrist_centre(profile.model, q), wrist_centre(profile.model, PAPER_CALIBRATION_POSE_DEG)
    )
    ctl.move_joints(q, timeout_s=10)
    tilted = pulser.read_gate(fresh=True).amplitude
    assert 0.45 < tilted / normal < 0.55
