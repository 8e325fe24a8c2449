"""The tank's drift and the arm's lost motion as unknowns of the solvers (no simulator).

Synthetic face measurements of a cell whose sound speed drifts linearly over the run and whose
joints lag their encoders by half their lost motion against each reading's approach: the
drift is recovered from the water paths' trend, the lost motion from readings of both sides,
and readings from one side leave it unmeasured without inflating the offsets' std.
"""

from __future__ import annotations

import numpy as np
import pytest

from ucal.acoustics import sound_speed_m_s
from ucal.calibration.exact import solve_exact_with_priors
from ucal.cell import PAPER_CALIBRATION_POSE_DEG
from ucal.kinematics.dh import transform, wrist_centre
from ucal.model import least_squares
from ucal.model.fit import (
    BACKLASH,
    DRIFT,
    PARAMETERS,
    CellPrior,
    ParameterTable,
    ResidualRow,
    RunEffects,
    likely_cause,
    readings_approach,
    solve_cell,
)
from ucal.model.geometry import CellGeometry, FaceMeasurement
from ucal.model.kinematic import full_table
from ucal.model.least_squares import (
    curvature_covariance,
    curvature_std_m_s_per_min2,
    face_row_minutes,
)
from ucal.profile.calibration import written_stds
from ucal.profile.models import load_model

from doubles import noisy_face

MODEL = load_model("tx90l")
TOOL_MM = np.array([0.0, 0.0, 80.0])
CORNER_MM = wrist_centre(MODEL, PAPER_CALIBRATION_POSE_DEG) - 280.0
OFFSETS_DEG = np.array([0.8, -1.2, 1.5, -2.0, 1.1, 0.6])
#: (config, joint index, step deg, θ6 turn deg): paper 000's three plus a second J1 azimuth.
CONFIGS = (
    ("base", None, 0.0, 0.0),
    ("j3", 2, 5.0, 90.0),
    ("j2", 1, 5.0, -90.0),
    ("j1", 0, 6.0, 0.0),
)


#: The tank's rate turning (°C/min²) in the curving tank's test: 0.11 °C/min over its 5.5 min,
#: 2.2 times the curvature's std the declared drift tolerance gives.
CURVATURE_C_PER_MIN2 = 0.02


def prior(backlash_std_deg: float = 0.01, drift_std_c_per_min: float = 0.05) -> CellPrior:
    """The profile: a fixtured block and a measured tool, so the offsets' std is tight."""
    return CellPrior(
        MODEL,
        np.zeros(6),
        TOOL_MM,
        np.zeros(3),
        CORNER_MM,
        np.zeros(3),
        20.0,
        tool_position_std_mm=np.full(3, 0.01),
        tool_rotation_std_deg=np.full(3, 0.005),
        block_position_std_mm=np.full(3, 0.5),
        block_rotation_std_deg=np.full(3, 0.005),
        dh_length_std_mm=1e-4,
        dh_angle_std_deg=1e-5,
        drift_std_c_per_min=drift_std_c_per_min,
        backlash_std_deg=np.full(6, backlash_std_deg),
    )


def measure(
    drift_c_per_min: float = 0.0,
    backlash_deg: np.ndarray | None = None,
    sides: tuple[float, ...] = (1.0,),
    minutes_per_reading: float = 0.5,
    sigma_tilt_deg: float = 5e-4,
    sigma_dist_mm: float = 5e-4,
    seed: int = 0,
    curvature_c_per_min2: float = 0.0,
) -> list[FaceMeasurement]:
    """Face measurements of a true cell at 20 °C drifting ``drift_c_per_min`` (its rate turning
    by ``curvature_c_per_min2``), each reading ``minutes_per_reading`` after the previous,
    every posture read from each of ``sides``."""
    b = np.zeros(6) if backlash_deg is None else np.asarray(backlash_deg, float)
    truth = CellGeometry(MODEL, transform(TOOL_MM, np.eye(3)), np.eye(3))
    rng = np.random.default_rng(seed)
    out = []
    for side in sides:
        for cfg, joint, step, turn in CONFIGS:
            arm = PAPER_CALIBRATION_POSE_DEG.copy()
            if joint is not None:
                arm[joint] += step
            arm[5] += turn
            for face in (2, 0, 1):
                t = len(out) * minutes_per_reading
                link = OFFSETS_DEG - side * b / 2 + b / 2  # positive-approach offsets + lag
                c_t = sound_speed_m_s(
                    20.0 + drift_c_per_min * t + 0.5 * curvature_c_per_min2 * t**2
                )
                out.append(
                    noisy_face(
                        truth,
                        cfg,
                        face,
                        arm,
                        link,
                        CORNER_MM,
                        rng,
                        sigma_tilt_deg,
                        sigma_dist_mm,
                        sound_speed_m_s(20.0) / c_t,
                        time_min=t,
                        approach=np.full(6, side),
                    )
                )
    return out


