"""The simulated receiver: sampled broadband echoes and the peak-mode gate that measures them."""

from __future__ import annotations

import numpy as np
import pytest

from ucal import acoustics as ac
from ucal.sim.receiver import EchoReceiver

C_20 = ac.sound_speed_m_s(20.0)


@pytest.fixture(scope="module")
def rx() -> EchoReceiver:
    return EchoReceiver(25.0, 6.0)


def test_noise_free_detection_within_a_hundredth_of_a_ns(rx: EchoReceiver) -> None:
    spectrum = rx.spectrum(0.0, 50.0, C_20)
    assert spectrum.sum() == pytest.approx(1.0)
    errors_ns, heights = [], []
    for arrival_ns in np.linspace(67_000.0, 67_010.0, 201):  # two samples, every sub-position
        t0_ns, samples = rx.waveform(arrival_ns, 0.8, spectrum)
        assert t0_ns <= arrival_ns <= t0_ns + rx.n * rx.sample_ns
        height, tof_ns = rx.detect(t0_ns, samples)
        errors_ns.append(tof_ns - arrival_ns)
        heights.append(height / 0.8)
    assert np.max(np.abs(errors_ns)) < 0.012
    assert np.max(np.abs(np.array(heights) - 1.0)) < 1.2e-4
    assert np.std(errors_ns) > 1e-4  # the parabola's bias depends on the sub-sample position


def test_the_echo_is_a_25_mhz_pulse_with_a_25_ns_envelope(rx: EchoReceiver) -> None:
    t0_ns, samples = rx.waveform(1000.0, 1.0, rx.spectrum(0.0, 50.0, C_20))
    t_ns = t0_ns + np.arange(rx.n) * rx.sample_ns
    env = np.abs(samples)
    sigma_ns = np.sqrt(np.sum(env * (t_ns - 1000.0) ** 2) / np.sum(env))
    assert sigma_ns == pytest.approx(25.0, rel=0.02)
    rf = samples.real
    crossings = np.sum(np.diff(np.sign(rf[np.abs(t_ns - 1000.0) < 50.0])) != 0)
    assert crossings == pytest.approx(2 * 25e6 * 100e-9, abs=1)  # 5 periods over 100 ns
    assert rf[np.argmin(np.abs(t_ns - 1000.0))] == pytest.approx(1.0, abs=0.05)  # cosine


def test_the_peak_follows_the_broadband_echo_factor(rx: EchoReceiver) -> None:
    for tilt in (0.0, 0.05, 0.1, 0.2, 0.25):
        for path in (40.0, 50.0, 100.0, 150.0):
            height, _ = rx.detect(*rx.waveform(67_003.3, 1.0, rx.spectrum(tilt, path, C_20)))
            expected = ac.broadband_echo_factor(tilt, path, 25.0, 6.0, 20.0)
            # 1e-3 at 150 mm: the receiver has bins 3.125 MHz apart and no DC
            assert height == pytest.approx(expected, rel=1.5e-3)


def test_far_off_normal_the_echo_splits_into_edge_waves(rx: EchoReceiver) -> None:
    # 0.5°: the element's rim reflects ±a·sin 2θ / c = ±35 ns apart from its centre
    t0_ns, samples = rx.waveform(67_003.3, 1.0, rx.spectrum(0.5, 50.0, C_20))
    height, tof_ns = rx.detect(t0_ns, samples)
    assert abs(tof_ns - 67_003.3) > 20.0
    assert height > ac.broadband_echo_factor(0.5, 50.0, 25.0, 6.0, 20.0)


def test_warmer_water_widens_the_directivity(rx: EchoReceiver) -> None:
    cold_c, warm_c = ac.sound_speed_m_s(10.0), ac.sound_speed_m_s(30.0)
    cold = rx.detect(*rx.waveform(500.0, 1.0, rx.spectrum(0.2, 50.0, cold_c)))[0]
    warm = rx.detect(*rx.waveform(500.0, 1.0, rx.spectrum(0.2, 50.0, warm_c)))[0]
    assert warm > cold  # faster sound, longer wavelength, wider beam


def test_receiver_noise_moves_the_reading_by_its_share(rx: EchoReceiver) -> None:
    rng = np.random.default_rng(0)
    spectrum = rx.spectrum(0.0, 50.0, C_20)
    sigma = 1e-3  # per quadrature component, for an echo of height 1: SNR 60 dB
    tofs, heights = [], []
    for _ in range(400):
        t0_ns, samples = rx.waveform(5000.0, 1.0, spectrum)
        z = rng.standard_normal(2 * rx.n)
        h, t = rx.detect(t0_ns, samples + sigma * (z[: rx.n] + 1j * z[rx.n :]))
        tofs.append(t)
        heights.append(h)
    assert np.std(heights) == pytest.approx(sigma, rel=0.3)
    assert 0.005 < np.std(tofs) < 0.2  # ns: a fraction of the 25 ns envelope times the noise
    assert np.mean(tofs) == pytest.approx(5000.0, abs=0.02)
