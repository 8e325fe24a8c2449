"""The joint-offset calibration procedure (paper 000): the ``calibrate`` command's job.

Read with ``ucal.procedure`` (the order every moving command follows): the plan and its checks
(``ucal.measure.sequence.plan_calibration``), the plan in words (``plan_summary``), the
measurement of every planned face (``run_calibration``: the rig, ``ucal.devices.rig``; a face
measurement, ``ucal.measure.face``), the solvers (``ucal.measure.sequence.solve``:
``exact`` with the cell's tolerances as priors, ``paper`` for comparison), the verdict
(``judge``), the ``[calibration]`` keys written and the typed result the tables and ``--json``
are drawn from (``ucal.calibration.result``).

``calibrate --level full`` (``FullCalibration``) goes through the same steps with its own plan
(``ucal.model.postures``: postures chosen by D-optimality), measurement
(``ucal.measure.postures``) and identification (``ucal.model.kinematic``), and the same
verdict, ``[calibration]`` keys and result fields (``CalibrationJob`` holds what both share).
"""

from __future__ import annotations

import datetime as dt
from collections.abc import Iterable
from pathlib import Path
from typing import Any, Literal, Protocol, TypeVar

import numpy as np

from ucal.acoustics import sound_speed_m_s
from ucal.calibration.budget import TcpBudget, calibration_budget
from ucal.calibration.load import load_posture
from ucal.calibration.result import (
    CalibrationResult,
    FullResult,
    FullSolved,
    Judged,
    OffsetsResult,
    OffsetsSolved,
    Solution,
    SolvedT,
    Verdict,
    calibration_readings,
    run_effects,
)
from ucal.calibration.solve import beam_fixed, solve
from ucal.calibration.weak import keep_weak
from ucal.cell import CellProfile
from ucal.devices.session import CellSession
from ucal.errors import UcalError
from ucal.measure.approach import APPROACH
from ucal.measure.postures import FullRun, estimate_postures, run_full
from ucal.measure.sequence import CalibrationRun, run_calibration, with_lost_motion
from ucal.model.fit import (
    PRIOR_MEANING,
    CellFit,
    FitQuality,
    prior_from_profile,
)
from ucal.model.gauge import (
    J1Gauge,
    block_keys,
    block_pose,
)
from ucal.model.geometry import FACE_NAMES, FaceMeasurement
from ucal.model.kinematic import solve_full
from ucal.model.postures import FullPlan, first_postures, plan_full
from ucal.model.readings import CalibrationReadings, write_readings
from ucal.model.stiffness import written_stiffness
from ucal.model.targets import CalibrationPlan, plan_calibration
from ucal.procedure import (
    WRIST_SEARCH,
    CountedT,
    Measured,
    Outcome,
    ProfileJob,
    RunFacts,
    plan_line,
    plan_rows,
)
from ucal.profile import description_keys, write_profile
from ucal.profile.calibration import WrittenCalibration
from ucal.profile.models import joint_speeds_deg_s
from ucal.progress import Report
from ucal.timing import DurationEstimate, estimate_run

#: An offset less certain than this is not written: a joint the data determine that weakly is
#: kept at its profile value with the reason (``ucal.calibration.weak``); the paper method's
#: truncation error beyond it is out of tolerance.
TOLERANCE_STD_DEG = 0.02

CalibrationT = TypeVar("CalibrationT", bound=CalibrationResult[Any])


class JointSolution(Protocol):
    """What ``judge`` reads of a solution, whichever level solved it."""

    @property
    def offsets_deg(self) -> np.ndarray: ...

    @property
    def std_deg(self) -> np.ndarray: ...

    @property
    def unobservable_joints(self) -> tuple[int, ...]: ...

    @property
    def cell_fit(self) -> CellFit | None: ...

    @property
    def truncation_deg(self) -> np.ndarray | None: ...

    @property
    def std_block_deg(self) -> np.ndarray | None: ...


