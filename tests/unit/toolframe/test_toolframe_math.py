"""Tool-frame maths without processes: plane fit, paper 002's KKT solver, our exact method."""

from __future__ import annotations

import numpy as np
import pytest

from ucal.errors import InputError, ProfileError
from ucal.kinematics.dh import transform
from ucal.kinematics.rotations import angle_between_deg, rpy_to_matrix, tangent_basis
from ucal.measure.edges import fit_edge_profile
from ucal.toolframe.exact import (
    EdgeCrossing,
    TofRecord,
    along_beam_offset_mm,
    beam_from_normal_incidence,
    rot_about,
    rotation_for_beam,
    solve_offsets,
)
from ucal.toolframe.paper import residuals_mm, solve_paper
from ucal.toolframe.plan import tcp_pose
from ucal.toolframe.plane import fit_plane, hull_reach_mm

TRUE_P = np.array([2.5, -3.0, 83.5])
TRUE_ROT = np.array([1.2, -0.8, 5.0])
TRUE_A = rpy_to_matrix(TRUE_ROT)[:, 2]
SQUARE = np.array([[500.0, -100.0, -200.0], [620.0, -100.0, -200.0], [560.0, 20.0, -200.0]])


def tilted_points() -> np.ndarray:
    """Four points on a plate tilted 3° about x, 2° about y."""
    rot = rpy_to_matrix([3.0, 2.0, 0.0])
    uv = np.array([[-60.0, -40.0, 0.0], [60.0, -40.0, 0.0], [0.0, 80.0, 0.0], [30.0, 30.0, 0.0]])
    return uv @ rot.T + np.array([600.0, -50.0, -220.0])


def flange_for(
    tool_p: np.ndarray,
    tool_a: np.ndarray,
    hit: np.ndarray,
    beam: np.ndarray,
    path: float,
    phi_deg: float,
) -> np.ndarray:
    """Flange pose whose tool (p, a) sends the beam along ``beam`` to ``hit`` after ``path``;
    ``phi_deg`` turns the flange about the beam."""
    z = beam / np.linalg.norm(beam)
    axis = np.cross(tool_a, z)
    s = np.linalg.norm(axis)
    r0 = rot_about(axis / s, float(np.arctan2(s, tool_a @ z))) if s > 1e-15 else np.eye(3)
    r = rot_about(z, np.radians(phi_deg)) @ r0  # r @ tool_a = z
    c = hit - path * z
    return transform(c - r @ tool_p, r)


# --- plane ---------------------------------------------------------------------------------


def test_plane_three_points_is_paper_eq_9_10() -> None:
    plane = fit_plane(SQUARE)
    a, b, c = SQUARE
    n = np.cross(b - a, c - a)
    n /= np.linalg.norm(n)
    assert abs(abs(plane.normal @ n) - 1.0) < 1e-14
    assert plane.normal[2] > 0  # towards the robot base above the plate
    np.testing.assert_allclose(plane.distance_mm(SQUARE), 0.0, atol=1e-10)
    assert plane.rms_mm < 1e-10
    assert abs(plane.e1 @ plane.normal) < 1e-14 and abs(plane.e2 @ plane.normal) < 1e-14


def test_plane_least_squares_beyond_three_points() -> None:
    pts = tilted_points()
    rng = np.random.default_rng(3)
    noisy = pts + rng.normal(0.0, 0.01, pts.shape)
    plane = fit_plane(noisy)
    true_n = rpy_to_matrix([3.0, 2.0, 0.0])[:, 2]
    assert angle_between_deg(plane.normal, true_n) < 0.05
    # the SVD plane minimises the squared distances: any other plane through the centroid
    # with a slightly turned normal fits worse
    base = np.sum(plane.distance_mm(noisy) ** 2)
    for d in (plane.e1, plane.e2):
        n2 = plane.normal + 1e-3 * d
        n2 /= np.linalg.norm(n2)
        assert np.sum(((noisy - plane.centroid_mm) @ n2) ** 2) > base
    assert plane.n_points == 4