def z_scores(sol, truth_deg: np.ndarray) -> np.ndarray:
    ok = np.isfinite(sol.std_deg)
    return np.abs(sol.offsets_deg[ok] - truth_deg[ok]) / sol.std_deg[ok]


def test_a_drifting_tank_is_recovered_from_the_trend_of_the_water_paths() -> None:
    drift = 0.3  # °C/min: 6σ of the default prior
    meas = measure(drift_c_per_min=drift, seed=1)
    sol = solve_exact_with_priors(prior(), meas)
    assert sol.cell_fit is not None
    effects = RunEffects.of(sol.cell_fit)
    last = max(m.time_min or 0.0 for m in meas)
    # c(T) is not linear: the rate over the run is the secant's, not 20 °C's slope
    true_rate = (sound_speed_m_s(20.0 + drift * last) - sound_speed_m_s(20.0)) / last
    assert abs(effects.drift_m_s_per_min - true_rate) <= 3 * effects.drift_std_m_s_per_min
    assert effects.drift_std_m_s_per_min < 0.2 * prior().drift_std_m_s_per_min
    assert sol.fit is not None and sol.fit.verdict == "ok"
    assert np.all(z_scores(sol, OFFSETS_DEG) <= 3.0), z_scores(sol, OFFSETS_DEG)
    # the sound speed is the one of the middle of the run
    middle = sound_speed_m_s(20.0 + drift * np.mean([m.time_min for m in meas]))
    assert abs(sol.sound_speed_m_s - middle) <= 3 * sol.sound_speed_std_m_s
    # held at 0 (the previous solver), the offsets are off and the fit names the tank
    held = solve_exact_with_priors(prior(), meas, fixed=DRIFT)
    assert np.max(z_scores(held, OFFSETS_DEG)) > 3.0
    assert held.fit is not None and held.fit.verdict == "misfit"
    assert "trend with their time" in held.fit.cause, held.fit.cause


def test_a_tank_whose_rate_turns_is_within_the_stds(monkeypatch: pytest.MonkeyPatch) -> None:
    """A tank warming ever faster (a curvature the linear drift does not model): the rate
    may turn by its declared tolerance over the run (``curvature_std_m_s_per_min2``); the
    stds carry it, where the linear drift alone reports the sound speed of the middle of the
    run 5σ off."""
    k = CURVATURE_C_PER_MIN2
    meas = measure(drift_c_per_min=0.1, curvature_c_per_min2=k, seed=2)
    span_min = max(m.time_min or 0.0 for m in meas)
    slope = prior().sound_speed_slope_m_s_per_c
    assert curvature_std_m_s_per_min2(prior(), np.array([0.0, span_min])) == pytest.approx(
        slope * 0.05 / span_min
    )
    middle = float(np.mean([m.time_min for m in meas]))
    true_m_s = sound_speed_m_s(20.0 + 0.1 * middle + 0.5 * k * middle**2)
    sol = solve_exact_with_priors(prior(), meas)
    assert abs(sol.sound_speed_m_s - true_m_s) <= 3 * sol.sound_speed_std_m_s
    assert np.all(z_scores(sol, OFFSETS_DEG) <= 3.0), z_scores(sol, OFFSETS_DEG)
    monkeypatch.setattr(least_squares, "curvature_std_m_s_per_min2", lambda *_: 0.0)
    linear_only = solve_exact_with_priors(prior(), meas)
    assert linear_only.sound_speed_m_s == pytest.approx(sol.sound_speed_m_s)  # the same fit
    assert abs(linear_only.sound_speed_m_s - true_m_s) > 5 * linear_only.sound_speed_std_m_s


