"""The receiver's RF output the simulated scope records: the cell's echo as a waveform."""

from __future__ import annotations

import numpy as np
import pytest

from ucal.sim.ascan import Digitiser, TransducerPulse, echo_shape, synthesise
from ucal.sim.rf import FULL_SCREEN_V, RfOutput

T0_NS, DT_NS, N = 5_000.0, 5.0, 80_001  # a 400 µs gate at 200 MS/s


def test_the_echo_sits_at_its_arrival_as_the_pulse_model_puts_it() -> None:
    rf = RfOutput(25.0, noise_floor_fsh=1e-4, seed=1)
    arrival = 67_460.37
    record = rf.record(T0_NS, DT_NS, N, 0.6, arrival, 0.0)
    # the same echo synthesised over a short record by ucal.sim.ascan
    shape = echo_shape(TransducerPulse(25.0), Digitiser(200.0, 24, 10.0))
    first = 12_000
    reference = synthesise(
        shape,
        np.random.default_rng(0),
        t0_ns=T0_NS + first * DT_NS,
        n_samples=1000,
        arrival_ns=[arrival],
        amplitude=0.6 * FULL_SCREEN_V,
        noise_rms=0.0,
    )[0].samples
    np.testing.assert_allclose(record[first : first + 1000], reference, atol=2e-6)
    assert np.count_nonzero(record) < 400  # the rest of the gate is silent without noise


def test_noise_follows_the_gain_and_the_averages_and_repeats_with_the_seed() -> None:
    rf = RfOutput(25.0, noise_floor_fsh=1e-4, seed=3)
    sigma = rf.noise_rms_fsh(40.0, 4)
    assert sigma == pytest.approx(1e-4 * 10 / 4.6 / 2)
    a = rf.record(T0_NS, DT_NS, N, 0.0, float("nan"), sigma)
    assert np.std(a) == pytest.approx(sigma, rel=0.02)
    again = RfOutput(25.0, noise_floor_fsh=1e-4, seed=3).record(
        T0_NS, DT_NS, N, 0.0, float("nan"), sigma
    )
    np.testing.assert_array_equal(a, again)


def test_an_echo_outside_the_record_is_not_in_it() -> None:
    rf = RfOutput(25.0, noise_floor_fsh=1e-4, seed=1)
    assert not np.any(rf.record(T0_NS, DT_NS, 1000, 0.6, 67_000.0, 0.0))
