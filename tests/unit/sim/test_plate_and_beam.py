"""A realistic plate and beam: rounded edges, flatness error, beam squint, near-field directivity
(each changes the readings the way the physics says; the same world and seed, the same
readings)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import least_squares

from ucal import acoustics as ac
from ucal.cell import CellProfile, Noise, Reflector, WorldTruth
from ucal.kinematics.dh import fk
from ucal.kinematics.rotations import angle_between_deg
from ucal.profile.models import load_model
from ucal.sim.cell import SimulatedCell
from ucal.sim.receiver import EchoReceiver

CENTRE = np.array([700.0, 300.0, -300.0])
DOWN = np.array([0.0, 0.0, -1.0])
PLATE = Reflector(point_mm=CENTRE, normal=np.array([0.0, 0.0, 1.0]))


@pytest.fixture(scope="module")
def world() -> WorldTruth:
    profile = CellProfile(model=load_model("tx90l"), sample_position_mm=np.array([0, 0, -2000.0]))
    return WorldTruth.nominal(profile).replace(reflector=PLATE)


def pose(cell: SimulatedCell, tcp_mm: np.ndarray, guess: np.ndarray | None = None) -> np.ndarray:
    """Readings with the true acoustic axis straight down from ``tcp_mm``."""

    def residual(q: np.ndarray) -> np.ndarray:
        origin, beam = cell.true_beam(q)
        return np.concatenate([origin - tcp_mm, 100.0 * (beam - DOWN)])

    g = np.array([30, 30, 110, 0, 40, 0], float) if guess is None else guess
    return least_squares(residual, g, xtol=1e-14, ftol=1e-14, gtol=1e-14).x


def test_squint_tilts_the_acoustic_axis_from_the_housing(world: WorldTruth) -> None:
    cell = SimulatedCell(world.replace(beam_squint_deg=0.8, beam_squint_azimuth_deg=30.0))
    q = np.array([10.0, 20.0, 100.0, 5.0, 40.0, 15.0])
    housing_z = (fk(world.model, q) @ world.tool_matrix)[:3, 2]
    _, beam = cell.true_beam(q)
    assert angle_between_deg(beam, housing_z) == pytest.approx(0.8, abs=1e-9)
    # towards the azimuth: in the housing frame the beam leans along (cos 30°, sin 30°)
    local = (fk(world.model, q) @ world.tool_matrix)[:3, :3].T @ beam
    assert np.degrees(np.arctan2(local[1], local[0])) == pytest.approx(30.0, abs=1e-6)
    assert world.beam_matrix[:3, 3] == pytest.approx(world.tool_matrix[:3, 3])


def edge_crossing_mm(cell: SimulatedCell) -> float:
    """Where the echo falls to half along +x from the plate centre (mm from the centre)."""
    ts = np.arange(90.0, 110.01, 0.5)
    q = pose(cell, CENTRE + [ts[0], 0.0, 60.0])
    amps = []
    for t in ts:
        q = pose(cell, CENTRE + [t, 0.0, 60.0], q)
        amps.append(cell.ideal_echo(q)[0])
    amps = np.array(amps) / amps[0]
    i = int(np.nonzero(amps < 0.5)[0][0])
    return float(np.interp(0.5, amps[[i, i - 1]], ts[[i, i - 1]]))


def test_rounded_edges_move_the_half_echo_inward_by_the_radius(world: WorldTruth) -> None:
    sharp = edge_crossing_mm(SimulatedCell(world))
    rounded = edge_crossing_mm(
        SimulatedCell(world.replace(reflector=Reflector(CENTRE, PLATE.normal, edge_radius_mm=3.0)))
    )
    assert sharp == pytest.approx(100.0, abs=0.05)
    assert sharp - rounded == pytest.approx(3.0, abs=0.05)


def test_a_bowed_plate_changes_path_and_normal_across_it(world: WorldTruth) -> None:
    f = 0.4
    flat = SimulatedCell(world)
    bowed = SimulatedCell(world.replace(reflector=Reflector(CENTRE, PLATE.normal, flatness_mm=f)))
    q = pose(flat, CENTRE + [0.0, 0.0, 60.0])
    # at the centre the surface lies f/2 below the plane of the plate's point
    assert bowed.hit(q).distance_mm - flat.hit(q).distance_mm == pytest.approx(f / 2, abs=1e-9)
    c = ac.sound_speed_m_s(20.0)
    dt = bowed.ideal_echo(q)[1] - flat.ideal_echo(q)[1]
    assert dt == pytest.approx(2 * (f / 2) * 1e6 / c, abs=0.02)
    # 50 mm out along u the local normal leans by the slope 4f·u/w² (w = 200 mm)
    q = pose(flat, CENTRE + [50.0, 0.0, 60.0], q)
    assert bowed.hit(q).tilt_deg == pytest.approx(
        np.degrees(np.arctan(4 * f * 50 / 200**2)), rel=1e-3
    )
    assert flat.hit(q).tilt_deg == pytest.approx(0.0, abs=1e-6)


def test_near_field_narrows_the_lobe_more_at_short_water_paths() -> None:
    plain = EchoReceiver(25.0, 6.0)
    near = EchoReceiver(25.0, 6.0, near_field=True)
    c = ac.sound_speed_m_s(20.0)
    for path in (50.0, 100.0):
        assert near.spectrum(0.0, path, c).sum() == pytest.approx(
            plain.spectrum(0.0, path, c).sum()
        )
    ratio = {
        path: near.spectrum(0.15, path, c).sum() / plain.spectrum(0.15, path, c).sum()
        for path in (50.0, 100.0, 1000.0)
    }
    assert ratio[50.0] < 0.99 and ratio[100.0] < ratio[50.0]
    assert ratio[1000.0] > 0.99  # far field: the piston directivity alone


def test_same_world_and_seed_give_the_same_readings_with_the_new_effects(world: WorldTruth) -> None:
    w = world.replace(
        beam_squint_deg=0.7,
        near_field=True,
        reflector=Reflector(CENTRE, PLATE.normal, edge_radius_mm=2.0, flatness_mm=0.05),
        noise=Noise(tof_ns=0.5, amplitude=0.01, seed=5),
    )
    q = pose(SimulatedCell(w), CENTRE + [20.0, 10.0, 60.0])
    a, b = SimulatedCell(w), SimulatedCell(w)
    assert [a.echo(q, 4) for _ in range(5)] == [b.echo(q, 4) for _ in range(5)]
