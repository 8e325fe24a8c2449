"""Edge scans: the coarse fall and the fine scan on a synthetic edge profile."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.special import ndtr

from ucal.measure.edges import coarse_edge_fall, fine_edge_scan

EDGE_MM = 37.3
SIGMA_MM = 1.5


def amplitude(t: float) -> float:
    return float(0.8 * ndtr((EDGE_MM - t) / SIGMA_MM))


def test_coarse_fall_is_the_middle_of_the_step_that_halves_the_echo() -> None:
    probed: list[float] = []

    def probe(t: float) -> float:
        probed.append(t)
        return amplitude(t)

    t_c = coarse_edge_fall(probe, 20.0, amplitude(20.0), 60.0, 2.0, 4)
    # 36 mm: 0.8·Φ(0.87) = 0.65; 38 mm: 0.8·Φ(−0.47) = 0.26 < 0.4
    assert t_c == pytest.approx(37.0)
    assert probed == pytest.approx(np.arange(22.0, 38.1, 2.0))
    # no fall before the end of the line
    assert coarse_edge_fall(probe, 0.0, amplitude(0.0), 30.0, 2.0, 4) is None


def test_fine_scan_finds_the_half_point_and_keeps_inside_the_line() -> None:
    ts: list[float] = []

    def probe(t: float) -> tuple[float, float]:
        ts.append(t)
        return t + 0.25, amplitude(t)  # the caller's coordinate: 0.25 mm off the command

    fit = fine_edge_scan(probe, 37.0, 5.0, 21, t_max_mm=41.0)
    assert fit.crossing == pytest.approx(EDGE_MM + 0.25, abs=1e-6)
    assert fit.width_mm == pytest.approx(SIGMA_MM, abs=1e-6)
    assert len(ts) == 21 and ts[0] == pytest.approx(32.0) and ts[-1] == pytest.approx(41.0)
    with pytest.raises(ValueError, match="does not cross the edge"):
        fine_edge_scan(probe, 10.0, 5.0, 21)