@pytest.mark.parametrize(
    "points, words",
    [
        (SQUARE[:2], "at least three points"),
        ([[0, 0, 0], [10, 0, 0], [20, 0, 0]], "collinear"),
        ([[0, 0, 0], [10, 0, 0], [0.001, 0, 0], [0, 10, 0]], "duplicates"),
        (None, "missing"),
    ],
)
def test_plane_bad_points_name_the_key(points: object, words: str) -> None:
    with pytest.raises(InputError) as err:
        fit_plane(points)
    assert "reflector.points_mm" in str(err.value) and words in str(err.value)
    with pytest.raises(ProfileError) as err2:
        fit_plane(points, path="cell.toml")
    assert str(err2.value).startswith("cell.toml: reflector.points_mm: ")
    assert err2.value.exit_code == 2


def test_hull_reach() -> None:
    plane = fit_plane(SQUARE)
    centre = SQUARE.mean(0)
    # from the centroid (560, -60) along +x the hull edge (620,-100)-(560,20) is at x = 600
    assert hull_reach_mm(plane, SQUARE, plane.e1, centre) == pytest.approx(40.0, abs=1e-9)
    assert hull_reach_mm(plane, SQUARE, -plane.e2, centre) == pytest.approx(40.0, abs=1e-9)
    assert hull_reach_mm(plane, SQUARE, plane.e1, centre + [500.0, 0.0, 0.0]) == 0.0


# --- paper 002 -----------------------------------------------------------------------------


def paper_data(tilt_deg: float, m: int, seed: int) -> tuple:
    """Flange poses and water paths for incidence points with beam tilts up to ``tilt_deg``."""
    plane = fit_plane(tilted_points())
    rng = np.random.default_rng(seed)
    rots, poss, paths = [], [], []
    for _ in range(m):
        hit = plane.centroid_mm + rng.uniform(-40, 40) * plane.e1 + rng.uniform(-40, 40) * plane.e2
        tilt = np.radians(tilt_deg) * rng.uniform(-1, 1, 2)
        beam = -plane.normal + tilt[0] * plane.e1 + tilt[1] * plane.e2
        beam /= np.linalg.norm(beam)
        path = rng.uniform(60.0, 140.0)  # along the beam
        f = flange_for(TRUE_P, TRUE_A, hit, beam, path, rng.uniform(-150, 150))
        rots.append(f[:3, :3])
        poss.append(f[:3, 3])
        paths.append(path)
    return plane, np.array(rots), np.array(poss), np.array(paths)


def test_paper_kkt_recovers_tool_with_tilted_incidence() -> None:
    plane, rots, poss, paths = paper_data(tilt_deg=10.0, m=30, seed=1)
    t_true = np.concatenate([TRUE_P, TRUE_A])
    np.testing.assert_allclose(residuals_mm(t_true, rots, poss, paths, plane), 0.0, atol=1e-9)
    sol = solve_paper(
        rots, poss, paths, plane, np.array([0.0, 0.0, 80.0]), np.array([0.0, 0.0, 1.0]), 1e-4
    )
    assert sol.converged and sol.second_order_ok
    np.testing.assert_allclose(sol.position_mm, TRUE_P, atol=1e-7)
    assert angle_between_deg(sol.beam, TRUE_A) < 1e-7
    assert sol.rms_residual_mm < 1e-9
    assert abs(np.linalg.norm(sol.beam) - 1.0) < 1e-14
    assert np.all(sol.reduced_hessian_eig > 0)


def test_paper_near_normal_incidence_is_ill_conditioned() -> None:
    """Within the echo's 0.3° the flat plate barely sees the offsets across the beam."""
    plane, rots, poss, paths = paper_data(tilt_deg=0.02, m=30, seed=2)
    rng = np.random.default_rng(5)
    noisy = paths + rng.normal(0.0, 0.0004, paths.shape)  # 0.5 ns of TOF
    sol = solve_paper(
        rots, poss, noisy, plane, np.array([0.0, 0.0, 80.0]), np.array([0.0, 0.0, 1.0]), 0.0004
    )
    assert sol.condition > 1e8
    assert any("ill-conditioned" in n for n in sol.notes)
    # what it does see: the offset along the beam
    assert abs(sol.beam @ sol.position_mm - TRUE_A @ TRUE_P) < 0.01
    # and the reported uncertainty across the beam is large, honestly
    assert np.max(sol.std_position_mm) > 0.05


