"""Joint 1 and the block's yaw: one rotation about the base axis, and the gauge that fixes it.

No measurement of the block separates joint 1's offset δ1 from the block's yaw ψ: turning the
arm by ε about the base axis and the block by −ε (its corner moved with it) gives the same
readings. What the data determine is their difference, the arm's azimuth relative to the
block. The solvers therefore fix a gauge: the block's yaw is held at the profile's value (the
block as placed, ``[sample] rotation_deg[2]``) and δ1 is fitted relative to it. With the true
yaw ψ and the profile's ψ0,

    δ1 (block gauge) = δ1 − (ψ − ψ0)                  std from the data alone (≈ 0.003°)

so every pose the profile computes relative to the block — a scan of a part located from the
block, ``verify``'s points — is right to the data's std, while in the robot's base frame δ1 is
known only as well as the yaw is: ``std_abs = √(std_block² + σψ²)`` (0.5° for a hand-placed
block, 0.01° for a doweled, levelled one).

What the results say (``calibrate --json``, ``[calibration]``):

* ``joint_offsets_deg[0]``: δ1 in the block gauge; J1 is no longer "unobservable" (its value is
  measured, not kept from the profile);
* ``std_deg[0]``: the absolute one sigma ``std_abs``, honest as SPEC.md asks (it includes the
  yaw tolerance the data cannot separate);
* ``std_block_deg``: one sigma relative to the block as placed (the other joints: as
  ``std_deg``); ``calibrate`` judges J1 by it;
* ``gauge``: ``"block"`` when ``std_abs`` exceeds the tolerance a joint is judged by
  (``MAX_STD_DEG``): J1 is known relative to the block only; ``"base"`` when the block's yaw
  is declared well enough (a doweled fixture) that J1 is absolute too.

The block's pose the same fit measured (corner, tilts; the yaw held as placed) is written into
``[sample]`` with it (``block_pose``): the corner was known to the hand's 5 mm, and a pose
relative to the block is only as right as both the offsets and the block. Only the values are
written; ``[sample]``'s tolerances stay the ones declared for the block as placed. Every run
measures the block again (it is an unknown of every fit), and the corner's std from one run
is mostly the tool's tolerance along the beam (time of flight sees the corner and the tool's
length as one quantity): taken as the next run's prior it would be counted again each run,
the corner's std shrinking with no new information.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.optimize import brentq
from scipy.spatial.transform import Rotation

from ucal.kinematics.rotations import matrix_to_rpy, rpy_to_matrix
from ucal.model.fit import BLOCK, MAX_STD_DEG, OFFSETS, PRIOR_MEANING, CellFit

#: The unknown held as placed: the block's yaw (Staubli rz about the block's z axis).
BLOCK_YAW = "block_rz_deg"
#: J1 relative to the block as placed (a hand-placed block) ...
GAUGE_BLOCK = "block"
#: ... or absolute too (the block's yaw declared to a few thousandths of a degree).
GAUGE_BASE = "base"


@dataclass(frozen=True)
class J1Gauge:
    """How joint 1's offset is known: relative to the block as placed, and absolutely."""

    block_std_deg: float  # one sigma relative to the block as placed (NaN: not determined)
    yaw_std_deg: float  # the block's yaw tolerance as placed ([sample] rotation_std_deg[2])
    max_std_deg: float = MAX_STD_DEG

    @property
    def absolute_std_deg(self) -> float:
        """One sigma of J1 in the robot's base frame: the data's and the yaw's."""
        return math.hypot(self.block_std_deg, self.yaw_std_deg)

    @property
    def frame(self) -> str:
        """``"base"`` when J1 is absolute within ``max_std_deg``, else ``"block"``."""
        return GAUGE_BASE if self.absolute_std_deg <= self.max_std_deg else GAUGE_BLOCK

    def statement(self) -> str:
        """The gauge in words, for the result and the profile."""
        if not math.isfinite(self.block_std_deg):
            return "J1 not determined (unobservable_joints says why); kept from the profile"
        if self.frame == GAUGE_BASE:
            return (
                f"J1 absolute: the block's yaw is declared to {self.yaw_std_deg:g} deg ([sample] "
                f"rotation_std_deg), so J1 is known to {self.absolute_std_deg:.3g} deg in the "
                "robot's base frame"
            )
        return (
            f"J1 relative to the block as placed (std {self.block_std_deg:.2g} deg); absolute "
            f"only as well as the block's yaw is known ({self.yaw_std_deg:g} deg as placed: std "
            f"{self.absolute_std_deg:.2g} deg); a doweled, levelled block "
            f"(rotation_std_deg ≤ {0.5 * self.max_std_deg:g}) makes it absolute"
        )


@dataclass(frozen=True)
class GaugedOffsets:
    """The offsets a fit in the block gauge gives, with both kinds of std."""

    offsets_deg: np.ndarray  # kept from the prior where unobservable
    std_deg: np.ndarray  # absolute one sigma (J1's includes the yaw), NaN where unobservable
    std_block_deg: np.ndarray  # one sigma relative to the block as placed
    reasons: dict[int, str]  # 1-based joint → why it is unobservable
    gauge: J1Gauge


