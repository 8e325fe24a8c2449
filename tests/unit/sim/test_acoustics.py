"""Acoustics of the simulated cell: sound speed, time of flight, directivity, footprint."""

from __future__ import annotations

import numpy as np
import pytest

from ucal import acoustics as ac


def test_sound_speed_at_20c_is_marczak_value() -> None:
    assert ac.sound_speed_m_s(20.0) == pytest.approx(1482.38, abs=0.01)


def test_sound_speed_has_its_maximum_near_74c() -> None:
    t = np.linspace(0.0, 95.0, 951)
    assert t[np.argmax(ac.sound_speed_m_s(t))] == pytest.approx(74.0, abs=1.0)


def test_tof_of_50mm_path_at_20c() -> None:
    assert ac.tof_ns(50.0, 20.0) == pytest.approx(67460.0, abs=10.0)


def test_water_path_inverts_tof() -> None:
    paths = np.array([1.0, 37.5, 50.0, 180.0])
    for temp in (5.0, 20.0, 35.0):
        np.testing.assert_allclose(
            ac.water_path_mm(ac.tof_ns(paths, temp), temp), paths, rtol=1e-12
        )
    # warmer water is faster: a shorter TOF for the same path
    assert ac.tof_ns(50.0, 30.0) < ac.tof_ns(50.0, 20.0)


def test_directivity_half_amplitude_at_0_2_deg() -> None:
    normal = ac.directivity(0.0, 25.0, 6.0, 20.0)
    assert normal == pytest.approx(1.0)
    assert 0.45 <= ac.directivity(0.2, 25.0, 6.0, 20.0) / normal <= 0.55


def test_minus_6db_half_angle() -> None:
    half = ac.directivity_half_angle_deg(0.5, 25.0, 6.0, 20.0)
    assert half == pytest.approx(0.20, abs=0.005)
    assert ac.directivity(half, 25.0, 6.0, 20.0) == pytest.approx(0.5, abs=1e-9)


def test_directivity_is_even_and_falls_in_the_main_lobe() -> None:
    tilts = np.linspace(0.0, 0.3, 31)
    d = ac.directivity(tilts, 25.0, 6.0, 20.0)
    assert np.all(np.diff(d) < 0.0)
    np.testing.assert_allclose(ac.directivity(-tilts, 25.0, 6.0, 20.0), d)


def test_first_null_of_the_main_lobe() -> None:
    # 2·J1(x)/x has its first zero at x = 3.8317
    ka = ac.wavenumber_per_mm(25.0, 20.0) * 3.0
    null_deg = np.degrees(np.arcsin(3.8317 / ka) / 2.0)
    assert ac.directivity(null_deg, 25.0, 6.0, 20.0) < 1e-3


def test_footprint_sigma_is_a_quarter_of_the_element() -> None:
    assert ac.footprint_sigma_mm(6.0) == pytest.approx(1.5)


def test_edge_share() -> None:
    sigma = ac.footprint_sigma_mm(6.0)
    assert ac.edge_share(0.0, sigma) == pytest.approx(0.5)
    assert ac.edge_share(10.0, sigma) == pytest.approx(1.0, abs=1e-9)
    assert ac.edge_share(-10.0, sigma) == pytest.approx(0.0, abs=1e-9)
    assert ac.edge_share(sigma, sigma) == pytest.approx(0.8413, abs=1e-4)


def test_rectangle_share_on_an_edge_inside_and_off_the_face() -> None:
    sigma = 1.5
    # axis on the u_min edge, mid-height of a 300 mm face
    assert ac.rectangle_share(np.array([0.0, 300.0, 150.0, 150.0]), sigma) == pytest.approx(0.5)
    assert ac.rectangle_share(np.array([150.0, 150.0, 150.0, 150.0]), sigma) == pytest.approx(1.0)
    # on a corner: a quarter
    assert ac.rectangle_share(np.array([0.0, 300.0, 0.0, 300.0]), sigma) == pytest.approx(0.25)
    # 10 mm off the face
    assert ac.rectangle_share(np.array([-10.0, 310.0, 150.0, 150.0]), sigma) < 1e-9


def test_rectangle_share_is_the_2d_integral() -> None:
    # Monte Carlo of the isotropic Gaussian footprint on a narrow 4 mm × 300 mm strip
    rng = np.random.default_rng(7)
    sigma = 1.5
    pts = rng.normal(0.0, sigma, size=(200_000, 2)) + np.array([1.0, 0.5])
    inside = (pts[:, 0] >= 0) & (pts[:, 0] <= 4) & (pts[:, 1] >= 0) & (pts[:, 1] <= 300)
    share = ac.rectangle_share(np.array([1.0, 3.0, 0.5, 299.5]), sigma)
    assert share == pytest.approx(inside.mean(), abs=0.005)


