"""The A-scan generator that is not ucal's (``benchmarks/_ascan_generator.py``), for the tests:
the benchmark and the tests time the same independent echoes."""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

from _ascan_generator import (
    ALPHA_WATER_DB_PER_MM_MHZ2,
    Digitiser,
    Pulse,
    delay_bound_ns,
    kappa_of_water_mm,
    record_axis,
    records,
)

__all__ = [
    "ALPHA_WATER_DB_PER_MM_MHZ2",
    "Digitiser",
    "Pulse",
    "delay_bound_ns",
    "kappa_of_water_mm",
    "record_axis",
    "records",
]
