"""The offsets level's plan makes the tank's drift and the arm's lost motion observable (no
simulator): synthetic readings at the planned targets, in the run's order and timing, of a
cell whose tank drifts and whose joints have lost motion.

The first face's water path read again at the end (``read_again``) measures a drift of 6σ of
the default tolerance; the calibration pose's faces measured again from above
(``with_lost_motion``) measure each joint's lost motion, the offsets staying
those of the positive approach.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from ucal.acoustics import sound_speed_m_s
from ucal.calibration.exact import solve_exact_with_priors
from ucal.cell import CellProfile
from ucal.measure.running import PATH_ONLY_TILT_STD_DEG
from ucal.measure.sequence import with_lost_motion
from ucal.model.fit import RunEffects, prior_from_profile
from ucal.model.geometry import FaceMeasurement, beam_and_tcp
from ucal.model.targets import PlannedTarget, geometry, plan_calibration
from ucal.model.wrist import aim_wrist
from ucal.profile import load_profile

REPO = Path(__file__).resolve().parents[3]
OFFSETS_DEG = np.array([0.02, -0.03, 0.04, -0.05, 0.03, 0.01])
BACKLASH_DEG = np.array([0.015, 0.02, 0.008, 0.018, 0.012, 0.01])
DRIFT_C_PER_MIN = 0.3  # 6σ of the default tolerance (0.05 °C/min)
MINUTES_PER_FACE = 0.04  # the demo run: 12 faces in about half a minute
SIGMA = 5e-4  # deg of posture, mm of water path


@pytest.fixture(scope="module")
def cell() -> CellProfile:
    """The example cell with its block doweled and levelled and its tool measured (the
    offsets' std is then the readings')."""
    return load_profile(REPO / "profiles" / "example_cell.toml").replace(
        sample_position_std_mm=np.full(3, 0.5),
        sample_rotation_std_deg=np.full(3, 0.01),
        tool_position_std_mm=np.full(3, 0.05),
        tool_rotation_std_deg=np.full(3, 0.02),
    )


def reading(
    profile: CellProfile, target: PlannedTarget, side: float, t_min: float, rng
) -> FaceMeasurement:
    """The target read on the true cell at ``t_min``, every joint reached from ``side``."""
    geom = geometry(profile)
    link = OFFSETS_DEG - side * BACKLASH_DEG / 2  # the link lags its last motion by b/2
    q = aim_wrist(geom, target.joints_deg, -geom.normal(target.face), link)
    _, tcp = beam_and_tcp(geom, q, link)
    path = geom.normal(target.face) @ (tcp - np.asarray(profile.sample_position_mm, float))
    t0 = profile.water_temperature_c
    scale = sound_speed_m_s(t0) / sound_speed_m_s(t0 + DRIFT_C_PER_MIN * t_min)
    q[3:5] += rng.normal(0.0, SIGMA, 2)
    return FaceMeasurement(
        str(target.config),
        target.face,
        q,
        float(path * scale + rng.normal(0.0, SIGMA)),
        SIGMA,
        SIGMA,
        time_min=t_min,
        approach=np.full(6, side),
    )


def run(profile: CellProfile, again: bool, lost_motion: bool, seed: int = 1):
    """The run's readings as ``run_calibration`` takes them: the planned faces, those from
    above, the first water path again."""
    plan = plan_calibration(profile)
    plan = with_lost_motion(plan) if lost_motion else plan
    rng = np.random.default_rng(seed)
    meas = []
    for t in plan.targets:
        meas.append(reading(profile, t, 1.0, (len(meas) + 1) * MINUTES_PER_FACE, rng))
    for t in plan.above:
        m = reading(profile, t, -1.0, (len(meas) + 1) * MINUTES_PER_FACE, rng)
        meas.append(replace(m, config=f"{m.config}-above"))
    if again:
        first = meas[0]
        t_end = (len(meas) + 0.3) * MINUTES_PER_FACE
        t0 = profile.water_temperature_c
        ratio = sound_speed_m_s(t0 + DRIFT_C_PER_MIN * first.time_min) / sound_speed_m_s(
            t0 + DRIFT_C_PER_MIN * t_end
        )
        meas.append(
            replace(
                first,
                config="base-again",
                distance_mm=first.distance_mm * ratio + rng.normal(0.0, SIGMA),
                tilt_std_deg=PATH_ONLY_TILT_STD_DEG,
                time_min=t_end,
            )
        )
    return plan, meas


def drift_truth(profile: CellProfile, meas: list[FaceMeasurement]) -> float:
    """The drift of the sound speed (m/s per min) over the readings' span."""
    t0, times = profile.water_temperature_c, [m.time_min or 0.0 for m in meas]
    c = [sound_speed_m_s(t0 + DRIFT_C_PER_MIN * t) for t in (min(times), max(times))]
    return (c[1] - c[0]) / (max(times) - min(times))


def test_the_first_water_path_read_again_measures_the_drift(cell) -> None:
    prior = prior_from_profile(cell)
    truth = OFFSETS_DEG - BACKLASH_DEG / 2  # the positive approach's
    for again in (False, True):
        _, meas = run(cell, again, lost_motion=False)
        sol = solve_exact_with_priors(prior, meas)
        assert sol.cell_fit is not None
        effects = RunEffects.of(sol.cell_fit)
        ok = np.isfinite(sol.std_deg)
        z = np.abs(sol.offsets_deg[ok] - truth[ok]) / sol.std_deg[ok]
        drift_z = abs(effects.drift_m_s_per_min - drift_truth(cell, meas)) / (
            effects.drift_std_m_s_per_min
        )
        if again:
            # one water path, read again: the data, not the prior, say the drift
            assert effects.drift_std_m_s_per_min < 0.5 * prior.drift_std_m_s_per_min
            assert drift_z <= 3.0 and np.all(z <= 3.0), (drift_z, z)
        else:
            # each configuration's faces back to back: the drift barely seen, shrunk to 0
            assert effects.drift_std_m_s_per_min > 0.8 * prior.drift_std_m_s_per_min
            assert drift_z > 4.0
        assert np.all(np.isnan(effects.backlash_deg))  # every reading from below


def test_the_calibration_pose_from_above_measures_the_lost_motion(cell) -> None:
    plan, meas = run(cell, again=True, lost_motion=True)
    assert [t.label for t in plan.above] == ["base/XZ", "base/YZ", "base/XY"]
    assert plan_calibration(cell).above == ()  # an option: not by default
    sol = solve_exact_with_priors(prior_from_profile(cell), meas)
    assert sol.cell_fit is not None and sol.fit is not None and sol.fit.verdict == "ok"
    effects = RunEffects.of(sol.cell_fit)
    seen = np.isfinite(effects.backlash_deg)
    assert seen[:5].all()
    err = np.abs(effects.backlash_deg[seen] - BACKLASH_DEG[seen])
    assert np.all(err <= 3 * effects.backlash_std_deg[seen]), (err, effects.backlash_std_deg)
    assert np.all(effects.backlash_std_deg[:5] < 0.002)
    # the offsets are those of the positive approach
    truth = OFFSETS_DEG - BACKLASH_DEG / 2
    ok = np.isfinite(sol.std_deg)
    assert np.all(np.abs(sol.offsets_deg[ok] - truth[ok]) <= 3 * sol.std_deg[ok])
