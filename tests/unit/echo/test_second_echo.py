"""Another echo two periods or more after the main one is fitted with it, not taken into its
time (``ucal.echo.timing``: the pair fitted by turns, the std of the two together)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from ascan_generator import Pulse, delay_bound_ns, record_axis, records

from ucal.echo import estimate_echo
from ucal.echo.files import reference_from_samples

ARRIVAL_NS = 20_000.0
AMPLITUDE = 0.5


@pytest.mark.parametrize("periods, height", [(2.0, 0.5), (3.0, -0.4)])
def test_a_second_echo_periods_later_is_separated(periods: float, height: float) -> None:
    rng = np.random.default_rng(int(10 * periods))
    pulse = Pulse(10.0, 200.0)
    t = record_axis(pulse, ARRIVAL_NS, 13.0)
    noise = AMPLITUDE * 10 ** (-30.0 / 20)
    capture = records(pulse, rng, t, [ARRIVAL_NS], amplitude=AMPLITUDE, noise=noise / 4)[0]
    ref = reference_from_samples(capture.t0_ns - ARRIVAL_NS, capture.dt_ns, capture.samples)
    clean = records(pulse, rng, t, [ARRIVAL_NS], amplitude=AMPLITUDE, noise=1e-5)[0]
    t0_error = estimate_echo(clean, ref).tof_ns - ARRIVAL_NS
    delays = ARRIVAL_NS + rng.uniform(-0.5, 0.5, 150) * pulse.dt_ns
    second = (height, periods * 1e3 / pulse.fc_mhz)
    got = records(pulse, rng, t, delays, amplitude=AMPLITUDE, noise=noise, second=second)
    estimates = [estimate_echo(r, ref) for r in got]
    errors = np.array([e.tof_ns for e in estimates]) - delays - t0_error
    crb = delay_bound_ns(pulse, t, ARRIVAL_NS, AMPLITUDE, noise, 2.0 / 4096)
    bound = math.hypot(crb, noise / 4 / AMPLITUDE * delay_bound_ns(pulse, t, ARRIVAL_NS, 1, 1, 0))
    spread = float(errors.std())
    assert np.mean([e.separated for e in estimates]) > 0.95
    assert abs(float(errors.mean())) < 0.05  # the plain correlation: pulled 0.3–2 ns
    assert spread < 1.5 * bound  # the pair's own bound is above the lone echo's
    assert 1 / 1.5 < float(np.mean([e.tof_std_ns for e in estimates])) / spread < 1.5
