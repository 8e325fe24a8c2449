"""An echo through more water than the reference's: its spectrum is the reference's times
exp(−κf²) (α ∝ f²), fitted, not taken for another echo over it (``ucal.echo.timing``)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from ascan_generator import Pulse, delay_bound_ns, kappa_of_water_mm, record_axis, records

from ucal.echo import estimate_echo
from ucal.echo.files import reference_from_samples

ARRIVAL_NS = 20_000.0
AMPLITUDE = 0.5


@pytest.mark.parametrize("fc_mhz, rate_mhz, water_mm", [(25.0, 500.0, 60.0), (15.0, 200.0, 120.0)])
def test_more_water_is_fitted_and_the_std_stays_honest(
    fc_mhz: float, rate_mhz: float, water_mm: float
) -> None:
    rng = np.random.default_rng(int(water_mm + fc_mhz))
    pulse = Pulse(fc_mhz, rate_mhz)
    t = record_axis(pulse, ARRIVAL_NS)
    kappa = kappa_of_water_mm(water_mm)
    capture = records(pulse, rng, t, [ARRIVAL_NS], amplitude=AMPLITUDE, noise=0.0158 / 4)[0]
    ref = reference_from_samples(capture.t0_ns - ARRIVAL_NS, capture.dt_ns, capture.samples)
    t0_error = (
        estimate_echo(
            records(pulse, rng, t, [ARRIVAL_NS], amplitude=AMPLITUDE, noise=1e-5)[0], ref
        ).tof_ns
        - ARRIVAL_NS
    )
    peak = float(np.max(np.abs(pulse.waveforms(t, np.array([ARRIVAL_NS]), kappa)[0])))
    noise = AMPLITUDE * peak * 10 ** (-30.0 / 20)  # 30 dB of the echo as it arrives
    delays = ARRIVAL_NS + rng.uniform(-0.5, 0.5, 200) * pulse.dt_ns
    got = records(pulse, rng, t, delays, amplitude=AMPLITUDE, noise=noise, kappa=kappa)
    estimates = [estimate_echo(r, ref) for r in got]
    errors = np.array([e.tof_ns for e in estimates]) - delays - t0_error
    crb = delay_bound_ns(pulse, t, ARRIVAL_NS, AMPLITUDE, noise, 2.0 / 4096, kappa)
    bound = math.hypot(crb, 0.0158 / 4 / AMPLITUDE * delay_bound_ns(pulse, t, ARRIVAL_NS, 1, 1, 0))
    spread = float(errors.std())
    assert not any(e.overlapped for e in estimates)  # before: every one, its std ×9–44
    assert spread < 1.3 * bound
    assert abs(float(errors.mean())) < 0.05
    assert 1 / 1.5 < float(np.mean([e.tof_std_ns for e in estimates])) / spread < 1.5
    assert np.median([e.extra_water_mm for e in estimates]) == pytest.approx(water_mm, rel=0.2)
    assert np.mean([e.amplitude for e in estimates]) == pytest.approx(AMPLITUDE * peak, rel=0.1)


def test_no_more_water_leaves_the_reference_as_it_is() -> None:
    rng = np.random.default_rng(7)
    pulse = Pulse(10.0, 200.0)
    t = record_axis(pulse, ARRIVAL_NS)
    capture = records(pulse, rng, t, [ARRIVAL_NS], amplitude=AMPLITUDE, noise=0.004)[0]
    ref = reference_from_samples(capture.t0_ns - ARRIVAL_NS, capture.dt_ns, capture.samples)
    got = records(pulse, rng, t, ARRIVAL_NS + np.zeros(60), amplitude=AMPLITUDE, noise=0.016)
    water = [estimate_echo(r, ref).extra_water_mm for r in got]
    assert np.mean(np.array(water) == 0.0) > 0.9  # not significant: κ = 0
