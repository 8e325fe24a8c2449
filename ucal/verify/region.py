"""Region check (``ucal verify --region N``): the kinematic model against the block's faces over
postures spread like a full calibration's.

``ucal verify`` checks twenty points above one face; a model fitted near one configuration can
pass it and still be wrong across the workspace. Here the model under test (the profile's
table, ``[calibration] dh`` where present, with its joint offsets and tool) is held fixed and
the block is measured from N postures spread over what the block allows (the candidates of
``ucal.model.postures``, chosen farthest apart in J1-J3 and face, not the calibration's
own). Each measurement gives a normal-incidence posture and a water path; only the block's pose,
the sound speed and the tool's orientation are fitted to them (the cell's, not the robot's
kinematics), so what remains
is the model's error in the directions ultrasound sees: the beam's tilt (deg) and the distance
along each face's normal (mm). A χ² test against the measurements' own noise gives the verdict;
the largest residuals must stay within ``--tolerance-mm`` (distances) as well.

The run is the full level's (``ucal.measure.postures.run_full``): each posture's arm is
re-placed onto the block as measured so far (``retarget``). So the postures keep the full
plan's room for what the run does not know yet (``ucal.model.postures.visit_order``):
three sigma of the block's tolerance and of the joint offsets' std (``[calibration] std_deg``;
a fresh cell's degree where ``calibrate`` has not written it, so after a calibrate the room
shrinks to what is left), visited in an order where each has it, or the plan is refused before
any motion naming the cure (calibrate the offsets first, or where to move the block).
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from ucal.cell import CellProfile
from ucal.devices.session import CellSession
from ucal.measure.postures import FullRun, estimate_postures, run_full
from ucal.model.fit import (
    BETA,
    DH,
    OFFSETS,
    TOOL,
    prior_from_profile,
    readings_approach,
    solve_cell,
)
from ucal.model.geometry import FaceMeasurement
from ucal.model.postures import (
    FullPlan,
    Posture,
    candidate_postures,
    no_candidates,
    posture_jacobians,
    unknown_spread,
    visit_order,
)
from ucal.procedure import CheckingJob, Measured, Outcome, RunFacts, plan_rows
from ucal.progress import Report
from ucal.timing import DurationEstimate
from ucal.verify.inputs import wrist_left_unidentified, written_budget
from ucal.verify.result import RegionCheck, RegionResult

#: Joint-space weights of the farthest-point spread (deg of J1, J2, J3; a face change = 30°).
_SPREAD_FACE_DEG = 30.0
#: What a refused plan names.
_COMMAND = "plan verify --region"


def plan_region(
    profile: CellProfile, n: int, seed: int = 0, exclude: tuple[Posture, ...] = ()
) -> FullPlan:
    """``n`` checked postures spread farthest apart (J1-J3 and face) over the candidates,
    starting from a seeded random one, none within 1° of an ``exclude`` posture, visited in
    an order where each keeps the room the run needs (module docstring; ``SafetyError``
    naming the cure where none has it, or where the block leaves no candidate)."""
    cands = [
        c
        for c in candidate_postures(profile)
        if not c.step  # the faces only: the model is judged, not the step
        and all(np.max(np.abs(c.joints_deg - e.joints_deg)) > 1.0 for e in exclude)
    ]
    if not cands:
        raise no_candidates(profile, _COMMAND)
    key = np.array([np.append(c.joints_deg[:3], _SPREAD_FACE_DEG * c.face) for c in cands])
    rng = np.random.default_rng(seed)
    chosen = [int(rng.integers(len(cands)))]
    dist = np.linalg.norm(key - key[chosen[0]], axis=1)
    while len(chosen) < min(n, len(cands)):
        i = int(np.argmax(dist))
        chosen.append(i)
        dist = np.minimum(dist, np.linalg.norm(key - key[i], axis=1))
    prior = prior_from_profile(profile)
    jacs, names = posture_jacobians(prior, profile, cands)
    spread = unknown_spread(profile, prior, names)
    order = visit_order(profile, cands, jacs, spread, chosen, len(chosen), _COMMAND)
    postures = [
        Posture(f"r{i + 1:02d}", cands[k].face, cands[k].joints_deg, cands[k].water_path_mm)
        for i, k in enumerate(order)
    ]
    j1 = [p.joints_deg[0] for p in postures]
    return FullPlan(
        tuple(postures), len(cands), float("nan"), float("nan"), (float(min(j1)), float(max(j1)))
    )


def judge_region(
    profile: CellProfile, meas: list[FaceMeasurement], tolerance_mm: float
) -> RegionResult:
    """Fit only the block pose and the sound speed to ``meas`` with the profile's model held;
    the residuals are the model's (module docstring)."""
    prior = prior_from_profile(profile)
    # the robot's model is what is checked; the block, the water and the tool's orientation
    # (tool-frame's, and invisible to the kinematics of the TCP) are the cell's
    cell = solve_cell(prior, meas, fixed=OFFSETS + DH + BETA + TOOL[:3])
    q = cell.quality
    dist = np.array(
        [r.distance * m.distance_std_mm for r, m in zip(q.residuals, meas, strict=True)]
    )
    tilt = np.array(
        [np.hypot(*r.tilt) * m.tilt_std_deg for r, m in zip(q.residuals, meas, strict=True)]
    )
    return RegionResult(
        len(meas),
        float(np.sqrt(np.mean(dist**2))),
        float(np.max(np.abs(dist))),
        float(np.sqrt(np.mean(tilt**2))),
        float(np.max(tilt)),
        q.chi2_reduced,
        q.verdict,
        q.worst,
        tolerance_mm,
        approach=readings_approach(meas),
    )