def test_a_tank_whose_rate_turns_fast_is_a_misfit_that_names_it() -> None:
    """The rate turning by 0.55 °C/min over the run, eleven times the declared tolerance: the
    water paths bend with their time, and the misfit's message says so rather than blaming a
    quantity of the cell."""
    meas = measure(drift_c_per_min=0.1, curvature_c_per_min2=0.1, seed=2)
    sol = solve_exact_with_priors(prior(), meas)
    assert sol.fit is not None and sol.fit.verdict == "misfit"
    assert sol.fit.cause.startswith("a drift of the sound speed that turns during the run explains")
    assert "bend with their time" in sol.fit.cause


def test_a_fit_stopped_before_it_converged_says_so() -> None:
    """A misfit whose fit ran out of evaluations is not blamed on the cell alone: the message
    says the fit stopped first, then what the residuals would name."""
    meas = measure(drift_c_per_min=0.1, curvature_c_per_min2=0.1, seed=2)
    stopped = solve_cell(prior(), meas, max_evaluations=3)
    assert stopped.quality.verdict == "misfit"
    assert stopped.quality.cause.startswith("the fit stopped at its limit of 3 evaluations")
    converged = solve_cell(prior(), meas)
    assert not converged.quality.cause.startswith("the fit stopped")


def test_the_curvature_moves_the_sound_speed_by_a_parabolas_best_line() -> None:
    """Three readings at −1, 0 and 1 min whose water paths see only the sound speed: a bend
    ½·c̈·t² of the speed is [0.5, 0, 0.5]·c̈, whose best line is 1/3·c̈ flat, so the speed's
    variance grows by (σ/3)² and the drift's not at all (the held block is not free)."""
    table = ParameterTable(
        ("sound_speed_m_s", DRIFT[0], "block_x_mm"), np.zeros(3), np.ones(3), [True, True, False]
    )
    minutes = np.array([-1.0, 0.0, 1.0])
    jac = np.zeros((9, 2))
    jac[2::3, 0] = 1.0  # each reading's water-path row: c + ċ·t
    jac[2::3, 1] = minutes
    cov = np.linalg.inv(jac.T @ jac)
    added = curvature_covariance(table, jac, cov, face_row_minutes(minutes), 0.6)
    np.testing.assert_allclose(added, [[(0.6 / 3) ** 2, 0.0], [0.0, 0.0]], atol=1e-15)
    table.free[1] = False  # the drift held: no bend is carried
    rows = face_row_minutes(minutes)
    assert not curvature_covariance(table, jac[:, :1], cov[:1, :1], rows, 0.6).any()


def test_readings_without_time_leave_the_drift_at_its_prior() -> None:
    meas = [
        FaceMeasurement(m.config, m.face, m.joints_deg, m.distance_mm, 5e-4, 5e-4)
        for m in measure(seed=2)
    ]
    cell = solve_cell(prior(), meas)
    effects = RunEffects.of(cell)
    assert effects.drift_m_s_per_min == 0.0
    assert np.isclose(effects.drift_std_m_s_per_min, prior().drift_std_m_s_per_min)
    assert not cell.table.free[cell.table.index(DRIFT[0])]


def test_lost_motion_is_recovered_from_readings_of_both_sides() -> None:
    backlash = np.array([0.015, 0.02, 0.012, 0.018, 0.01, 0.0])
    meas = measure(backlash_deg=backlash, sides=(1.0, -1.0), seed=3)
    sol = solve_exact_with_priors(prior(), meas)
    assert sol.cell_fit is not None
    effects = RunEffects.of(sol.cell_fit)
    seen = [0, 1, 2, 3, 4]  # J6 turns nothing the beam on its axis sees
    err = np.abs(effects.backlash_deg[seen] - backlash[seen])
    assert np.all(err <= 3 * effects.backlash_std_deg[seen]), (err, effects.backlash_std_deg)
    assert np.all(effects.backlash_std_deg[seen] < 0.003)
    # the offsets are those of the positive approach (reached from below)
    assert np.all(z_scores(sol, OFFSETS_DEG) <= 3.0), z_scores(sol, OFFSETS_DEG)
    # J6, read from both sides but left at its prior by the data, is not reported measured
    json = effects.to_json()
    assert [v is not None for v in json["backlash_deg"]] == [True] * 5 + [False]
    assert written_stds(effects.backlash_deg)[5] == -1.0
    # held at 0, the two sides disagree by the lost motion: a misfit split by approach
    held = solve_exact_with_priors(prior(), meas, fixed=BACKLASH)
    assert held.fit is not None and held.fit.verdict == "misfit"
    assert "split by the approach of J" in held.fit.cause, held.fit.cause


