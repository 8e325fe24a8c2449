"""The arm configuration in the controller's words (``ucal.kinematics.configuration``)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from ucal.kinematics.configuration import (
    ELBOW,
    SHOULDER,
    WRIST,
    ArmConfig,
    arm_configs,
    configuration_codes,
)
from ucal.kinematics.dh import fk, wrist_centre
from ucal.kinematics.ik import ik_all
from ucal.profile.models import load_model

MODELS = ("tx90", "tx90l", "tx90xl")


def reach_mm(model_name: str, q: np.ndarray) -> float:
    """How far (mm) the wrist centre of readings ``q`` is in front of axis 1, along the
    direction J1 points the arm (the shipped tables have no θ1 offset)."""
    w = wrist_centre(load_model(model_name), q)
    return float(w[0] * np.cos(np.radians(q[0])) + w[1] * np.sin(np.radians(q[0])))


def recomputed(model_name: str, q: np.ndarray) -> ArmConfig:
    """The configuration of readings ``q`` from its definition, read off the arm: the wrist
    centre in front of axis 1 or behind it, the signs of J3 and J5."""
    return ArmConfig(
        "lefty" if reach_mm(model_name, q) >= 0.0 else "righty",
        "epositive" if q[2] >= 0.0 else "enegative",
        "wpositive" if q[4] >= 0.0 else "wnegative",
    )


@pytest.mark.parametrize("name", MODELS)
def test_zero_is_lefty_epositive_wpositive(name: str) -> None:
    assert arm_configs(load_model(name), np.zeros(6)) == (
        ArmConfig("lefty", "epositive", "wpositive"),
    )


def test_reaching_back_over_the_base_is_righty() -> None:
    model = load_model("tx90l")
    front = np.array([0.0, 30.0, 90.0, 0.0, 45.0, 0.0])
    back = np.array([0.0, -60.0, -30.0, 0.0, -45.0, 0.0])
    assert wrist_centre(model, front)[0] > 0.0 > wrist_centre(model, back)[0]
    assert arm_configs(model, np.array([front, back])) == (
        ArmConfig("lefty", "epositive", "wpositive"),
        ArmConfig("righty", "enegative", "wnegative"),
    )


@settings(max_examples=200)
@given(
    name=st.sampled_from(MODELS),
    u=st.lists(st.floats(0.0, 1.0), min_size=6, max_size=6),
)
def test_hypothesis_codes_match_the_definition(name: str, u: list[float]) -> None:
    model = load_model(name)
    q = model.joint_min_deg + np.array(u) * (model.joint_max_deg - model.joint_min_deg)
    # away from the boundaries, where rounding could put a reading on either side
    assume(abs(q[2]) > 1e-6 and abs(q[4]) > 1e-6 and abs(reach_mm(name, q)) > 1e-6)
    assert arm_configs(model, q)[0] == recomputed(name, q)
    # ±360° equivalents of joints 4 and 6 (inside ±270°) keep the configuration
    turned = q + np.array([0.0, 0.0, 0.0, 360.0 if q[3] < 0 else -360.0, 0.0, 0.0])
    assert configuration_codes(model, turned) == configuration_codes(model, q)


@settings(max_examples=100)
@given(
    name=st.sampled_from(MODELS),
    u=st.lists(st.floats(0.0, 1.0), min_size=6, max_size=6),
)
def test_hypothesis_the_eight_solutions_are_the_eight_configurations(
    name: str, u: list[float]
) -> None:
    """Every pose reached by all eight closed-form branches has them in eight different
    configurations: the configuration names a solution, as the controller uses it."""
    model = load_model(name)
    q = model.joint_min_deg + np.array(u) * (model.joint_max_deg - model.joint_min_deg)
    sols, real = ik_all(model, fk(model, q))
    assume(real.all())
    codes = configuration_codes(model, sols)
    # near a boundary two branches meet (and rounding decides their names)
    assume(np.min(np.abs(sols[:, [2, 4]])) > 1e-3)
    assume(min(abs(reach_mm(name, s)) for s in sols) > 1e-3)
    assert sorted(codes.tolist()) == list(range(8))
    assert [recomputed(name, s) for s in sols] == list(arm_configs(model, sols))


def test_words_codes_and_changes() -> None:
    assert [ArmConfig.from_code(c).words() for c in (0, 7)] == [
        (SHOULDER[0], ELBOW[0], WRIST[0]),
        ("righty", "enegative", "wnegative"),
    ]
    a, b = ArmConfig.from_code(0), ArmConfig.from_code(5)
    assert a.changed(b) == ("shoulder", "wrist") and a.changed(a) == ()
    assert str(b) == "righty, epositive, wnegative"
    assert b.to_json() == {"shoulder": "righty", "elbow": "epositive", "wrist": "wnegative"}
    with pytest.raises(ValueError):
        ArmConfig.from_code(-1)
    nan = np.full(6, np.nan)
    assert configuration_codes(load_model("tx90"), np.array([nan, np.zeros(6)])).tolist() == [
        -1,
        0,
    ]
