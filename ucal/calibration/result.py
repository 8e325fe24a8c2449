"""The calibration as ``calibrate`` reports it: one typed result per level, the tables and
``--json`` drawn from it.

``OffsetsResult`` (``--level offsets``: both methods' solutions, the joints kept as measured
too weakly, the joint steps) and ``FullResult`` (``--level full``: the identified model and the
D-optimal plan) share ``CalibrationResult``: the chosen solution with its fit and verdict, the
solution that fitted the sound speed and the run's effects (drift, lost motion), the block as
measured, what the unidentified quantities allow at the tool centre, and what became of the run
(``ucal.procedure.RunFacts``; on a simulated cell, the truth).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, ClassVar, Generic, Protocol, TypeVar

import numpy as np

from ucal.calibration.budget import TcpBudget
from ucal.calibration.exact import OffsetSolution
from ucal.calibration.load import load_posture
from ucal.calibration.weak import WeakJoint
from ucal.measure.approach import APPROACH
from ucal.model.fit import FitQuality, RunEffects
from ucal.model.gauge import J1Gauge, gauge_fields, j1_relative_to_block
from ucal.model.geometry import FaceMeasurement
from ucal.model.kinematic import FullSolution
from ucal.model.postures import FullPlan
from ucal.model.readings import CalibrationReadings
from ucal.model.residuals import reference_time_min
from ucal.model.stiffness import stiffness_note
from ucal.procedure import RunFacts
from ucal.sim.cell import SimulatedCell

#: Why ``backlash_deg`` is null: no joint was read from both sides.
BACKLASH_NOTE = (
    "lost motion not measured: every posture was approached from below (--lost-motion, or a "
    "full plan long enough to spare postures, reads some from above), so the offsets hold for "
    "that approach (a joint with lost motion b reached from above is off by b/2)"
)

Solution = OffsetSolution | FullSolution


def backlash_note(effects: RunEffects | None) -> str:
    """What the run measured of the lost motion, in words for the result."""
    if effects is None or not np.any(np.isfinite(effects.backlash_deg)):
        return BACKLASH_NOTE
    measured = np.flatnonzero(np.isfinite(effects.backlash_deg))
    joints = ", ".join(
        f"J{j + 1} {effects.backlash_deg[j]:.4f} ± {effects.backlash_std_deg[j]:.4f}°"
        for j in measured
    )
    return (
        f"lost motion measured on {joints} (read from both sides); the offsets are those of the "
        "positive approach"
    )


def run_effects(sound: Solution) -> RunEffects | None:
    """The drift and lost motion of the solution that fitted the sound speed, if it has a fit."""
    cell = sound.cell_fit
    return None if cell is None else RunEffects.of(cell)


class Verdict:
    """Whether a solution may be written, and the one-line message when not."""

    def __init__(self, ok: bool, misfit_only: bool, message: str):
        self.ok = ok
        self.misfit_only = misfit_only
        self.message = message


class Judged(Protocol):
    """What the results of both levels read of what their solve step concluded."""

    @property
    def chosen(self) -> Solution:
        """The solution reported and written."""
        ...

    @property
    def sound(self) -> Solution:
        """The solution that fitted the sound speed, the drift and the lost motion."""
        ...

    @property
    def fit(self) -> FitQuality: ...

    @property
    def verdict(self) -> Verdict: ...

    @property
    def budget(self) -> TcpBudget | None:
        """What the unidentified quantities' priors allow at the tool centre
        (``ucal.calibration.budget``)."""
        ...


SolvedT = TypeVar("SolvedT", bound=Judged)


@dataclass
class OffsetsSolved:
    """Both solutions of a run, the one chosen and its verdict."""

    exact: OffsetSolution
    paper: OffsetSolution | None
    chosen: OffsetSolution
    fit: FitQuality
    verdict: Verdict
    #: 1-based joint → its estimate, measured too weakly to write (kept at the profile value)
    weak: dict[int, WeakJoint]
    budget: TcpBudget | None = None

    @property
    def sound(self) -> OffsetSolution:
        return self.exact


@dataclass
class FullSolved:
    """The identified model, its fit and its verdict."""

    chosen: FullSolution
    fit: FitQuality
    verdict: Verdict
    budget: TcpBudget | None = None

    @property
    def sound(self) -> FullSolution:
        return self.chosen


@dataclass(frozen=True)
class CalibrationResult(Generic[SolvedT]):
    """What both levels report (SPEC.md's ``calibrate --json`` fields every level gives)."""

    run: RunFacts
    #: The block as the fit measured it (``ucal.model.gauge.block_pose``; None: the
    #: paper's equations measure none).
    block: dict[str, Any] | None
    solved: SolvedT

    level: ClassVar[str]

    @property
    def effects(self) -> RunEffects | None:
        return run_effects(self.solved.sound)

    @property
    def gauge(self) -> J1Gauge | None:
        chosen = self.solved.chosen
        return None if chosen.std_block_deg is None else chosen.gauge

    def weak(self) -> dict[int, WeakJoint]:
        """Joints measured too weakly to write (the offsets level's; none at the full level)."""
        return {}

    def to_json(self) -> dict[str, Any]:
        """The ``calibrate --json`` object of SPEC.md (and more)."""
        return {**self.common_json(), **self.level_json(), **self.verdict_json()}

    def level_json(self) -> dict[str, Any]:
        """The level's own fields, after the common ones."""
        raise NotImplementedError

    def common_json(self) -> dict[str, Any]:
        """The fields every level reports, and the block."""
        chosen, sound, fit, run = self.solved.chosen, self.solved.sound, self.solved.fit, self.run
        gauge, effects = self.gauge, self.effects
        return {
            "joint_offsets_deg": chosen.offsets_deg,
            "std_deg": [float(v) if np.isfinite(v) else None for v in chosen.std_deg],
            "unobservable_joints": list(chosen.unobservable_joints),
            "unobservable_reasons": {str(j): r for j, r in chosen.unobservable_reasons.items()},
            **(
                {}
                if gauge is None or chosen.std_block_deg is None
                else gauge_fields(chosen.std_block_deg, gauge)
            ),
            "method": chosen.method,
            "level": self.level,
            "approach": APPROACH,
            "load_posture_deg": load_posture(chosen, sound),
            # SPEC.md: null where not measured (readings from one side only)
            "backlash_deg": [None] * 6,
            "backlash_std_deg": [None] * 6,
            "sound_speed_drift_m_s_per_min": None,
            "sound_speed_drift_m_s_per_min_std": None,
            **({} if effects is None else effects.to_json()),
            "backlash_note": backlash_note(effects),
            "moves": run.moves,
            "pulser_reads": run.reads,
            # time the run took on the cell: simulated time on the simulated cell (what a real
            # cell would take over Modbus TCP)
            "duration_s": run.duration_s,
            "profile": str(run.profile_path),
            "written": run.written,
            "sound_speed_m_s": sound.sound_speed_m_s,
            "sound_speed_std_m_s": sound.sound_speed_std_m_s,
            "fit": fit.to_json(),
            "residuals": [
                {"label": r.label, "tilt": list(r.tilt), "distance": r.distance}
                for r in fit.residuals
            ],
            "block": self.block,
        }

    def budget_json(self) -> dict[str, object] | None:
        budget = self.solved.budget
        return None if budget is None else budget.to_json()

    def verdict_json(self) -> dict[str, Any]:
        """Out of tolerance or not and, on the simulated cell, the true offsets."""
        out: dict[str, Any] = {"out_of_tolerance": not self.solved.verdict.ok}
        truth = self.run.truth
        if truth is not None:
            out["truth_offsets_deg"] = truth.joint_offsets_deg
            cell = self.solved.chosen.cell_fit or self.solved.sound.cell_fit
            if truth.arm.bends and cell is not None and cell.load_posture_deg is not None:
                # what the offsets hold on a bent arm: each link's sag at the load posture
                out["truth_load_sag_deg"] = SimulatedCell(truth).sag_deg(
                    cell.load_posture_deg, np.ones(6)
                )
            if truth.arm.bends:
                out["truth_stiffness_nm_per_rad"] = truth.arm.stiffness_nm_per_rad
            if self.block is not None:
                out["truth_offsets_block_deg"] = self.truth_offsets_block_deg()
        return out

    def truth_offsets_block_deg(self) -> np.ndarray:
        """What the block gauge should give: J1 relative to the true block as placed."""
        truth = self.run.truth
        assert truth is not None and self.block is not None
        relative = np.array(truth.joint_offsets_deg, float)
        relative[0] = j1_relative_to_block(
            relative[0], truth.sample_rotation_deg, self.block["rotation_deg"][2]
        )
        return relative


@dataclass(frozen=True)
class OffsetsResult(CalibrationResult[OffsetsSolved]):
    """``calibrate --level offsets``: the six joint offsets."""

    joint_steps_deg: dict[str, float | None]  # "arm" (J2, J3) and "azimuth" (J1; None: no room)

    level: ClassVar[str] = "offsets"

    def weak(self) -> dict[int, WeakJoint]:
        return self.solved.weak

    def level_json(self) -> dict[str, Any]:
        return {
            "condition_number": self.solved.chosen.condition_number,
            "joint_steps_deg": self.joint_steps_deg,
            "weak_joints": {str(j): w.to_json() for j, w in self.solved.weak.items()},
            "unidentified_tcp_mm": self.budget_json(),
        }


@dataclass(frozen=True)
class FullResult(CalibrationResult[FullSolved]):
    """``calibrate --level full``: the identified kinematic model and the joint offsets."""

    plan: FullPlan

    level: ClassVar[str] = "full"

    def level_json(self) -> dict[str, Any]:
        sol, plan = self.solved.chosen, self.plan
        return {
            "dh": sol.dh_rows(),
            "dh_std": [
                {k: (None if v < 0 else v) for k, v in row.items()} for row in sol.dh_std_rows()
            ],
            "identification": sol.to_json(),
            # SPEC.md: null where not identified (ucal.model.stiffness)
            "stiffness_nm_per_rad": [s.stiffness_nm_per_rad for s in sol.stiffness],
            "stiffness_std_nm_per_rad": [s.std_nm_per_rad for s in sol.stiffness],
            "stiffness_std_pct": [s.std_pct if s.identified else None for s in sol.stiffness],
            "stiffness_status": [s.status for s in sol.stiffness],
            "stiffness_note": stiffness_note(sol.stiffness),
            "unidentified_tcp_mm": self.budget_json(),
            "plan": {
                "postures": len(plan.postures),
                "candidates": plan.candidates,
                "log_det": plan.log_det,
                "d_criterion": plan.d_criterion,
            },
        }


def calibration_readings(
    faces: Sequence[FaceMeasurement], conversion_m_s: float, sound: Solution
) -> CalibrationReadings:
    """The readings ``faces`` a fit received, converted with ``conversion_m_s``, and what
    ``sound`` (the solution that fitted the sound speed) found of the tank."""
    effects = run_effects(sound)
    rate, rate_std = (
        (0.0, float("nan"))
        if effects is None
        else (
            effects.drift_m_s_per_min,
            effects.drift_std_m_s_per_min,
        )
    )
    return CalibrationReadings(
        tuple(faces),
        float(conversion_m_s),
        float(sound.sound_speed_m_s),
        float(sound.sound_speed_std_m_s),
        float(rate),
        float(rate_std),
        reference_time_min(list(faces)),
    )
