"""The simulated scope's trigger: a record the sync output triggered is taken at the pulse's
time; one left to AUTO (no trigger set, or the sync output not on its source) runs free, the
echo at a random place in it or not there at all: a driver that does not set the trigger
gets records it cannot time."""

from __future__ import annotations

import numpy as np

from drivers.digitizer.scpi_simulator import AcquisitionRequest, SimulatedScope

ECHO_NS = 40_000.0


def test_an_auto_triggered_record_runs_free_and_a_triggered_one_holds_the_echo() -> None:
    seen: list[AcquisitionRequest] = []

    def signal(request: AcquisitionRequest) -> np.ndarray:
        seen.append(request)
        t = request.t_ns - ECHO_NS
        return np.asarray(0.5 * np.exp(-((t / 40.0) ** 2)) * np.cos(2 * np.pi * 0.025 * t))

    def holds_echo(request: AcquisitionRequest) -> bool:
        return bool(request.t0_ns <= ECHO_NS <= request.t0_ns + (request.n - 1) * request.dt_ns)

    scope = SimulatedScope(signal, family="keysight")  # not started: its commands directly
    scope.execute(":TIM:REF LEFT;:TIM:RANG 50E-6;:TIM:POS 20E-6")
    # power-on: sweep AUTO, the edge trigger on CHAN1, which the sync output is not wired to
    for _ in range(20):
        scope.execute(":DIG")
    free = seen[:]
    assert not any(r.triggered for r in free)
    assert len({r.t0_ns for r in free}) == 20  # each at its own time
    assert sum(holds_echo(r) for r in free) <= 3  # the echo mostly not in the record
    assert scope.execute(":TER?") == b"+0\n"  # and the trigger event register says so
    # the trigger set as the driver sets it: every record at the pulse's time, the echo in it
    seen.clear()
    scope.execute(":TRIG:EDGE:SOUR EXT;:TRIG:EDGE:LEV 1.4;:TRIG:SWE NORM")
    for _ in range(5):
        scope.execute(":DIG")
    assert all(r.triggered and r.t0_ns == 20_000.0 and holds_echo(r) for r in seen)
    assert scope.execute(":TER?") == b"+1\n"
