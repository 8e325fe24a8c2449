"""The ``verify`` command's job on the measuring procedure (``ucal.procedure``).

Check the files (the "before" offsets and block, the sound speed, the gauge:
``ucal.verify.inputs``), plan (``ucal.verify.plan``), measure (``ucal.verify.measure``), solve
(the statistics and the gauge's reach), write (the picture: ``ucal.verify.picture``; the profile
is never written), result (``ucal.verify.result``; on a simulated cell, the truth of
``ucal.sim.truth``).
"""

from __future__ import annotations

import hashlib
import json
from contextlib import AbstractContextManager
from dataclasses import replace
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from ucal.acoustics import sound_speed_m_s
from ucal.cell import CellProfile
from ucal.devices.record import decode, encode, measured_from_lines, measurement_lines
from ucal.devices.session import CellSession
from ucal.model.geometry import FACE_ORDER, distance_joints
from ucal.model.priors import prior_from_profile
from ucal.model.readings import CalibrationReadings
from ucal.model.targets import calibration_pose
from ucal.procedure import CheckingJob, Measured, Outcome, RunFacts, RunOptions
from ucal.profile.models import joint_speeds_deg_s
from ucal.progress import Report
from ucal.sim.truth import iso9283_truth, verify_truth
from ucal.timing import EDGE_SCAN, NO_SEARCH, DurationEstimate, SearchCost, estimate_run
from ucal.verify.inputs import (
    BeforeProfile,
    SoundSpeed,
    VerifyGauge,
    calibration_gauge,
    offsets_before_calibration,
    sound_speed_for_verify,
    tank_reference,
    wrist_left_unidentified,
    written_budget,
)
from ucal.verify.iso9283 import iso_figures, iso_summary, plan_iso9283
from ucal.verify.measure import VerifyResult, run_verify, tank_corrected
from ucal.verify.picture import DPI, PictureText, verify_figure, verify_picture_path
from ucal.verify.plan import DEFAULT_POINTS, VerifyPlan, plan_summary, plan_verify, with_tank
from ucal.verify.result import (
    MEASURED_WITHIN_MM,
    Verification,
    VerifySolved,
    marginal,
    profile_notes,
    table_note,
    table_words,
    tool_misfit_mm,
    tool_notes,
    water_note,
)
from ucal.verify.solve import unidentified_at_points_mm
from ucal.verify.tank import estimate_tank
from ucal.verify.uncertainty import measurement_std_mm, point_stds_mm, table_share

#: A water path read again where calibrate read it: no search, the readings of one path.
PATH_READ = SearchCost(moves=0, reads=8, motion_s=0.0)
#: The PNG text chunk in which the picture carries the facts of its run (``picture_facts``).
PICTURE_FACTS_KEY = "ucal-verify"


def rehearsal_picture_path(profile_path: Path, world: str) -> Path:
    """The default picture of a verify against a world file (``--sim WORLD``) where the default
    one is of the profile's own cell: a rehearsal on the cell that file describes leaves that
    picture alone: ``cell.toml``, ``faulty_world.toml`` → ``cell.verify.faulty_world.png``."""
    own = verify_picture_path(profile_path)
    return own.with_name(f"{Path(profile_path).stem}.verify.{Path(world).stem}.png")


def _of_own_cell(picture: Path) -> bool:
    """The picture at ``picture`` is of a verify on the profile's own cell (the real cell or
    the built-in simulated one), as the facts it carries say."""
    from PIL import Image  # matplotlib's own PNG library, only here

    try:
        with Image.open(picture) as png:
            facts = json.loads(getattr(png, "text", {}).get(PICTURE_FACTS_KEY, "null"))
    except (OSError, ValueError):
        return False
    return isinstance(facts, dict) and facts.get("cell", {}).get("world") is None


