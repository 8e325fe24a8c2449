"""The ``tool-frame`` command's job on the measuring procedure (``ucal.procedure``).

Plan (``ucal.toolframe.plan``), measure (``ucal.toolframe.measure``), solve
(``ucal.toolframe.solve``), write ``[tool]`` (in tolerance, or with ``--force``), result
(``ucal.toolframe.result``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from ucal.cell import CellProfile
from ucal.devices.session import CellSession
from ucal.procedure import Measured, Outcome, ProfileJob, RunFacts
from ucal.profile import description_keys, write_profile
from ucal.profile.models import joint_speeds_deg_s
from ucal.progress import Report
from ucal.timing import EDGE_SCAN, NO_SEARCH, PLATE_PEAK, DurationEstimate, estimate_run
from ucal.toolframe.measure import ToolFrameMeasurements, measure_tool_frame
from ucal.toolframe.plan import ToolFramePlan, plan_tool_frame
from ucal.toolframe.result import (
    NOT_WRITTEN,
    SimulatedError,
    ToolFrameResult,
    refusal,
    tool_keys,
)
from ucal.toolframe.solve import ToolFrameRun, solve_measured


class ToolFrameCalibration(ProfileJob):
    """``tool-frame``: the tool frame → ``[tool]`` (with its stds from the exact fit)."""

    command = "tool-frame"

    def __init__(
        self,
        profile: CellProfile,
        profile_path: Path,
        method: str = "exact",
        points: int | None = None,
        force: bool = False,
    ) -> None:
        super().__init__(profile, profile_path)
        self.method = method
        self.points = points
        self.force = force

    def plan(self) -> ToolFramePlan:
        return plan_tool_frame(self.profile, self.method, self.points)

    def summary(self, plan: ToolFramePlan) -> str:
        return plan.summary()

    def estimate(self, plan: ToolFramePlan) -> DurationEstimate:
        speed = self.profile.procedure.speed
        joints = joint_speeds_deg_s(self.profile.model)
        postures = [t.joints_deg for t in plan.peaks + plan.incidence]
        at_postures = estimate_run(
            postures,
            plan.reference_deg,
            speed,
            speeds_deg_s=joints,
            search=PLATE_PEAK,
            first=NO_SEARCH,
        )
        # each edge scan starts near the plate centre, where the first posture looks from
        scans = [postures[0]] * plan.edge_lines
        return at_postures + estimate_run(
            scans, postures[0], speed, speeds_deg_s=joints, search=EDGE_SCAN, first=NO_SEARCH
        )

    def record_header(self, plan: ToolFramePlan) -> dict[str, Any]:
        return {"options": {"method": self.method, "points": self.points}, "plan": []}

    def measure(
        self, plan: ToolFramePlan, session: CellSession, report: Report
    ) -> ToolFrameMeasurements:
        return measure_tool_frame(self.profile, plan, session.rig, report)

    def solve(self, plan: ToolFramePlan, measured: Measured[ToolFrameMeasurements]) -> ToolFrameRun:
        return solve_measured(self.profile, plan, measured.data)

    def may_write(self, run: ToolFrameRun) -> bool:
        return run.in_tolerance or self.force

    def write(self, run: ToolFrameRun) -> None:
        reason = f"tool-frame ({run.method})"
        keys, capped = tool_keys(run)
        if not run.in_tolerance:
            reason += f", written with --force: {refusal(run).replace(NOT_WRITTEN, '')}"
        if capped:
            reason += f"; {capped}"
        # the tool as drawn kept beside the measured one (ucal.profile.described)
        keys |= description_keys(self.profile, "tool", keys["position_mm"], keys["rotation_deg"])
        write_profile(self.profile_path, {"tool": keys}, reason=reason)

    def result(
        self,
        plan: ToolFramePlan,
        measured: Measured[ToolFrameMeasurements],
        run: ToolFrameRun,
        written: bool,
    ) -> Outcome[ToolFrameResult]:
        truth = measured.truth
        result = ToolFrameResult(
            run,
            RunFacts.of(measured, self.profile_path, written),
            None if truth is None else SimulatedError.of(run, self.profile, truth),
        )
        message = refusal(run)
        if written and not run.in_tolerance:
            message = message.replace(NOT_WRITTEN, "") + " (written with --force)"
        return Outcome(
            self.command, result, written, out_of_tolerance=not run.in_tolerance, message=message
        )