def plan_summary(plan: FullPlan, profile_path: Path) -> str:
    """The region check's plan in words, for the technician before the first motion."""
    lo, hi = plan.azimuths_deg
    lines = [
        f"Region check of {profile_path}: {len(plan.postures)} postures spread over "
        f"{plan.candidates} candidates, J1 {lo:.1f} to {hi:.1f} deg; the model is held, only "
        "the block pose, the sound speed and the tool's orientation are fitted"
    ]
    lines += [
        f"  {p.label} {p.face_name:<3}" + "".join(f"{v:9.2f}" for v in p.joints_deg)
        for p in plan.postures
    ]
    return "\n".join(lines)


class RegionJob(CheckingJob):
    """``verify --region N``: the model judged over N spread postures; writes nothing."""

    def __init__(
        self,
        profile: CellProfile,
        profile_path: Path,
        n_postures: int,
        tolerance_mm: float | None = None,
    ) -> None:
        super().__init__(profile, profile_path, tolerance_mm)
        self.n_postures = n_postures

    def plan(self) -> FullPlan:
        return plan_region(self.profile, self.n_postures)

    def summary(self, plan: FullPlan) -> str:
        return plan_summary(plan, self.profile_path)

    def estimate(self, plan: FullPlan) -> DurationEstimate:
        return estimate_postures(plan, self.profile)

    def record_header(self, plan: FullPlan) -> dict[str, Any]:
        return {"options": {"region": self.n_postures}, "plan": plan_rows(plan.postures)}

    def measure(self, plan: FullPlan, session: CellSession, report: Report) -> FullRun:
        """Each posture measured as ``calibrate --level full`` measures it."""
        return run_full(self.profile, plan, session.rig, report)

    def solve(self, plan: FullPlan, measured: Measured[FullRun]) -> RegionResult:
        solved = judge_region(self.profile, measured.data.measurements, self.tolerance_mm)
        return replace(
            solved,
            unidentified_tcp_mm=written_budget(self.profile_path),
            unidentified_names=wrist_left_unidentified(self.profile),
        )

    def may_write(self, solved: RegionResult) -> bool:
        return False

    def write(self, solved: RegionResult) -> None:
        raise AssertionError("a region check writes nothing")

    def result(
        self, plan: FullPlan, measured: Measured[FullRun], solved: RegionResult, written: bool
    ) -> Outcome[RegionCheck]:
        return Outcome(
            self.command,
            RegionCheck(solved, RunFacts.of(measured, self.profile_path, written=False)),
            written=False,
            out_of_tolerance=not solved.passed,
            message=solved.message(),
        )
