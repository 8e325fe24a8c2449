"""The simulated cell: echoes from the calibration block and plate at joint readings."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import tomlkit
from scipy.optimize import least_squares

from ucal import acoustics as ac
from ucal.cell import (
    DEFAULT_PULSER_DELAY_NS,
    CellProfile,
    Noise,
    Reflector,
    TemperatureLog,
    WorldTruth,
)
from ucal.kinematics.dh import fk
from ucal.kinematics.rotations import angle_between_deg
from ucal.profile import create_profile, description_keys, load_profile, write_profile
from ucal.profile.models import load_model
from ucal.sim.cell import SimulatedCell, ideal_echo
from ucal.sim.demo import DEMO_JOINT_OFFSETS_DEG, demo_world
from ucal.sim.geometry import block_faces, intersect

CORNER_MM = np.array([450.0, -150.0, -450.0])
SIZE_MM = 300.0
PATH_MM = 50.0
C_20 = ac.sound_speed_m_s(20.0)
#: Largest error of the gate's peak detection on a noise-free echo: time (ns) and relative
#: height (a three-point parabola through an envelope sampled every 5 ns).
DETECT_NS = 0.02
DETECT_REL = 2e-4


def reading_tof_ns(path_mm: float, c_m_s: float = C_20) -> float:
    """What a noise-free gate reads for a water path: round trip plus the electronic delay."""
    return 2.0 * path_mm * 1e6 / c_m_s + DEFAULT_PULSER_DELAY_NS


@pytest.fixture(scope="module")
def profile() -> CellProfile:
    return CellProfile(
        model=load_model("tx90l"), sample_position_mm=CORNER_MM.copy(), sample_face_size_mm=SIZE_MM
    )


@pytest.fixture(scope="module")
def world(profile: CellProfile) -> WorldTruth:
    return WorldTruth.nominal(profile)


@pytest.fixture(scope="module")
def cell(world: WorldTruth) -> SimulatedCell:
    return SimulatedCell(world)


def solve_pose(
    cell: SimulatedCell, tcp_mm: np.ndarray, beam: np.ndarray, guess_deg: np.ndarray
) -> np.ndarray:
    """Joint readings that put the true TCP at ``tcp_mm`` with the beam along ``beam``."""

    def residual(q: np.ndarray) -> np.ndarray:
        t = cell.true_tcp(q)
        return np.concatenate([t[:3, 3] - tcp_mm, 100.0 * (t[:3, 2] - beam)])

    r = least_squares(residual, guess_deg, xtol=1e-14, ftol=1e-14, gtol=1e-14)
    assert np.abs(r.fun).max() < 1e-8
    return r.x


#: face name → (TCP 50 mm in front of the face centre, beam direction, initial guess)
FACE_POSES = {
    "z": (CORNER_MM + [150.0, 150.0, PATH_MM], [0.0, 0.0, -1.0], [0, 30, 110, 0, 40, 0]),
    "x": (CORNER_MM + [PATH_MM, 150.0, 150.0], [-1.0, 0.0, 0.0], [0, 30, 100, 0, -40, 0]),
    "y": (CORNER_MM + [150.0, PATH_MM, 150.0], [0.0, -1.0, 0.0], [-20, 30, 100, 90, 40, 0]),
}


def normal_pose(cell: SimulatedCell, face: str) -> np.ndarray:
    tcp, beam, guess = FACE_POSES[face]
    return solve_pose(
        cell, np.asarray(tcp, float), np.asarray(beam, float), np.asarray(guess, float)
    )


def test_true_flange_matches_dh_fk_with_offsets(profile: CellProfile, world: WorldTruth) -> None:
    offsets = np.array([0.3, -0.7, 1.1, 2.0, -0.4, 0.9])
    w = world.replace(
        joint_offsets_deg=offsets,
        tool_position_mm=np.array([1.0, -2.0, 90.0]),
        tool_rotation_deg=np.array([0.5, -0.3, 10.0]),
    )
    c = SimulatedCell(w)
    q = np.array([30.53, 31.15, 109.49, 0.0, 39.36, 30.54])
    np.testing.assert_allclose(c.true_tcp(q), fk(w.model, q, w.tool_matrix, offsets), atol=1e-9)
    origin, beam = c.true_beam(q)
    np.testing.assert_allclose(beam, c.true_tcp(q)[:3, 2])
    np.testing.assert_allclose(origin, c.true_tcp(q)[:3, 3])


@pytest.mark.parametrize("face", ["x", "y", "z"])
def test_normal_incidence_on_each_face(cell: SimulatedCell, face: str) -> None:
    q = normal_pose(cell, face)
    assert cell.world.model.within_limits(q)
    hit = cell.hit(q)
    assert hit is not None and hit.face.name == face
    assert hit.tilt_deg == pytest.approx(0.0, abs=1e-6)
    amp, tof = cell.ideal_echo(q)
    assert tof == pytest.approx(reading_tof_ns(PATH_MM), abs=DETECT_NS)
    assert tof == pytest.approx(67459.1 + DEFAULT_PULSER_DELAY_NS, abs=0.1)
    assert amp == pytest.approx(ac.REFERENCE_AMPLITUDE, rel=DETECT_REL)
    # a maximum: joints 4 and 5 tilt the beam and lower the echo; joint 6 turns the beam
    # about itself (nominal tool along the flange axis) and changes nothing
    for step in (-0.05, 0.05):
        for joint in (3, 4):
            dq = np.zeros(6)
            dq[joint] = step
            assert cell.ideal_echo(q + dq)[0] < amp - 1e-3
        assert cell.ideal_echo(q + [0, 0, 0, 0, 0, step]) == pytest.approx((amp, tof))


def test_wrist_tilt_halves_the_echo(cell: SimulatedCell) -> None:
    q = normal_pose(cell, "z")
    dq = np.array([0.0, 0.0, 0.0, 0.0, 0.2, 0.0])  # joint 5 ⟂ beam: tilts it by 0.2°
    hit = cell.hit(q + dq)
    assert hit.tilt_deg == pytest.approx(0.2, abs=1e-6)
    amp, _ = cell.ideal_echo(q + dq)
    ratio = amp / ac.broadband_echo_factor(0.0, hit.distance_mm, 25.0, 6.0, 20.0)
    assert 0.45 <= ratio / ac.REFERENCE_AMPLITUDE <= 0.55


def test_hidden_offset_follows_the_spec_sign(world: WorldTruth, cell: SimulatedCell) -> None:
    q = normal_pose(cell, "z")
    offsets = np.array([0.8, -1.2, 1.5, -2.0, 1.1, 0.6])
    hidden = SimulatedCell(world.replace(joint_offsets_deg=offsets))
    # actual = reading + offset: reading q − offset reaches the pose of q
    np.testing.assert_allclose(hidden.ideal_echo(q - offsets), cell.ideal_echo(q), atol=1e-6)
    assert hidden.ideal_echo(q)[0] < 0.01  # the uncorrected reading is degrees off normal


def test_joint1_offset_keeps_a_vertical_beam_and_its_tof(
    world: WorldTruth, cell: SimulatedCell
) -> None:
    # joint 1 turns about the vertical: the beam stays normal to face z, at the same height
    q = normal_pose(cell, "z")
    hidden = SimulatedCell(world.replace(joint_offsets_deg=np.array([1.0, 0, 0, 0, 0, 0])))
    amp, tof = hidden.ideal_echo(q)
    assert amp == pytest.approx(cell.ideal_echo(q)[0], abs=1e-9)
    assert tof == pytest.approx(cell.ideal_echo(q)[1], abs=1e-6)
    assert np.linalg.norm(hidden.true_tcp(q)[:3, 3] - cell.true_tcp(q)[:3, 3]) > 5.0


def test_joint2_offset_changes_the_water_path(world: WorldTruth, cell: SimulatedCell) -> None:
    q = normal_pose(cell, "z")
    offsets = np.array([0.0, 0.3, 0.0, 0.0, -0.3, 0.0])  # joint 5 undoes joint 2's tilt
    hidden = SimulatedCell(world.replace(joint_offsets_deg=offsets))
    t = fk(world.model, q, world.tool_matrix, offsets)
    assert angle_between_deg(t[:3, 2], np.array([0.0, 0.0, -1.0])) < 1e-6
    path = t[2, 3] - CORNER_MM[2]
    assert abs(path - PATH_MM) > 1.0
    amp, tof = hidden.ideal_echo(q)
    assert tof == pytest.approx(reading_tof_ns(path), abs=DETECT_NS)
    # broadband absorption: the low frequencies of the pulse carry further than its centre's
    expected = ac.REFERENCE_AMPLITUDE * ac.broadband_echo_factor(0.0, path, 25.0, 6.0, 20.0)
    assert amp == pytest.approx(expected, rel=DETECT_REL)


def test_half_echo_with_the_beam_axis_on_an_edge(cell: SimulatedCell) -> None:
    # the far edge u = S of face z (not shared with another face)
    q = solve_pose(
        cell,
        CORNER_MM + [SIZE_MM, 150.0, PATH_MM],
        np.array([0.0, 0.0, -1.0]),
        np.array([0, 30, 110, 0, 40, 0], float),
    )
    amp, tof = cell.ideal_echo(q)
    assert amp == pytest.approx(0.5 * ac.REFERENCE_AMPLITUDE, rel=DETECT_REL)
    assert np.isfinite(tof)
    q_off = solve_pose(
        cell, CORNER_MM + [SIZE_MM + 10.0, 150.0, PATH_MM], np.array([0.0, 0.0, -1.0]), q
    )
    amp_off, tof_off = cell.ideal_echo(q_off)
    assert amp_off < 1e-6 and np.isnan(tof_off)


def test_no_echo_when_the_beam_misses(cell: SimulatedCell) -> None:
    q = np.zeros(6)  # arm straight up, beam to the ceiling
    assert cell.hit(q) is None
    amp, tof = cell.ideal_echo(q)
    assert amp == 0.0 and np.isnan(tof)
    amp, tof = cell.echo(q)
    assert np.isnan(tof) and 0.0 < amp < 0.02


def test_a_face_seen_from_behind_does_not_reflect(cell: SimulatedCell) -> None:
    faces = block_faces(cell.world.sample_matrix, SIZE_MM)
    below = CORNER_MM + [150.0, 150.0, -50.0]
    hit = intersect(below, np.array([0.0, 0.0, 1.0]), faces[2])
    assert hit is not None and not hit.facing and hit.inside
    q = solve_pose(cell, below, np.array([0.0, 0.0, 1.0]), np.array([0, 60, 60, 0, -60, 0.0]))
    assert cell.hit(q) is None
    assert np.isnan(cell.ideal_echo(q)[1])


def test_reflector_plate_echo(world: WorldTruth, cell: SimulatedCell) -> None:
    plate = Reflector(point_mm=np.array([700.0, 300.0, -300.0]), normal=np.array([0.0, 0.0, 1.0]))
    c = SimulatedCell(world.replace(reflector=plate))
    q = solve_pose(
        c,
        np.array([700.0, 300.0, -240.0]),
        np.array([0.0, 0.0, -1.0]),
        np.array([30, 30, 110, 0, 40, 0], float),
    )
    hit = c.hit(q)
    assert hit.face.name == "reflector"
    amp, tof = c.ideal_echo(q)
    assert tof == pytest.approx(reading_tof_ns(60.0), abs=DETECT_NS)
    assert amp == pytest.approx(
        ac.REFERENCE_AMPLITUDE * ac.broadband_echo_factor(0.0, 60.0, 25.0, 6.0, 20.0),
        rel=DETECT_REL,
    )
    assert np.isnan(cell.ideal_echo(q)[1])  # no plate in the plain world


def test_gain_scales_and_saturates(cell: SimulatedCell) -> None:
    q = normal_pose(cell, "z")
    assert cell.ideal_echo(q, gain_db=14.0)[0] == pytest.approx(
        0.8 / ac.gain_factor(26.0), rel=DETECT_REL
    )
    assert cell.ideal_echo(q, gain_db=26.0)[0] == 1.0
    assert cell.echo(q, gain_db=40.0)[0] == 1.0


def test_gate_hides_an_echo_outside_it(cell: SimulatedCell) -> None:
    q = normal_pose(cell, "z")
    assert np.isfinite(cell.echo(q, gate_us=(5.0, 200.0))[1])
    amp, tof = cell.echo(q, gate_us=(70.0, 50.0))
    assert np.isnan(tof) and amp < 0.02


def test_module_ideal_echo_equals_the_method(world: WorldTruth, cell: SimulatedCell) -> None:
    q = normal_pose(cell, "x") + np.array([0.0, 0.0, 0.0, 0.05, 0.1, 0.0])
    assert ideal_echo(world, q) == cell.ideal_echo(q)


def noisy_cell(world: WorldTruth, seed: int = 11) -> SimulatedCell:
    return SimulatedCell(world.replace(noise=Noise(tof_ns=0.5, amplitude=0.01, seed=seed)))


def test_noise_statistics_and_averaging(world: WorldTruth, cell: SimulatedCell) -> None:
    q = normal_pose(cell, "z")
    amp0, tof0 = cell.ideal_echo(q)
    for averages, scale in ((1, 1.0), (16, 0.25)):
        c = noisy_cell(world)
        draws = np.array([c.echo(q, averages=averages) for _ in range(2000)])
        assert np.std(draws[:, 1]) == pytest.approx(0.5 * scale, rel=0.1)
        assert np.std(draws[:, 0] / amp0) == pytest.approx(0.01 * scale, rel=0.1)
        assert np.mean(draws[:, 1]) == pytest.approx(tof0, abs=0.1)
        assert np.mean(draws[:, 0]) == pytest.approx(amp0, rel=0.002)


def test_noise_is_seeded(world: WorldTruth, cell: SimulatedCell) -> None:
    q = normal_pose(cell, "z")
    a = [noisy_cell(world, 3).echo(q) for _ in range(1)] + [noisy_cell(world, 3).echo(q)]
    assert a[0] == a[1]
    c1, c2 = noisy_cell(world, 3), noisy_cell(world, 4)
    assert [c1.echo(q) for _ in range(5)] != [c2.echo(q) for _ in range(5)]
    # zero world noise: echo is the ideal echo but for the receiver's own noise (its peak
    # over a whole gate is 1e-4 of full screen at 20 dB)
    amp, tof = cell.echo(q)
    ideal_amp, ideal_tof = cell.ideal_echo(q)
    assert amp == pytest.approx(ideal_amp, abs=1e-4)
    assert tof == pytest.approx(ideal_tof, abs=0.01)


def test_echo_synthesises_a_short_window(cell: SimulatedCell) -> None:
    # thousands of readings per run: each synthesises at most 128 samples around its echo
    assert cell._receiver.n <= 128
    assert cell._receiver.n * cell._receiver.sample_ns >= 6 * 2 * 25.0  # ±6σ of the envelope


def test_demo_world_hides_non_trivial_errors(profile: CellProfile) -> None:
    w = demo_world(profile)
    np.testing.assert_allclose(w.joint_offsets_deg, [0.8, -1.2, 1.5, -2.0, 1.1, 0.6])
    assert w.joint_offsets_deg is not DEMO_JOINT_OFFSETS_DEG
    tool_err = np.linalg.norm(w.tool_position_mm - profile.tool_position_mm)
    assert 0.1 < tool_err < 1.0
    tilt = angle_between_deg(w.tool_matrix[:3, 2], profile.tool_matrix[:3, 2])
    assert 0.25 < tilt < 0.35
    block_err = np.abs(w.sample_position_mm - profile.sample_position_mm)
    assert 0.0 < block_err.max() <= 2.0
    assert w.noise.tof_ns == 0.5 and w.noise.amplitude == 0.01
    np.testing.assert_allclose(w.sample_rotation_deg, profile.sample_rotation_deg)
    # the truth shows: the nominal normal pose is no longer normal
    nominal = SimulatedCell(WorldTruth.nominal(profile))
    q = normal_pose(nominal, "z")
    assert SimulatedCell(w).ideal_echo(q)[0] < 0.5 * nominal.ideal_echo(q)[0]


# --- the truth is richer than the solvers' model ---------------------------------------------

E5 = np.array([0.0, 0.0, 0.0, 0.0, 1.0, 0.0])  # joint 5: at the z pose it tilts the beam


def test_backlash_lags_the_link_against_the_last_motion(
    world: WorldTruth, cell: SimulatedCell
) -> None:
    q = normal_pose(cell, "z")
    slack = SimulatedCell(world.replace(backlash_deg=np.array([0, 0, 0, 0, 0.2, 0])))
    # no motion known (None or 0): the link is where the encoder says
    np.testing.assert_array_equal(slack.true_tcp(q), cell.true_tcp(q))
    np.testing.assert_array_equal(slack.true_tcp(q, np.zeros(6)), cell.true_tcp(q))
    # after a positive motion the link lags: it is half the backlash behind the reading
    np.testing.assert_allclose(slack.true_tcp(q, E5), cell.true_tcp(q - 0.1 * E5), atol=1e-12)
    np.testing.assert_allclose(slack.true_tcp(q, -E5), cell.true_tcp(q + 0.1 * E5), atol=1e-12)
    np.testing.assert_allclose(
        slack.joint_angles_deg(q, -3.0 * E5) - slack.joint_angles_deg(q), 0.1 * E5
    )  # only the sign counts
    # approached from either side the beam differs by the whole lost motion
    up, down = slack.true_beam(q, E5)[1], slack.true_beam(q, -E5)[1]
    assert angle_between_deg(up, down) == pytest.approx(0.2, abs=1e-9)
    assert slack.hit(q, E5).tilt_deg == pytest.approx(0.1, abs=1e-9)
    # and so does the echo: normal incidence is found 0.1° past the reading on either side
    assert slack.ideal_echo(q, motion_sign=E5) == pytest.approx(cell.ideal_echo(q - 0.1 * E5))
    assert slack.ideal_echo(q + 0.1 * E5, motion_sign=E5)[0] == pytest.approx(
        cell.ideal_echo(q)[0], rel=1e-9
    )
    assert slack.ideal_echo(q - 0.1 * E5, motion_sign=-E5)[0] == pytest.approx(
        cell.ideal_echo(q)[0], rel=1e-9
    )
    assert slack.echo(q, motion_sign=E5)[0] < 0.9 * slack.echo(q)[0]


def test_hayati_twist_follows_its_link(world: WorldTruth, cell: SimulatedCell) -> None:
    from scipy.spatial.transform import Rotation

    from ucal.kinematics.dh import dh_matrix

    beta = np.array([0.0, 0.05, -0.02, 0.0, 0.01, 0.0])
    twisted = SimulatedCell(world.replace(dh_beta_deg=beta))
    q = np.array([30.53, 31.15, 109.49, 0.0, 39.36, 30.54])
    m = world.model
    th = np.radians(q + m.theta_offset_deg)
    t = np.eye(4)
    for i in range(6):  # A_i = Rz(θ)·Tz(d)·Tx(a)·Rx(α)·Ry(β)
        ry = np.eye(4)
        ry[:3, :3] = Rotation.from_euler("y", beta[i], degrees=True).as_matrix()
        t = t @ dh_matrix(th[i], m.d_mm[i], m.a_mm[i], np.radians(m.alpha_deg[i])) @ ry
    np.testing.assert_allclose(twisted.true_flange(q), t, atol=1e-9)
    # 0.05° about y of link 2 swings the 550 mm forearm by about 0.5 mm
    moved_mm = np.linalg.norm(twisted.true_tcp(q)[:3, 3] - cell.true_tcp(q)[:3, 3])
    assert 0.3 < moved_mm < 1.5
    zero = SimulatedCell(world.replace(dh_beta_deg=np.zeros(6)))
    np.testing.assert_array_equal(zero.true_flange(q), cell.true_flange(q))


def test_one_degree_warmer_shortens_the_tof_by_the_sound_speed_ratio(
    world: WorldTruth, cell: SimulatedCell
) -> None:
    q = normal_pose(cell, "z")
    warm = SimulatedCell(world.replace(water_temperature_c=21.0))
    c20, c21 = ac.sound_speed_m_s(20.0), ac.sound_speed_m_s(21.0)
    flight_20 = cell.ideal_echo(q)[1] - DEFAULT_PULSER_DELAY_NS
    flight_21 = warm.ideal_echo(q)[1] - DEFAULT_PULSER_DELAY_NS
    assert flight_21 == pytest.approx(flight_20 * c20 / c21, abs=2 * DETECT_NS)
    assert flight_20 - flight_21 == pytest.approx(135.0, abs=5.0)  # ~0.2 % of 67.5 µs


def test_water_drift_changes_the_tof_over_simulated_time(
    world: WorldTruth, cell: SimulatedCell
) -> None:
    q = normal_pose(cell, "z")
    drifting = SimulatedCell(world.replace(water_drift_c_per_min=0.5))
    assert drifting.water_temperature_c(120.0) == pytest.approx(21.0)
    warm = SimulatedCell(world.replace(water_temperature_c=21.0))
    assert drifting.ideal_echo(q) == cell.ideal_echo(q)  # at the start: as without drift
    assert drifting.ideal_echo(q, t_s=120.0)[1] == pytest.approx(warm.ideal_echo(q)[1], abs=1e-6)
    assert drifting.echo(q, t_s=120.0)[1] == pytest.approx(warm.ideal_echo(q)[1], abs=0.01)
    tofs = [drifting.ideal_echo(q, t_s=t)[1] for t in (0.0, 30.0, 60.0, 90.0)]
    assert np.all(np.diff(tofs) < -30.0)  # warming: sound faster, TOF shorter, ~34 ns per 30 s
    cooling = SimulatedCell(world.replace(water_drift_c_per_min=-0.5))
    assert cooling.ideal_echo(q, t_s=60.0)[1] > cell.ideal_echo(q)[1]


def test_the_tof_follows_the_thermometers_log(world: WorldTruth, cell: SimulatedCell) -> None:
    """A logged tank: the water between two readings is on the line between them, and held at
    the first and the last outside them, in minutes of simulated time since the cell started."""
    q = normal_pose(cell, "z")
    log = TemperatureLog(Path("t.csv"), np.array([0.0, 1.0, 3.0]), np.array([20.0, 22.0, 21.0]))
    logged = SimulatedCell(world.replace(water_temperature_log=log, water_drift_c_per_min=0.3))
    for t_s, temp_c in ((0.0, 20.0), (30.0, 21.0), (60.0, 22.0), (150.0, 21.25), (900.0, 21.0)):
        assert logged.water_temperature_c(t_s) == pytest.approx(temp_c, abs=1e-12)
        at_temp = SimulatedCell(world.replace(water_temperature_c=temp_c))
        assert logged.ideal_echo(q, t_s=t_s)[1] == pytest.approx(at_temp.ideal_echo(q)[1], abs=1e-6)
    # 2 °C warmer at one minute: the sound faster by ~7.7 m/s, the 67.5 µs round trip ~0.35 µs
    # shorter; the linear drift the world also states is not added to the log's temperature
    assert logged.ideal_echo(q)[1] - logged.ideal_echo(q, t_s=60.0)[1] == pytest.approx(
        266.0, abs=10.0
    )


def test_amplitude_is_quantised_to_levels_of_full_screen(
    world: WorldTruth, cell: SimulatedCell
) -> None:
    from ucal.cell import PulserTruth

    q = normal_pose(cell, "z")
    noisy = world.replace(noise=Noise(tof_ns=0.5, amplitude=0.01, seed=9))
    fine = SimulatedCell(noisy)
    coarse = SimulatedCell(noisy.replace(pulser=PulserTruth(amplitude_bits=8)))
    level = 1.0 / 256
    for dq in (0.0, 0.05, 0.1, 0.2, 0.4):
        for gain_db in (20.0, 14.0):
            raw, raw_tof = fine.echo(q + dq * E5, gain_db=gain_db)
            amp, tof = coarse.echo(q + dq * E5, gain_db=gain_db)
            assert amp / level == pytest.approx(round(amp / level), abs=1e-9)  # whole levels
            assert amp == np.floor(raw / level) * level  # truncated, the same draws
            assert tof == raw_tof or (np.isnan(tof) and np.isnan(raw_tof))
    # below one level the amplitude reads 0: an empty gate, and a weak echo
    assert fine.echo(np.zeros(6))[0] > 0.0  # the noise floor, unquantised
    assert coarse.echo(np.zeros(6)) == (0.0, pytest.approx(np.nan, nan_ok=True))
    weak = 0.5 * level / ac.gain_factor(0.0)  # the echo at 0 dB below half a level
    edge = solve_pose(
        cell, CORNER_MM + [SIZE_MM + 6.5, 150.0, PATH_MM], np.array([0.0, 0.0, -1.0]), q
    )  # the footprint's tail on the face
    raw = fine.ideal_echo(edge, gain_db=0.0)[0]
    assert 0.0 < raw < weak
    amp, tof = SimulatedCell(
        world.replace(pulser=PulserTruth(amplitude_bits=8)), threshold=0.0
    ).ideal_echo(edge, gain_db=0.0)
    assert amp == 0.0 and np.isnan(tof)


def test_gain_error_changes_the_amplitude_at_gain_changes_only(
    world: WorldTruth, cell: SimulatedCell
) -> None:
    from ucal.cell import PulserTruth

    q = normal_pose(cell, "z") + 0.1 * E5  # an echo at half screen: no saturation
    exact = SimulatedCell(world)
    erring = SimulatedCell(world.replace(pulser=PulserTruth(gain_error_db=0.5)))

    def ratio_db(gain_db: float) -> float:
        return 20.0 * np.log10(
            erring.echo(q, gain_db=gain_db)[0] / exact.echo(q, gain_db=gain_db)[0]
        )

    first = [ratio_db(20.0) for _ in range(5)]
    np.testing.assert_allclose(first, first[0], atol=1e-3)  # one gain, one error
    assert abs(first[0]) > 1e-3
    after = [ratio_db(14.0), ratio_db(14.0), ratio_db(20.0), ratio_db(20.0)]
    assert after[0] == pytest.approx(after[1], abs=1e-3)
    assert after[2] == pytest.approx(after[3], abs=1e-3)
    assert abs(after[0] - first[0]) > 1e-3 and abs(after[2] - first[0]) > 1e-3  # drawn anew
    # the errors are N(0, 0.5 dB)
    errors = [ratio_db(20.0 + (i % 2)) for i in range(400)]
    assert np.std(errors) == pytest.approx(0.5, rel=0.15)
    assert abs(np.mean(errors)) < 0.1
    # the gain error does not touch the time of flight
    assert erring.echo(q, gain_db=26.0)[1] == pytest.approx(exact.ideal_echo(q)[1], abs=0.01)


def test_the_electronic_delay_adds_a_constant(world: WorldTruth, cell: SimulatedCell) -> None:
    from ucal.cell import PulserTruth

    q = normal_pose(cell, "x")
    bare = SimulatedCell(world.replace(pulser=PulserTruth(delay_ns=0.0)))
    late = SimulatedCell(world.replace(pulser=PulserTruth(delay_ns=45.0)))  # 9 samples later
    for dq in (0.0, 0.03, 0.1):
        amp0, tof0 = bare.ideal_echo(q + dq * E5)
        amp1, tof1 = late.ideal_echo(q + dq * E5)
        assert tof1 - tof0 == pytest.approx(45.0, abs=1e-6)
        assert amp1 == pytest.approx(amp0, rel=1e-9)
    assert cell.ideal_echo(q)[1] - bare.ideal_echo(q)[1] == pytest.approx(
        DEFAULT_PULSER_DELAY_NS, abs=2 * DETECT_NS
    )


def test_gate_reads_geometry_plus_delay_within_a_fraction_of_a_ns(world: WorldTruth) -> None:
    q = normal_pose(SimulatedCell(world), "z")
    worst_ns = 0.0
    for dz in np.linspace(0.0, 0.04, 41):  # the TOF sweeps 54 ns, every sub-sample position
        c = SimulatedCell(
            world.replace(
                noise=Noise(seed=4),  # receiver noise only
                sample_position_mm=CORNER_MM - [0.0, 0.0, dz],
            )
        )
        geometry_ns = reading_tof_ns(c.hit(q).distance_mm)
        worst_ns = max(
            worst_ns, abs(c.ideal_echo(q)[1] - geometry_ns), abs(c.echo(q)[1] - geometry_ns)
        )
    assert worst_ns < DETECT_NS


def test_broadband_echo_is_not_the_fitted_directivity(cell: SimulatedCell) -> None:
    q = normal_pose(cell, "z")
    tilts = np.linspace(-0.3, 0.3, 61)
    amps = np.array([cell.ideal_echo(q + t * E5)[0] for t in tilts])
    assert tilts[np.argmax(amps)] == 0.0  # the peak is at normal incidence
    np.testing.assert_allclose(amps, amps[::-1], rtol=DETECT_REL)  # and symmetric about it
    path = cell.hit(q).distance_mm
    broadband = ac.REFERENCE_AMPLITUDE * ac.broadband_echo_factor(tilts, path, 25.0, 6.0, 20.0)
    main = np.abs(tilts) <= 0.25
    np.testing.assert_allclose(amps[main], broadband[main], rtol=1e-3)
    fitted = ac.REFERENCE_AMPLITUDE * ac.directivity(tilts, 25.0, 6.0, 20.0)
    assert amps[np.isclose(tilts, 0.3)][0] > 1.25 * fitted[np.isclose(tilts, 0.3)][0]


def test_same_world_and_seed_give_the_same_readings(world: WorldTruth, cell: SimulatedCell) -> None:
    from ucal.cell import PulserTruth

    rich = world.replace(
        noise=Noise(tof_ns=0.5, amplitude=0.01, seed=17),
        backlash_deg=np.full(6, 0.02),
        water_drift_c_per_min=0.2,
        pulser=PulserTruth(amplitude_bits=10, gain_error_db=0.3),
    )
    q = normal_pose(cell, "z")
    rng = np.random.default_rng(1)
    calls = [
        (
            q + rng.normal(0.0, 0.05, 6),
            float(rng.choice([14.0, 20.0, 26.0])),
            int(rng.integers(1, 17)),
            3.0 * i,
            rng.integers(-1, 2, 6),
        )
        for i in range(40)
    ]

    def run(w: WorldTruth) -> list[tuple[float, float]]:
        c = SimulatedCell(w)
        return [c.echo(j, averages=n, gain_db=g, t_s=t, motion_sign=s) for j, g, n, t, s in calls]

    a, b = run(rich), run(rich)
    np.testing.assert_array_equal(a, b)
    assert np.isfinite(np.array(a)[:, 1]).sum() > 10
    other = run(rich.replace(noise=Noise(tof_ns=0.5, amplitude=0.01, seed=18)))
    assert not np.array_equal(np.array(a), np.array(other))


def test_one_stream_per_effect(world: WorldTruth, cell: SimulatedCell) -> None:
    from ucal.cell import PulserTruth

    q = normal_pose(cell, "z") + 0.05 * E5
    base = world.replace(noise=Noise(tof_ns=0.5, amplitude=0.01, seed=23))
    with_gain_error = base.replace(pulser=PulserTruth(gain_error_db=0.5))
    plain, erring = SimulatedCell(base), SimulatedCell(with_gain_error)
    gains = [20.0, 14.0, 20.0, 8.0] * 5
    a = np.array([plain.echo(q, gain_db=g) for g in gains])
    b = np.array([erring.echo(q, gain_db=g) for g in gains])
    # adding the gain error leaves the TOF jitter and the relative amplitude noise as they were
    np.testing.assert_allclose(a[:, 1], b[:, 1], atol=1e-6)
    # and the amplitude differs by the gain error alone: one factor per gain setting
    ratio_db = 20.0 * np.log10(b[:, 0] / a[:, 0])
    assert np.std(ratio_db) > 0.05
    assert ratio_db[0] != pytest.approx(ratio_db[2], abs=1e-3)  # 20 dB again: a new error


def measured(path: Path, table: str, pose: dict[str, list[float]], reason: str) -> None:
    """Write a measured ``[tool]`` or ``[sample]`` pose as tool-frame and calibrate write it:
    the description it replaces kept beside it (``ucal.profile.described``)."""
    keys = pose | description_keys(
        load_profile(path), table, pose["position_mm"], pose["rotation_deg"]
    )
    write_profile(path, {table: keys}, reason)


def test_demo_truth_stays_one_cell_whatever_ucal_writes(tmp_path) -> None:
    """The demo's errors are added to the profile as described: a tool-frame or a calibration
    written into the profile does not move the demo's tool, table or block, and a profile
    copied without its history is the same cell."""
    path = create_profile(tmp_path / "cell.toml", "tx90l")
    first = demo_world(load_profile(path))
    tool = {"position_mm": [0.3, -0.2, 80.4], "rotation_deg": [0.2, -0.22, 0.0]}
    measured(path, "tool", tool, "tool-frame (exact)")
    rows = [dict(r) for r in tomlkit.parse(path.read_text())["robot"]["dh"]]
    rows[5]["alpha_deg"] = 0.3
    write_profile(path, {"calibration": {"dh": rows}}, "calibrate --level full")
    written = load_profile(path)
    assert written.tool_rotation_deg[0] == pytest.approx(0.2)  # the profile did change
    assert written.model.alpha_deg[5] == pytest.approx(0.3)
    after = demo_world(written)
    np.testing.assert_array_equal(after.tool_position_mm, first.tool_position_mm)
    np.testing.assert_array_equal(after.tool_rotation_deg, first.tool_rotation_deg)
    np.testing.assert_array_equal(after.model.alpha_deg, first.model.alpha_deg)
    # a hand edit is the cell's own description, not a measurement: the demo follows it
    write_profile(path, {"sample": {"position_mm": [700.0, 0.0, -400.0]}}, "the block moved")
    moved = demo_world(load_profile(path))
    np.testing.assert_allclose(moved.sample_position_mm - [700.0, 0.0, -400.0], [1.5, -1.0, 0.8])
    # calibrate writes the block it measured: a measurement, which the demo does not follow
    block = {"position_mm": [701.3, -0.8, -399.1], "rotation_deg": [0.001, -0.002, 0.0]}
    measured(path, "sample", block, "calibrate --method exact: fit ok")
    tool = {"position_mm": [0.3, -0.2, 80.3], "rotation_deg": [0.2, -0.22, 0.0]}
    measured(path, "tool", tool, "tool-frame (exact)")
    block = {"position_mm": [701.4, -0.8, -399.1], "rotation_deg": [0.001, -0.002, 0.0]}
    measured(path, "sample", block, "calibrate")
    again = demo_world(load_profile(path))
    np.testing.assert_allclose(again.sample_position_mm - [700.0, 0.0, -400.0], [1.5, -1.0, 0.8])
    np.testing.assert_array_equal(again.sample_rotation_deg, moved.sample_rotation_deg)
    np.testing.assert_array_equal(again.tool_position_mm, first.tool_position_mm)
    # a profile copied without its history is the same cell
    copy = tmp_path / "copy" / "cell.toml"
    copy.parent.mkdir()
    copy.write_bytes(path.read_bytes())
    alone = demo_world(load_profile(copy))
    for name in ("tool_position_mm", "tool_rotation_deg", "sample_position_mm"):
        np.testing.assert_array_equal(getattr(alone, name), getattr(again, name))
    np.testing.assert_array_equal(alone.model.alpha_deg, first.model.alpha_deg)
    # and a hand edit after it is the description again
    write_profile(path, {"sample": {"position_mm": [650.0, 0.0, -400.0]}}, "the block moved")
    last = demo_world(load_profile(path))
    np.testing.assert_allclose(last.sample_position_mm - [650.0, 0.0, -400.0], [1.5, -1.0, 0.8])
