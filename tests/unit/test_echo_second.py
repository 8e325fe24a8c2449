"""A second echo in the gate (the simulated cell's: a multiple, another face's, a corner's): the
main echo is still the one timed, and one over it widens its std and says so."""

from __future__ import annotations

import numpy as np
import pytest

from drivers.digitizer.base import AScanRecord
from ucal.echo import AScan, EchoEstimate, build_reference, estimate_echo
from ucal.echo.host import HostEchoTimer
from ucal.sim.rf import RfOutput

T0_NS, DT_NS, N = 5_000.0, 5.0, 40_001  # a 200 µs gate at 200 MS/s
ARRIVAL_NS = 67_460.37
LSB = 2.0 / 4096
NOISE = 3e-4  # 64 dB below an echo at 0.5 of full screen


@pytest.fixture(scope="module")
def rf() -> RfOutput:
    return RfOutput(25.0, noise_floor_fsh=1e-4, seed=22)


@pytest.fixture(scope="module")
def timer(rf: RfOutput) -> HostEchoTimer:
    """The cell's reference: 16 captures of the lone echo, near the main one's arrival."""
    t0 = ARRIVAL_NS - 600.0
    captures = [
        AScan(t0, DT_NS, rf.record(t0, DT_NS, 300, 0.5, ARRIVAL_NS + 0.1 * k, NOISE))
        for k in range(16)
    ]
    return HostEchoTimer(build_reference(captures))


def record(samples: np.ndarray) -> AScanRecord:
    samples = np.round(samples / LSB) * LSB
    return AScanRecord(T0_NS, DT_NS, samples, (-1.0, 1.0), LSB, False, 1, 1, 0.0)


def test_weaker_echoes_in_the_gate_are_not_timed_instead(
    rf: RfOutput, timer: HostEchoTimer
) -> None:
    # a step's face 2 mm behind (2.7 µs, 0.9 of the main) and the multiple (8 %) in the gate
    later = [(2_698.0, 0.9), (ARRIVAL_NS - 8.0, 0.081)]
    gate = (T0_NS, T0_NS + (N - 1) * DT_NS)
    errors, stds = [], []
    for k in range(6):
        arrival = ARRIVAL_NS + 0.8 * k
        echo = timer(record(rf.record(T0_NS, DT_NS, N, 0.5, arrival, NOISE, later)), gate)
        errors.append(echo.tof_ns - arrival)
        stds.append(echo.tof_std_ns)
        assert echo.amplitude == pytest.approx(0.5, rel=0.01)
    # the reference's arrival is common to every reading (its averaging): take it out
    errors = np.array(errors) - np.mean(errors)
    assert np.all(np.abs(errors) <= 3.0 * np.array(stds))
    assert np.max(stds) < 0.05


def test_an_echo_over_the_main_one_is_separated_or_flagged_its_std_widened(
    rf: RfOutput, timer: HostEchoTimer
) -> None:
    assert timer.reference is not None
    ref = timer.reference
    t0 = ARRIVAL_NS - 600.0

    def estimate(later: list[tuple[float, float]], arrival: float) -> EchoEstimate:
        samples = np.round(rf.record(t0, DT_NS, 400, 0.5, arrival, NOISE, later) / LSB) * LSB
        return estimate_echo(AScan(t0, DT_NS, samples, rails=(-1.0, 1.0), lsb=LSB), ref)

    arrivals = ARRIVAL_NS + 0.3 * np.arange(4)
    offset = np.mean([estimate([], a).tof_ns - a for a in arrivals])
    alone = estimate([], ARRIVAL_NS)
    assert not alone.overlapped
    # a corner's echo after the main one (1° off a face, 1 mm from the edge: 23 ns, 0.3)
    for delay_ns, relative, covered in ((23.0, 0.3, True), (7.0, 0.1, False)):
        over = estimate([(delay_ns, relative)], ARRIVAL_NS)
        error = over.tof_ns - offset - ARRIVAL_NS
        assert over.overlapped and not over.separated
        assert over.tof_std_ns > 10 * alone.tof_std_ns
        if covered:  # past a quarter period the widened std covers the other echo's pull
            assert abs(error) <= 2.0 * over.tof_std_ns
        else:  # closer, the pull is far beyond the bound, and the flag is what tells
            assert abs(error) > 100 * alone.tof_std_ns
    # 1.5 periods and more later (60 ns at 25 MHz): the two are fitted together, the first's
    # time and std those of the pair
    pair = estimate([(60.0, 0.2)], ARRIVAL_NS)
    assert pair.separated and not pair.overlapped
    assert abs(pair.tof_ns - offset - ARRIVAL_NS) <= 3.0 * pair.tof_std_ns
    assert pair.tof_std_ns < 3.0 * alone.tof_std_ns
