"""The echo estimator of issue 22 on A-scans it has not seen: bound, bias, honest std."""

from __future__ import annotations

import dataclasses
import functools
import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from scipy import signal

from ucal.echo import (
    METHOD_ENVELOPE,
    METHOD_REFERENCE,
    AScan,
    ReferenceEcho,
    build_reference,
    delay_crb_ns,
    echo_arrival_ns,
    estimate_echo,
)
from ucal.sim.ascan import (
    Digitiser,
    EchoShape,
    TransducerPulse,
    echo_shape,
    gate_around,
    synthesise,
    true_delay_crb_ns,
)

ARRIVAL_NS = 67_000.0
AMPLITUDE = 0.5


def shape_of(fc_mhz: float, rate_mhz: float, bits: int = 12) -> EchoShape:
    return echo_shape(TransducerPulse(fc_mhz), Digitiser(rate_mhz, bits, 1.0))


def noisy_reference(
    shape: EchoShape, rng: np.random.Generator, averages: int = 128
) -> ReferenceEcho:
    """The cell's reference: captures at 40 dB with 0.5 ns of trigger jitter, averaged."""
    t0, n = gate_around(shape, ARRIVAL_NS)
    captures = synthesise(
        shape,
        rng,
        t0_ns=t0,
        n_samples=n,
        arrival_ns=ARRIVAL_NS + 0.5 * rng.standard_normal(averages),
        amplitude=AMPLITUDE,
        noise_rms=AMPLITUDE * 1e-2,
    )
    return build_reference(captures)


def readings(
    shape: EchoShape,
    rng: np.random.Generator,
    snr_db: float,
    pairs: int,
    *,
    amplitude: float = AMPLITUDE,
    echoes: tuple[tuple[float, float], ...] = (),
    extra_samples: int = 0,
) -> tuple[list[AScan], np.ndarray]:
    """Antithetic pairs of records at random sub-sample positions (noise at ``snr_db`` below
    an echo of ``AMPLITUDE``), and their true arrivals."""
    t0, n = gate_around(shape, ARRIVAL_NS)
    arrivals = ARRIVAL_NS + rng.uniform(-0.5, 0.5, pairs) * shape.digitiser.dt_ns
    records = synthesise(
        shape,
        rng,
        t0_ns=t0,
        n_samples=n + extra_samples,
        arrival_ns=arrivals,
        amplitude=amplitude,
        noise_rms=AMPLITUDE * 10 ** (-snr_db / 20),
        echoes=echoes,
        antithetic=True,
    )
    return records, np.repeat(arrivals, 2)


@pytest.mark.parametrize(
    "fc_mhz, rate_mhz, snr_db",
    [(5, 100, 20), (5, 500, 40), (25, 100, 40), (25, 500, 20), (15, 200, 30)],
)
def test_issue_22_done_when(fc_mhz: float, rate_mhz: float, snr_db: float) -> None:
    # spread ≤ 1.3 × CRB, |bias| ≤ 0.05 ns, reported std within a factor 2 of the spread
    rng = np.random.default_rng([22, fc_mhz, rate_mhz, snr_db])
    shape = shape_of(fc_mhz, rate_mhz)
    ref = noisy_reference(shape, rng)
    records, truth = readings(shape, rng, snr_db, pairs=100)
    estimates = [estimate_echo(r, ref) for r in records]
    errors = np.array([e.tof_ns for e in estimates]) - truth
    crb = true_delay_crb_ns(shape, AMPLITUDE, AMPLITUDE * 10 ** (-snr_db / 20))
    spread = float(errors.std())
    assert spread <= 1.3 * crb
    assert abs(errors.mean()) <= 0.05
    ratio = np.mean([e.tof_std_ns for e in estimates]) / spread
    assert 0.5 <= ratio <= 2.0
    assert all(e.method == METHOD_REFERENCE and not e.clipped for e in estimates)
    assert np.mean([e.amplitude for e in estimates]) == pytest.approx(AMPLITUDE, rel=0.01)
    assert np.mean([e.snr_db for e in estimates]) == pytest.approx(snr_db, abs=0.5)
    assert np.median([e.centre_frequency_mhz for e in estimates]) == pytest.approx(fc_mhz, rel=0.03)
    assert np.median([e.bandwidth_mhz for e in estimates]) == pytest.approx(0.6 * fc_mhz, rel=0.08)


def test_the_reference_from_noisy_captures_keeps_the_truths_arrival_and_bandwidth() -> None:
    rng = np.random.default_rng(1)
    for fc, rate in ((5, 100), (25, 100), (25, 500)):
        shape = shape_of(fc, rate)
        ref = noisy_reference(shape, rng)
        t0, n = gate_around(shape, ARRIVAL_NS)
        clean = synthesise(
            shape,
            rng,
            t0_ns=t0,
            n_samples=n,
            arrival_ns=[ARRIVAL_NS + 0.37],
            amplitude=1.0,
            noise_rms=0.0,
        )[0]
        assert estimate_echo(clean, ref).tof_ns == pytest.approx(ARRIVAL_NS + 0.37, abs=0.02)
        assert ref.rms_bandwidth_mhz == pytest.approx(shape.rms_bandwidth_mhz, rel=0.005)
        assert ref.averages == 128 and ref.t0_ns < 0.0 < ref.t0_ns + ref.n * ref.dt_ns


