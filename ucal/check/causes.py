"""What moved, as causes with their sizes: a joint's offset, the tool across or along its beam or
its beam's direction, the block's position or its turn, the arm's growth (ppm,
``ucal.check.growth``); the water's change as its own cause.

A chosen suspect (``ucal.check.solve.select``) is split into what a commissioning acts on: the
tool's change of position ``Δp`` (flange frame) into its part along the beam ``a`` (the tool's
z axis as the reference fitted it), ``a·Δp``, and across it, ``|Δp − (a·Δp)a|``; the block's
corner change into its length ``|Δc|`` and its turn into the length of its rotation vector
(small angles). Each size has its one sigma from the changes' covariance: the tool's
components across the beam are correlated through joint 6's offset (which turns the flange
frame they are given in), their length far less. A cause *moved* when its
size exceeds 3σ and the tolerance of its unknowns (``ucal.check.solve``'s); ``causes`` gives
those, ``water_words`` the water's change beyond 3σ in words (docs/decisions/0016).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ucal.acoustics import sound_speed_m_s, sound_speed_slope_m_s_per_c
from ucal.check.growth import ARM
from ucal.check.solve import N_SIGMA, Change, GeometryComparison
from ucal.model.fit import BLOCK, OFFSETS, SOUND, TOOL, CellPrior, rpy_matrix


@dataclass(frozen=True)
class Cause:
    """One thing that moved: ``part`` (a suspect: "J2", "tool", "block", "arm"), ``what``
    ("offset", "across the beam", "along the beam", "beam direction", "position", "turn",
    "growth"), its ``size`` (signed for a joint, along the beam or the arm's growth, else a
    length) and one sigma in ``unit``, the
    tolerance it is judged by and the unknowns' changes it is made of."""

    part: str
    what: str
    size: float
    std: float
    unit: str
    tolerance: float
    changes: dict[str, float] = field(default_factory=dict)

    @property
    def moved(self) -> bool:
        return bool(abs(self.size) > N_SIGMA * self.std and abs(self.size) > self.tolerance)

    def words(self) -> str:
        digits = {"deg": 4, "ppm": 1}.get(self.unit, 3)
        parts = ", ".join(f"{n} {v:+.{digits}f}" for n, v in self.changes.items())
        return (
            f"{self.what} {self.size:+.{digits}f} {self.unit} (± {self.std:.2g}; tolerance "
            f"{self.tolerance:g} {self.unit}{'; ' + parts if len(self.changes) > 1 else ''})"
        )

    def to_json(self) -> dict[str, object]:
        return {
            "part": self.part,
            "what": self.what,
            "size": float(self.size),
            "std": float(self.std),
            "unit": self.unit,
            "tolerance": float(self.tolerance),
            "changes": {k: float(v) for k, v in self.changes.items()},
        }


def _by_name(changes: list[Change]) -> dict[str, Change]:
    return {c.parameter: c for c in changes}


def _length(
    vector: np.ndarray, cov: np.ndarray, projection: np.ndarray | None = None
) -> tuple[float, float]:
    """|P·vector| (P the ``projection``, the identity by default) and its one sigma from the
    components' covariance ``cov``."""
    p = np.eye(vector.size) if projection is None else projection
    part = p @ vector
    size = float(np.linalg.norm(part))
    unit = part / size if size > 0 else np.full(vector.size, 1 / np.sqrt(vector.size))
    grad = p.T @ unit
    return size, float(np.sqrt(max(float(grad @ cov @ grad), 0.0)))


def _along(vector: np.ndarray, cov: np.ndarray, direction: np.ndarray) -> tuple[float, float]:
    """The signed part of ``vector`` along ``direction`` and its one sigma."""
    return float(direction @ vector), float(np.sqrt(max(float(direction @ cov @ direction), 0.0)))


