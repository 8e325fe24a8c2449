"""The host's echo timer for back-ends that only digitise: the project's estimator on the
neighbourhood of the strongest echo, whatever the gate's length."""

from __future__ import annotations

import math

import numpy as np
import pytest

from drivers.digitizer.base import AScanRecord
from ucal.echo import METHOD_ENVELOPE, estimate_echo
from ucal.echo.ascan import AScan
from ucal.echo.host import HostEchoTimer
from ucal.sim.rf import RfOutput

T0_NS, DT_NS, N = 5_000.0, 5.0, 80_001
GATE = (T0_NS, T0_NS + (N - 1) * DT_NS)
LSB = 2.0 / 4096


def record(samples: np.ndarray) -> AScanRecord:
    samples = np.round(samples / LSB) * LSB
    return AScanRecord(T0_NS, DT_NS, samples, (-1.0, 1.0), LSB, False, 1, 1, 0.0)


@pytest.fixture(scope="module")
def rf() -> RfOutput:
    return RfOutput(25.0, noise_floor_fsh=1e-4, seed=11)


def test_a_long_gate_is_timed_as_the_echos_neighbourhood_alone(rf: RfOutput) -> None:
    samples = rf.record(T0_NS, DT_NS, N, 0.6, 67_460.0, 3e-4)
    echo = HostEchoTimer()(record(samples), GATE)
    assert echo.method == METHOD_ENVELOPE  # no reference echo: the labelled fallback
    k = int((67_000.0 - T0_NS) / DT_NS)
    whole = estimate_echo(AScan(T0_NS + k * DT_NS, DT_NS, record(samples).samples[k : k + 200]))
    assert echo.tof_ns == pytest.approx(whole.tof_ns, abs=0.05)
    assert echo.amplitude == pytest.approx(whole.amplitude, rel=1e-3)
    assert 0.0 < echo.tof_std_ns < 0.1


def test_the_envelope_timing_is_a_constant_offset_from_the_arrival(rf: RfOutput) -> None:
    timer = HostEchoTimer()
    offsets = [
        timer(record(rf.record(T0_NS, DT_NS, N, 0.6, arrival, 3e-4)), GATE).tof_ns - arrival
        for arrival in np.linspace(40_000.0, 41_000.0, 7) + 0.37
    ]
    assert np.ptp(offsets) < 0.1  # what a calibration's electronic delay absorbs


def test_a_record_with_nothing_in_it_has_no_echo() -> None:
    echo = HostEchoTimer()(record(np.zeros(N)), GATE)
    assert echo.amplitude == 0.0 and math.isnan(echo.tof_ns)