def test_readings_from_one_side_do_not_measure_the_lost_motion_nor_inflate_the_offsets() -> None:
    backlash = np.full(6, 0.02)
    for side in (1.0, -1.0):
        meas = measure(backlash_deg=backlash, sides=(side,), seed=4)
        wide = solve_exact_with_priors(prior(backlash_std_deg=0.05), meas)
        none = solve_exact_with_priors(prior(backlash_std_deg=0.0), meas)
        ok = np.isfinite(none.std_deg)
        assert ok.sum() >= 4
        assert np.allclose(wide.std_deg[ok], none.std_deg[ok], rtol=1e-3)
        assert np.allclose(wide.offsets_deg[ok], none.offsets_deg[ok], atol=1e-6)
        assert wide.cell_fit is not None
        effects = RunEffects.of(wide.cell_fit)
        assert np.all(np.isnan(effects.backlash_deg))
        assert effects.to_json()["backlash_deg"] == [None] * 6
        assert written_stds(effects.backlash_deg) == [-1.0] * 6
        # the offsets of the approach the readings had: from above, the link lags by b more
        truth = OFFSETS_DEG if side > 0 else OFFSETS_DEG + backlash
        assert np.all(z_scores(wide, truth) <= 3.0), z_scores(wide, truth)


def rows_of(distances: list[float], times: list[float] | None = None) -> tuple[ResidualRow, ...]:
    return tuple(
        ResidualRow(f"m{i}", (0.1, -0.1), d, None if times is None else times[i])
        for i, d in enumerate(distances)
    )


def test_the_full_level_is_never_told_to_calibrate_at_the_full_level() -> None:
    p = prior()
    scattered = rows_of([3.0, -2.5, 2.8, -3.1, 2.2, -2.7, 3.3, -2.9])
    offsets_table = ParameterTable(PARAMETERS, p.values(), p.stds())
    full = full_table(p)
    offsets_cause = likely_cause(scattered, {}, offsets_table, offsets_table.prior, p)
    full_cause = likely_cause(scattered, {}, full, full.prior, p)
    assert "--level full" in offsets_cause
    assert "--level full" not in full_cause and "identified kinematic model" in full_cause
    tilted = tuple(ResidualRow(f"m{i}", (3.0, -2.0), 0.1) for i in range(8))
    assert "--level full" not in likely_cause(tilted, {}, full, full.prior, p)


def test_residuals_that_trend_with_time_name_the_tank() -> None:
    p = prior()
    table = ParameterTable(PARAMETERS, p.values(), p.stds())
    # in time order, not in the order given
    times = [0.0, 5.0, 1.0, 4.0, 2.0, 3.0, 6.0, 7.0]
    dist = [-3.0 + t for t in times]
    cause = likely_cause(rows_of(dist, times), {}, table, table.prior, p)
    assert "trend with their time" in cause and "tank" in cause
    assert "drift_std_c_per_min" in cause


def test_the_approach_of_the_readings_is_named_as_spec_names_it() -> None:
    def reading(approach: list[float] | None) -> FaceMeasurement:
        signs = None if approach is None else np.asarray(approach, float)
        return FaceMeasurement("base", 0, np.zeros(6), 100.0, approach=signs)

    below, above = [1.0] * 6, [-1.0] * 6
    assert readings_approach([reading(below), reading(None)]) == "positive"
    assert readings_approach([reading(above), reading(above)]) == "negative"
    assert readings_approach([reading(below), reading([1.0, -1.0, 1.0, 1.0, 1.0, 1.0])]) == "both"
