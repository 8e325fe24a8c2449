"""A reference as a cell captures it (a record averaged 16 times, written whole with its noise,
offset): its offset removed on read, its noise kept out of the bound's bandwidth and carried
into each reading's std (``ucal.echo.files.reference_from_samples``, ``ucal.echo.timing``)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from ascan_generator import Digitiser, Pulse, delay_bound_ns, record_axis, records

from ucal.echo import build_reference, estimate_echo
from ucal.echo.files import reference_from_samples

ARRIVAL_NS = 20_000.0
AMPLITUDE = 0.5


@pytest.mark.parametrize(
    "fc_mhz, rate_mhz, snr_db, offset",
    [(5.0, 100.0, 20.0, 0.0), (25.0, 500.0, 20.0, 0.03), (10.0, 200.0, 30.0, 0.30)],
)
def test_a_captured_reference_with_its_noise_and_offset_keeps_the_std_honest(
    fc_mhz: float, rate_mhz: float, snr_db: float, offset: float
) -> None:
    rng = np.random.default_rng(int(fc_mhz * 100 + rate_mhz + snr_db))
    pulse = Pulse(fc_mhz, rate_mhz)
    t = record_axis(pulse, ARRIVAL_NS)
    dig = Digitiser(offset=offset * AMPLITUDE)
    noise = AMPLITUDE * 10 ** (-snr_db / 20)
    capture = records(
        pulse, rng, t, [ARRIVAL_NS], amplitude=AMPLITUDE, noise=noise / 4.0, digitiser=dig
    )[0]
    ref = reference_from_samples(capture.t0_ns - ARRIVAL_NS, capture.dt_ns, capture.samples)
    assert ref.noise_rms == pytest.approx(10 ** (-snr_db / 20) / 4.0, rel=0.15)
    # the bandwidth is the echo's, not its noise's: as a clean reference's
    clean_ref = build_reference(
        records(pulse, rng, t, ARRIVAL_NS + np.zeros(4), amplitude=AMPLITUDE, noise=1e-4)
    )
    assert ref.rms_bandwidth_mhz == pytest.approx(clean_ref.rms_bandwidth_mhz, rel=0.05)

    exact = Digitiser(bits=16, offset=offset * AMPLITUDE)
    clean = records(pulse, rng, t, [ARRIVAL_NS], amplitude=AMPLITUDE, noise=0.0, digitiser=exact)
    t0_error = estimate_echo(clean[0], ref).tof_ns - ARRIVAL_NS
    delays = ARRIVAL_NS + rng.uniform(-0.5, 0.5, 300) * pulse.dt_ns
    got = records(pulse, rng, t, delays, amplitude=AMPLITUDE, noise=noise, digitiser=dig)
    estimates = [estimate_echo(r, ref) for r in got]
    errors = np.array([e.tof_ns for e in estimates]) - delays - t0_error
    reported = float(np.mean([e.tof_std_ns for e in estimates]))
    crb = delay_bound_ns(pulse, t, ARRIVAL_NS, AMPLITUDE, noise, dig.lsb)
    bound = math.hypot(crb, ref.noise_rms * delay_bound_ns(pulse, t, ARRIVAL_NS, 1.0, 1.0, 0.0))
    spread = float(errors.std())
    assert spread < 1.3 * bound
    assert abs(float(errors.mean())) < 0.05 + 3 * spread / math.sqrt(errors.size)
    assert 1 / 1.5 < reported / spread < 1.5
    assert np.mean([e.amplitude for e in estimates]) == pytest.approx(AMPLITUDE, rel=0.03)
    assert not any(e.overlapped for e in estimates)
