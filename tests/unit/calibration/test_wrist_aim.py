"""Aiming the beam with the wrist: the closed form and its least-squares fallback."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from ucal.kinematics.dh import transform
from ucal.kinematics.rotations import angle_between_deg, rpy_to_matrix
from ucal.model.geometry import CellGeometry, beam_and_tcp
from ucal.model.wrist import aim_wrist
from ucal.profile.models import load_model

MODEL = load_model("tx90l")
POSE = np.array([30.53, 31.15, 109.49, 0.0, 39.36, 30.54])
DOWN = np.array([0.0, 0.0, -1.0])


def _geom(model, tilt_deg) -> CellGeometry:
    tool = transform(np.array([0.0, 0.0, 80.0]), rpy_to_matrix(np.asarray(tilt_deg, float)))
    return CellGeometry(model, tool, np.eye(3))


@settings(max_examples=40, deadline=None)
@given(
    tilt=st.lists(st.floats(-15, 15), min_size=3, max_size=3),
    offsets=st.lists(st.floats(-3, 3), min_size=6, max_size=6),
    wrist=st.lists(st.floats(-20, 20), min_size=3, max_size=3),
)
def test_aims_exactly_holding_the_arm_and_joint_6(tilt, offsets, wrist) -> None:
    geom = _geom(MODEL, tilt)
    q0 = POSE.copy()
    q0[3:] += wrist
    q = aim_wrist(geom, q0, DOWN, np.asarray(offsets))
    beam, _ = beam_and_tcp(geom, q, np.asarray(offsets))
    assert angle_between_deg(beam, DOWN) < 1e-6
    np.testing.assert_array_equal(q[:3], q0[:3])


def test_a_twisted_wrist_link_is_aimed_by_the_fallback() -> None:
    """A Hayati twist on link 5 is outside the closed form's model: still aimed exactly."""
    beta = np.zeros(6)
    beta[4] = 0.5
    model = MODEL.with_dh(MODEL.dh, beta)
    geom = _geom(model, (0.0, 12.0, 0.0))
    q = aim_wrist(geom, POSE, DOWN, np.zeros(6))
    beam, _ = beam_and_tcp(geom, q, np.zeros(6))
    assert angle_between_deg(beam, DOWN) < 1e-6