# --- exact: (a) beam -----------------------------------------------------------------------


def test_beam_from_normal_incidence_is_exact() -> None:
    plane = fit_plane(tilted_points())
    rots = [
        flange_for(TRUE_P, TRUE_A, plane.centroid_mm, -plane.normal, 100.0, phi)[:3, :3]
        for phi in (0.0, 90.0, 180.0, 270.0)
    ]
    est = beam_from_normal_incidence(np.array(rots), plane.normal, np.full(4, 0.002))
    assert angle_between_deg(est.direction, TRUE_A) < 1e-10
    assert est.scatter_deg < 1e-10
    assert est.std_deg == pytest.approx(0.002 / 2.0)


def test_beam_scatter_inflates_std() -> None:
    plane = fit_plane(SQUARE)
    rng = np.random.default_rng(9)
    rots = []
    for phi in np.arange(0.0, 360.0, 45.0):
        f = flange_for(TRUE_P, TRUE_A, plane.centroid_mm, -plane.normal, 100.0, phi)
        jitter = rot_about(tangent_basis(plane.normal)[0], np.radians(0.05 * rng.normal()))
        rots.append(jitter @ f[:3, :3])
    est = beam_from_normal_incidence(np.array(rots), plane.normal, np.full(8, 0.001))
    assert est.std_deg > 0.01  # the 0.05° scatter, not the claimed 0.001°
    assert angle_between_deg(est.direction, TRUE_A) < 4 * est.std_deg


# --- exact: (E4) edge profile --------------------------------------------------------------


def test_edge_profile_fit() -> None:
    from scipy.special import ndtr

    t = np.linspace(95.0, 105.0, 21)
    a = 0.7 * ndtr((100.123 - t) / 1.5)
    fit = fit_edge_profile(t, a)
    assert fit.crossing == pytest.approx(100.123, abs=1e-7)
    assert fit.width_mm == pytest.approx(1.5, abs=1e-6)
    rng = np.random.default_rng(4)
    errs, stds = [], []
    for _ in range(40):
        noisy = a * (1 + 0.0025 * rng.standard_normal(a.shape))
        f = fit_edge_profile(t, noisy)
        errs.append(f.crossing - 100.123)
        stds.append(f.crossing_std)
    # reported σ matches the scatter (within a factor of 1.5)
    assert 0.67 < np.std(errs) / np.mean(stds) < 1.5
    with pytest.raises(ValueError, match="does not cross"):
        fit_edge_profile(t, np.full_like(t, 0.7))


@pytest.mark.parametrize(
    ("relative", "additive"),
    [(0.0025, 0.0), (0.0, 0.001)],
    ids=["relative", "additive"],
)
def test_edge_crossing_std_holds_whatever_the_noise(relative: float, additive: float) -> None:
    """The 50 % point's std covers its error whether the echo's noise is relative to the
    amplitude (large on the plate, nil off it), additive, or both: the rms of error / std over
    many scans is 1 (one variance for every probe gave about 1.5 with relative noise)."""
    from scipy.special import ndtr

    rng = np.random.default_rng(11)
    t = np.linspace(95.0, 105.0, 21)
    z = []
    for _ in range(100):
        edge = 100.0 + rng.uniform(-0.25, 0.25)
        clean = 0.4 * ndtr((edge - t) / 1.5)
        noisy = clean * (1 + relative * rng.standard_normal(21)) + additive * rng.normal(size=21)
        fit = fit_edge_profile(t, noisy)
        z.append((fit.crossing - edge) / fit.crossing_std)
    rms = float(np.sqrt(np.mean(np.square(z))))
    assert 0.8 < rms < 1.2
    assert np.mean(np.abs(z) <= 3.0) >= 0.95


# --- exact: (b) + (c) offsets -------------------------------------------------------------


