"""The tool-frame fit with the cell's uncertain quantities as unknowns, on synthetic readings of a
cell whose offsets, plate, sound speed and delay differ from the profile (no processes)."""

from __future__ import annotations

import dataclasses
import functools
import re

import numpy as np
import pytest
import tomlkit

from ucal.acoustics import sound_speed_m_s
from ucal.cell import CellProfile, WorldTruth
from ucal.kinematics.ik import ik
from ucal.kinematics.rotations import angle_between_deg, rpy_to_matrix, tangent_basis
from ucal.model import least_squares
from ucal.model.fit import offsets_prior_std_deg, prior_from_profile
from ucal.model.geometry import CellGeometry, beam_and_tcp
from ucal.model.least_squares import CURVATURE
from ucal.model.wrist import aim_wrist
from ucal.profile import default_profile_text, profile_from_data
from ucal.toolframe.fit import (
    TOLERANCE_POSITION_MM,
    PlateCrossing,
    PlatePeak,
    _cause,
    plate_prior,
    solve_tool_frame,
    truth_in_profile_flange,
)
from ucal.toolframe.plan import (
    HALF_TURNS,
    QUARTER_TURNS,
    ToolFramePlan,
    plan_tool_frame,
    tcp_pose,
)
from ucal.toolframe.plane import fit_plane

TRUE_OFFSETS = np.array([0.8, -0.6, 0.9, -1.2, 0.7, 0.5])
TRUE_TOOL_MM = np.array([2.5, -3.0, 82.0])
TRUE_TOOL_DEG = np.array([1.0, -0.8, 0.0])
DELAY_NS = 8.0
#: The middle of the synthetic run's water paths (its four peaks read at 0-3 min).
PATHS_MIDDLE_MIN = 1.5


@functools.lru_cache
def _plan(points: bytes) -> ToolFramePlan:
    """The plan of the fresh profile (its postures only start each synthetic reading)."""
    return plan_tool_frame(fresh_profile(), "exact", 4)


def fresh_profile() -> CellProfile:
    return profile_from_data(tomlkit.parse(default_profile_text("tx90l")), "cell.toml")


