"""Forward kinematics of the shipped TX90-family tables against an independent DH product."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ucal.cell import PAPER_CALIBRATION_POSE_DEG
from ucal.kinematics.dh import fk, fk_frames, wrist_centre
from ucal.profile.models import KNOWN_MODELS, load_model, model_sheet


def _link(theta_deg: float, d: float, a: float, alpha_deg: float) -> np.ndarray:
    """Rz(θ)·Tz(d)·Tx(a)·Rx(α), written out as four separate matrices."""
    t, al = math.radians(theta_deg), math.radians(alpha_deg)
    rz = np.array(
        [
            [math.cos(t), -math.sin(t), 0, 0],
            [math.sin(t), math.cos(t), 0, 0],
            [0, 0, 1, 0],
            [0, 0, 0, 1],
        ]
    )
    tz = np.array([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, d], [0, 0, 0, 1]], dtype=float)
    tx = np.array([[1, 0, 0, a], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]], dtype=float)
    rx = np.array(
        [
            [1, 0, 0, 0],
            [0, math.cos(al), -math.sin(al), 0],
            [0, math.sin(al), math.cos(al), 0],
            [0, 0, 0, 1],
        ]
    )
    return rz @ tz @ tx @ rx


def _reference_fk(model, joints_deg, offsets_deg=(0,) * 6) -> np.ndarray:
    t = np.eye(4)
    for i in range(6):
        th0, d, a, al = model.dh[i]
        t = t @ _link(joints_deg[i] + th0 + offsets_deg[i], d, a, al)
    return t


@pytest.mark.parametrize("name", KNOWN_MODELS)
def test_zero_pose_flange_is_straight_up(name: str) -> None:
    """The controller's zero pose, from the model file's data-sheet lengths."""
    model = load_model(name)
    t = fk(model, np.zeros(6))
    sheet = model_sheet(name)
    upper, fore = sheet.upper_arm_mm, sheet.forearm_mm
    np.testing.assert_allclose(t[:3, 3], [50.0, 50.0, upper + fore + 100.0], atol=1e-9)
    np.testing.assert_allclose(t[:3, 2], [0, 0, 1], atol=1e-12)  # flange z up
    np.testing.assert_allclose(t[:3, 0], [1, 0, 0], atol=1e-12)  # flange x along base X


def test_pinned_zero_positions() -> None:
    expected = {"tx90": 950.0, "tx90l": 1150.0, "tx90xl": 1400.0}
    expected |= {"tx2-90": 950.0, "tx2-90l": 1150.0, "tx2-90xl": 1400.0}
    for name, z in expected.items():
        np.testing.assert_allclose(fk(load_model(name), np.zeros(6))[:3, 3], [50, 50, z], atol=1e-9)


@pytest.mark.parametrize("name", KNOWN_MODELS)
def test_paper_000_calibration_pose_points_flange_down(name: str) -> None:
    t = fk(load_model(name), PAPER_CALIBRATION_POSE_DEG)
    np.testing.assert_allclose(t[:3, 2], [0, 0, -1], atol=1e-9)


@pytest.mark.parametrize("name", KNOWN_MODELS)
@settings(max_examples=60, deadline=None)
@given(
    q=st.lists(st.floats(-270, 270, allow_nan=False), min_size=6, max_size=6),
    off=st.lists(st.floats(-5, 5, allow_nan=False), min_size=6, max_size=6),
)
def test_fk_equals_product_of_dh_matrices(name: str, q: list[float], off: list[float]) -> None:
    model = load_model(name)
    np.testing.assert_allclose(
        fk(model, np.array(q), offsets_deg=np.array(off)), _reference_fk(model, q, off), atol=1e-9
    )


def test_fk_broadcasts_and_applies_tool() -> None:
    model = load_model("tx90xl")
    rng = np.random.default_rng(3)
    q = rng.uniform(model.joint_min_deg, model.joint_max_deg, (4, 5, 6))
    tool = _link(20.0, 80.0, 5.0, 30.0)
    t = fk(model, q, tool)
    assert t.shape == (4, 5, 4, 4)
    for idx in np.ndindex(4, 5):
        np.testing.assert_allclose(t[idx], _reference_fk(model, q[idx]) @ tool, atol=1e-9)


def test_wrist_centre_depends_on_first_three_joints_only() -> None:
    model = load_model("tx90l")
    q = np.array([12.0, -30.0, 70.0, 5.0, 40.0, -60.0])
    q2 = q.copy()
    q2[3:] = [-100.0, -80.0, 200.0]
    np.testing.assert_allclose(wrist_centre(model, q), wrist_centre(model, q2), atol=1e-9)
    # W is 100 mm behind the flange along the flange z axis
    t = fk_frames(model, q)[6]
    np.testing.assert_allclose(wrist_centre(model, q), t[:3, 3] - 100.0 * t[:3, 2], atol=1e-9)
