"""The ``check`` command's job on the measuring procedure (``ucal.procedure``).

Check the files (the profile held for the run: the check is appended to its history), plan
(``ucal.check.plan``: the postures, the reference to compare against), measure
(``ucal.check.measure``), solve (``ucal.check.solve``: what moved), write (the history entry:
``ucal.check.history``; the profile itself is never written), result (``ucal.check.result``).
With the tank thermometer's log (``--thermometer``) the measuring procedure has taken its turns
out of the water paths and set the drift's prior before ``solve`` (``ucal.procedure``); the
history entry keeps that run's water, and a later check fits the reference's drift with it.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Any

from ucal.cell import CellProfile
from ucal.check.causes import causes, water_words
from ucal.check.edges import EdgeReading
from ucal.check.history import append_check, model_digest, reference_check
from ucal.check.judge import (
    NOT_DETERMINED,
    echo_quantities,
    echo_record,
    geometry_quantities,
    profile_quantities,
)
from ucal.check.measure import CheckRun, EchoReading, run_check
from ucal.check.observe import what_would_determine
from ucal.check.plan import CheckPlan, estimate_check, plan_check, plan_summary
from ucal.check.profile_fit import compare_to_profile
from ucal.check.result import (
    CheckFindings,
    CheckResult,
    misfit_text,
    named_changes,
    unexplained_text,
)
from ucal.check.solve import (
    compare_geometry,
)
from ucal.devices.session import CellSession
from ucal.model.fit import prior_from_profile
from ucal.model.readings import faces_from_json
from ucal.procedure import Measured, Outcome, ProfileJob, RunFacts, plan_rows
from ucal.progress import Report
from ucal.timing import DurationEstimate


class CheckJob(ProfileJob):
    """``ucal check``: the cell against its commissioning (the reference check)."""

    command = "check"

    def __init__(self, profile: CellProfile, profile_path: Path, baseline: bool = False) -> None:
        super().__init__(profile, profile_path)
        self.baseline = baseline
        self.digest = model_digest(profile)
        self.duration_s = 0.0

    def plan(self) -> CheckPlan:
        reference = None if self.baseline else reference_check(self.profile_path, self.digest)
        return plan_check(self.profile, reference, self.baseline)

    def summary(self, plan: CheckPlan) -> str:
        return plan_summary(plan, self.profile, self.estimate(plan))

    def estimate(self, plan: CheckPlan) -> DurationEstimate:
        return estimate_check(plan, self.profile)

    def record_header(self, plan: CheckPlan) -> dict[str, Any]:
        return {
            "options": {"baseline": self.baseline},
            "plan": plan_rows(plan.targets),
            # a replay compares against it as recorded (the plan, ucal.procedure), whatever
            # the history holds by then
            "reference": None if plan.reference is None else plan.reference.id,
        }

    def measure(self, plan: CheckPlan, session: CellSession, report: Report) -> CheckRun:
        return run_check(self.profile, plan, session.rig, progress=report)

    def solve(self, plan: CheckPlan, measured: Measured[CheckRun]) -> CheckFindings:
        run = measured.data
        self.duration_s = measured.duration_s
        prior = prior_from_profile(self.profile)
        ref = plan.reference
        if ref is None:
            fit = compare_to_profile(self.profile, prior, run.faces)
            echo = echo_record(run.echoes, self.profile.frequency_mhz)
            named, moved = named_changes(None, echo, prior)
            if fit.misfit:
                moved.append("calibration")
            return CheckFindings(
                profile_quantities(fit, prior) + echo,
                named,
                moved,
                None,
                profile_fit=fit,
                unexplained=misfit_text(fit) if fit.misfit else "",
                run=run,
            )
        # the reference run's water as its own thermometer's log left it (or none)
        reference_prior = replace(
            prior,
            logged_departure_std_c=ref.logged_departure_std_c,
            drift_prior_c_per_min=ref.drift_prior_c_per_min,
        )
        edges = ([EdgeReading.from_json(e) for e in ref.edges], run.edges)
        geometry = compare_geometry(
            prior, faces_from_json(ref.faces), run.faces, reference_prior, edges
        )
        echo = echo_quantities([EchoReading.from_json(e) for e in ref.echoes], run.echoes)
        named, moved = named_changes(geometry, echo, prior)
        quantities = geometry_quantities(geometry, prior) + echo
        edges_read = bool(edges[0]) and bool(edges[1])
        water = water_words(geometry, prior)
        return CheckFindings(
            quantities,
            named,
            moved,
            ref,
            geometry=geometry,
            unexplained=unexplained_text(geometry),
            run=run,
            causes=causes(geometry),
            noted=[water] if water else [],
            undetermined={
                q.name: what_would_determine(q.name, self.profile, edges_read)
                for q in quantities
                if q.verdict == NOT_DETERMINED
            },
        )

    def may_write(self, solved: CheckFindings) -> bool:
        return True  # every check goes into the history: a drift shows as a trend

    def write(self, solved: CheckFindings) -> None:
        entry = solved.history_entry(self.digest, self.duration_s, prior_from_profile(self.profile))
        solved.entry = append_check(self.profile_path, entry)

    def result(
        self, plan: CheckPlan, measured: Measured[CheckRun], solved: CheckFindings, written: bool
    ) -> Outcome[CheckResult]:
        result = CheckResult(
            solved,
            RunFacts.of(measured, self.profile_path, written),
            self.estimate(plan),
            [t.label for t in plan.targets],
        )
        return Outcome(
            "check",
            result,
            written,
            out_of_tolerance=solved.out_of_tolerance,
            message=solved.message(),
        )