def written(
    level: Literal["offsets", "full"],
    chosen: Any,
    sound: Any,
    fit: FitQuality,
    budget: TcpBudget | None,
    **own: Any,
) -> WrittenCalibration:
    """The ``[calibration]`` table a run of ``level`` writes: the offsets, their std (absolute,
    and relative to the block as placed: ``ucal.model.gauge``), the gauge, the sound speed and
    its drift, the lost motion (``sound``: the solution that fitted them), the fit, the TCP
    budget (``[calibration] unidentified_tcp_mm``: mean, max over the scanning region, one
    sigma, which ``verify --region`` reports beside what it measures) and the level's ``own``
    keys."""
    gauge: J1Gauge | None = chosen.gauge
    relative: dict[str, Any] = {}
    if gauge is not None and chosen.std_block_deg is not None:
        relative = {
            "gauge": gauge.frame,
            "gauge_note": gauge.statement(),
            "std_block_deg": [float(v) for v in chosen.std_block_deg],
        }
    effects = run_effects(sound)
    lost: dict[str, Any] = {}
    if effects is not None:
        lost = {
            "backlash_deg": [float(v) for v in effects.backlash_deg],
            "backlash_std_deg": [float(v) for v in effects.backlash_std_deg],
            "sound_speed_drift_m_s_per_min": effects.drift_m_s_per_min,
            "sound_speed_drift_m_s_per_min_std": effects.drift_std_m_s_per_min,
        }
    return WrittenCalibration(
        level=level,
        joint_offsets_deg=[float(v) for v in chosen.offsets_deg],
        std_deg=[float(v) for v in chosen.std_deg],
        unobservable_joints=list(chosen.unobservable_joints),
        method=chosen.method,
        approach=APPROACH,
        sound_speed_m_s=float(sound.sound_speed_m_s),
        fit_verdict=fit.verdict,
        chi2_reduced=float(fit.chi2_reduced),
        date=dt.datetime.now(dt.UTC).isoformat(timespec="seconds"),
        unidentified_tcp_mm=None if budget is None else (budget.mean_mm, budget.max_mm),
        load_posture_deg=load_posture(chosen, sound),
        **relative,
        **lost,
        **own,
    )


def block_measured(cell: CellFit | None, profile: CellProfile) -> dict[str, Any] | None:
    """The block as the fit measured it (the block gauge, ``ucal.model.gauge``), or
    None without a fit."""
    if cell is None:
        return None
    return block_pose(cell, float(np.broadcast_to(profile.sample_rotation_std_deg, 3)[2]))


def block_written(cell: CellFit | None, profile: CellProfile) -> dict[str, Any] | None:
    """``[sample]`` keys of the block as the fit measured it: its pose, not its stds; and the
    block as placed kept beside it (``ucal.profile.described``)."""
    block = block_measured(cell, profile)
    if block is None:
        return None
    keys = block_keys(block)
    return keys | description_keys(profile, "sample", keys["position_mm"], keys["rotation_deg"])


def write_calibration(
    profile_path: Path,
    run: str,
    fit: FitQuality,
    verdict: Verdict,
    table: WrittenCalibration,
    block: dict[str, Any] | None = None,
    readings: CalibrationReadings | None = None,
) -> None:
    """Write ``table`` as ``[calibration]`` (and ``block`` as ``[sample]``: the block as the
    fit measured it), the history naming the ``run``, its fit and, when written with
    ``--force``, why it was out of tolerance; ``readings`` (what the fit received) beside its
    history entry (``ucal.model.readings``: verify reads the tank again at them)."""
    reason = f"{run}: fit {fit.verdict} (χ²ᵣ {fit.chi2_reduced:.3g})"
    if not verdict.ok:
        reason += f", written with --force: {verdict.message}"
    keys = table.table()
    updates = {"calibration": keys} if block is None else {"calibration": keys, "sample": block}
    entry = write_profile(profile_path, updates, reason=reason)
    if entry is not None and readings is not None:
        write_readings(profile_path, entry, readings)


