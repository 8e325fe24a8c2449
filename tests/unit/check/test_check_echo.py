"""The echo chain's A-scan at a posture: its band, or none when the pulser gives no A-scan."""

from __future__ import annotations

import numpy as np
import pytest

from drivers.pulser.base import GateReading
from drivers.pulser.simulator import gaussian_pulse
from ucal.check.measure import NoAScan, read_echo_band
from ucal.devices.rig import Rig

from doubles import QuietPulser

ECHO_NS = 135_000.0


class SteadyEcho(QuietPulser):
    """An echo at ``ECHO_NS`` at 60 % of full screen; an A-scan of it at 10 MHz if asked."""

    def __init__(self, centre_mhz: float | None) -> None:
        super().__init__("test://pulser")
        self.centre_mhz = centre_mhz
        self.counter = 0

    def read_gate(self, fresh: bool = True, timeout_s: float | None = 1.0) -> GateReading:
        self.counter += 1
        return GateReading(0.6, ECHO_NS, self.counter, 0.0, 0.0)

    def read_ascan(self, timeout_s: float = 2.0) -> tuple[np.ndarray, float] | None:
        if self.centre_mhz is None:
            return None
        t_ns = ECHO_NS - 1000.0 + np.arange(401) * 5.0  # 200 MS/s over the 2 µs window
        return gaussian_pulse(t_ns, ECHO_NS, 0.6, self.centre_mhz * 1e6), 200e6


def rig(pulser: SteadyEcho) -> Rig:
    return Rig(None, pulser, np.full(6, -180.0), np.full(6, 180.0))  # type: ignore[arg-type]


def test_the_band_of_the_echo_and_the_gate_restored() -> None:
    r = rig(SteadyEcho(10.0))
    before = r.settings
    band = read_echo_band(r, ECHO_NS)
    assert band is not None and band.centre_frequency_mhz == pytest.approx(10.0, abs=0.05)
    assert r.settings == before


def test_a_pulser_without_a_scan_says_so() -> None:
    r = rig(SteadyEcho(None))
    before = r.settings
    with pytest.raises(NoAScan, match="gives no A-scan"):
        read_echo_band(r, ECHO_NS)
    assert r.settings == before