def test_no_bias_at_any_sub_sample_position_where_a_parabola_has_one() -> None:
    # 25 MHz at 100 MS/s: four samples a cycle, the parabola's worst case; 24 bits, no noise
    shape = shape_of(25, 100, bits=24)
    rng = np.random.default_rng(2)
    t0, n = gate_around(shape, ARRIVAL_NS)
    ref = build_reference(
        synthesise(
            shape,
            rng,
            t0_ns=t0,
            n_samples=n,
            arrival_ns=[ARRIVAL_NS + 3.3],
            amplitude=0.7,
            noise_rms=0.0,
        )
    )
    arrivals = ARRIVAL_NS + np.linspace(0.0, 10.0, 41)  # one sample, every sub-position
    records = synthesise(
        shape, rng, t0_ns=t0, n_samples=n, arrival_ns=arrivals, amplitude=0.5, noise_rms=0.0
    )
    ours = np.array([estimate_echo(r, ref).tof_ns for r in records]) - arrivals
    parabola = []
    for r in records:
        c = signal.correlate(r.samples, ref.samples, mode="full")
        lags = signal.correlation_lags(r.n, ref.n, mode="full")
        k = int(np.argmax(c))
        delta = 0.5 * (c[k - 1] - c[k + 1]) / (c[k - 1] - 2 * c[k] + c[k + 1])
        parabola.append(r.t0_ns - ref.t0_ns + (lags[k] + delta) * r.dt_ns)
    parabola_errors = np.array(parabola) - arrivals
    assert np.max(np.abs(ours)) < 1e-4

    assert np.ptp(parabola_errors) > 0.5


@functools.cache
def clean_reference() -> tuple[EchoShape, ReferenceEcho]:
    """A 10 MHz echo at 200 MS/s, 24 bits, and its reference from one noise-free capture."""
    shape = shape_of(10, 200, bits=24)
    t0, n = gate_around(shape, ARRIVAL_NS)
    capture = synthesise(
        shape,
        np.random.default_rng(3),
        t0_ns=t0,
        n_samples=n,
        arrival_ns=[ARRIVAL_NS + 1.1],
        amplitude=0.5,
        noise_rms=0.0,
    )
    return shape, build_reference(capture)


@given(
    offset_ns=st.floats(min_value=-300.0, max_value=300.0),
    origin_ns=st.floats(min_value=-1e6, max_value=1e6),
    scale=st.floats(min_value=0.05, max_value=0.9),
)
def test_a_shift_round_trips(offset_ns: float, origin_ns: float, scale: float) -> None:
    # any arrival, any time origin, any height: timed where it was put, to a thousandth of a ns
    shape, ref = clean_reference()
    t0, n = gate_around(shape, ARRIVAL_NS)
    arrival = ARRIVAL_NS + offset_ns
    record = synthesise(
        shape,
        np.random.default_rng(0),
        t0_ns=t0 - 320.0,
        n_samples=n + 128,
        arrival_ns=[arrival],
        amplitude=scale,
        noise_rms=0.0,
    )[0]
    moved = dataclasses.replace(record, t0_ns=record.t0_ns + origin_ns, rails=None, lsb=None)
    e = estimate_echo(moved, ref)
    assert e.tof_ns - origin_ns == pytest.approx(arrival, abs=1e-3)
    assert e.amplitude == pytest.approx(scale, rel=1e-4)


def test_the_bound_has_the_textbook_form() -> None:
    # β = 10 MHz, SNR_eff = 10⁴: 1 / (2π · 0.01 ns⁻¹ · 100)
    assert delay_crb_ns(10.0, 1e4) == pytest.approx(1.0 / (2 * math.pi))
    assert delay_crb_ns(10.0, 0.0) == math.inf
    # the reference's β is √(f_c² + B²) of its band: above the centre frequency
    shape = shape_of(10, 200)
    assert 10.0 < shape.rms_bandwidth_mhz < 12.0