def exact_data(edge_turn_deg: float) -> tuple:
    """Normal-incidence water paths and edge crossings of a plate whose edges are turned by
    ``edge_turn_deg`` from the nominal axes."""
    plane = fit_plane(tilted_points())
    c0 = plane.centroid_mm
    tofs = []
    for phi in (0.0, 90.0, 180.0, 270.0):
        f = flange_for(TRUE_P, TRUE_A, c0, -plane.normal, 100.0, phi)
        tofs.append(TofRecord(f, 100.0, 1e-4))
    crossings = []
    turn = np.radians(edge_turn_deg)
    for k, dist in ((0, 100.0), (1, 80.0)):
        psi = turn + k * np.pi / 2
        e = np.cos(psi) * plane.e1 + np.sin(psi) * plane.e2
        w = np.cross(plane.normal, e)
        for lateral in (-25.0, 25.0):
            for phi in (10.0, 190.0):
                hit = c0 + dist * e + lateral * w
                f = flange_for(TRUE_P, TRUE_A, hit, -plane.normal, 50.0, phi)
                scan = np.cos(k * np.pi / 2) * plane.e1 + np.sin(k * np.pi / 2) * plane.e2
                crossings.append(EdgeCrossing(f, k, 0.003, scan))
    return plane, tofs, crossings


def test_exact_offsets_recover_tool_with_turned_edges() -> None:
    plane, tofs, crossings = exact_data(edge_turn_deg=2.0)
    beam = beam_from_normal_incidence(
        np.array([t.flange[:3, :3] for t in tofs]), plane.normal, np.full(4, 0.001)
    )
    s, _ = along_beam_offset_mm(beam.direction, tofs, plane)
    assert s == pytest.approx(TRUE_A @ TRUE_P, abs=1e-9)
    est = solve_offsets(beam, tofs, crossings, plane, np.array([0.0, 0.0, 80.0]))
    np.testing.assert_allclose(est.position_mm, TRUE_P, atol=1e-8)
    np.testing.assert_allclose(est.edge_angles_deg, [2.0, 92.0], atol=1e-6)
    assert est.rms_residual_mm < 1e-9
    assert np.all(est.std_mm > 0) and np.all(est.std_mm < 0.01)
    assert not est.notes


def test_exact_offsets_need_both_edges() -> None:
    """One edge sees one component across the beam: the design is singular, and said so."""
    plane, tofs, crossings = exact_data(edge_turn_deg=0.0)
    beam = beam_from_normal_incidence(
        np.array([t.flange[:3, :3] for t in tofs]), plane.normal, np.full(4, 0.001)
    )
    est = solve_offsets(
        beam, tofs, [c for c in crossings if c.edge == 0], plane, np.array([0.0, 0.0, 80.0])
    )
    assert est.notes and "do not determine" in est.notes[0]


# --- rotation ------------------------------------------------------------------------------


def test_rotation_closest_to_nominal_maps_z_onto_beam() -> None:
    nominal = np.array([10.0, -20.0, 30.0])
    rot = rpy_to_matrix(rotation_for_beam(TRUE_A, nominal))
    assert angle_between_deg(rot[:, 2], TRUE_A) < 1e-10
    # the nominal beam gives back the nominal rotation
    same = rotation_for_beam(rpy_to_matrix(nominal)[:, 2], nominal)
    np.testing.assert_allclose(same, nominal, atol=1e-10)
    # any other rotation about the beam is farther from the nominal
    r0 = rpy_to_matrix(nominal)
    from ucal.kinematics.rotations import rotation_angle_deg

    best = rotation_angle_deg(r0, rot)
    for g in (-5.0, -0.5, 0.5, 5.0):
        assert rotation_angle_deg(r0, rot @ rot_about([0, 0, 1], np.radians(g))) > best


def test_tcp_pose_points_beam_at_target() -> None:
    plane = fit_plane(tilted_points())
    t = tcp_pose(plane, plane.centroid_mm, 75.0, 30.0)
    np.testing.assert_allclose(t[:3, 2], -plane.normal, atol=1e-15)
    np.testing.assert_allclose(t[:3, 3] + 75.0 * t[:3, 2], plane.centroid_mm, atol=1e-12)
    assert np.degrees(np.arctan2(t[:3, 0] @ plane.e2, t[:3, 0] @ plane.e1)) == pytest.approx(30)
