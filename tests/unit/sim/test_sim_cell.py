"""The simulated cell: echoes from the calibration block and plate at joint readings."""

from __future__ import annotations

import time

import numpy as np
import pytest
from scipy.optimize import least_squares

from ucal import acoustics as ac
from ucal.cell import CellProfile, Noise, Reflector, WorldTruth
from ucal.kinematics.dh import fk
from ucal.kinematics.rotations import angle_between_deg
from ucal.models import load_model
from ucal.sim.cell import SimulatedCell, ideal_echo
from ucal.sim.demo import DEMO_JOINT_OFFSETS_DEG, demo_world
from ucal.sim.geometry import block_faces, intersect

CORNER_MM = np.array([450.0, -150.0, -450.0])
SIZE_MM = 300.0
PATH_MM = 50.0
C_20 = ac.sound_speed_m_s(20.0)


@pytest.fixture(scope="module")
def profile() -> CellProfile:
    return CellProfile(model=load_model("tx90l"), sample_position_mm=CORNER_MM.copy(),
                       sample_face_size_mm=SIZE_MM)


@pytest.fixture(scope="module")
def world(profile: CellProfile) -> WorldTruth:
    return WorldTruth.nominal(profile)


@pytest.fixture(scope="module")
def cell(world: WorldTruth) -> SimulatedCell:
    return SimulatedCell(world)


def solve_pose(cell: SimulatedCell, tcp_mm: np.ndarray, beam: np.ndarray,
               guess_deg: np.ndarray) -> np.ndarray:
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
    return solve_pose(cell, np.asarray(tcp, float), np.asarray(beam, float),
                      np.asarray(guess, float))


def test_true_flange_matches_dh_fk_with_offsets(profile: CellProfile, world: WorldTruth) -> None:
    offsets = np.array([0.3, -0.7, 1.1, 2.0, -0.4, 0.9])
    w = world.replace(joint_offsets_deg=offsets, tool_position_mm=np.array([1.0, -2.0, 90.0]),
                      tool_rotation_deg=np.array([0.5, -0.3, 10.0]))
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
    assert tof == pytest.approx(2.0 * PATH_MM * 1e6 / C_20, abs=1e-6)
    assert tof == pytest.approx(67459.1, abs=0.1)
    assert amp == pytest.approx(ac.REFERENCE_AMPLITUDE, abs=1e-9)
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
    ratio = amp / ac.water_attenuation(hit.distance_mm, 25.0) / ac.REFERENCE_AMPLITUDE
    assert 0.45 <= ratio <= 0.55


def test_hidden_offset_follows_the_spec_sign(world: WorldTruth, cell: SimulatedCell) -> None:
    q = normal_pose(cell, "z")
    offsets = np.array([0.8, -1.2, 1.5, -2.0, 1.1, 0.6])
    hidden = SimulatedCell(world.replace(joint_offsets_deg=offsets))
    # actual = reading + offset: reading q − offset reaches the pose of q
    np.testing.assert_allclose(hidden.ideal_echo(q - offsets), cell.ideal_echo(q), atol=1e-6)
    assert hidden.ideal_echo(q)[0] < 0.01  # the uncorrected reading is degrees off normal


def test_joint1_offset_keeps_a_vertical_beam_and_its_tof(world: WorldTruth,
                                                        cell: SimulatedCell) -> None:
    # joint 1 turns about the vertical: the beam stays normal to face z, at the same height
    q = normal_pose(cell, "z")
    hidden = SimulatedCell(world.replace(joint_offsets_deg=np.array([1.0, 0, 0, 0, 0, 0])))
    amp, tof = hidden.ideal_echo(q)
    assert amp == pytest.approx(ac.REFERENCE_AMPLITUDE, abs=1e-9)
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
    assert tof == pytest.approx(2.0 * path * 1e6 / C_20, abs=1e-6)
    assert amp == pytest.approx(ac.REFERENCE_AMPLITUDE * ac.water_attenuation(path, 25.0),
                                abs=1e-9)


def test_half_echo_with_the_beam_axis_on_an_edge(cell: SimulatedCell) -> None:
    # the far edge u = S of face z (not shared with another face)
    q = solve_pose(cell, CORNER_MM + [SIZE_MM, 150.0, PATH_MM], np.array([0.0, 0.0, -1.0]),
                   np.array([0, 30, 110, 0, 40, 0], float))
    amp, tof = cell.ideal_echo(q)
    assert amp == pytest.approx(0.5 * ac.REFERENCE_AMPLITUDE, abs=1e-6)
    assert np.isfinite(tof)
    q_off = solve_pose(cell, CORNER_MM + [SIZE_MM + 10.0, 150.0, PATH_MM],
                       np.array([0.0, 0.0, -1.0]), q)
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
    q = solve_pose(c, np.array([700.0, 300.0, -240.0]), np.array([0.0, 0.0, -1.0]),
                   np.array([30, 30, 110, 0, 40, 0], float))
    hit = c.hit(q)
    assert hit.face.name == "reflector"
    amp, tof = c.ideal_echo(q)
    assert tof == pytest.approx(2.0 * 60.0 * 1e6 / C_20, abs=1e-6)
    assert amp == pytest.approx(ac.REFERENCE_AMPLITUDE * ac.water_attenuation(60.0, 25.0))
    assert np.isnan(cell.ideal_echo(q)[1])  # no plate in the plain world


def test_gain_scales_and_saturates(cell: SimulatedCell) -> None:
    q = normal_pose(cell, "z")
    assert cell.ideal_echo(q, gain_db=14.0)[0] == pytest.approx(0.8 / ac.gain_factor(26.0))
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
    # zero noise: echo is the ideal echo
    assert cell.echo(q) == pytest.approx(cell.ideal_echo(q))


def test_echo_is_fast(cell: SimulatedCell) -> None:
    q = normal_pose(cell, "y")
    t0 = time.perf_counter()
    for _ in range(1000):
        cell.echo(q)
    assert time.perf_counter() - t0 < 1.0  # about 35 µs each on a laptop


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