def test_one_hit_share_is_its_row_of_a_batch_bit_for_bit() -> None:
    # a single hit (every simulated reading) takes a path of its own on Python floats
    edges = np.random.default_rng(7).normal(0.0, 3.0, size=(400, 4))
    batch = ac.rectangle_share(edges, 1.5)
    singles = [ac.rectangle_share(row, 1.5) for row in edges]
    assert singles == batch.tolist()
    assert min(singles) == 0.0 and 0.5 < max(singles) < 1.0


def test_gain_and_saturation() -> None:
    assert ac.gain_factor(26.0) == pytest.approx(1.9953, abs=1e-4)
    assert ac.gain_factor(20.0) == 1.0
    base = ac.echo_amplitude(0.0, 1.0, 50.0, 20.0, 25.0, 6.0, 20.0)
    assert base == pytest.approx(ac.REFERENCE_AMPLITUDE)
    assert ac.echo_amplitude(0.0, 1.0, 50.0, 14.0, 25.0, 6.0, 20.0) == pytest.approx(
        base / 1.9953, rel=1e-4
    )
    assert ac.echo_amplitude(0.0, 1.0, 50.0, 26.0, 25.0, 6.0, 20.0) == 1.0


def test_water_attenuation_grows_with_path_and_frequency() -> None:
    assert ac.water_attenuation(50.0, 25.0) == 1.0
    per_mm_db = -20.0 * np.log10(ac.water_attenuation(51.0, 25.0))
    assert per_mm_db == pytest.approx(0.275, abs=0.01)
    assert ac.water_attenuation(60.0, 10.0) > ac.water_attenuation(60.0, 25.0)


def test_pulse_spectrum_has_its_bandwidth() -> None:
    assert ac.pulse_spectrum(25.0, 25.0) == 1.0
    for edge in (25.0 * (1 - 0.3), 25.0 * (1 + 0.3)):  # −6 dB at f_c·(1 ± bw/2)
        assert ac.pulse_spectrum(edge, 25.0, 0.6) == pytest.approx(0.5)


def test_broadband_directivity_peaks_at_normal_incidence_and_is_not_the_fitted_one() -> None:
    tilts = np.linspace(-1.0, 1.0, 401)
    broadband = ac.broadband_directivity(tilts, 25.0, 6.0, 20.0)
    assert tilts[np.argmax(broadband)] == 0.0
    assert np.max(broadband) == pytest.approx(1.0)
    np.testing.assert_allclose(broadband, broadband[::-1])
    assert 0.45 <= ac.broadband_directivity(0.2, 25.0, 6.0, 20.0) <= 0.55
    narrow = ac.directivity(tilts, 25.0, 6.0, 20.0)
    assert np.max(np.abs(broadband - narrow)) > 0.03
    assert ac.broadband_directivity(0.3, 25.0, 6.0, 20.0) == pytest.approx(0.167, abs=0.005)
    assert ac.directivity(0.3, 25.0, 6.0, 20.0) == pytest.approx(0.125, abs=0.005)
    # a narrow band tends to the centre frequency's function
    np.testing.assert_allclose(
        ac.broadband_directivity(tilts, 25.0, 6.0, 20.0, 0.01), narrow, atol=2e-3
    )


def test_broadband_absorption_downshifts_the_spectrum() -> None:
    at_ref = ac.broadband_echo_factor(0.0, ac.REFERENCE_WATER_PATH_MM, 25.0, 6.0, 20.0)
    assert at_ref == pytest.approx(1.0)
    # the pulse's low frequencies carry further than its centre frequency
    assert ac.broadband_echo_factor(0.0, 100.0, 25.0, 6.0, 20.0) > ac.water_attenuation(100.0, 25.0)
    assert ac.broadband_echo_factor(0.0, 40.0, 25.0, 6.0, 20.0) > 1.0
    # so the main lobe widens with the path
    half = [
        ac.broadband_echo_factor(0.2, p, 25.0, 6.0, 20.0)
        / ac.broadband_echo_factor(0.0, p, 25.0, 6.0, 20.0)
        for p in (50.0, 100.0, 150.0)
    ]
    assert half[0] == pytest.approx(0.5, abs=0.01)
    assert half[0] < half[1] < half[2]
