"""The echoes besides the main one: the multiple, another face's, a corner's (``echoes``)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.optimize import least_squares

from ucal import acoustics as ac
from ucal.cell import CellProfile, Step, WorldTruth
from ucal.profile.models import load_model
from ucal.sim.cell import BLOCK_FACE_REFLECTION, TRANSDUCER_FACE_REFLECTION, SimulatedCell
from ucal.sim.rf import later_echoes

CORNER = np.array([600.0, -100.0, -350.0])  # the block's corner, its axes the base's
PATH_MM = 50.0


@pytest.fixture(scope="module")
def cell() -> SimulatedCell:
    profile = CellProfile(model=load_model("tx90l"), sample_position_mm=CORNER)
    return SimulatedCell(WorldTruth.nominal(profile))


def pose(cell: SimulatedCell, hit_mm: np.ndarray, tilt_deg: float) -> np.ndarray:
    """Readings with the true beam meeting the XY face at ``hit_mm`` (block frame, z = 0)
    ``PATH_MM`` away, leaning ``tilt_deg`` from its normal towards the YZ face (−x)."""
    t = math.radians(tilt_deg)
    beam = np.array([-math.sin(t), 0.0, -math.cos(t)])
    origin = CORNER + hit_mm - PATH_MM * beam

    def residual(q: np.ndarray) -> np.ndarray:
        o, d = cell.true_beam(q)
        return np.concatenate([o - origin, 100.0 * (d - beam)])

    guess = np.array([-10.0, 30.0, 110.0, 0.0, 40.0, 0.0])
    return least_squares(residual, guess, xtol=1e-14, ftol=1e-14, gtol=1e-14).x


def path_mm(cell: SimulatedCell, tof_ns: float) -> float:
    c_mm_ns = cell.sound_speed_m_s() * 1e-6
    return 0.5 * (tof_ns - cell.world.pulser.delay_ns) * c_mm_ns


def test_far_from_the_corner_the_main_echo_and_its_multiple(cell: SimulatedCell) -> None:
    q = pose(cell, np.array([100.0, 100.0, 0.0]), 0.0)
    (tof, amplitude), (tof2, amplitude2) = cell.echoes(q)
    assert (amplitude, tof) == pytest.approx(cell.ideal_echo(q), rel=1e-4)
    assert path_mm(cell, tof) == pytest.approx(PATH_MM, abs=1e-6)
    assert path_mm(cell, tof2) == pytest.approx(2 * PATH_MM, abs=1e-6)
    # the model: R_transducer · R_block · the echo at twice the path (absorption) = 8.1 %
    ratio = amplitude2 / amplitude
    assert ratio == pytest.approx(0.081, abs=0.002)
    assert 0.03 < ratio < 0.2
    rough = TRANSDUCER_FACE_REFLECTION * BLOCK_FACE_REFLECTION * ac.water_attenuation(100.0, 25.0)
    assert rough < ratio < 2 * rough  # absorption downshifts the spectrum: it takes less
    # a gate that ends before the multiple keeps the main echo alone
    assert cell.echoes(q, gate_ns=(0.0, 100_000.0)) == [(tof, amplitude)]


def test_near_the_corner_a_corner_echo_at_the_edge_path(cell: SimulatedCell) -> None:
    tilt = 1.0
    hit = np.array([1.0, 100.0, 0.0])  # 1 mm from the YZ face
    q = pose(cell, hit, tilt)
    echoes = cell.echoes(q)
    assert len(echoes) == 3
    main, corner, multiple = echoes
    # the corner returns as if from its edge: the path along the beam to the edge x = 0
    t = math.radians(tilt)
    expected = PATH_MM + hit[0] * math.sin(t)
    assert path_mm(cell, corner[0]) == pytest.approx(expected, abs=0.1)
    assert path_mm(cell, corner[0]) == pytest.approx(expected, abs=1e-4)
    # the rays that meet both faces (0.87 mm either side of the edge, a band of 50 mm·sin 1°)
    # and return onto the element (6 mm): 32 % of it, × R_block, × 0.8 of full screen
    assert 0.15 < corner[1] < 0.35
    assert corner[1] > main[1]  # 1° off the XY face's normal its own echo is weak
    assert multiple[0] > corner[0]
    # at normal incidence no ray meets the YZ face: no corner echo
    q0 = pose(cell, hit, 0.0)
    assert len(cell.echoes(q0)) == 2
    # relative to the main one for the RF output
    later = later_echoes(echoes)
    assert later[0] == pytest.approx((corner[0] - main[0], corner[1] / main[1]))


def test_a_step_in_the_footprint_gives_the_face_under_it_its_own_echo() -> None:
    step = Step(centre_mm=np.array([100.0, 100.0]), size_mm=20.0, height_mm=2.0)
    profile = CellProfile(model=load_model("tx90l"), sample_position_mm=CORNER)
    cell = SimulatedCell(WorldTruth.nominal(profile).replace(step=step))
    # the axis on the step, 0.5 mm inside its edge: the footprint's outer part reaches the face
    q = pose(cell, np.array([109.5, 100.0, 2.0]), 0.0)
    main, face, _ = cell.echoes(q)[:3]
    assert path_mm(cell, main[0]) == pytest.approx(PATH_MM, abs=1e-6)
    assert path_mm(cell, face[0]) == pytest.approx(PATH_MM + 2.0, abs=1e-6)
    # the shares: Φ(0.5/σ) on the step, the rest on the face (σ 1.5 mm widened by the spread),
    # 2 mm more of water for the face's echo
    assert main[1] / 0.8 == pytest.approx(ac.edge_share(0.5, 1.5), rel=0.01)
    absorbed = ac.broadband_echo_factor(0.0, PATH_MM + 2.0, 25.0, 6.0, 20.0)
    assert face[1] / 0.8 / absorbed == pytest.approx(1.0 - ac.edge_share(0.5, 1.5), rel=0.02)


def test_a_step_beside_the_beam_leaves_the_face_under_it_its_echo() -> None:
    # the step's top 2 mm below the transducer, its edge 6 mm (4 σ of the footprint) beside the
    # axis: the sliver of the footprint on it does not take the face's echo
    step = Step(centre_mm=np.array([100.0, 100.0]), size_mm=20.0, height_mm=PATH_MM - 2.0)
    profile = CellProfile(model=load_model("tx90l"), sample_position_mm=CORNER)
    cell = SimulatedCell(WorldTruth.nominal(profile).replace(step=step))
    far = pose(cell, np.array([116.0, 100.0, 0.0]), 0.0)
    assert cell.hit(far).face.name == "z"
    amplitude, tof = cell.ideal_echo(far)
    assert path_mm(cell, tof) == pytest.approx(PATH_MM, abs=1e-4)
    assert amplitude / 0.8 == pytest.approx(1.0 - ac.edge_share(-6.0, 1.5), rel=1e-3)
    # half a mm beside it, 2 mm from the transducer: Φ(−0.5/σ) of the footprint on the step
    # gives the larger echo, the face's the smaller one after it
    near = pose(cell, np.array([110.5, 100.0, 0.0]), 0.0)
    assert cell.hit(near).face.name == "step"
    top, *others = cell.echoes(near)
    assert path_mm(cell, top[0]) == pytest.approx(2.0, abs=1e-6)
    face = [e for e in others if abs(path_mm(cell, e[0]) - PATH_MM) < 1e-6]
    assert len(face) == 1 and 0.1 < face[0][1] / top[1] < 1.0