def judge(chosen: JointSolution, fit: FitQuality) -> Verdict:
    """Judge a solution: a misfit, or an observable offset less certain than the tolerance.

    At the offsets level a joint the measurements determine weakly has already been kept at its
    profile value (``ucal.calibration.weak``) and is unobservable here; what remains loose is
    the paper method's truncation (or the full level's joints). A misfit names the worst
    measurement and the likely cause; a std above ``TOLERANCE_STD_DEG`` names the joint and
    what its uncertainty comes from (noise, or the method's truncation for the paper method).
    Stds are judged relative to the block as placed (``std_block_deg``): J1's absolute std
    carries the block's yaw tolerance, which a hand-placed block makes 0.5°, and is reported,
    not judged.
    """
    observable = [j for j in range(6) if j + 1 not in chosen.unobservable_joints]
    # relative to the block as placed (J1: without the block's yaw, ucal.model.gauge)
    std = chosen.std_deg if chosen.std_block_deg is None else chosen.std_block_deg
    loose = [j for j in observable if not np.isfinite(std[j]) or std[j] > TOLERANCE_STD_DEG]
    if fit.verdict == "misfit":
        msg = (
            f"calibration misfit: the measurements disagree with the model (χ²ᵣ "
            f"{fit.chi2_reduced:.3g} on {fit.dof} degrees of freedom; worst: {fit.worst}); "
            f"likely cause: {fit.cause}; the profile was not written (--force writes it)"
        )
        return Verdict(False, not loose, msg)
    if loose:
        j = max(loose, key=lambda k: std[k] if np.isfinite(std[k]) else np.inf)
        why = ""
        trunc = chosen.truncation_deg
        cell = chosen.cell_fit
        shares = cell.variance_share.get(f"J{j + 1}", {}) if cell is not None else {}
        source = max(shares, key=lambda k: shares[k]) if shares else "data"
        if trunc is not None and trunc[j] > 0.5 * std[j]:
            why = (
                f", mostly the paper method's first-order truncation error ({trunc[j]:.3g} "
                "deg, about half the joint step); use --method exact"
            )
        elif source != "data":
            why = (
                f", mostly from {PRIOR_MEANING.get(source, source)} "
                f"({100 * shares[source]:.0f} % of its variance)"
            )
        else:
            worst = max(fit.residuals, key=lambda r: r.norm).label if fit.residuals else "?"
            why = (
                f": the measurements' own scatter ({100 * shares.get('data', 1.0):.0f} % of "
                f"its variance; the peak postures are uncertain, worst fitted {worst}); check "
                "the water, the gain and the transducer, or measure again"
            )
        return Verdict(
            False,
            False,
            f"calibration out of tolerance: J{j + 1}'s std {std[j]:.3g} deg exceeds "
            f"{TOLERANCE_STD_DEG} deg{why}; the profile was not written",
        )
    return Verdict(True, False, "")


def plan_summary(plan: CalibrationPlan, profile: CellProfile) -> str:
    """The plan in words for the confirmation (stderr); the procedure adds the estimated
    duration."""
    temp = profile.water_temperature_c
    c_std = prior_from_profile(profile).sound_speed_std_m_s
    azimuth = (
        f", joint 1 by ±{plan.azimuth_step_deg:g} deg (second azimuth)"
        if plan.azimuth_step_deg
        else ", no room for a second J1 azimuth"
    )
    lines = [
        (
            f"Calibration plan for {profile.model.name}: {len(plan.targets)} normal-incidence "
            f"measurements; joints 2 and 3 stepped by ±{plan.step_deg:g} deg{azimuth} (the sign is "
            "chosen on the way for clearance)"
        ),
        (
            f"Water {temp:g} ± {profile.water_temperature_std_c:g} °C: sound speed "
            f"{sound_speed_m_s(temp):.2f} ± {c_std:.2f} m/s (Marczak), fitted with the offsets; "
            f"transducer {profile.frequency_mhz:g} MHz, {profile.element_diameter_mm:g} mm"
        ),
    ]
    if plan.sound_speed_gain_deg_per_m_s is not None:
        gain = plan.sound_speed_gain_deg_per_m_s
        noise = plan.distance_noise_gain_deg_per_um
        assert noise is not None
        j = int(np.argmax(gain[1:5])) + 1
        k = int(np.argmax(noise[1:5])) + 1
        per_c = c_std / max(profile.water_temperature_std_c, 1e-9)  # m/s per °C
        lines.append(
            f"Amplification of this plan: 1 °C of water temperature ({per_c:.2f} m/s), if not "
            f"fitted, would move J{j + 1} by {gain[j] * per_c:.3f} deg; 1 µm of water-path "
            f"noise gives J{k + 1} a std of {noise[k]:.4f} deg"
        )
    lines.append("  target      J1       J2       J3       J4       J5       J6    water path")
    lines += [plan_line(f"{t.config:>4}/{FACE_NAMES[t.face]:<3}", t) for t in plan.targets]
    if plan.above:
        lines.append(from_above(t.label for t in plan.above) + ", measured again at the end")
    if plan.path_again:
        lines.append(
            "At the end the first face's water path is read again where it was read: the "
            "tank's drift over the run"
        )
    return "\n".join([*lines, WRIST_SEARCH])


def from_above(labels: Iterable[str]) -> str:
    """The plan's line for the postures reached from above (each joint's lost motion)."""
    return f"From above on every joint (lost motion): {', '.join(labels)}"


