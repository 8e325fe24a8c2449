"""The synthetic digitiser: a ringing, asymmetric 60 %-bandwidth echo, sampled, noisy, clipped."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import signal

from ucal.echo import echo_arrival_ns, echo_band, noise_rms
from ucal.sim.ascan import Digitiser, TransducerPulse, echo_shape, gate_around, synthesise

ARRIVAL_NS = 67_000.0


@pytest.mark.parametrize("fc_mhz", [5.0, 25.0])
def test_the_echo_has_the_asked_band_and_is_not_a_gaussian(fc_mhz: float) -> None:
    shape = echo_shape(TransducerPulse(fc_mhz), Digitiser(500.0, 24))
    t0, n = gate_around(shape, ARRIVAL_NS)
    record = synthesise(
        shape,
        np.random.default_rng(0),
        t0_ns=t0,
        n_samples=n,
        arrival_ns=[ARRIVAL_NS],
        amplitude=0.5,
        noise_rms=0.0,
    )[0]
    band = echo_band(record.samples, record.dt_ns)
    assert band.centre_frequency_mhz == pytest.approx(fc_mhz, rel=2e-3)
    assert band.bandwidth_mhz == pytest.approx(0.6 * fc_mhz, rel=5e-3)
    # asymmetric: the envelope peaks and the energy sits well before the arrival (the echo
    # rises at once and rings down), and the waveform is not its own mirror image
    t = record.t_ns - ARRIVAL_NS
    envelope = np.abs(signal.hilbert(record.samples))
    period_ns = 1e3 / fc_mhz
    assert t[np.argmax(envelope)] < -0.25 * period_ns
    assert np.sum(t * record.samples**2) / np.sum(record.samples**2) < -0.15 * period_ns
    k = int(np.argmin(np.abs(t)))
    half = int(2 * period_ns / record.dt_ns)
    left, right = record.samples[k - half : k], record.samples[k + 1 : k + half + 1][::-1]
    assert np.linalg.norm(left - right) > 0.3 * np.linalg.norm(left)
    assert np.max(np.abs(record.samples)) == pytest.approx(0.5, rel=1e-3)  # peak = amplitude


def test_the_true_arrival_is_the_twin_correlation_peak_of_the_record() -> None:
    # two independent computations: the shape's from its exact spectrum, the reference
    # module's from the samples
    for fc, rate in ((5.0, 100.0), (25.0, 100.0), (15.0, 500.0)):
        shape = echo_shape(TransducerPulse(fc), Digitiser(rate, 24))
        t0, n = gate_around(shape, ARRIVAL_NS)
        for offset in (0.0, 0.31, 0.77):
            arrival = ARRIVAL_NS + offset * shape.digitiser.dt_ns
            record = synthesise(
                shape,
                np.random.default_rng(0),
                t0_ns=t0,
                n_samples=n,
                arrival_ns=[arrival],
                amplitude=0.5,
                noise_rms=0.0,
            )[0]
            found = echo_arrival_ns(record.t0_ns, record.dt_ns, record.samples)
            assert found == pytest.approx(arrival, abs=1e-4)


def test_noise_quantisation_rails_and_pairs() -> None:
    dig = Digitiser(200.0, 8, 1.0)
    shape = echo_shape(TransducerPulse(10.0), dig)
    t0, n = gate_around(shape, ARRIVAL_NS, noise_samples=4096)
    records = synthesise(
        shape,
        np.random.default_rng(1),
        t0_ns=t0,
        n_samples=n,
        arrival_ns=[ARRIVAL_NS] * 2,
        amplitude=3.0,
        noise_rms=0.05,
        antithetic=True,
    )
    assert len(records) == 4
    a, b = records[0].samples, records[1].samples
    quiet = np.ones(n, bool)
    quiet[2048 : n - 2048] = False  # the echo
    assert noise_rms(a, quiet, dig.lsb) == pytest.approx(0.05, rel=0.1)
    levels = a / dig.lsb
    assert np.allclose(levels, np.round(levels))
    assert a.max() == dig.rails[1] and a.min() == dig.rails[0]  # 3 × full scale: clipped
    assert records[0].at_rails().any() and records[0].rails == dig.rails
    # a pair shares the echo and has opposite noise (before rounding)
    assert np.allclose((a + b)[quiet] / 2, 0.0, atol=dig.lsb)
    again = synthesise(
        shape,
        np.random.default_rng(1),
        t0_ns=t0,
        n_samples=n,
        arrival_ns=[ARRIVAL_NS] * 2,
        amplitude=3.0,
        noise_rms=0.05,
        antithetic=True,
    )
    assert np.array_equal(again[3].samples, records[3].samples)  # seeded


def test_out_of_range_settings_are_refused() -> None:
    with pytest.raises(ValueError, match="fractional bandwidth"):
        TransducerPulse(10.0, 2.0)
    with pytest.raises(ValueError, match="bits"):
        Digitiser(200.0, 2)
    with pytest.raises(ValueError, match="sample rate"):
        Digitiser(0.1)
