"""Verify's typed result: the measured run with its verdict, what "before" was, the sound speed,
the gauge, the notes and the simulator's truth, as the tables, the picture and ``--json`` draw
it."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ucal.cell import CellProfile
from ucal.verify.inputs import BeforeProfile, SoundSpeed, VerifyGauge
from ucal.verify.measure import VerifyResult
from ucal.verify.solve import ToolOffset

#: How far verify's reached TCP may be from the real one (mm), set from the commissioning
#: benchmark (``benchmarks/commissioning.py`` prints the largest difference on fresh cells). A
#: largest deviation that close to the tolerance gives a marginal verdict.
MEASURED_WITHIN_MM = 0.05


def profile_notes(profile: CellProfile) -> list[str]:
    """What the profile says it does not know that shows in every "after" figure: joints the
    last calibration could not determine (J6 excepted: the tool is measured in its frame) or
    a profile never calibrated. One sentence each, for ``notes`` in ``--json``."""
    if profile.joint_offsets_std_deg is None:
        return [
            "the profile's joint offsets were never calibrated ([calibration] has no std_deg): "
            "'after' is the robot as its controller zeroes it; run `ucal calibrate` first"
        ]
    kept = [j for j in profile.unobservable_joints if j != 6]
    if not kept:
        return []
    names = ", ".join(f"J{j}" for j in kept)
    why = (
        " (with a hand-placed block J1's offset and the block's yaw are one rotation: a "
        "doweled, levelled fixture and its [sample] rotation_std_deg let calibrate measure it)"
        if 1 in kept
        else ""
    )
    return [
        f"{names} not calibrated ([calibration] unobservable_joints, kept at the profile's "
        f"value): its error is in every 'after' figure{why}"
    ]


@dataclass
class VerifyShown:
    """What the result tables are drawn from."""

    result: VerifyResult
    before: BeforeProfile
    sound: SoundSpeed
    tolerance_mm: float
    worst_mm: float
    truth: dict[str, Any] | None
    plot_path: Path | None
    gauge: VerifyGauge = field(default_factory=lambda: VerifyGauge(None, 0.0))
    #: "before" is the profile as it is (no calibration in its history): both passes alike
    before_is_after: bool = False


def tool_notes(tool: ToolOffset | None, profile: CellProfile) -> list[str]:
    """What the tool check says of the profile's ``[tool]``: off by more than its stated std
    (moved since ``tool-frame``, or never measured), or, along the beam, off within it (the
    hand-touched plate's tolerance, which shows in X and Y of the points straight down)."""
    if tool is None:
        return []
    std = np.broadcast_to(np.asarray(profile.tool_position_std_mm, float), 3)
    beam = np.abs(profile.tool_matrix[:3, 2])
    along_std = float(np.sqrt(np.sum((beam * std) ** 2)))
    across_std = float(np.sqrt(np.sum(((1.0 - beam) * std) ** 2)))
    across = float(np.linalg.norm(tool.across_mm))
    notes = []
    if across > max(3.0 * across_std, MEASURED_WITHIN_MM):
        notes.append(
            f"the tool check finds the real tool {across:.3f} mm off the profile's across the "
            f"beam, beyond what [tool] says it is known to (±{across_std:.3f} mm): moved since "
            "`ucal tool-frame` measured it, or never measured? run `ucal tool-frame`"
        )
    along = abs(tool.along_mm)
    longer = f"{along:.3f} mm {'longer' if tool.along_mm > 0 else 'shorter'} along the beam"
    if along > max(3.0 * along_std, MEASURED_WITHIN_MM):
        notes.append(
            f"the tool check finds the real tool {longer} than the profile's, beyond what "
            f"[tool] says it is known to (±{along_std:.3f} mm): run `ucal tool-frame`"
        )
    elif along > MEASURED_WITHIN_MM:
        notes.append(
            f"the real tool is {longer} than the profile's, within what [tool] says it is "
            f"known to (±{along_std:.2f} mm; after `ucal tool-frame`, the touched plate's "
            "tolerance): it shows in X and Y of the points straight down"
        )
    return notes


def tool_misfit_mm(shown: VerifyShown) -> float:
    """The tool check's largest misfit (mm; 0 without a tool check)."""
    tool = shown.result.tool
    return 0.0 if tool is None else tool.misfit_mm


def marginal(shown: VerifyShown) -> bool:
    """The verdict could go the other way within what verify measures to (plus the tool
    check's misfit)."""
    return bool(
        abs(shown.worst_mm - shown.tolerance_mm) <= MEASURED_WITHIN_MM + tool_misfit_mm(shown)
    )