class VerifyJob(CheckingJob):
    """``verify``: the positioning error before and after calibration; writes its picture,
    never the profile."""

    def __init__(
        self,
        profile: CellProfile,
        profile_path: Path,
        n_points: int = DEFAULT_POINTS,
        tolerance_mm: float | None = None,
        plot_path: Path | None = None,
        recorded_inputs: dict[str, Any] | None = None,
        iso_cycles: int | None = None,
    ) -> None:
        """``recorded_inputs``: a replayed record's ``inputs``, read in place of the history
        (which may have moved on since the run); ``iso_cycles``: the five poses of ISO 9283
        visited that many times in place of the points (``ucal.verify.iso9283``)."""
        super().__init__(profile, profile_path, tolerance_mm)
        self.recorded_inputs = recorded_inputs
        self.n_points = n_points
        self.iso_cycles = iso_cycles
        self.plot_path = plot_path
        self.before = BeforeProfile(np.zeros(6), "")
        self.sound = SoundSpeed(0.0, 0.0, "")
        self.gauge = VerifyGauge(None, 0.0)
        self.unidentified: tuple[float, float] | None = None
        self.tank: CalibrationReadings | None = None
        self.cell: dict[str, Any] = {}  # the cell the run measures, for the picture's facts
        self.profile_sha256 = ""

    def check(self, options: RunOptions) -> AbstractContextManager[object]:
        """The "before" offsets and block from the profile's history, the sound speed of its
        last calibration, its J1 gauge and what it left unidentified (a replay's: as
        recorded); nothing is held (the profile is not written)."""
        if self.recorded_inputs is not None:
            inputs = decode(self.recorded_inputs)
            self.before, self.sound, self.gauge = inputs["before"], inputs["sound"], inputs["gauge"]
            self.unidentified = inputs.get("unidentified")
            self.tank = inputs.get("tank")
        else:
            self.before = offsets_before_calibration(self.profile_path)
            self.sound = sound_speed_for_verify(self.profile, self.profile_path)
            self.gauge = calibration_gauge(self.profile, self.profile_path)
            self.unidentified = written_budget(self.profile_path)
            self.tank = tank_reference(self.profile_path)
        self.profile_sha256 = hashlib.sha256(self.profile_path.read_bytes()).hexdigest()
        cell = options.cell
        world = None if cell is None else cell.sim_world
        self.cell = {
            "simulated": cell is None or world is not None,
            "world": world or None,
            "controller": None if cell is None else cell.controller_url,
        }
        own = verify_picture_path(self.profile_path)
        if world and self.plot_path == own and _of_own_cell(own):
            # a rehearsal on another cell never replaces this cell's own verify picture
            self.plot_path = rehearsal_picture_path(self.profile_path, world)
        return super().check(options)

    def plan(self) -> VerifyPlan:
        if self.iso_cycles is not None:
            plan = plan_iso9283(self.profile, self.iso_cycles)
        else:
            plan = plan_verify(
                self.profile,
                self.n_points,
                before_offsets_deg=self.before.offsets_deg,
                before_placed=self.before.placed(self.profile),
            )
        return plan if self.tank is None else with_tank(plan, self.profile, self.tank)

    def summary(self, plan: VerifyPlan) -> str:
        if plan.iso is not None:
            return iso_summary(plan, self.profile_path)
        return plan_summary(plan, self.profile_path)

    def estimate(self, plan: VerifyPlan) -> DurationEstimate:
        speed = self.profile.procedure.speed
        joints = joint_speeds_deg_s(self.profile.model)
        postures = [t.face_joints_deg[k] for t in plan.targets for k in FACE_ORDER]
        faces = estimate_run(postures, calibration_pose(self.profile), speed, speeds_deg_s=joints)
        edges = [plan.targets[-1].joints_deg] * len(plan.edge_points)
        total = faces + estimate_run(
            edges, edges[0], speed, speeds_deg_s=joints, search=EDGE_SCAN, first=NO_SEARCH
        )
        if plan.tank_faces:
            # the tank read again at the start and the end: a move and a water path each
            tank = [distance_joints(m) for m in plan.tank_faces]
            once = estimate_run(
                tank, postures[0], speed, speeds_deg_s=joints, search=PATH_READ, first=NO_SEARCH
            )
            total = total + once + once
        return total

    def record_header(self, plan: VerifyPlan) -> dict[str, Any]:
        # what the run read from the profile's history: a replay reads these instead
        inputs = {
            "before": self.before,
            "sound": self.sound,
            "gauge": self.gauge,
            "unidentified": self.unidentified,
            "tank": self.tank,
        }
        options: dict[str, Any] = {"points": self.n_points}
        if self.iso_cycles is not None:
            options["iso9283"] = self.iso_cycles
        return {"options": options, "plan": [], "inputs": encode(inputs)}

    def measure(self, plan: VerifyPlan, session: CellSession, report: Report) -> VerifyResult:
        # times of flight converted with the measured sound speed (as a water temperature)
        measuring = self.profile.replace(water_temperature_c=self.sound.temperature_c)
        return run_verify(measuring, plan, session.rig, report)

    def measurement_lines(self, data: VerifyResult) -> list[dict[str, Any]]:
        """One line per point and edge check; the plan is the replay's own."""
        return measurement_lines(data, given=("plan",))

    def measured_from(
        self, lines: list[dict[str, Any]], plan: VerifyPlan, source: str
    ) -> VerifyResult:
        result: VerifyResult = measured_from_lines(lines, source, plan=plan)
        return result

    def solve(self, plan: VerifyPlan, measured: Measured[VerifyResult]) -> VerifySolved:
        result = measured.data
        tank = None
        if self.tank is not None and result.tank_readings:
            conversion = float(sound_speed_m_s(self.sound.temperature_c))
            drift = prior_from_profile(self.profile).drift_std_m_s_per_min
            tank = estimate_tank(self.tank, result.tank_readings, conversion, drift)
            if tank.used:
                # the points' paths were converted at the speed the start read (measure)
                result = tank_corrected(result, tank, result.points_speed_m_s or conversion)
        names = wrist_left_unidentified(self.profile)
        s_mat = self.profile.sample_matrix
        points_base = plan.nominal_mm @ s_mat[:3, :3].T + s_mat[:3, 3]
        reach = float(np.max(np.hypot(points_base[:, 0], points_base[:, 1])))
        solved = VerifySolved(
            result,
            self.before,
            self.sound,
            self.tolerance_mm,
            float(np.max(result.stats("after")["max"])),
            replace(self.gauge, reach_mm=reach),
            self.before.same_as(self.profile),
            self.unidentified,
            tank,
            names,
            unidentified_at_points_mm(self.profile, plan, names) if names else None,
        )
        measuring = self.profile.replace(water_temperature_c=self.sound.temperature_c)
        path_std = solved.path_std_mm
        share = table_share(measuring, plan)
        stds = point_stds_mm(measuring, result, path_std, share[0])
        return replace(
            solved,
            measurement_std_mm=measurement_std_mm(stds),
            point_std_mm=stds,
            iso=None if plan.iso is None else iso_figures(measuring, result, path_std, share=share),
        )

    def may_write(self, solved: VerifySolved) -> bool:
        return self.plot_path is not None

    def write(self, solved: VerifySolved) -> None:
        assert self.plot_path is not None
        fig = verify_figure(solved.result, self.picture_text(solved))
        facts = json.dumps(self.picture_facts(solved), ensure_ascii=True)  # a latin-1 tEXt
        png = self.plot_path.suffix.lower() == ".png"
        fig.savefig(self.plot_path, dpi=DPI, metadata={PICTURE_FACTS_KEY: facts} if png else None)

    def picture_facts(self, solved: VerifySolved) -> dict[str, Any]:
        """What the picture's PNG carries of its run, for ``ucal report``: when, on which cell
        (a world file: a rehearsal on another cell), the profile version (SHA-256) and the
        verdict with its terms (mm)."""
        stats = solved.result.to_json(solved.tolerance_mm)
        return {
            "time_utc": datetime.now(UTC).isoformat(timespec="seconds"),
            "profile": self.profile_path.name,
            "profile_sha256": self.profile_sha256,
            "cell": self.cell,
            "points": solved.result.plan.points,
            "tolerance_mm": solved.tolerance_mm,
            "worst_mm": solved.worst_mm,
            "passed": solved.passed,
            "marginal": marginal(solved),
            "measured_within_mm": solved.measured_within_mm,
            "before_max_mm": None if solved.before_is_after else stats["before_mm"]["max"],
            "after_max_mm": stats["after_mm"]["max"],
            "gauge_note": solved.gauge.statement(),
            "notes": self.notes(solved),
            "iso9283": None if solved.iso is None else solved.iso.facts(),
        }

    def picture_text(self, solved: VerifySolved) -> PictureText:
        """What the picture says beside its data: the profile, the verdict's terms, why
        "before" is what it is, the gauge and the notes."""
        return PictureText(
            name=self.profile_path.name,
            tolerance_mm=solved.tolerance_mm,
            marginal=marginal(solved),
            before_source=solved.before.source,
            before_is_after=solved.before_is_after,
            gauge_note=solved.gauge.statement(),
            notes=tuple(self.notes(solved)),
        )

    def notes(self, solved: VerifySolved) -> list[str]:
        """``notes`` of the result: what the profile says it does not know (its joints, its DH
        table), and a tool check off or whose scans disagree beyond what verify measures to."""
        within = solved.measured_within_mm
        notes = profile_notes(self.profile) + table_note(solved) + water_note(solved)
        notes += tool_notes(solved.result.tool, self.profile, within)
        misfit = tool_misfit_mm(solved)
        if misfit > MEASURED_WITHIN_MM:
            notes.append(
                f"the tool check's scans in the two senses about the beam disagree by "
                f"{misfit:.3f} mm: "
                + (
                    f"{table_words(solved)} not identified (above) or "
                    if misfit <= within and solved.table_unidentified
                    else ""
                )
                + "the beam is not where the profile's [tool] puts it in the flange (not yet "
                "measured?), and every 'after' figure may be off by as much; run `ucal "
                "tool-frame`"
            )
        return notes

    def result(
        self,
        plan: VerifyPlan,
        measured: Measured[VerifyResult],
        solved: VerifySolved,
        written: bool,
    ) -> Outcome[Verification]:
        truth = None
        if measured.truth is not None:
            # a simulated cell: the true reached points, from the simulator's hidden truth
            truth = verify_truth(
                measured.truth,
                solved.result.points,
                solved.result.stats("after")["max"],
                self.profile.sample_matrix,
            )
            if solved.iso is not None:
                truth["iso9283"] = iso9283_truth(measured.truth, plan)
        result = Verification(
            solved,
            RunFacts.of(measured, self.profile_path, written),
            self.notes(solved),
            self.plot_path if written else None,
            truth,
        )
        return Outcome(
            self.command,
            result,
            written,
            out_of_tolerance=not solved.passed,
            message=result.message(),
        )
