"""Scanning the beam across a reflector's straight edge: where the echo falls to half.

A knife edge is a reflector whose echo sees the beam across its axis: moving the beam outward
across the edge at normal incidence, the echo falls from the plate's level to nothing over the
footprint (σ ~1.5 mm at 25 MHz), and the 50 % point is where the beam axis crosses the edge
(``fit_edge_profile``, paper 002's eq. E4). Both the tool frame (the plate's edges) and verify's
tool check (the block's far edges) find it the same way: coarse steps outward until the echo falls
below half the largest of the last few readings, then static probes across that fall fitted
with the edge profile. Only the scan coordinate of a probe differs: each caller's ``probe``
moves the robot and says where it is. Every probe is static (moved to, then read), and the
probes step outward: with a ``FinalApproachRig`` each is reached from below on every joint.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares
from scipy.special import ndtr


@dataclass(frozen=True)
class EdgeFit:
    """Fitted edge profile along one scan (eq. E4)."""

    crossing: float  # t_e, scan coordinate (mm) of the 50 % point
    crossing_std: float  # one-sigma of t_e (mm)
    amplitude: float  # A0 (any amplitude unit)
    width_mm: float  # σ of the footprint (mm)
    rms: float  # fit residual rms (amplitude units)


def fit_edge_profile(t_mm: np.ndarray, amps: np.ndarray, outward: float = 1.0) -> EdgeFit:
    """Fit ``A0·Φ(outward·(t_e − t)/σ)`` to amplitudes along a scan (eq. E4).

    ``outward`` is +1 when the plate lies at smaller t (the echo falls as t grows), −1
    otherwise. Raises ``ValueError`` if the scan does not contain a fall from the plate's
    level to below half of it.
    """
    t = np.asarray(t_mm, float)
    a = np.asarray(amps, float)
    order = np.argsort(t)
    t, a = t[order], a[order]
    top = float(np.percentile(a, 90))
    if not (np.min(a) < 0.5 * top < np.max(a)):
        raise ValueError("the scan does not cross the edge (no fall to half amplitude)")
    # start: where the amplitude passes half of the plate level
    inside = a >= 0.5 * top
    idx = np.nonzero(inside)[0]
    t0 = float(t[idx].max() if outward > 0 else t[idx].min())

    def model(p: np.ndarray) -> np.ndarray:
        a0, te, sig, slope = p
        return np.asarray((a0 + slope * (t - te)) * ndtr(outward * (te - t) / sig))

    span = float(t.max() - t.min())
    p0 = np.array([top, t0, 1.5, 0.0])
    lo = np.array([0.0, t.min(), 0.05, -top / max(span, 1e-9)])
    hi = np.array([np.inf, t.max(), 0.5 * span + 1.0, top / max(span, 1e-9)])
    p0 = np.clip(p0, lo + 1e-9, hi - 1e-9)
    sol = least_squares(
        lambda p: model(p) - a,
        p0,
        bounds=(lo, hi),
        xtol=1e-14,
        ftol=1e-14,
        gtol=1e-14,
        max_nfev=2000,
    )
    res = sol.fun
    cov = _sandwich_cov(sol.jac, res, (1e-9 * sol.x[0]) ** 2)
    return EdgeFit(
        float(sol.x[1]),
        float(np.sqrt(max(cov[1, 1], 0.0))),
        float(sol.x[0]),
        float(sol.x[2]),
        float(np.sqrt(np.mean(res**2))),
    )


def _sandwich_cov(jac: np.ndarray, res: np.ndarray, floor: float) -> np.ndarray:
    """Covariance of a least-squares fit from its Jacobian and residuals, each reading's
    variance its own squared residual inflated by its leverage (HC3, MacKinnon and White 1985);
    ``floor``: the least variance a reading is given.

    An echo's noise is not the same along a scan: part of it is relative to the amplitude,
    large on the plate and nil off it. A single variance (the residuals' mean square) spreads
    the plate's noise over the probes off the plate, where there is none, and so understates
    how far the plate's level, and with it the 50 % point, can move; each reading weighted by
    its own residual does not, whatever the noise's shape.
    """
    bread = np.linalg.pinv(jac.T @ jac)
    leverage = np.einsum("ij,jk,ik->i", jac, bread, jac)
    var = np.maximum(res**2, floor) / np.maximum(1.0 - leverage, 1e-3) ** 2
    return np.asarray(bread @ (jac.T * var) @ jac @ bread)


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