@pytest.mark.parametrize("rails_known", [True, False])
def test_a_clipped_echo_is_flagged_and_timed_by_its_flanks(rails_known: bool) -> None:
    shape = shape_of(10, 200)
    rng = np.random.default_rng(4)
    ref = noisy_reference(shape, rng, averages=64)
    records, truth = readings(shape, rng, 30.0, pairs=40, amplitude=2.0)  # twice full scale
    if not rails_known:  # a CSV file: the digitiser's rails are not known
        records = [dataclasses.replace(r, rails=None, lsb=None) for r in records]
    clipped = [estimate_echo(r, ref) for r in records]
    errors = np.array([e.tof_ns for e in clipped]) - truth
    assert all(e.clipped for e in clipped)
    assert np.mean([e.amplitude for e in clipped]) == pytest.approx(2.0, rel=0.02)
    assert abs(errors.mean()) < 0.05
    # fewer samples carry the delay: a larger std than the bound of that echo unclipped
    unclipped_crb = true_delay_crb_ns(shape, 2.0, AMPLITUDE * 10 ** (-30 / 20))
    assert np.mean([e.tof_std_ns for e in clipped]) > 1.1 * unclipped_crb
    assert 0.5 <= np.mean([e.tof_std_ns for e in clipped]) / errors.std() <= 2.0


def test_a_second_echo_in_the_gate_changes_neither_the_first_nor_its_std() -> None:
    shape = shape_of(15, 200)
    rng = np.random.default_rng(5)
    ref = noisy_reference(shape, rng, averages=64)
    delay_ns = shape.pre_ns + shape.post_ns
    extra = int(delay_ns / shape.digitiser.dt_ns)
    records, truth = readings(
        shape, rng, 30.0, pairs=50, echoes=((delay_ns, 0.6),), extra_samples=extra
    )
    estimates = [estimate_echo(r, ref) for r in records]
    errors = np.array([e.tof_ns for e in estimates]) - truth
    assert abs(errors.mean()) < 0.05
    assert np.mean([e.snr_db for e in estimates]) == pytest.approx(30.0, abs=0.5)
    assert 0.5 <= np.mean([e.tof_std_ns for e in estimates]) / errors.std() <= 2.0
    # a gate around the second echo times it instead
    gate = (ARRIVAL_NS + 0.5 * delay_ns, ARRIVAL_NS + 1.5 * delay_ns)
    second = estimate_echo(records[0], ref, gate_ns=gate)
    assert second.tof_ns == pytest.approx(truth[0] + delay_ns, abs=1.0)
    assert second.amplitude == pytest.approx(0.6 * AMPLITUDE, rel=0.05)


def test_without_a_reference_the_envelope_is_coarse_and_says_so() -> None:
    shape = shape_of(10, 200)
    rng = np.random.default_rng(6)
    ref = noisy_reference(shape, rng, averages=64)
    records, truth = readings(shape, rng, 30.0, pairs=60)
    coarse = [estimate_echo(r) for r in records]
    fine = [estimate_echo(r, ref) for r in records]
    errors = np.array([e.tof_ns for e in coarse]) - truth
    assert all(e.method == METHOD_ENVELOPE for e in coarse)
    assert np.mean([e.tof_std_ns for e in coarse]) > 3.0 * np.mean([e.tof_std_ns for e in fine])
    assert 0.5 <= np.mean([e.tof_std_ns for e in coarse]) / errors.std() <= 2.0
    assert np.median([e.centre_frequency_mhz for e in coarse]) == pytest.approx(10.0, rel=0.05)


def test_a_reference_at_another_rate_is_resampled() -> None:
    fine, coarse = shape_of(5, 500), shape_of(5, 100)
    rng = np.random.default_rng(7)
    ref = noisy_reference(fine, rng, averages=32)
    t0, n = gate_around(coarse, ARRIVAL_NS)
    record = synthesise(
        coarse,
        rng,
        t0_ns=t0,
        n_samples=n,
        arrival_ns=[ARRIVAL_NS + 2.2],
        amplitude=0.5,
        noise_rms=0.0,
    )[0]
    # the two digitisers' anti-alias filters differ only far above a 5 MHz echo's band
    assert estimate_echo(record, ref).tof_ns == pytest.approx(ARRIVAL_NS + 2.2, abs=0.02)
    with pytest.raises(ValueError, match="cannot be resampled"):
        noisy_reference(shape_of(25, 500), rng, averages=8).resampled(20.0)


def test_the_arrival_is_the_twin_correlation_peak() -> None:
    # a symmetric pulse arrives at its centre
    t = np.arange(-400.0, 400.0, 2.0)
    pulse = np.exp(-0.5 * ((t - 13.0) / 40.0) ** 2) * np.cos(2 * np.pi * 0.01 * (t - 13.0))
    assert echo_arrival_ns(t[0], 2.0, pulse) == pytest.approx(13.0, abs=1e-4)


def test_bad_input_is_refused() -> None:
    record = AScan(0.0, 5.0, np.zeros(64))
    with pytest.raises(ValueError, match="holds no sample"):
        estimate_echo(record, gate_ns=(1000.0, 2000.0))
    with pytest.raises(ValueError, match="at least 8 samples"):
        AScan(0.0, 5.0, np.zeros(3))
    with pytest.raises(ValueError, match="positive"):
        AScan(0.0, 0.0, np.zeros(16))
    with pytest.raises(ValueError, match="all zeros"):
        ReferenceEcho(0.0, 5.0, np.zeros(16))
    with pytest.raises(ValueError, match="no captures"):
        build_reference([])