class CalibrationJob(ProfileJob):
    """What both levels share: the beam's treatment (``--beam``), ``--force``, the verdict that
    lets the result be written, and the outcome."""

    command = "calibrate"

    def __init__(
        self, profile: CellProfile, profile_path: Path, beam: str = "auto", force: bool = False
    ) -> None:
        super().__init__(profile, profile_path)
        self.beam = beam
        self.force = force
        self.faces: list[FaceMeasurement] = []  # what the fit received (solve)

    def readings(self, sound: Solution) -> CalibrationReadings:
        """The faces the fit received, with what ``sound`` found of the tank, as the history
        keeps them beside the write."""
        conversion = float(sound_speed_m_s(self.profile.water_temperature_c))
        return calibration_readings(self.faces, conversion, sound)

    def may_write(self, solved: Judged) -> bool:
        return solved.verdict.ok or self.force

    def found(
        self, measured: Measured[CountedT], solved: SolvedT, written: bool
    ) -> tuple[RunFacts, dict[str, Any] | None, SolvedT]:
        """What either level's result begins with: the run, the block as measured, the
        solution."""
        block = block_measured(solved.chosen.cell_fit, self.profile)
        return RunFacts.of(measured, self.profile_path, written), block, solved

    def outcome(self, result: CalibrationT) -> Outcome[CalibrationT]:
        """The outcome of either level: out of tolerance as the verdict says."""
        verdict = result.solved.verdict
        return Outcome(
            self.command,
            result,
            result.run.written,
            out_of_tolerance=not verdict.ok,
            message=verdict.message,
        )


class OffsetsCalibration(CalibrationJob):
    """``calibrate --level offsets``: the six joint offsets → ``[calibration]``."""

    def __init__(
        self,
        profile: CellProfile,
        profile_path: Path,
        method: str = "exact",
        beam: str = "auto",
        force: bool = False,
        lost_motion: bool = False,
    ) -> None:
        super().__init__(profile, profile_path, beam, force)
        self.method = method
        self.lost_motion = lost_motion  # the calibration pose's faces again, from above

    def plan(self) -> CalibrationPlan:
        plan = plan_calibration(self.profile)
        return with_lost_motion(plan) if self.lost_motion else plan

    def summary(self, plan: CalibrationPlan) -> str:
        return plan_summary(plan, self.profile)

    def estimate(self, plan: CalibrationPlan) -> DurationEstimate:
        targets = [t.joints_deg for t in plan.targets + plan.above]
        return estimate_run(
            targets,
            plan.pose_deg,
            self.profile.procedure.speed,
            speeds_deg_s=joint_speeds_deg_s(self.profile.model),
        )

    def record_header(self, plan: CalibrationPlan) -> dict[str, Any]:
        return {
            "options": {"method": self.method, "beam": self.beam, "level": "offsets"},
            "plan": plan_rows(plan.targets),
        }

    def measure(
        self, plan: CalibrationPlan, session: CellSession, report: Report
    ) -> CalibrationRun:
        return run_calibration(self.profile, plan, session.rig, progress=report)

    def solve(self, plan: CalibrationPlan, measured: Measured[CalibrationRun]) -> OffsetsSolved:
        self.faces = list(measured.data.measurements)
        exact, paper = solve(self.profile, measured.data, self.beam)
        chosen = exact if self.method == "exact" else paper
        if chosen is None:
            raise UcalError("the paper's method could not be applied to these measurements")
        fit = exact.fit
        assert fit is not None
        kept, weak = keep_weak(
            chosen, self.profile.joint_offsets_deg, self.profile.model, TOLERANCE_STD_DEG
        )
        if chosen is exact:
            exact = kept
        budget = calibration_budget(self.profile, exact.cell_fit, measured.data.measurements)
        return OffsetsSolved(exact, paper, kept, fit, judge(kept, fit), weak, budget)

    def write(self, solved: OffsetsSolved) -> None:
        chosen = solved.chosen
        write_calibration(
            self.profile_path,
            f"calibrate --method {self.method}",
            solved.fit,
            solved.verdict,
            # the level that wrote these offsets (a table identified by an earlier full run
            # stays in force: these offsets were fitted on it)
            written(
                "offsets",
                chosen,
                solved.exact,
                solved.fit,
                solved.budget,
                condition_number=float(chosen.condition_number),
            ),
            # the block the offsets were fitted with (the paper's equations measure none)
            block_written(chosen.cell_fit, self.profile),
            self.readings(solved.exact),
        )

    def result(
        self,
        plan: CalibrationPlan,
        measured: Measured[CalibrationRun],
        solved: OffsetsSolved,
        written: bool,
    ) -> Outcome[OffsetsResult]:
        steps = {"arm": plan.step_deg, "azimuth": plan.azimuth_step_deg}
        return self.outcome(OffsetsResult(*self.found(measured, solved, written), steps))


