"""The RF output through water (world ``[water] absorption``), its baseline offset, and the
other faces' echoes in the A-scan where the geometry puts them."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import fft

from ucal.sim.ascan import TransducerPulse
from ucal.sim.rf import RfOutput

DT_NS, N = 2.0, 8192  # 500 MS/s, 16 µs
ARRIVAL_NS = 6000.0
#: Water's absorption, written out here: 2.17e-4 dB/(mm·MHz²) at 20 °C (Pinkerton).
ALPHA0_NP = 2.17e-4 * math.log(10.0) / 20.0


def mean_frequency_mhz(samples: np.ndarray) -> float:
    power = np.abs(fft.rfft(samples)) ** 2
    f = fft.rfftfreq(samples.size, DT_NS * 1e-3)
    return float(np.sum(f * power) / np.sum(power))


@pytest.mark.parametrize("path_mm", [20.0, 60.0, 120.0])
def test_the_echo_s_centre_frequency_falls_with_its_water_path_as_alpha_f2_says(
    path_mm: float,
) -> None:
    rf = RfOutput(25.0, noise_floor_fsh=1e-4, seed=1, water_absorption=True)
    record = rf.record(0.0, DT_NS, N, 0.5, ARRIVAL_NS, 0.0, water_mm=[path_mm])
    # independently: the transducer's spectrum times exp(−2·α₀·f²·L), its power's mean
    f = np.linspace(0.01, 150.0, 60_000)
    power = np.abs(TransducerPulse(25.0).spectrum(f)) ** 2 * np.exp(-4 * ALPHA0_NP * f**2 * path_mm)
    expected = float(np.sum(f * power) / np.sum(power))
    assert mean_frequency_mhz(record) == pytest.approx(expected, abs=0.05)
    # without the water the same echo keeps the transducer's own spectrum
    plain = RfOutput(25.0, noise_floor_fsh=1e-4, seed=1).record(
        0.0, DT_NS, N, 0.5, ARRIVAL_NS, 0.0, water_mm=[path_mm]
    )
    assert mean_frequency_mhz(plain) > expected + 0.5 * path_mm / 20.0
    # its peak is the gate's amplitude, however much water it crossed
    assert np.max(np.abs(record)) == pytest.approx(0.5, rel=0.02)


def test_the_echo_broadens_with_its_water_path() -> None:
    rf = RfOutput(25.0, noise_floor_fsh=1e-4, seed=1, water_absorption=True)

    def width_ns(path_mm: float) -> float:
        x = rf.record(0.0, DT_NS, N, 0.5, ARRIVAL_NS, 0.0, water_mm=[path_mm])
        t = np.arange(N) * DT_NS
        w = x**2 / np.sum(x**2)
        centre = float(np.sum(t * w))
        return math.sqrt(float(np.sum((t - centre) ** 2 * w)))

    widths = [width_ns(p) for p in (10.0, 60.0, 120.0)]
    assert widths[0] < widths[1] < widths[2]
    assert widths[2] > 1.05 * widths[0]  # 18.7 to 20.5 ns rms at 25 MHz


def test_a_later_echo_sits_at_its_own_delay_shaped_by_its_own_path() -> None:
    rf = RfOutput(25.0, noise_floor_fsh=1e-4, seed=1, water_absorption=True)
    # another face 2 mm further (2.7 µs later at 1482 m/s), half as high
    delay_ns = 2 * 2.0 / 1.48238 * 1e3
    record = rf.record(
        0.0, DT_NS, N, 0.5, ARRIVAL_NS, 0.0, [(delay_ns, 0.5)], water_mm=[50.0, 52.0]
    )
    alone = rf.record(0.0, DT_NS, N, 0.5, ARRIVAL_NS, 0.0, water_mm=[50.0])
    second = record - alone
    envelope = np.abs(second)
    peak_ns = float(np.argmax(envelope)) * DT_NS
    assert peak_ns == pytest.approx(ARRIVAL_NS + delay_ns, abs=40.0)
    assert np.max(envelope) == pytest.approx(0.25, rel=0.03)
    assert not np.any(second[: round((ARRIVAL_NS + delay_ns - 300.0) / DT_NS)])


def test_the_baseline_offset_is_in_every_sample_and_in_the_averages() -> None:
    rf = RfOutput(25.0, noise_floor_fsh=1e-4, seed=2, baseline_offset=0.03)
    sigma = rf.noise_rms_fsh(20.0, 64)
    quiet = rf.record(0.0, DT_NS, N, 0.0, float("nan"), sigma)
    assert np.mean(quiet) == pytest.approx(0.03, abs=4 * sigma / math.sqrt(N))
    echo = rf.record(0.0, DT_NS, N, 0.5, ARRIVAL_NS, sigma)
    assert np.median(echo) == pytest.approx(0.03, abs=1e-4)
    assert np.max(np.abs(echo - 0.03)) == pytest.approx(0.5, rel=0.02)


def test_without_absorption_or_offset_the_record_is_the_one_shape_as_before() -> None:
    a = RfOutput(25.0, noise_floor_fsh=1e-4, seed=3).record(
        0.0, DT_NS, N, 0.5, ARRIVAL_NS, 1e-5, [(900.0, 0.2)], water_mm=[50.0, 100.0]
    )
    b = RfOutput(25.0, noise_floor_fsh=1e-4, seed=3).record(
        0.0, DT_NS, N, 0.5, ARRIVAL_NS, 1e-5, [(900.0, 0.2)]
    )
    np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("path_mm", [40.0, 80.0])
def test_an_echo_through_less_or_more_water_than_the_reference_s_is_timed_as_one_alike(
    path_mm: float,
) -> None:
    from ucal.echo.ascan import AScan
    from ucal.echo.reference import build_reference
    from ucal.echo.timing import estimate_echo

    rng = np.random.default_rng(5)
    dt, n, c_mm_ns = 12.2, 400, 1.48238
    rf = RfOutput(25.0, noise_floor_fsh=1e-4, seed=5, water_absorption=True)

    def record(path: float, averages: int) -> tuple[AScan, float]:
        tof = 2.0 * path / c_mm_ns + 8.0
        t0 = tof - 200 * dt + rng.uniform(0.0, dt)
        sigma = rf.noise_rms_fsh(31.0, averages)
        return AScan(t0, dt, rf.record(t0, dt, n, 0.8, tof, sigma, water_mm=[path])), tof

    # the cell's capture: 16 records of 64 averages, 60 mm of water
    reference = build_reference([record(60.0, 64)[0] for _ in range(16)])
    at_reference = [estimate_echo(*record(60.0, 16)[:1], reference) for _ in range(2)]
    estimates, errors = [], []
    for _ in range(20):
        ascan, tof = record(path_mm, 16)
        e = estimate_echo(ascan, reference)
        estimates.append(e)
        errors.append(e.tof_ns - tof)
    assert not any(e.overlapped for e in estimates)
    assert np.mean([e.extra_water_mm for e in estimates]) == pytest.approx(path_mm - 60.0, abs=1.0)
    # the reference's own convention is a constant in every time (the calibrated delay's)
    common = at_reference[0].tof_ns - (2.0 * 60.0 / c_mm_ns + 8.0)
    assert abs(np.mean(errors) - common) < 3 * at_reference[0].tof_std_ns
    assert np.mean([e.tof_std_ns for e in estimates]) < 2 * at_reference[0].tof_std_ns