def suspect_causes(comparison: GeometryComparison, suspect: str) -> list[Cause]:
    """The causes a suspect's changes make (module docstring), moved or not."""
    by = _by_name([c for c in comparison.changes if c.suspect == suspect])
    if suspect in OFFSETS:
        c = by[suspect]
        return [Cause(suspect, "offset", c.change, c.std, "deg", c.tolerance)]
    if suspect == ARM:
        (c,) = by.values()
        return [Cause(ARM, "growth", c.change, c.std, "ppm", c.tolerance)]
    if suspect not in ("tool", "block"):
        return []
    names = TOOL if suspect == "tool" else BLOCK
    here = [by[n] for n in names[:3]]
    d = np.array([c.change for c in here])
    cov = comparison.covariances.get(suspect)
    if cov is None:  # the changes' own variances
        cov = np.diag([c.std**2 for c in comparison.changes if c.suspect == suspect])
    tol = here[0].tolerance
    changes = {c.parameter: c.change for c in here}
    turns = [by[n] for n in names[3:] if n in by]
    turn = np.array([c.change for c in turns])
    turn_cov = cov[3:, 3:]
    turn_tol = turns[0].tolerance
    turn_changes = {c.parameter: c.change for c in turns}
    if suspect == "block":
        return [
            Cause("block", "position", *_length(d, cov[:3, :3]), "mm", tol, changes),
            Cause("block", "turn", *_length(turn, turn_cov), "deg", turn_tol, turn_changes),
        ]
    rx, ry = (by[n].baseline for n in TOOL[3:5])
    beam = rpy_matrix(np.array([rx, ry, 0.0]))[:, 2]
    across = np.eye(3) - np.outer(beam, beam)
    return [
        Cause("tool", "across the beam", *_length(d, cov[:3, :3], across), "mm", tol, changes),
        Cause("tool", "along the beam", *_along(d, cov[:3, :3], beam), "mm", tol, changes),
        Cause("tool", "beam direction", *_length(turn, turn_cov), "deg", turn_tol, turn_changes),
    ]


def causes(comparison: GeometryComparison) -> list[Cause]:
    """What moved: the causes of the chosen suspects beyond 3σ and their tolerance, in the
    order chosen."""
    return [
        c for suspect in comparison.chosen for c in suspect_causes(comparison, suspect) if c.moved
    ]


def water_words(comparison: GeometryComparison, prior: CellPrior) -> str:
    """The water's change beyond 3σ, chosen as a suspect, in words ("" when none): its own
    cause, not a failure of the cell (docs/decisions/0016)."""
    if "water" not in comparison.chosen:
        return ""
    c = _by_name(comparison.changes)[SOUND[0]]
    if not abs(c.change) > N_SIGMA * c.std:
        return ""
    dt = temperature_change_c(prior, c.change)
    return (
        f"the water changed since the reference: sound speed {c.change:+.2f} m/s (± "
        f"{c.std:.2g}), about {dt:+.2f} °C; every measurement of ucal's uses the sound speed it "
        "measures, a scan that takes it from [water] temperature_c is off by "
        f"{100 * c.change / prior.sound_speed_m_s:+.3f} % of its water path"
    )


def temperature_change_c(prior: CellPrior, sound_change_m_s: float) -> float:
    """The water temperature change (°C) that a sound speed change (m/s) means, at the
    profile's temperature (Marczak's c(T))."""
    return float(sound_change_m_s / sound_speed_slope_m_s_per_c(prior.water_temperature_c))


def temperature_of(prior: CellPrior, speed_m_s: float) -> float:
    """The water temperature (°C) at which Marczak's c(T) is ``speed_m_s`` (near the
    profile's temperature; Newton's method)."""
    t = prior.water_temperature_c
    for _ in range(20):
        step = (speed_m_s - sound_speed_m_s(t)) / sound_speed_slope_m_s_per_c(t)
        t += step
        if abs(step) < 1e-9:
            break
    return float(t)
