"""Scanning the beam across a reflector's straight edge: where the echo falls to half.

A knife edge is a reflector whose echo sees the beam across its axis: moving the beam outward
across the edge at normal incidence, the echo falls from the plate's level to nothing over the
footprint (σ ~1.5 mm at 25 MHz), and the 50 % point is where the beam axis crosses the edge
(``ucal.toolframe.exact``, eq. E4). Both the tool frame (the plate's edges) and verify's tool
check (the block's far edges) find it the same way: coarse steps outward until the echo falls
below half the largest of the last few readings, then static probes across that fall fitted
with the edge profile. Only the scan coordinate of a probe differs: each caller's ``probe``
moves the robot and says where it is. Every probe is static (moved to, then read), and the
probes step outward: with a ``FinalApproachRig`` each is reached from below on every joint.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ucal.toolframe.exact import EdgeFit, fit_edge_profile


@dataclass(frozen=True)
class EdgeScan:
    """The settings of an edge scan, the same for the plate's edges and the block's.

    ``coarse_step_mm``: the coarse search's step outward, below the footprint's width (σ =
    D/4 = 1.5 mm for a 6 mm element: 4σ = 6 mm), so the fall to half takes a few steps;
    ``coarse_memory``: the last readings whose largest a new one is compared with;
    ``fine_half_mm`` and ``fine_probes``: the fine scan's half width about the coarse
    crossing and its static probes; ``averages``: pulser readings averaged per probe.
    """

    coarse_step_mm: float = 2.0
    coarse_memory: int = 4
    fine_half_mm: float = 5.0
    fine_probes: int = 21
    averages: int = 16


EDGES = EdgeScan()


def coarse_edge_fall(
    probe: Callable[[float], float],
    t_mm: float,
    first: float,
    t_max_mm: float,
    step_mm: float,
    memory: int,
) -> float | None:
    """Step outward from ``t_mm`` (where the echo read ``first``) by ``step_mm`` up to
    ``t_max_mm``, ``probe(t)`` giving the amplitude at each step; the middle of the first step
    whose echo falls below half the largest of the last ``memory`` readings (the edge: a fall to
    half within a few steps; a beam drifting off normal along the line fades slowly), or None
    when it never falls."""
    recent = [first]
    prev = t = t_mm
    while t < t_max_mm:
        t = min(t + step_mm, t_max_mm)
        a = probe(t)
        if a < 0.5 * max(recent):
            return 0.5 * (prev + t)
        recent = (recent + [a])[-memory:]
        prev = t
    return None


def fine_edge_scan(
    probe: Callable[[float], tuple[float, float]],
    t_c_mm: float,
    half_mm: float,
    probes: int,
    t_max_mm: float = np.inf,
) -> EdgeFit:
    """``probes`` static probes from ``t_c_mm − half_mm`` to ``t_c_mm + half_mm`` (at most
    ``t_max_mm``), ``probe(t)`` giving each one's scan coordinate and amplitude, fitted with
    the edge profile (the echo falling as the coordinate grows). ``ValueError`` when the scan
    does not show the echo falling to half."""
    rows = [
        probe(float(t))
        for t in np.linspace(t_c_mm - half_mm, min(t_c_mm + half_mm, t_max_mm), probes)
    ]
    ts, amps = (np.array(c) for c in zip(*rows, strict=True))
    return fit_edge_profile(ts, amps, outward=1.0)