def synthetic_run(
    profile,
    plate_h_mm: float,
    plate_tilt_deg: float,
    water_c: float,
    seed: int = 1,
    drift_c_per_min: float = 0.0,
    backlash_deg: np.ndarray | None = None,
    from_above: tuple[int, ...] = (),
    curvature_c_per_min2: float = 0.0,
    plan: ToolFramePlan | None = None,
    tool_deg: np.ndarray = TRUE_TOOL_DEG,
) -> tuple[list[PlatePeak], list[PlateCrossing], np.ndarray]:
    """Peaks and edge crossings the true cell gives for the profile's plan, with noise.

    Each reading a minute after the last, the water warming by ``drift_c_per_min`` (its rate
    turning by ``curvature_c_per_min2`` about ``PATHS_MIDDLE_MIN``); the
    joints with lost motion ``backlash_deg`` (the link lagging its reading by half of it
    against the approach), every other reading approaching the joints ``from_above`` (index
    0…5) from above, the others from below; ``plan``: the profile's (the fresh profile's by
    default), ``tool_deg``: the true tool's orientation."""
    rng = np.random.default_rng(seed)
    lost = np.zeros(6) if backlash_deg is None else np.asarray(backlash_deg, float)
    count = iter(range(1000))

    def reading(q: np.ndarray) -> tuple[np.ndarray, float, np.ndarray]:
        """The encoder's reading where the link is at ``q``, its minute and approach."""
        i = next(count)
        approach = np.ones(6)
        if i % 2:
            approach[list(from_above)] = -1.0
        return q + approach * lost / 2, float(i), approach

    plan = plan or _plan(profile.reflector_points_mm.tobytes())
    plane = plan.plane
    n = rpy_to_matrix([plate_tilt_deg, 0.0, 0.0]) @ plane.normal
    h = n @ (plane.centroid_mm + plate_h_mm * plane.normal)
    tool = np.eye(4)
    tool[:3, :3] = rpy_to_matrix(tool_deg)
    tool[:3, 3] = TRUE_TOOL_MM
    geom = CellGeometry(profile.model, tool, np.eye(3))
    c0 = sound_speed_m_s(profile.water_temperature_c)

    def ray(q: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
        b, p = beam_and_tcp(geom, q, TRUE_OFFSETS)
        return b, p, float((p @ n - h) / -(b @ n))

    peaks = []
    for t in plan.peaks:
        q = aim_wrist(geom, t.joints_deg, -n, TRUE_OFFSETS)
        _, _, path = ray(q)
        q_read, minute, approach = reading(q)
        c = sound_speed_m_s(
            water_c
            + drift_c_per_min * minute
            + 0.5 * curvature_c_per_min2 * (minute - PATHS_MIDDLE_MIN) ** 2
        )
        d = (c0 / c) * (path + c * 1e-6 * DELAY_NS / 2) + rng.normal(0.0, 0.003)
        q_seen = q_read.copy()
        q_seen[3:5] += rng.normal(0.0, 0.0005, 2)
        peaks.append(PlatePeak(t.label, q_seen, 0.0007, q_read, float(d), 0.003, minute, approach))
    crossings = []
    starts = []
    nominal = np.zeros(6)
    for ep in plan.edges:
        u, w = ep.direction, ep.along
        e = np.cos(np.radians(1.0)) * u + np.sin(np.radians(1.0)) * w  # edge 1° off the scan
        edge_d = float(e @ (plan.centre_mm + 100.0 * u))
        starts += [float(np.degrees(np.arctan2(u @ plane.e2, u @ plane.e1))), edge_d]
        for phi in (plan.phi0_deg + t for t in plan.edge_turns_deg):
            for lat in ep.lateral_mm:
                p = plan.centre_mm + 100.0 * u + lat * w
                # as the procedure scans: the tool centre (as far as it is known) on the line
                q = ik(
                    profile.model,
                    tcp_pose(plane, p, 50.0, phi),
                    tool,
                    TRUE_OFFSETS,
                    near_deg=plan.peaks[0].joints_deg,
                )
                q = aim_wrist(geom, q, -n, TRUE_OFFSETS)
                b, tcp, path = ray(q)
                hit = tcp + path * b
                shift = (edge_d - e @ hit) / (e @ u) * u + rng.normal(0.0, 0.003) * u
                q_read, minute, approach = reading(q)
                crossings.append(
                    PlateCrossing(
                        f"edge {ep.name} {lat:+.0f} {phi:+.0f}",
                        q_read,
                        shift,
                        ep.index,
                        0.003,
                        minute,
                        approach,
                    )
                )
                nominal = q
    assert nominal.any()
    return peaks, crossings, np.array(starts)


@pytest.fixture
def profile() -> CellProfile:
    return fresh_profile()


def truth(profile) -> WorldTruth:
    return WorldTruth.nominal(profile).replace(
        joint_offsets_deg=TRUE_OFFSETS,
        tool_position_mm=TRUE_TOOL_MM,
        tool_rotation_deg=TRUE_TOOL_DEG,
    )


def solve(profile, peaks, crossings, starts, fixed: tuple[str, ...] = ()):
    """The fit of the readings (``fixed``: held at their priors, as the previous fit held the
    drift and the lost motion)."""
    plane = fit_plane(profile.reflector_points_mm)
    return solve_tool_frame(
        prior_from_profile(profile),
        plate_prior(plane, profile.reflector_points_mm, profile.reflector_points_std_mm),
        offsets_prior_std_deg(profile),
        peaks,
        crossings,
        starts,
        fixed=fixed,
    )


@pytest.mark.parametrize("calibrated", [False, True])
def test_tool_across_the_beam_within_its_std_before_and_after_calibrate(
    profile, calibrated: bool
) -> None:
    """A fresh cell (offsets up to 1.2° and never calibrated: wide priors) and the same cell
    after calibrate (offsets known to 0.01°); the plate 1.5 mm high and tilted 0.2°, the water
    1.5 °C warmer, an 8 ns delay."""
    if calibrated:
        profile = profile.replace(
            joint_offsets_deg=TRUE_OFFSETS + 0.005, joint_offsets_std_deg=np.full(6, 0.01)
        )
    peaks, crossings, starts = synthetic_run(profile, 1.5, 0.2, 21.5)
    tf = solve(profile, peaks, crossings, starts)
    true_tool = truth_in_profile_flange(profile, truth(profile))
    err = tf.position_mm - true_tool[:3, 3]
    tb = tangent_basis(tf.beam)
    assert tf.quality.verdict == "ok", tf.quality
    assert np.all(np.abs(tb @ err) <= 3 * tf.across_beam_std_mm), (tb @ err, tf.across_beam_std_mm)
    assert angle_between_deg(tf.beam, true_tool[:3, 2]) <= 3 * np.sqrt(2) * tf.beam_std_deg
    # along the beam: not measured apart from the plate's height and the tool's prior
    assert abs(tf.beam @ err) <= 3 * tf.along_beam_std_mm
    assert tf.along_beam_std_mm > 0.5
    assert set(tf.along_beam_limited_by) & {"tool_z_mm", "plate_h_mm", "sound_speed_m_s"}
    if calibrated:
        assert tf.in_tolerance and np.all(tf.across_beam_std_mm < 0.02), tf.refusal
    else:
        # uncalibrated wrist offsets and the plate's tilt turn the beam differently in the two
        # senses of the edge reversal: refused, and the message says why
        assert not tf.in_tolerance
        assert "across the beam" in tf.refusal and "plate tilt" in tf.refusal, tf.refusal
        # the offsets the plate sees are measured on the way, within their std
        est, std = tf.solution.estimate[1:5], tf.solution.std[1:5]
        assert np.all(np.abs(est - TRUE_OFFSETS[1:5]) <= 3 * std)


def test_plate_above_its_touched_plane_is_carried_in_the_std_not_written_as_tool(profile) -> None:
    """The plate 2 mm above where it was touched: the tool length along the beam is 2 mm off at
    most as the declared plate tolerance (1 mm) says, never with a 0.0001 mm std."""
    profile = profile.replace(
        joint_offsets_deg=TRUE_OFFSETS, joint_offsets_std_deg=np.full(6, 0.001)
    )
    peaks, crossings, starts = synthetic_run(profile, 2.0, 0.0, 20.0)
    tf = solve(profile, peaks, crossings, starts)
    err = tf.position_mm - TRUE_TOOL_MM
    assert abs(tf.beam @ err) <= 3 * tf.along_beam_std_mm
    assert 0.5 < tf.along_beam_std_mm < 1.5
    assert "plate_h_mm" in tf.along_beam_limited_by
    # with the plate declared exactly known (points touched by a calibrated robot), the same
    # readings would place it: the tolerance is what the std carries
    tight = profile.replace(
        reflector_points_std_mm=0.01,
        water_temperature_std_c=0.01,
        dh_length_std_mm=0.0,
        dh_angle_std_deg=0.0,
    )
    peaks, crossings, starts = synthetic_run(tight, 0.0, 0.0, 20.0)
    tf = solve(tight, peaks, crossings, starts)
    err = tf.position_mm - TRUE_TOOL_MM
    assert tf.along_beam_std_mm < 0.1
    assert abs(tf.beam @ err) <= 3 * tf.along_beam_std_mm


def calibrated(profile: CellProfile, backlash_deg: np.ndarray) -> CellProfile:
    """The profile after calibrate: the offsets of the positive approach (the world's less
    half the lost motion) known to 0.01°."""
    return profile.replace(
        joint_offsets_deg=TRUE_OFFSETS - backlash_deg / 2 + 0.003,
        joint_offsets_std_deg=np.full(6, 0.01),
    )


def across_z(tf, profile, backlash_deg: np.ndarray) -> np.ndarray:
    """|error| / std of the tool across the beam against the truth (reached from below)."""
    true = truth_in_profile_flange(profile, truth(profile).replace(backlash_deg=backlash_deg))
    return np.abs(tangent_basis(tf.beam) @ (tf.position_mm - true[:3, 3])) / tf.across_beam_std_mm


def test_the_tanks_drift_is_fitted_and_a_fit_without_it_names_the_drift(profile) -> None:
    """The water warming 0.2 °C/min (four times its declared 0.05 °C/min, a minute between
    readings): the drift is measured from the water paths' times and the tool is right; held
    at 0, the fit is a misfit whose message names the drift, not a quantity dragged away."""
    profile = calibrated(profile, np.zeros(6))
    peaks, crossings, starts = synthetic_run(profile, 0.5, 0.1, 20.5, drift_c_per_min=0.2)
    tf = solve(profile, peaks, crossings, starts)
    assert tf.quality.verdict == "ok" and tf.in_tolerance, tf.refusal
    assert tf.effects is not None and tf.time_ref_min == pytest.approx(1.5)
    slope = (sound_speed_m_s(20.51) - sound_speed_m_s(20.49)) / 0.02
    drift = tf.effects.drift_m_s_per_min
    assert abs(drift - 0.2 * slope) <= 3 * tf.effects.drift_std_m_s_per_min
    assert tf.effects.drift_std_m_s_per_min < 0.5 * 0.05 * slope  # the data, not its prior
    c_mid = sound_speed_m_s(20.5 + 0.2 * tf.time_ref_min)
    assert abs(tf.sound_speed_m_s - c_mid) <= 3 * tf.sound_speed_std_m_s
    assert np.all(across_z(tf, profile, np.zeros(6)) <= 3)
    assert np.all(np.isnan(tf.effects.backlash_deg))  # every reading from below: not seen

    held = solve(profile, peaks, crossings, starts, ("sound_speed_drift_m_s_per_min",))
    assert held.quality.verdict == "misfit"
    assert "a drift of the sound speed during the run" in held.refusal, held.refusal
    assert "fitted at" not in held.refusal


def test_a_tank_whose_rate_turns_widens_the_tool_across_the_beam_by_what_it_moves(
    profile,
) -> None:
    """The drift's curvature, not fitted, is carried in the covariance as calibrate carries
    it: each across-beam variance grows by the square of what a bend of the tank moves that
    component (measured here by solving the same readings bent by 0.02 °C/min²) times the
    curvature's std (the declared 0.05 °C/min over the water paths' 3 minutes)."""
    profile = calibrated(profile, np.zeros(6))
    k = 0.02
    peaks, crossings, starts = synthetic_run(profile, 0.5, 0.1, 20.5, drift_c_per_min=0.1)
    bent = synthetic_run(profile, 0.5, 0.1, 20.5, drift_c_per_min=0.1, curvature_c_per_min2=k)
    tf, tf_bent = solve(profile, peaks, crossings, starts), solve(profile, *bent)
    assert tf.quality.verdict == tf_bent.quality.verdict == "ok"
    # the sound speed bent by ½·c̈·(t − 1.5)², c̈ = dc/dT·k about the middle temperature
    slope = (sound_speed_m_s(20.66) - sound_speed_m_s(20.64)) / 0.02
    moved = tangent_basis(tf.beam) @ (tf_bent.position_mm - tf.position_mm) / (slope * k)
    sigma = 0.05 * prior_from_profile(profile).sound_speed_slope_m_s_per_c / 3.0
    linear_only = solve(profile, peaks, crossings, starts, (CURVATURE,))  # held: as before
    np.testing.assert_allclose(linear_only.position_mm, tf.position_mm)  # the same fit
    added = tf.across_beam_std_mm**2 - linear_only.across_beam_std_mm**2
    assert np.max(added / linear_only.across_beam_std_mm**2) > 0.2  # a fifth more at least
    assert np.sum(added) == pytest.approx(np.sum((moved * sigma) ** 2), rel=0.02)


def test_readings_at_one_time_carry_no_curvature(profile, monkeypatch: pytest.MonkeyPatch) -> None:
    """Every water path read at the same minute: the drift is not seen (held) and its
    curvature adds nothing to any std."""
    profile = calibrated(profile, np.zeros(6))
    peaks, crossings, starts = synthetic_run(profile, 0.5, 0.1, 20.5)
    peaks = [dataclasses.replace(p, time_min=2.0) for p in peaks]
    tf = solve(profile, peaks, crossings, starts)
    monkeypatch.setattr(least_squares, "curvature_std_m_s_per_min2", lambda *_: 1.0)
    steep = solve(profile, peaks, crossings, starts)  # a bend of 1 m/s per min² if one counted
    assert tf.solution is not None and steep.solution is not None
    np.testing.assert_array_equal(steep.solution.std, tf.solution.std)


def test_a_tank_whose_rate_turns_fast_is_a_misfit_that_names_the_turn(profile) -> None:
    """The rate turning by 0.9 °C/min over the water paths' 3 minutes, eighteen times the
    declared tolerance: the misfit's message names a drift that turns, not its rate."""
    profile = calibrated(profile, np.zeros(6))
    run = synthetic_run(profile, 0.5, 0.1, 20.5, drift_c_per_min=0.1, curvature_c_per_min2=0.3)
    tf = solve(profile, *run)
    assert tf.quality.verdict == "misfit"
    assert "a drift of the sound speed that turns during the run explains" in tf.refusal, tf.refusal


def test_lost_motion_read_from_both_sides_is_fitted_and_a_fit_without_it_names_it(
    profile,
) -> None:
    """J4 and J5 with 0.02° of lost motion, every other reading approaching them from above:
    theirs is measured, the other joints' held (read from below only), and the tool is right;
    held at 0, the misfit names the lost motion of a wrist joint."""
    lost = np.array([0.0, 0.0, 0.0, 0.02, 0.02, 0.0])
    profile = calibrated(profile, lost)
    peaks, crossings, starts = synthetic_run(
        profile, 0.5, 0.1, 20.5, backlash_deg=lost, from_above=(3, 4)
    )
    tf = solve(profile, peaks, crossings, starts)
    assert tf.quality.verdict == "ok" and tf.in_tolerance, tf.refusal
    assert tf.effects is not None
    seen = np.isfinite(tf.effects.backlash_deg)
    np.testing.assert_array_equal(seen, [False, False, False, True, True, False])
    z = np.abs(tf.effects.backlash_deg[seen] - lost[seen]) / tf.effects.backlash_std_deg[seen]
    assert np.all(z <= 3), z
    assert np.all(across_z(tf, profile, lost) <= 3)

    held = solve(profile, peaks, crossings, starts, tuple(f"backlash_J{j}" for j in range(1, 7)))
    assert held.quality.verdict == "misfit"
    assert re.search(r"lost motion of J[45] explains", held.refusal), held.refusal


def test_lost_motion_read_from_below_only_is_held_and_the_tool_is_right(profile) -> None:
    """Every joint with 0.02° of lost motion, every reading from below (the tool-frame's own
    discipline): the lag is the same everywhere, the offsets of the positive approach carry
    it, and the lost motion is not reported."""
    lost = np.full(6, 0.02)
    profile = calibrated(profile, lost)
    peaks, crossings, starts = synthetic_run(profile, 0.5, 0.1, 20.5, backlash_deg=lost)
    tf = solve(profile, peaks, crossings, starts)
    assert tf.quality.verdict == "ok" and tf.in_tolerance, tf.refusal
    assert tf.effects is not None and np.all(np.isnan(tf.effects.backlash_deg))
    assert np.all(across_z(tf, profile, lost) <= 3)


@pytest.mark.parametrize("calibrated", [False, True])
def test_a_std_the_dh_tolerance_carries_is_refused_naming_the_arms_links(calibrated) -> None:
    """The across-beam variance of a fresh cell with a 20° holder (``benchmarks/drift.py``,
    seed 8, world 5): the DH table's tolerance in several parameters, the rest noise."""
    shares = {
        "data": 0.31,
        "dh4_a_mm": 0.33,
        "dh5_d_mm": 0.22,
        "dh1_alpha_deg": 0.06,
        "dh3_alpha_deg": 0.05,
        "plate_t2_deg": 0.02,
        "J2": 0.01,
    }
    text = _cause(shares, calibrated)
    # one tolerance, its parameters' shares summed; the noise named too
    assert (
        "the kinematic model's tolerance ([robot] dh_length_std_mm, dh_angle_std_deg; "
        "[calibration] dh_std where the full level identified it) 66 %"
    ) in text
    assert text.count("kinematic model") == 1 and "measurement noise 31 %" in text
    assert "link lengths and twists within the DH table's tolerance" in text
    assert ("run ucal calibrate first" in text) is not calibrated
    assert "points_std_mm" not in text and "[calibration] std_deg" not in text
    # noise first: more data, or on a fresh cell the offsets measured first
    noise = _cause({"data": 0.7, "dh4_a_mm": 0.3}, calibrated)
    assert noise.startswith("70 % of its variance is measurement noise")
    assert ("run ucal calibrate first" in noise) is not calibrated


def test_a_refusal_after_quarter_turns_says_the_edges_were_scanned_a_quarter_turn_apart() -> None:
    """A 20° holder's refusal spoke of the tool turned 180° about the beam where the run had
    scanned the edges a quarter turn apart: it says what the run did."""
    shares = {"data": 0.31, "dh4_a_mm": 0.33, "dh5_d_mm": 0.36}
    quarter = _cause(shares, False, turns=4)
    assert "a quarter turn apart about the beam (4 orientations)" in quarter
    assert "180°" not in quarter and "run ucal calibrate first" in quarter
    half = _cause(shares, False, turns=2)
    assert "turned 180° about the beam" in half and "quarter" not in half


def test_quarter_turns_tell_a_holders_tool_from_the_wrists_links() -> None:
    """A 20° holder on a fresh cell: turned half a turn about the beam, the wrist takes another
    posture, and the DH table's tolerance moves the flange between the two as a tool off the
    beam would; scans a quarter turn apart put the wrist in four postures the fit tells apart
    (``ucal.toolframe.plan``). The same readings' model, two orientations against four."""
    holder = fresh_profile().replace(tool_rotation_deg=np.array([0.0, 20.0, 0.0]))
    planned = plan_tool_frame(holder, "exact", 4)
    assert planned.edge_turns_deg == QUARTER_TURNS
    stds = {}
    for turns in (HALF_TURNS, QUARTER_TURNS):
        plan = dataclasses.replace(planned, edge_turns_deg=turns)
        peaks, crossings, starts = synthetic_run(
            holder, 1.5, 0.2, 21.5, plan=plan, tool_deg=holder.tool_rotation_deg + TRUE_TOOL_DEG
        )
        assert len(crossings) == 4 * len(turns)
        tf = solve(holder, peaks, crossings, starts)
        assert tf.quality.verdict == "ok", tf.quality
        stds[turns] = float(np.max(tf.across_beam_std_mm))
    # two orientations: the DH table's share refuses it; four: within the tolerance
    assert stds[HALF_TURNS] > TOLERANCE_POSITION_MM > stds[QUARTER_TURNS], stds
    assert stds[QUARTER_TURNS] < 0.5 * stds[HALF_TURNS], stds
