"""A joint the measurements determine too weakly to write: kept at its profile value, with why.

An offset whose std (relative to the block as placed) exceeds the write tolerance while most of
its variance comes from the measurements themselves is not a veto on the others: the fit's
other offsets are marginal over it (its uncertainty is already in their stds), so they are
written, and the weak joint keeps its profile value. It is reported as SPEC.md reports a joint
that is not calibrated (``unobservable_joints``: the profile's value, a null std) with the
reason naming the physics, and its estimate and std under ``weak_joints``.

The common case is joint 6 with a beam a fraction of a degree off the flange axis: turning
joint 6 swings the beam only through that angle (and the tool centre only through its distance
from the axis), so the tilt readings see a degree of J6 as sin(angle) of a degree of tilt.

A std that comes from the paper method's truncation, or a misfit, stays a refusal
(``ucal.calibration.procedure.judge``).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from ucal.calibration.exact import OffsetSolution
from ucal.kinematics.dh import RobotModel
from ucal.model.fit import CellFit, cell_geometry
from ucal.model.gauge import J1Gauge


@dataclass(frozen=True)
class WeakJoint:
    """A joint measured, but less certainly than the write tolerance: its estimate, not written."""

    joint: int  # 1-based
    offset_deg: float  # the fit's estimate (the profile keeps its own value)
    std_deg: float  # one sigma relative to the block as placed
    reason: str

    def to_json(self) -> dict[str, Any]:
        return {"offset_deg": self.offset_deg, "std_deg": self.std_deg, "reason": self.reason}


def weak_candidates(chosen: OffsetSolution, tolerance_deg: float) -> list[int]:
    """The 0-based joints of ``chosen`` measured (not unobservable) with a std above
    ``tolerance_deg`` that comes from the measurements, not from the paper method's truncation."""
    std = chosen.std_deg if chosen.std_block_deg is None else chosen.std_block_deg
    trunc = chosen.truncation_deg
    out = []
    for j in range(6):
        if j + 1 in chosen.unobservable_joints or not np.isfinite(std[j]):
            continue
        if std[j] <= tolerance_deg:
            continue
        if trunc is not None and trunc[j] > 0.5 * std[j]:
            continue  # the method's own error: --method exact, not a weak joint
        out.append(j)
    return out


def joint6_lever(cell: CellFit, model: RobotModel) -> tuple[float, float]:
    """The beam's angle to the joint-6 axis (deg) and the tool centre's distance from that axis
    (mm), as the fit put the tool: what turning joint 6 moves."""
    geom = cell_geometry(cell.table, cell.estimate, model)
    beam = geom.beam_flange
    angle = math.degrees(math.acos(float(np.clip(beam[2], -1.0, 1.0))))
    return angle, float(np.hypot(*geom.tool_matrix[:2, 3]))


def weak_reason(
    joint: int, std_deg: float, tolerance_deg: float, data_share: float, lever: tuple[float, float]
) -> str:
    """Why joint ``joint`` (1-based) is kept: which measurement lacks what."""
    head = (
        f"weakly determined: std {std_deg:.3g} deg exceeds {tolerance_deg:g} deg, "
        f"{100 * data_share:.0f} % of it from the measurements' scatter"
    )
    if joint == 6:
        angle, radius = lever
        # std scales as 1/sin(angle): the angle that would bring it within the tolerance
        need = math.degrees(
            math.asin(min(1.0, math.sin(math.radians(angle)) * std_deg / tolerance_deg))
        )
        return (
            f"{head}: the beam is {angle:.2f} deg off the joint-6 axis, so turning J6 by 1 deg "
            f"tilts it by {math.sin(math.radians(angle)):.4f} deg, and the tool centre, "
            f"{radius:.2f} mm off the axis, moves the water paths by "
            f"{math.radians(radius):.4f} mm; the tilt and water-path readings barely see J6. "
            f"A beam about {need:.1f} deg or more off the flange axis (or a quieter posture "
            "search) determines it; kept at its profile value"
        )
    return (
        f"{head}: the normal-incidence postures and water paths of this plan move little with "
        f"J{joint}; a larger joint step or quieter readings (water, gain, transducer) "
        "determine it; kept at its profile value"
    )


def keep_weak(
    chosen: OffsetSolution,
    prior_offsets_deg: np.ndarray,
    model: RobotModel,
    tolerance_deg: float,
) -> tuple[OffsetSolution, dict[int, WeakJoint]]:
    """``chosen`` with every weakly determined joint kept at ``prior_offsets_deg`` (std NaN,
    listed unobservable with the reason), and those joints' estimates (1-based keys)."""
    joints = weak_candidates(chosen, tolerance_deg)
    if not joints:
        return chosen, {}
    std = chosen.std_deg if chosen.std_block_deg is None else chosen.std_block_deg
    cell = chosen.cell_fit
    lever = joint6_lever(cell, model) if cell is not None else (float("nan"), float("nan"))
    offsets = np.array(chosen.offsets_deg, float)
    std_abs = np.array(chosen.std_deg, float)
    std_block = None if chosen.std_block_deg is None else np.array(chosen.std_block_deg, float)
    reasons = dict(chosen.unobservable_reasons)
    weak: dict[int, WeakJoint] = {}
    for j in joints:
        share = 1.0
        if cell is not None:
            share = cell.variance_share.get(f"J{j + 1}", {}).get("data", 1.0)
        reason = weak_reason(j + 1, float(std[j]), tolerance_deg, share, lever)
        weak[j + 1] = WeakJoint(j + 1, float(offsets[j]), float(std[j]), reason)
        reasons[j + 1] = reason
        offsets[j] = float(prior_offsets_deg[j])
        std_abs[j] = np.nan
        if std_block is not None:
            std_block[j] = np.nan
    gauge = chosen.gauge
    if gauge is not None and 1 in weak:
        gauge = J1Gauge(float("nan"), gauge.yaw_std_deg, gauge.max_std_deg)
    kept = dataclasses.replace(
        chosen,
        offsets_deg=offsets,
        std_deg=std_abs,
        std_block_deg=std_block,
        unobservable_joints=tuple(sorted(reasons)),
        unobservable_reasons=reasons,
        gauge=gauge,
    )
    return kept, weak