def full_plan_summary(plan: FullPlan, profile: CellProfile) -> str:
    """The full level's plan in words for the confirmation (stderr); the procedure adds the
    estimated duration."""
    c_std = prior_from_profile(profile).sound_speed_std_m_s
    step = profile.step
    scale = (
        f"with the DH length tolerance ({profile.dh_length_std_mm:g} mm) it sets the scale of "
        "every length"
        if step is None
        else f"the step of {step.height_mm:g} ± {step.height_std_mm:g} mm on the XY face sets "
        "the scale of every length (its water paths against the face's)"
    )
    lines = [
        f"Full kinematic calibration plan for {profile.model.name}: {plan.describe()}",
        (
            f"Water {profile.water_temperature_c:g} ± {profile.water_temperature_std_c:g} °C "
            f"(sound speed ± {c_std:.2f} m/s); {scale}"
        ),
        "  posture face     J1       J2       J3       J4       J5       J6    water path",
    ]
    if plan.first is not None:  # the offsets level's faces, never calibrated: measured first
        lines += [plan_line(f"{t.label:>11}", t) for t in plan.first.targets]
    lines += [plan_line(f"{p.label:>7} {p.face_name:<3}", p) for p in plan.postures]
    if plan.above:
        lines.append(from_above(plan.above))
    return "\n".join([*lines, WRIST_SEARCH])


class FullCalibration(CalibrationJob):
    """``calibrate --level full``: the identifiable kinematic parameters and the joint offsets
    → ``[calibration]`` with its ``dh`` table."""

    def __init__(
        self,
        profile: CellProfile,
        profile_path: Path,
        beam: str = "auto",
        force: bool = False,
        max_postures: int | None = None,
    ) -> None:
        super().__init__(profile, profile_path, beam, force)
        self.max_postures = max_postures  # None: as many as the D-optimal criterion finds

    def plan(self) -> FullPlan:
        if self.max_postures is None:
            return plan_full(self.profile)
        return plan_full(self.profile, max_postures=self.max_postures)

    def summary(self, plan: FullPlan) -> str:
        return full_plan_summary(plan, self.profile)

    def estimate(self, plan: FullPlan) -> DurationEstimate:
        return estimate_postures(plan, self.profile)

    def record_header(self, plan: FullPlan) -> dict[str, Any]:
        return {
            "options": {
                "method": "exact",
                "beam": self.beam,
                "level": "full",
                "max_postures": self.max_postures,
            },
            "plan": plan_rows(first_postures(plan.first) + list(plan.postures)),
        }

    def measure(self, plan: FullPlan, session: CellSession, report: Report) -> FullRun:
        return run_full(self.profile, plan, session.rig, progress=report)

    def solve(self, plan: FullPlan, measured: Measured[FullRun]) -> FullSolved:
        run = measured.data
        self.faces = list(run.measurements)
        solution = solve_full(
            prior_from_profile(self.profile),
            run.measurements,
            fixed=beam_fixed(self.beam),
            structure=plan.structure,
            steps=run.steps,
        )
        fit = solution.cell.quality
        budget = calibration_budget(self.profile, solution.cell, run.measurements, run.steps)
        return FullSolved(solution, fit, judge(solution, fit), budget)

    def write(self, solved: FullSolved) -> None:
        sol = solved.chosen
        write_calibration(
            self.profile_path,
            "calibrate --level full",
            solved.fit,
            solved.verdict,
            # dh_std, each identified parameter's std: the later solvers' prior in place of
            # the [robot] tolerance (an offsets level keeps both keys: it fits on this table)
            written(
                "full",
                sol,
                sol,
                solved.fit,
                solved.budget,
                dh=sol.dh_rows(),
                dh_std=sol.dh_std_rows(),
                stiffness=written_stiffness(sol.stiffness),
            ),
            block_written(sol.cell, self.profile),
            self.readings(sol),
        )

    def result(
        self, plan: FullPlan, measured: Measured[FullRun], solved: FullSolved, written: bool
    ) -> Outcome[FullResult]:
        return self.outcome(FullResult(*self.found(measured, solved, written), plan))