def gauged_offsets(
    cell: CellFit, prior_offsets_deg: np.ndarray, yaw_std_deg: float, max_std_deg: float
) -> GaugedOffsets:
    """The offsets of a fit made with the block's yaw held (``BLOCK_YAW`` fixed).

    A joint whose std exceeds ``max_std_deg`` while less than half of its variance comes from
    the measurements is reported unobservable (prior value kept) with the prior that
    dominates it as the reason; a joint whose large std comes from the data stays observable
    (the caller judges it out of tolerance).
    """
    offsets = np.array(prior_offsets_deg, float)
    std = np.full(6, np.nan)
    reasons: dict[int, str] = {}
    for j, name in enumerate(OFFSETS):
        sigma = cell.sigma(name)
        shares = cell.variance_share.get(name, {"data": 0.0, name: 1.0})
        if not np.isfinite(sigma) or (sigma > max_std_deg and shares["data"] < 0.5):
            reasons[j + 1] = unobservable_reason(j + 1, sigma, shares)
            continue
        offsets[j] = cell.value(name)
        std[j] = sigma
    gauge = J1Gauge(float(std[0]), float(yaw_std_deg), max_std_deg)
    absolute = std.copy()
    if np.isfinite(std[0]):
        absolute[0] = gauge.absolute_std_deg
    return GaugedOffsets(offsets, absolute, std, reasons, gauge)


def unobservable_reason(joint: int, sigma_deg: float, shares: dict[str, float]) -> str:
    """Why joint ``joint`` (1-based) cannot be calibrated, from the sources of its variance."""
    source, share = max(((k, v) for k, v in shares.items() if k != "data"), key=lambda kv: kv[1])
    if source == OFFSETS[joint - 1]:
        return "the measurements do not move it (e.g. joint 6 with the beam on its axis)"
    what = PRIOR_MEANING.get(source, source)
    text = (
        f"cannot be separated from {what}: {100 * share:.0f} % of its variance, "
        f"std {sigma_deg:.3g} deg"
    )
    if source == BLOCK_YAW:
        text += "; fixture the block (doweled and levelled to 0.01 deg) and state it"
    elif source in ("block_rx_deg", "block_ry_deg"):
        text += "; level the block or see it from a second J1 azimuth"
    return text


def block_pose(cell: CellFit, yaw_std_deg: float) -> dict[str, Any]:
    """The block as the fit measured it (block gauge): corner and tilts with their stds, the
    yaw as placed with its tolerance (``block`` in ``calibrate --json``)."""
    value = [cell.value(n) for n in BLOCK]
    # a quantity the fit held (a zero tolerance) keeps the tolerance it had
    sigma = [
        cell.sigma(n) if np.isfinite(cell.sigma(n)) else float(cell.table.prior_stds[i])
        for i, n in ((cell.table.index(n), n) for n in BLOCK)
    ]
    return {
        "position_mm": [round(v, 6) for v in value[:3]],
        "rotation_deg": [round(v, 6) for v in value[3:]],
        "position_std_mm": [round(s, 6) for s in sigma[:3]],
        "rotation_std_deg": [round(s, 6) for s in sigma[3:5]] + [float(yaw_std_deg)],
    }


def block_keys(block: dict[str, Any]) -> dict[str, Any]:
    """What ``calibrate`` writes into ``[sample]`` of ``block_pose``: the values only."""
    return {k: block[k] for k in ("position_mm", "rotation_deg")}


def j1_relative_to_block(
    offset_deg: float, block_rpy_deg: np.ndarray, placed_yaw_deg: float
) -> float:
    """Joint 1's offset in the block gauge of a cell whose true J1 offset is ``offset_deg`` and
    whose block is truly turned ``block_rpy_deg`` (Staubli rx, ry, rz), placed with the yaw
    ``placed_yaw_deg``: the arm and the block turned together by θ about the base axis give the
    same readings, so the data give δ1 + θ for the θ that brings the block's yaw to the placed
    one: −(ψ − ψ0) for a level block, within 1e-6° for one tilted by tenths of a degree."""
    rot = rpy_to_matrix(np.asarray(block_rpy_deg, float))

    def yaw_off(theta_deg: float) -> float:
        turned = Rotation.from_euler("z", theta_deg, degrees=True).as_matrix() @ rot
        return float(matrix_to_rpy(turned)[2]) - placed_yaw_deg

    guess = placed_yaw_deg - float(block_rpy_deg[2])
    return float(offset_deg) + float(brentq(yaw_off, guess - 1.0, guess + 1.0, xtol=1e-12))


def gauge_fields(std_block_deg: np.ndarray, gauge: J1Gauge) -> dict[str, Any]:
    """The gauge's fields of ``calibrate --json`` (``None``: not determined)."""
    return {
        "gauge": gauge.frame,
        "gauge_note": gauge.statement(),
        "std_block_deg": [float(v) if np.isfinite(v) else None for v in std_block_deg],
    }
