"""Verify's typed result: the measured run with its verdict, what "before" was, the sound speed,
the gauge, the notes and the simulator's truth, as the tables, the picture and ``--json`` draw
it."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ucal.cell import CellProfile
from ucal.model.fit import readings_approach
from ucal.procedure import RunFacts
from ucal.verify.inputs import BeforeProfile, SoundSpeed, VerifyGauge
from ucal.verify.iso9283 import Iso9283
from ucal.verify.measure import VerifyResult
from ucal.verify.plan import WALL_PATH_MM
from ucal.verify.solve import ToolOffset, passed
from ucal.verify.tank import TankEstimate

#: How far verify's reached TCP may be from the real one (mm) with the profile's DH table
#: right, set from the commissioning benchmark (``benchmarks/commissioning.py`` prints the
#: largest difference on fresh cells). A largest deviation that close to the tolerance gives a
#: marginal verdict.
MEASURED_WITHIN_MM = 0.05
#: Sigmas of the last calibration's ``unidentified_tcp_mm`` (its largest one sigma over the
#: scanning region) that verify's reached TCP may be off by besides ``MEASURED_WITHIN_MM``
#: (``measured_within_mm``): the error is mostly across the beam (X and Y of the points
#: straight down), about two components of one Gaussian, beyond twice its sigma 2 % of the time.
UNIDENTIFIED_SIGMAS = 2.0


def measured_within_mm(
    unidentified_tcp_mm: tuple[float, float] | None, water_std_mm: float = 0.0
) -> float:
    """How far verify's reached TCP may be from the real one (mm), with the DH table the last
    calibration left unidentified (``unidentified_tcp_mm``: its mean and largest one sigma at
    the tool centre over the scanning region, ``ucal.calibration.budget``; None: none stated).

    Physics. A water path at normal incidence gives the TCP's position along the beam alone;
    X and Y of a point come from the postures at which the wrist turns the beam onto the two
    walls, 90° away, carried back to the commanded posture by the profile's kinematics, and the
    tool check's edges from the points by the same. Where the DH table is off within its
    tolerance (the offsets level holds it at its prior; row 5's ``d`` and ``a`` make the wrist
    a non-spherical one), those turns move the TCP otherwise than the profile says, by as much
    as the table moves the robot's own TCP: no arrangement of echoes at these points measures
    the TCP across the commanded beam without that table. So the DH table's share is not taken
    out of verify's figure but stated with it: ``MEASURED_WITHIN_MM`` plus
    ``UNIDENTIFIED_SIGMAS`` times the largest one sigma the unidentified priors allow.

    The tank's sound speed is the other share no echo at these points measures: verify reads
    its water paths with the speed the calibration measured (``SoundSpeed``), and
    ``water_std_mm`` is one sigma of its farthest path (a wall's) from what the tank may have
    done since. The two are independent: their sigmas add in quadrature.
    """
    table = 0.0 if unidentified_tcp_mm is None else float(unidentified_tcp_mm[1])
    return MEASURED_WITHIN_MM + UNIDENTIFIED_SIGMAS * float(np.hypot(table, water_std_mm))


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


@dataclass(frozen=True)
class VerifySolved:
    """What verify's solve step concludes: the measured run, what "before" and the sound speed
    were, the tolerance and the largest deviation after calibration, the gauge."""

    result: VerifyResult
    before: BeforeProfile
    sound: SoundSpeed
    tolerance_mm: float
    worst_mm: float
    gauge: VerifyGauge = field(default_factory=lambda: VerifyGauge(None, 0.0))
    #: "before" is the profile as it is (no calibration in its history): both passes alike
    before_is_after: bool = False
    #: ``[calibration] unidentified_tcp_mm`` (mean, max; mm, one sigma) when the run was
    #: measured (``ucal.verify.inputs.written_budget``); None: the profile states none
    unidentified_tcp_mm: tuple[float, float] | None = None
    #: the tank's sound speed read again within the run (``ucal.verify.tank``); None: the
    #: history keeps no readings of the last calibration's
    tank: TankEstimate | None = None
    #: what of the table an identified one left at its tolerance (``wrist_left_unidentified``:
    #: "d5", "a5"); empty: no table identified
    unidentified_names: tuple[str, ...] = ()
    #: one sigma of what those move verify's own points (mm, ``unidentified_at_points_mm``);
    #: None: no table identified (the region's figure stands)
    unidentified_at_points_mm: float | None = None
    #: one sigma of an "after" point's measurement per block axis (mm,
    #: ``ucal.verify.iso9283.measurement_std_mm``); None: no point measured
    measurement_std_mm: list[float] | None = None
    #: the same per measured "after" point (n, 3; mm, ``VerifyResult.measured("after")``'s
    #: order); None: not computed
    point_std_mm: np.ndarray | None = None
    #: an ISO 9283 run's figures (``verify --iso9283``); None: verify's points
    iso: Iso9283 | None = None

    @property
    def passed(self) -> bool:
        return passed(self.result.stats("after"), self.tolerance_mm)

    @property
    def table_sigma(self) -> tuple[float, float] | None:
        """The DH table's share of the promise (mean, max; mm, one sigma): at verify's own
        points where the full level left only named lengths unidentified, else over the
        scanning region (``unidentified_tcp_mm``)."""
        at = self.unidentified_at_points_mm
        return self.unidentified_tcp_mm if at is None else (at, at)

    @property
    def measured_within_mm(self) -> float:
        """How far each reached TCP may be from the real one (mm): two sigma of the least
        well measured point on its worst axis (``point_std_mm``, ``ucal.verify.uncertainty``);
        where no point's sigma was computed, the bound ``measured_within_mm`` gives."""
        stds = self.point_std_mm
        if stds is not None and np.size(stds):
            return 2.0 * float(np.max(stds))
        return measured_within_mm(self.table_sigma, self.water_std_mm)

    @property
    def tank_used(self) -> TankEstimate | None:
        """The tank's sound speed read within the run, where the paths are converted with it
        (the readings changed as the water changes them)."""
        return self.tank if self.tank is not None and self.tank.used else None

    @property
    def water_std_mm(self) -> float:
        """One sigma of the farthest water path (a wall's) from the tank's sound speed: as
        read within the run (``TankEstimate.std_m_s``), else since the calibration measured
        it (``SoundSpeed.std_m_s``)."""
        return self.path_std_mm(max(WALL_PATH_MM))

    def path_std_mm(self, path_mm: float) -> float:
        """One sigma of a water path of ``path_mm`` from the sound speed it was converted
        with (mm): the tank's as read within the run, else the calibration's."""
        tank = self.tank_used
        return tank.path_std_mm(path_mm) if tank is not None else self.sound.path_std_mm(path_mm)

    @property
    def table_unidentified(self) -> bool:
        """The DH table the last calibration left unidentified weighs more in verify's figure
        than verify's own measurement."""
        return measured_within_mm(self.table_sigma) > 2.0 * MEASURED_WITHIN_MM

    @property
    def water_unknown(self) -> bool:
        """The tank's sound speed since the calibration weighs more in verify's figure than
        verify's own measurement."""
        return UNIDENTIFIED_SIGMAS * self.water_std_mm > MEASURED_WITHIN_MM


@dataclass(frozen=True)
class Verification:
    """``verify``'s result: what was solved, what became of the run, the notes, the picture
    written (None: not written) and, on a simulated cell, the true reached points
    (``ucal.sim.truth.verify_truth``); the tables and ``--json`` are drawn from it."""

    solved: VerifySolved
    run: RunFacts
    notes: list[str]
    plot_path: Path | None
    truth: dict[str, Any] | None = None

    @property
    def marginal(self) -> bool:
        return marginal(self.solved)

    def to_json(self) -> dict[str, Any]:
        """The ``verify --json`` object of SPEC.md plus per-point detail (mm, deg)."""
        solved, run = self.solved, self.run
        out: dict[str, Any] = solved.result.to_json(solved.tolerance_mm)
        out["before_source"] = solved.before.source
        out["sound_speed_m_s"] = solved.sound.m_s
        out["sound_speed_source"] = solved.sound.source
        out["sound_speed_std_m_s"] = solved.sound.std_m_s
        tank = solved.tank_used
        out["sound_speed_now_m_s"] = None if tank is None else tank.m_s
        out["sound_speed_now_std_m_s"] = None if tank is None else tank.std_m_s
        out["sound_speed_run_drift_m_s_per_min"] = None if tank is None else tank.drift_m_s_per_min
        out["sound_speed_run_drift_std_m_s_per_min"] = (
            None if tank is None else tank.drift_std_m_s_per_min
        )
        out["tank"] = None if solved.tank is None else solved.tank.to_json()
        out["profile"] = str(run.profile_path)
        out["duration_s"] = run.duration_s
        out["gauge"] = "block"
        out["gauge_note"] = solved.gauge.statement()
        out["absolute_std_mm"] = solved.gauge.absolute_std_mm
        out["j1_gauge"] = solved.gauge.j1
        out["before_is_after"] = solved.before_is_after
        out["notes"] = self.notes
        out["marginal"] = self.marginal
        out["measured_within_mm"] = solved.measured_within_mm
        out["measurement_std_mm"] = solved.measurement_std_mm
        stds = solved.point_std_mm
        # per measured "after" point, in "reached_mm"'s order
        out["measurement_std_points_mm"] = None if stds is None else np.asarray(stds).tolist()
        if solved.iso is not None:
            out["iso9283"] = solved.iso.to_json()
        out["unidentified_tcp_mm"] = budget_json(
            solved.unidentified_tcp_mm, solved.unidentified_names
        )
        if out["unidentified_tcp_mm"] is not None:
            out["unidentified_tcp_mm"]["at_points"] = solved.unidentified_at_points_mm
        # the approach of every reading: calibrate's offsets hold for the positive one
        out["approach"] = readings_approach([m for p in solved.result.points for m in p.faces])
        out["plot"] = None if self.plot_path is None else str(self.plot_path)
        if self.truth is not None:
            out["truth"] = self.truth
        return out

    def message(self) -> str:
        """The one-line error of a run out of tolerance, with the DH table left unidentified
        named when the verdict lies within what it allows."""
        solved = self.solved
        text = (
            f"verify: a point deviates {solved.worst_mm:.3f} mm after calibration, above "
            f"the tolerance of {solved.tolerance_mm:g} mm"
        )
        if self.marginal and solved.table_unidentified:
            text += (
                f" (marginal: verify measures it to ±{solved.measured_within_mm:.2f} mm with "
                + f"{table_words(solved)} not identified"
                + (
                    ", which no echo at normal incidence sees)"
                    if solved.unidentified_names
                    else "; `ucal calibrate --level full` identifies it)"
                )
            )
        return text


@dataclass(frozen=True)
class RegionResult:
    """The model's residuals over the region (block pose and sound speed fitted)."""

    postures: int
    rms_distance_mm: float
    max_distance_mm: float
    rms_tilt_deg: float
    max_tilt_deg: float
    chi2_reduced: float
    verdict: str
    worst: str
    tolerance_mm: float
    #: What the last calibration's unidentified quantities allow at the tool centre, one sigma
    #: (mm, mean and max over the scanning region; ``ucal.calibration.budget``): across the
    #: beam, where these echoes do not look either. None: the profile states none.
    unidentified_tcp_mm: tuple[float, float] | None = None
    #: The approach the readings had (``ucal.model.fit.readings_approach``).
    approach: str = "positive"
    #: What of an identified table is left at its tolerance (``VerifySolved``'s).
    unidentified_names: tuple[str, ...] = ()

    @property
    def passed(self) -> bool:
        return self.verdict == "ok" and self.max_distance_mm <= self.tolerance_mm

    def message(self) -> str:
        """The one-line error of a failed check."""
        return (
            f"region check failed: the model leaves {self.max_distance_mm:.4f} mm (rms "
            f"{self.rms_distance_mm:.4f}) along the face normals and "
            f"{self.max_tilt_deg:.4f} deg of beam tilt over {self.postures} postures (χ²ᵣ "
            f"{self.chi2_reduced:.3g}, worst {self.worst}); calibrate with --level full"
        )

    def to_json(self) -> dict[str, Any]:
        return {
            "region": {
                "postures": self.postures,
                "rms_distance_mm": self.rms_distance_mm,
                "max_distance_mm": self.max_distance_mm,
                "rms_tilt_deg": self.rms_tilt_deg,
                "max_tilt_deg": self.max_tilt_deg,
                "chi2_reduced": self.chi2_reduced,
                "verdict": self.verdict,
                "worst": self.worst,
                "approach": self.approach,
                "unidentified_tcp_mm": budget_json(
                    self.unidentified_tcp_mm, self.unidentified_names
                ),
            },
            "tolerance_mm": self.tolerance_mm,
            "passed": self.passed,
        }


@dataclass(frozen=True)
class RegionCheck:
    """``verify --region``'s result: the model's residuals and what became of the run."""

    region: RegionResult
    run: RunFacts

    def to_json(self) -> dict[str, Any]:
        """The ``verify --region --json`` object."""
        return {
            **self.region.to_json(),
            "profile": str(self.run.profile_path),
            "moves": self.run.moves,
            "pulser_reads": self.run.reads,
            "duration_s": self.run.duration_s,
        }


def budget_json(
    unidentified_tcp_mm: tuple[float, float] | None, names: tuple[str, ...]
) -> dict[str, Any] | None:
    """``unidentified_tcp_mm`` in ``--json``: mean and max (mm, one sigma) and, after the full
    level, the quantities of the table it left unidentified (``quantities``: "d5", "a5")."""
    if unidentified_tcp_mm is None:
        return None
    out: dict[str, Any] = dict(zip(("mean", "max"), unidentified_tcp_mm, strict=True))
    out["quantities"] = list(names)
    return out


def table_words(solved: VerifySolved) -> str:
    """What of the DH table is not identified, in words: "the DH table's d5, a5" after the full
    level, else "the DH table"."""
    names = solved.unidentified_names
    return f"the DH table's {', '.join(names)}" if names else "the DH table"


def table_note(solved: VerifySolved) -> list[str]:
    """What the DH table the last calibration left unidentified does to verify's figures, when
    it weighs more than verify's own measurement (``measured_within_mm``), for ``notes``."""
    if not solved.table_unidentified or solved.unidentified_tcp_mm is None:
        return []
    names, table = solved.unidentified_names, solved.table_sigma
    if names and table is not None:
        return [
            f"{table_words(solved)} are not identified (`ucal calibrate --level "
            "full` leaves them at [robot] dh_length_std_mm: they move the flange across the "
            "beam, which no echo at normal incidence shows): with them the last calibration's "
            f"unidentified quantities allow up to {solved.unidentified_tcp_mm[1]:.3f} mm at the "
            "tool centre over the scanning region ([calibration] unidentified_tcp_mm, one "
            "sigma); at these points they put the reconstructed tool centre up to "
            f"{table[1]:.3f} mm off on an axis (one sigma: the wrist's turns onto the faces are "
            "computed without them), so each 'after' point is known to "
            f"±{solved.measured_within_mm:.2f} mm, not ±{MEASURED_WITHIN_MM:g}"
        ]
    return [
        f"the DH table is not identified ([calibration] unidentified_tcp_mm: up to "
        f"{solved.unidentified_tcp_mm[1]:.3f} mm at the tool centre, one sigma, from [robot] "
        "dh_length_std_mm and dh_angle_std_deg): the wrist's turns onto the faces and the arm's "
        "moves to the edges are computed with it, so each 'after' point and the tool check are "
        f"known to ±{solved.measured_within_mm:.2f} mm, not ±{MEASURED_WITHIN_MM:g}; "
        "`ucal calibrate --level full` identifies it"
    ]


def water_note(solved: VerifySolved) -> list[str]:
    """What verify knows of the tank's sound speed, for ``notes``: as read again within the run
    (``tank_note``), else what the tank may have done since the calibration measured it, when
    that weighs more than verify's own measurement (``measured_within_mm``)."""
    if solved.tank is not None:
        return tank_note(solved)
    if not solved.water_unknown:
        return []
    return [age_text(solved)]


def age_text(solved: VerifySolved) -> str:
    """The sound speed's promise from its age, in words."""
    sound, far = solved.sound, max(WALL_PATH_MM)
    why = (
        "its thermometer's tolerance, [water] temperature_std_c"
        if sound.age_min is None
        else f"the tank may have changed since the calibration {sound.age_min:.0f} min ago: "
        "[water] drift_std_c_per_min, at most temperature_std_c"
    )
    return (
        f"the water paths are read with the sound speed of {sound.source}, known to "
        f"±{sound.std_m_s:.2f} m/s (one sigma; {why}), which moves a wall's {far:g} mm by "
        f"±{solved.water_std_mm:.2f} mm: each 'after' point is known to "
        f"±{solved.measured_within_mm:.2f} mm; `ucal calibrate` measures the water"
    )


def tank_note(solved: VerifySolved) -> list[str]:
    """The tank's sound speed as read again within the run, or why it was not used."""
    tank = solved.tank
    assert tank is not None
    read = (
        f"{tank.readings} of calibrate's water paths ({tank.source}) read again where it read "
        f"them, at the start and the end of the run ({tank.extra_moves} moves)"
    )
    if not tank.used:
        moved = max(abs(v) for s in tank.sets for v in s.misfit_mm)
        return [
            f"{read} changed otherwise than a sound speed change changes them (up to "
            f"{moved:.3f} mm not in proportion to their paths): the block or the arm moved "
            "since calibrate, which the water cannot be told from here; " + age_text(solved)
        ]
    drift = tank.drift_std_m_s_per_min
    within = (
        ""
        if drift is None
        else f", drifting {tank.drift_m_s_per_min:+.3f} ± {drift:.3f} m/s a minute within the run"
    )
    return [
        f"the tank's sound speed, from {read}: {tank.m_s:.2f} ± {tank.std_m_s:.2f} m/s at the "
        f"start (calibrate's {solved.sound.m_s:.2f}, changed by "
        f"{tank.m_s - solved.sound.m_s:+.2f} ± {tank.change_std_m_s:.2f}){within}; each water "
        f"path is read with the speed of its time, which leaves a wall's "
        f"{max(WALL_PATH_MM):g} mm known to ±{solved.water_std_mm:.3f} mm since calibrate"
    ]


def tool_notes(
    tool: ToolOffset | None, profile: CellProfile, within_mm: float = MEASURED_WITHIN_MM
) -> list[str]:
    """What the tool check says of the profile's ``[tool]``: off by more than its stated std
    (moved since ``tool-frame``, or never measured), or, along the beam, off within it (the
    hand-touched plate's tolerance, which shows in X and Y of the points straight down).
    Nothing is said of an error within ``within_mm``, what the check measures to
    (``measured_within_mm``: with the DH table unidentified, its share)."""
    if tool is None:
        return []
    std = np.broadcast_to(np.asarray(profile.tool_position_std_mm, float), 3)
    beam = np.abs(profile.tool_matrix[:3, 2])
    along_std = float(np.sqrt(np.sum((beam * std) ** 2)))
    across_std = float(np.sqrt(np.sum(((1.0 - beam) * std) ** 2)))
    across = float(np.linalg.norm(tool.across_mm))
    notes = []
    if across > max(3.0 * across_std, within_mm):
        notes.append(
            f"the tool check finds the real tool {across:.3f} mm off the profile's across the "
            f"beam, beyond what [tool] says it is known to (±{across_std:.3f} mm): moved since "
            "`ucal tool-frame` measured it, or never measured? run `ucal tool-frame`"
        )
    along = abs(tool.along_mm)
    longer = f"{along:.3f} mm {'longer' if tool.along_mm > 0 else 'shorter'} along the beam"
    if along > max(3.0 * along_std, within_mm):
        notes.append(
            f"the tool check finds the real tool {longer} than the profile's, beyond what "
            f"[tool] says it is known to (±{along_std:.3f} mm): run `ucal tool-frame`"
        )
    elif along > within_mm:
        notes.append(
            f"the real tool is {longer} than the profile's, within what [tool] says it is "
            f"known to (±{along_std:.2f} mm; after `ucal tool-frame`, the touched plate's "
            "tolerance): it shows in X and Y of the points straight down"
        )
    return notes


def tool_misfit_mm(solved: VerifySolved) -> float:
    """The tool check's largest misfit (mm; 0 without a tool check)."""
    tool = solved.result.tool
    return 0.0 if tool is None else tool.misfit_mm


def marginal(solved: VerifySolved) -> bool:
    """The verdict could go the other way within two sigmas of each "after" point's
    measurement (``point_std_mm``, per axis; the tool check's misfit added): a pass where some
    deviation lies that close below the tolerance, a fail where every deviation above it lies
    that close above. Where no point's sigma was computed, the largest deviation within
    ``measured_within_mm`` of the tolerance."""
    misfit = tool_misfit_mm(solved)
    stds = solved.point_std_mm
    dev = np.abs(solved.result.deviations("after"))
    tol = solved.tolerance_mm
    if stds is not None and np.shape(stds) == dev.shape and dev.size:
        reach = 2.0 * np.asarray(stds) + misfit
        above = dev > tol
        if not np.any(above):
            return bool(np.any(tol - dev < reach))
        return bool(np.all((dev - tol)[above] < reach[above]))
    return bool(abs(solved.worst_mm - tol) <= solved.measured_within_mm + misfit)
