"""Exact and paper-000 solvers on ideal measurements synthesised from a hidden truth."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ucal.calibration.exact import solve_exact
from ucal.calibration.paper import paper_offsets, solve_paper
from ucal.cell import PAPER_CALIBRATION_POSE_DEG
from ucal.kinematics.dh import transform, wrist_centre
from ucal.kinematics.rotations import angle_between_deg, rpy_to_matrix
from ucal.model.geometry import CellGeometry, FaceMeasurement, beam_and_tcp
from ucal.model.wrist import aim_wrist
from ucal.profile.models import load_model

MODEL = load_model("tx90l")


def synthesise(
    offsets,
    tool_rpy=(0.0, 0.0, 0.0),
    true_tool_rpy=None,
    step=2.0,
    turn6=True,
    noise_tilt_deg=0.0,
    noise_dist_mm=0.0,
    seed=0,
):
    """Nine ideal face measurements of a robot with hidden ``offsets`` (deg)."""
    tool = transform(np.array([0.0, 0.0, 80.0]), rpy_to_matrix(np.array(tool_rpy, float)))
    true_tool = (
        tool
        if true_tool_rpy is None
        else transform(np.array([0.0, 0.0, 80.0]), rpy_to_matrix(np.array(true_tool_rpy, float)))
    )
    geom = CellGeometry(MODEL, tool, np.eye(3))
    truth = CellGeometry(MODEL, true_tool, np.eye(3))
    corner = wrist_centre(MODEL, PAPER_CALIBRATION_POSE_DEG) - 280.0
    rng = np.random.default_rng(seed)
    meas = []
    shifts = (
        {"base": 0.0, "j3": 90.0, "j2": -90.0} if turn6 else {"base": 0.0, "j3": 0.0, "j2": 0.0}
    )
    for cfg, joint in (("base", None), ("j3", 2), ("j2", 1)):
        arm = PAPER_CALIBRATION_POSE_DEG.copy()
        if joint is not None:
            arm[joint] += step
        arm[5] += shifts[cfg]
        for face in (2, 0, 1):
            q = aim_wrist(truth, arm, -truth.normal(face), offsets)
            _, tcp = beam_and_tcp(truth, q, offsets)
            d = truth.normal(face) @ (tcp - corner)
            q_noisy = q.copy()
            q_noisy[3:5] += rng.normal(0.0, noise_tilt_deg, 2)
            meas.append(
                FaceMeasurement(
                    cfg,
                    face,
                    q_noisy,
                    d + rng.normal(0.0, noise_dist_mm),
                    distance_std_mm=max(noise_dist_mm, 1e-4),
                    tilt_std_deg=max(noise_tilt_deg, 1e-4),
                )
            )
    return geom, meas


@pytest.mark.parametrize("value", [-5.0, -2.5, 1.0, 5.0])
def test_exact_recovers_identical_offsets_with_angled_tool(value):
    offsets = np.full(6, value)
    geom, meas = synthesise(offsets, tool_rpy=(0.0, 12.0, 0.0))
    sol = solve_exact(geom, meas, np.zeros(6))
    assert sol.unobservable_joints == ()
    np.testing.assert_allclose(sol.offsets_deg, offsets, atol=1e-6)
    assert np.all(np.isfinite(sol.std_deg))


def test_joint6_unobservable_with_on_axis_beam_and_kept_at_prior():
    offsets = np.array([0.8, -1.2, 1.5, -2.0, 1.1, 0.6])
    geom, meas = synthesise(offsets)
    prior = np.array([0, 0, 0, 0, 0, 0.25])
    sol = solve_exact(geom, meas, prior, beam="fixed")
    assert sol.unobservable_joints == (6,)
    assert sol.offsets_deg[5] == 0.25  # kept from the profile, never fabricated
    assert np.isnan(sol.std_deg[5])
    np.testing.assert_allclose(sol.offsets_deg[:5], offsets[:5], atol=1e-6)


def test_fitted_beam_absorbs_tool_tilt_without_biasing_the_wrist():
    offsets = np.array([0.8, -1.2, 1.5, -2.0, 1.1, 0.6])
    geom, meas = synthesise(offsets, true_tool_rpy=(0.2, -0.22, 0.0))
    fixed = solve_exact(geom, meas, np.zeros(6), beam="fixed")
    fitted = solve_exact(geom, meas, np.zeros(6), beam="auto")
    assert np.max(np.abs(fixed.offsets_deg[:5] - offsets[:5])) > 0.1  # the tilt biases it
    np.testing.assert_allclose(fitted.offsets_deg[:5], offsets[:5], atol=1e-5)
    assert fitted.unobservable_joints == (6,)
    true_beam = rpy_to_matrix(np.array([0.2, -0.22, 0.0]))[:, 2]
    # The tilt is seen; its azimuth about the joint-6 axis absorbs the unobservable δ6 (kept at
    # 0 instead of 0.6): the fitted beam is the true one turned by δ6 about flange z.
    turned = rpy_to_matrix(np.array([0.0, 0.0, offsets[5]])) @ true_beam
    assert angle_between_deg(fitted.beam_flange, turned) < 1e-5


def test_constant_theta6_leaves_joint5_confounded_with_beam_tilt():
    """Why the plan turns θ6 between configurations: without it θ5 and the beam tilt trade."""
    offsets = np.array([0.8, -1.2, 1.5, -2.0, 1.1, 0.6])
    geom, meas = synthesise(offsets, turn6=False)
    sol = solve_exact(geom, meas, np.zeros(6), beam="fit")
    assert 5 in sol.unobservable_joints


def test_paper_method_bias_is_half_the_step_on_theta23():
    offsets = np.full(6, 1.0)
    for step in (2.0, 0.5):
        geom, meas = synthesise(offsets, step=step)
        off = paper_offsets(geom, meas)
        assert abs(off[0] - 1.0) < 1e-3  # θ1 exact: a direction
        assert abs((off[1] + off[2]) - 2.0 - step / 2) < 0.05 * step  # θ2+θ3 by half the step


def test_paper_std_and_unobservable_kept():
    geom, meas = synthesise(np.full(6, 1.0), noise_dist_mm=0.001, noise_tilt_deg=0.001)
    sol = solve_paper(geom, meas, np.full(6, 0.3), unobservable=(6,))
    assert sol.offsets_deg[5] == 0.3 and np.isnan(sol.std_deg[5])
    assert np.all(sol.std_deg[:5] > 0)


def test_exact_errors_within_three_sigma_under_noise():
    offsets = np.array([2.0, -3.0, 1.0, 4.0, -2.0, 3.0])
    z = []
    for seed in range(8):
        geom, meas = synthesise(
            offsets, tool_rpy=(0.0, 12.0, 0.0), noise_tilt_deg=0.003, noise_dist_mm=0.002, seed=seed
        )
        sol = solve_exact(geom, meas, np.zeros(6))
        z.append((sol.offsets_deg - offsets) / sol.std_deg)
    z = np.abs(np.array(z))
    assert np.all(z < 3.5)
    assert np.mean(z) < 1.5  # the reported σ is not wildly pessimistic either


@settings(max_examples=15, deadline=None)
@given(st.lists(st.floats(-5.0, 5.0), min_size=6, max_size=6))
def test_exact_recovers_any_offsets_within_five_degrees(values):
    offsets = np.array(values)
    geom, meas = synthesise(offsets, tool_rpy=(0.0, 12.0, 0.0))
    sol = solve_exact(geom, meas, np.zeros(6))
    np.testing.assert_allclose(sol.offsets_deg, offsets, atol=1e-5)
