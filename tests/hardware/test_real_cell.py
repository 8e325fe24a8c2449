"""Read-only checks of a real cell (no motion): status, joint stream, pulser settings, a reading."""

from __future__ import annotations

import numpy as np
import pytest

from drivers.controller.client import SimpleMessageController
from drivers.pulser.modbus import ModbusPulser

pytestmark = pytest.mark.hardware


def test_controller_streams_joints_and_status(controller_url):
    with SimpleMessageController.from_url(controller_url) as ctl:
        joints = ctl.read_joints(timeout_s=5.0)
        status = ctl.status(timeout_s=5.0)
        assert joints.shape == (6,) and np.all(np.isfinite(joints))
        assert status.e_stopped is not None
        assert len(ctl.joint_samples(0.0)) >= 1


def test_pulser_settings_round_trip_and_a_reading(pulser_url):
    with ModbusPulser.from_url(pulser_url) as pulser:
        before = pulser.settings()
        try:
            pulser.configure(before)
            assert pulser.settings() == before
            first = pulser.read_gate()
            second = pulser.read_gate(fresh=True)
            assert second.counter != first.counter
        finally:
            pulser.configure(before)
