"""The report's checks: each ``ucal check`` of the cell as its history keeps it
(``PROFILE.history/checks.json``, ``ucal.check.history``), and the arm's growth over them as a
trend (``ucal.report.figures.growth_figure``, ``ucal.report.story``).

A check fits the arm's growth since its reference (``ucal.check.growth``: every DH length
scaled by one factor, in ppm, an aluminium arm's 23 ppm/K); the trend shows it check by check
with ±3σ bars against its tolerance, so a cell that warms through a shift (or whose arm grows
as its room does over a season) is seen before a check fails. A reference check has no growth
of its own (it is the zero); a check taken before the growth was a suspect has none either.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from ucal.check.growth import GROWTH, GROWTH_TOLERANCE_PPM
from ucal.check.history import CheckEntry, read_checks


@dataclass(frozen=True)
class CheckFacts:
    """One check as the report shows it: when, its verdict, what it named, and the arm's
    growth since its reference (ppm, one sigma, tolerance; None: not fitted)."""

    id: int
    time: str
    verdict: str
    reference: bool
    named: tuple[str, ...]
    compared_with: int | None
    growth_ppm: float | None = None
    growth_std_ppm: float | None = None
    growth_tolerance_ppm: float = GROWTH_TOLERANCE_PPM

    @classmethod
    def of(cls, entry: CheckEntry) -> CheckFacts:
        growth = next((q for q in entry.quantities if q.get("name") == GROWTH), None)
        value = std = None
        tolerance = GROWTH_TOLERANCE_PPM
        if growth is not None and growth.get("difference") is not None:
            value, std = float(growth["difference"]), growth.get("std")
            std = None if std is None else float(std)
            tolerance = float(growth.get("tolerance") or GROWTH_TOLERANCE_PPM)
        return cls(
            entry.id,
            entry.time,
            entry.verdict,
            entry.reference,
            tuple(entry.named),
            entry.compared_with,
            value,
            std,
            tolerance,
        )


def gather_checks(profile_path: str | Path) -> tuple[CheckFacts, ...]:
    """The profile's checks, oldest first (``ProfileError`` for an unreadable index)."""
    return tuple(CheckFacts.of(e) for e in read_checks(profile_path))
