"""What the unidentified quantities allow at the tool centre, against the truth (no simulator).

Worlds whose DH table is drawn from the profile's declared tolerances are measured at the full
level's plan and solved; the tool centre the solution predicts over the scanning region is
compared with the true one after the best rigid alignment (the base frame is a gauge). The
budget is a one-sigma statement: the errors it does not cover must be rare, and it must not be
a wild overstatement either.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from ucal.calibration.budget import UNSEEN, tcp_budget
from ucal.kinematics.rotations import rpy_to_matrix
from ucal.model.fit import OFFSETS, prior_from_profile, solve_cell, table_geometry
from ucal.model.geometry import CellGeometry, beam_and_tcp
from ucal.model.kinematic import aligned_errors_mm, scanning_postures, solve_full
from ucal.model.postures import plan_full
from ucal.model.targets import calibration_pose
from ucal.profile import load_profile

from doubles import measured_cell

REPO = Path(__file__).resolve().parents[3]
SIGMA = 5e-4
BLOCK_RPY = np.array([0.3, -0.2, 0.4])


@pytest.fixture(scope="module")
def cell():
    profile = load_profile(REPO / "profiles" / "example_cell.toml").replace(
        dh_length_std_mm=0.3, dh_angle_std_deg=0.03, water_temperature_std_c=0.1
    )
    return profile, plan_full(profile), prior_from_profile(profile)


def world(profile, rng):
    dh = profile.model.dh.copy()
    dh[:, 1:3] += rng.normal(0.0, 0.3, (6, 2))
    dh[:, 3] += rng.normal(0.0, 0.03, 6)
    # link 6 belongs to the tool (tool-frame measures them together): left nominal here
    dh[5, 1:4] = profile.model.dh[5, 1:4]
    return profile.model.with_dh(dh, [0.0, rng.normal(0.0, 0.03), 0.0, 0.0, 0.0, 0.0])


def tcp_errors(profile, fit, prior, model, offsets, q):
    truth = CellGeometry(model, profile.tool_matrix, rpy_to_matrix(BLOCK_RPY))
    _, true_tcp = beam_and_tcp(truth, q, offsets)
    geom = table_geometry(fit.table, fit.estimate, prior.model)
    _, tcp = beam_and_tcp(geom, q, fit.table.get(OFFSETS, fit.estimate))
    return aligned_errors_mm(tcp, true_tcp)


def test_full_level_budget_covers_the_tcp_error_over_the_scanning_region(cell):
    profile, plan, prior = cell
    pose = calibration_pose(profile)
    q = scanning_postures(pose, 100, 0, profile.model)
    corner = profile.sample_position_mm + np.array([3.0, -2.0, 4.0])
    means, budgets = [], []
    for seed in range(6):
        rng = np.random.default_rng(100 + seed)
        model, offsets = world(profile, rng), rng.uniform(-0.3, 0.3, 6)
        water = 20.0 + rng.normal(0.0, 0.1)
        meas = measured_cell(profile, plan, model, offsets, BLOCK_RPY, corner, water, seed, SIGMA)
        sol = solve_full(prior, meas, structure=plan.structure)
        budget = tcp_budget(sol.cell, prior.model, meas, prior.sound_speed_m_s, pose)
        err = tcp_errors(profile, sol.cell, prior, model, offsets, q)
        means.append(err.mean())
        budgets.append(budget.mean_mm)
        # what no echo sees leads the list: row 5 moves the flange across the beam
        assert set(list(budget.by_quantity)[:3]) & {"dh5_d_mm", "dh5_a_mm"}
        assert not any(k.startswith("dh6_") for k in budget.by_quantity)
        assert budget.max_mm >= budget.mean_mm > 0.0 and budget.postures == 100
        assert err.max() < 4.0 * budget.max_mm
    rms_mean = float(np.sqrt(np.mean(np.square(means))))
    # one sigma: the error's typical size, neither hidden nor overstated
    assert 0.5 * np.mean(budgets) < rms_mean < 2.0 * np.mean(budgets), (means, budgets)


def test_a_gauge_costs_nothing_and_a_known_table_leaves_only_the_scale(cell):
    profile, plan, prior = cell
    pose = calibration_pose(profile)
    corner = profile.sample_position_mm + np.array([3.0, -2.0, 4.0])
    meas = measured_cell(
        profile, plan, profile.model, np.zeros(6), BLOCK_RPY, corner, 20.0, 1, SIGMA
    )
    sol = solve_full(prior, meas, structure=plan.structure)
    budget = tcp_budget(sol.cell, prior.model, meas, prior.sound_speed_m_s, pose)
    # d1 moves the whole arm along axis 1: held at nominal, the fit's block takes it up (all
    # but what the block's own prior resists), where row 5's d moves the flange unseen
    assert budget.by_quantity.get("dh1_d_mm", 0.0) < 0.1 * budget.by_quantity["dh5_d_mm"]
    # the table identified on this robot (tolerances 0), a rigid arm as the simulated one is
    # (no compliance to carry): the common scale is what is left
    known = prior_from_profile(
        profile.replace(
            dh_length_std_mm=0.0, dh_angle_std_deg=0.0, stiffness_nm_per_rad=np.zeros(6)
        )
    )
    fit = solve_cell(known, meas)
    small = tcp_budget(fit, known.model, meas, known.sound_speed_m_s, pose)
    assert set(small.by_quantity) <= {"sound_speed_m_s"}
    assert small.max_mm < 0.1 * budget.max_mm
    assert set(UNSEEN) >= {"dh5_d_mm", "dh5_a_mm", "sound_speed_m_s"}
