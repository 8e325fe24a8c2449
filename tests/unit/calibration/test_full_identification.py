"""Full kinematic identification on synthetic measurements (no simulator).

The truth is a robot whose DH lengths and twists are off (Hayati's β₂ included), with joint
offsets, a misplaced block and the water off its profile temperature; the measurements are its
exact normal-incidence postures and water paths at the planned postures, with seeded noise.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from ucal.acoustics import sound_speed_m_s
from ucal.cell import Step
from ucal.kinematics.dh import fk
from ucal.model.fit import prior_from_profile
from ucal.model.gauge import j1_relative_to_block
from ucal.model.kinematic import (
    aligned_errors_mm,
    scanning_postures,
    solve_full,
)
from ucal.model.postures import candidate_postures, plan_full
from ucal.model.targets import calibration_pose
from ucal.profile import load_profile
from ucal.verify.region import judge_region, plan_region

from doubles import measured_cell

REPO = Path(__file__).resolve().parents[3]
SIGMA = 5e-4  # deg of posture, mm of water path


@pytest.fixture(scope="module")
def cell():
    profile = load_profile(REPO / "profiles" / "example_cell.toml").replace(
        dh_length_std_mm=0.3, dh_angle_std_deg=0.03, water_temperature_std_c=0.1
    )
    return profile, plan_full(profile)


def measure(profile, plan, model, offsets, block_rpy, corner, water_c, seed):
    return measured_cell(profile, plan, model, offsets, block_rpy, corner, water_c, seed, SIGMA)


def true_parameters(model) -> dict[str, float]:
    out = {
        f"dh{i + 1}_{k}": model.dh[i, c + 1]
        for i in range(6)
        for c, k in enumerate(("d_mm", "a_mm", "alpha_deg"))
    }
    out["dh2_beta_deg"] = model.beta_deg[1]
    return out


def test_plan_is_d_optimal_and_spread(cell):
    _, plan = cell
    assert 15 <= len(plan.postures) <= 40
    assert {p.face for p in plan.postures} == {0, 1, 2}
    j = np.array([p.joints_deg for p in plan.postures])
    assert np.ptp(j[:, 0]) > 20.0 and np.ptp(j[:, 1]) > 20.0 and np.ptp(j[:, 2]) > 20.0
    assert plan.d_criterion > 3.0 and "D-optimality" in plan.describe()


def test_dh_errors_identified_within_std_and_tcp_recovered(cell):
    profile, plan = cell
    rng = np.random.default_rng(7)
    dh = profile.model.dh.copy()
    dh[:5, 1:3] += np.where(dh[:5, 1:3] != 0, rng.uniform(-0.5, 0.5, (5, 2)), 0.0)
    dh[:5, 3] += rng.uniform(-0.05, 0.05, 5)
    model = profile.model.with_dh(dh, [0.0, 0.04, 0.0, 0.0, 0.0, 0.0])
    offsets = rng.uniform(-0.3, 0.3, 6)
    meas = measure(
        profile,
        plan,
        model,
        offsets,
        [0.3, -0.2, 0.4],
        profile.sample_position_mm + [3.0, -2.0, 4.0],
        20.05,
        seed=1,
    )
    prior = prior_from_profile(profile)
    sol = solve_full(prior, meas, structure=plan.structure)
    assert set(sol.ident.redundant) == {
        "dh1_d_mm",
        "dh3_d_mm",
        "dh5_d_mm",
        "dh5_a_mm",
        "dh6_d_mm",
        "dh6_a_mm",
        "dh6_alpha_deg",
    }
    assert "across the beam" in sol.ident.redundant["dh5_a_mm"]
    assert "parallel" in sol.ident.redundant["dh3_d_mm"] and sol.ident.scale_note
    assert sol.cell.quality.verdict == "ok"
    truth = true_parameters(model)
    z = [
        (v.value - truth[n]) / v.std
        for n, v in sol.parameters.items()
        if v.std is not None and v.status != "not identifiable"
    ]
    assert max(np.abs(z)) < 4.0 and np.mean(np.abs(np.array(z)) <= 3.0) >= 0.9
    assert abs(sol.parameters["dh2_beta_deg"].value - 0.04) < 0.005
    # J1 relative to the hand-placed block as placed (measured); J6: beam on axis 6
    assert sol.unobservable_joints == (6,)
    assert sol.gauge is not None and sol.gauge.frame == "block"
    assert sol.std_block_deg is not None
    j1 = j1_relative_to_block(offsets[0], np.array([0.3, -0.2, 0.4]), 0.0)
    assert abs(sol.offsets_deg[0] - j1) < 3 * sol.std_block_deg[0]
    assert abs(sol.offsets_deg[0] - offsets[0]) < 3 * sol.std_deg[0]
    assert np.all(np.abs(sol.offsets_deg - offsets)[1:5] < 3 * sol.std_deg[1:5] + 1e-9)
    # TCP over the scanning region, after the best rigid alignment
    qs = scanning_postures(calibration_pose(profile), 100, 3, profile.model)
    true_p = fk(model, qs, profile.tool_matrix, offsets)[:, :3, 3]
    full = aligned_errors_mm(
        fk(sol.model, qs, profile.tool_matrix, sol.offsets_deg)[:, :3, 3], true_p
    )
    # even the true offsets on the nominal table leave the DH errors
    offs = aligned_errors_mm(fk(profile.model, qs, profile.tool_matrix, offsets)[:, :3, 3], true_p)
    assert full.mean() < 0.06 and full.max() < 0.15
    assert offs.mean() > 3 * full.mean()


def test_nominal_robot_gives_the_nominal_table_back(cell):
    profile, plan = cell
    meas = measure(
        profile,
        plan,
        profile.model,
        np.zeros(6),
        np.zeros(3),
        profile.sample_position_mm,
        profile.water_temperature_c,
        seed=2,
    )
    sol = solve_full(prior_from_profile(profile), meas, structure=plan.structure)
    truth = true_parameters(profile.model)
    for name, v in sol.parameters.items():
        if v.std is None:  # not identifiable: carried with its prior, which it stays near
            tolerance = profile.dh_angle_std_deg if "deg" in name else profile.dh_length_std_mm
            assert abs(v.value - truth[name]) <= 0.1 * tolerance, name
        else:
            assert abs(v.value - truth[name]) <= 3 * v.std, name


def test_region_check_flags_a_table_that_is_wrong_away_from_the_calibration(cell):
    """The model held, block and water fitted: a nominal table on a robot with DH errors leaves
    residuals far above the noise over spread postures; the true table leaves noise."""
    profile, plan = cell
    region = plan_region(profile, 10, exclude=plan.postures)
    assert len(region.postures) == 10
    assert not any(
        np.allclose(r.joints_deg, p.joints_deg) for r in region.postures for p in plan.postures
    )
    dh = profile.model.dh.copy()
    dh[1, 2] += 0.3
    dh[3, 1] -= 0.2
    dh[2, 3] += 0.03
    model = profile.model.with_dh(dh, [0.0, 0.03, 0.0, 0.0, 0.0, 0.0])
    offsets = np.array([0.0, 0.1, -0.1, 0.05, 0.1, 0.0])
    meas = measure(
        profile,
        region,
        model,
        offsets,
        [0.1, 0.0, -0.1],
        profile.sample_position_mm + [1.0, 2.0, -1.0],
        20.3,
        seed=4,
    )
    wrong = judge_region(profile.replace(joint_offsets_deg=offsets), meas, 0.5)
    assert wrong.verdict == "misfit" and not wrong.passed and wrong.max_distance_mm > 0.01
    right = judge_region(profile.replace(model=model, joint_offsets_deg=offsets), meas, 0.5)
    assert right.passed and right.max_distance_mm < 0.005 and right.max_tilt_deg < 0.005


def test_a_step_of_known_height_sets_the_scale_that_the_thermometer_cannot(cell):
    profile, plan = cell
    step = Step(50.0, np.array([250.0, 250.0]), 60.0, height_std_mm=0.002)
    profile = profile.replace(step=step, water_temperature_std_c=2.0)
    on_step = [c for c in candidate_postures(profile) if c.step]
    assert on_step and all(c.face == 2 for c in on_step)
    # the planned faces and one posture over the step; the water 3 °C warmer than the profile
    # says, the step 1.5 µm higher than its certificate
    postures = plan.postures + (on_step[0],)
    water_c, height = profile.water_temperature_c + 3.0, 50.0015
    meas = measure(
        profile,
        replace(plan, postures=postures),
        profile.model,
        np.zeros(6),
        profile.sample_rotation_deg,
        profile.sample_position_mm,
        water_c,
        seed=2,
    )
    scale = sound_speed_m_s(profile.water_temperature_c) / sound_speed_m_s(water_c)
    steps = [replace(meas[-1], distance_mm=meas[-1].distance_mm - height * scale)]
    prior = prior_from_profile(profile)
    sol = solve_full(prior, meas[:-1], steps=steps)
    assert "step" in sol.ident.scale_note
    # the thermometer alone: ±6 m/s; with the DH length tolerance, ±0.6 m/s (the plan's faces)
    assert prior.sound_speed_std_m_s > 5.0 and sol.sound_speed_std_m_s < 0.2
    assert abs(sol.sound_speed_m_s - sound_speed_m_s(water_c)) < 3 * sol.sound_speed_std_m_s
    standard = sol.length_standard
    assert standard is not None and standard.measurements == 1
    assert abs(standard.step_mm - height) < 3 * standard.std_mm
    assert sol.cell.quality.verdict == "ok"


def test_a_drifting_tank_is_measured_and_named_at_the_full_level(cell):
    profile, plan = cell
    meas = measure(
        profile,
        plan,
        profile.model,
        np.zeros(6),
        profile.sample_rotation_deg,
        profile.sample_position_mm,
        profile.water_temperature_c,
        seed=4,
    )
    # the tank warms 0.1 °C/min (twice the default tolerance), a reading every 0.1 min
    t0, drift = profile.water_temperature_c, 0.1
    c0 = sound_speed_m_s(t0)
    meas = [
        replace(
            m,
            distance_mm=m.distance_mm * c0 / sound_speed_m_s(t0 + drift * 0.1 * i),
            time_min=0.1 * i,
            approach=np.ones(6),
        )
        for i, m in enumerate(meas)
    ]
    prior = prior_from_profile(profile)
    sol = solve_full(prior, meas, structure=plan.structure)
    assert sol.cell.quality.verdict == "ok"
    effects = sol.effects
    t_mid = t0 + drift * sol.cell.time_ref_min
    rate = (sound_speed_m_s(t_mid + 0.01) - sound_speed_m_s(t_mid - 0.01)) / 0.02 * drift
    assert abs(effects.drift_m_s_per_min - rate) <= 3 * effects.drift_std_m_s_per_min
    assert effects.drift_std_m_s_per_min < 0.5 * prior.drift_std_m_s_per_min
    assert np.all(np.isnan(effects.backlash_deg))  # every reading from below: not measured
    # held at 0, the misfit names the drift, never the full level it already is
    held = solve_full(
        prior, meas, fixed=("sound_speed_drift_m_s_per_min",), structure=plan.structure
    )
    assert held.cell.quality.verdict == "misfit"
    assert "drift of the sound speed" in held.cell.quality.cause
    assert "--level full" not in held.cell.quality.cause


def test_postures_reached_from_above_measure_each_joints_lost_motion(cell):
    profile, plan = cell
    # a few postures, each reached from above on every joint; the rest carry the offsets
    assert 2 <= len(plan.above) <= len(plan.postures) // 2
    assert set(plan.above) <= {p.label for p in plan.postures if not p.step}
    offsets = np.array([0.2, -0.1, 0.15, -0.2, 0.1, 0.05])  # the positive approach's
    backlash = np.array([0.015, 0.02, 0.008, 0.018, 0.012, 0.01])
    args = (profile.sample_rotation_deg, profile.sample_position_mm, profile.water_temperature_c)
    below = measure(profile, plan, profile.model, offsets, *args, seed=5)
    # from above the link sits the whole lost motion further on
    above = measure(profile, plan, profile.model, offsets + backlash, *args, seed=5)
    meas = [
        replace(a, approach=-np.ones(6))
        if p.label in plan.above
        else replace(b, approach=np.ones(6))
        for p, a, b in zip(plan.postures, above, below, strict=True)
    ]
    sol = solve_full(prior_from_profile(profile), meas, structure=plan.structure)
    assert sol.cell.quality.verdict == "ok"
    effects = sol.effects
    seen = np.isfinite(effects.backlash_deg)
    assert seen[:5].all()
    err = np.abs(effects.backlash_deg[seen] - backlash[seen])
    assert np.all(err <= 3 * effects.backlash_std_deg[seen]), (err, effects.backlash_std_deg)
    assert np.all(effects.backlash_std_deg[:5] < 0.002)
    ok = np.isfinite(sol.std_deg)
    assert np.all(np.abs(sol.offsets_deg[ok] - offsets[ok]) <= 3 * sol.std_deg[ok])
