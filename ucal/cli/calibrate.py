"""``ucal calibrate``: joint zero offsets (paper 000) → ``[calibration]`` in the profile.

Parses the options, loads (or, with ``--sim``, creates) the profile and runs the calibration
procedure of the chosen level (``ucal.calibration.procedure``: ``OffsetsCalibration``,
``FullCalibration``) through the steps of ``ucal.procedure``; prints the result.
"""

from __future__ import annotations

import contextlib
import logging
import tempfile
from pathlib import Path
from typing import Any

import click
import numpy as np
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from ucal.calibration.load import load_posture
from ucal.calibration.procedure import FullCalibration, OffsetsCalibration
from ucal.calibration.result import CalibrationResult, FullResult, OffsetsResult, backlash_note
from ucal.cell import CellProfile
from ucal.cli.options import (
    MovingCall,
    check_can_confirm,
    choice_option,
    force_option,
    moving_options,
    table_console,
    thermometer_option,
    warn,
)
from ucal.cli.procedure import finish, replay_outcome, run_job, run_options
from ucal.devices.record import Record
from ucal.errors import InputError, NotConfirmed
from ucal.measure.approach import APPROACH
from ucal.model.fit import FitQuality
from ucal.model.stiffness import JointStiffness, stiffness_note
from ucal.procedure import Job, Outcome
from ucal.profile import (
    create_profile,
    default_profile_text,
    load_profile,
    real_path,
)
from ucal.profile.models import DEFAULT_MODEL

log = logging.getLogger(__name__)


@click.command(
    "calibrate",
    epilog="""\b
Examples:
  ucal calibrate cell.toml --sim --yes
  ucal calibrate cell.toml --sim examples/world.toml --method paper --json --yes
  ucal calibrate cell.toml --controller tcp://10.0.0.5:11000 --pulser modbus-tcp://10.0.0.6:502
  ucal calibrate cell.toml --sim --yes --level full
  ucal calibrate cell.toml --sim --yes --record run.jsonl
  ucal calibrate cell.toml --replay run.jsonl --method paper --json
""",
)
@moving_options(
    choice_option(
        "--method",
        ["exact", "paper"],
        "exact: nonlinear least squares over the full kinematics; paper: paper 000's "
        "first-order equations 11-21.",
    ),
    choice_option(
        "--beam",
        ["auto", "fit", "fixed"],
        "auto/fit: the beam direction in the flange frame is an unknown with the "
        "profile's tool tolerance as prior; fixed: take the profile's tool as exact.",
    ),
    choice_option(
        "--level",
        ["offsets", "full"],
        "offsets: the six joint offsets; full: the identifiable kinematic parameters "
        "as well, from many postures, written as [calibration] dh.",
    ),
    click.option(
        "--postures",
        type=click.IntRange(3, 200),
        default=None,
        help="--level full: at most N postures (default: as many as the D-optimal "
        "criterion finds worth measuring).",
    ),
    click.option(
        "--lost-motion",
        is_flag=True,
        help="Offsets level: measure the calibration pose's three faces again from above, so "
        "that each joint's lost motion is measured (backlash_deg); 3 more face searches. The "
        "full level reads some postures from above where its plan can spare them.",
    ),
    thermometer_option,
    force_option(
        "Write the result even when it is out of tolerance: a misfit, or the paper "
        "method's offsets less certain than 0.02 deg (the verdict is recorded in the profile "
        "history)."
    ),
)
def cli(
    call: MovingCall,
    method: str,
    beam: str,
    level: str,
    postures: int | None,
    lost_motion: bool,
    thermometer: Path | None,
    force: bool,
) -> None:
    """Find the six joint zero offsets with the ultrasonic transducer and write them.

    The beam is brought normal to the three faces of the calibration block in up to four arm
    configurations (the calibration pose, joint 3 stepped, joint 2 stepped and, where the cell
    leaves room, joint 1 stepped: 9 or 12 measurements; the plan lists them); the peak-echo
    postures and time-of-flight distances give the offsets (actual = reading + offset) with
    their stds, the cell's other uncertain quantities fitted with the profile's tolerances as
    priors. A joint the data cannot determine (J1 with a hand-placed block, J6 with the beam on
    its axis) is reported unobservable and keeps its profile value; so does one measured less
    certainly than 0.02 deg (a warning names why), and the others are written. With --level
    full, 25-30 postures chosen by D-optimality also identify the DH table's lengths and twists
    ([calibration] dh). Writes [calibration] (the previous version is kept in the profile's
    history); nothing is written with --dry-run, on failure, or when the result is out of
    tolerance (exit 1) unless --force. Every target is checked before the first motion. On any
    fault or Ctrl-C the robot is told to stop and the profile is left byte-for-byte unchanged.
    """
    if level == "full" and method != "exact":
        raise InputError(
            "--level full identifies the kinematic model by least squares: it "
            "takes --method exact only"
        )
    if level == "full" and lost_motion:
        raise InputError(
            "--lost-motion is the offsets level's option: --level full measures the lost "
            "motion from the postures its plan reaches from above"
        )
    profile_path = call.profile_path

    def job(profile: CellProfile, record: Record | None) -> Job[Any, Any, Any, Calibrated]:
        if record is None:
            return _job(level, profile, profile_path, method, beam, force, postures, lost_motion)
        options = record.options
        recorded_level = options.get("level", "offsets")
        max_postures = options.get("max_postures")
        # a replay measures, if at all, the recorded plan (its faces from above among them)
        return _job(recorded_level, profile, profile_path, method, beam, False, max_postures, False)

    fixed = {"level": "level", "max_postures": "postures"}
    outcome = replay_outcome(call, "calibrate", fixed, job)
    if outcome is not None:
        warn_weak(outcome.result)
        finish(outcome, call.as_json, show_outcome)
        return
    cell = call.cell()
    created = False
    scratch = contextlib.ExitStack()  # holds a dry run's default profile until the run ends
    if not profile_path.exists() and cell.sim_world is not None:
        if call.dry_run:
            tmp = Path(scratch.enter_context(tempfile.TemporaryDirectory(prefix="ucal-")))
            (tmp / profile_path.name).write_text(
                default_profile_text(DEFAULT_MODEL), encoding="utf-8"
            )
            profile = load_profile(tmp / profile_path.name)
            warn(
                f"{profile_path} does not exist: the dry run uses the default model "
                f"{DEFAULT_MODEL} (nothing is created)"
            )
        else:
            check_can_confirm(cell, call.yes)  # before a file is created for a run that cannot ask
            create_profile(profile_path, DEFAULT_MODEL)
            created = True
            # a warning, not info: a mistyped PROFILE must not silently calibrate a new cell
            warn(f"{profile_path} did not exist: created it from the default model {DEFAULT_MODEL}")
            profile = load_profile(profile_path)
    else:
        profile = load_profile(profile_path)
    with scratch:
        try:
            outcome = run_job(job(profile, None), run_options(call, cell, thermometer))
        except NotConfirmed as e:
            if not created:
                raise
            # declined: nothing written means no profile either (often a mistyped name)
            real_path(profile_path).unlink(missing_ok=True)
            raise NotConfirmed(f"{e} ({profile_path}, created for the run, removed)") from None
    outcome.created = created
    warn_weak(outcome.result)
    finish(outcome, call.as_json, show_outcome)


#: What ``calibrate`` finds, at either level.
Calibrated = OffsetsResult | FullResult


def _job(
    level: str,
    profile: CellProfile,
    profile_path: Path,
    method: str,
    beam: str,
    force: bool,
    postures: int | None,
    lost_motion: bool,
) -> Job[Any, Any, Any, Calibrated]:
    """The calibration procedure of ``level``."""
    if level == "full":
        return FullCalibration(profile, profile_path, beam, force, postures)
    return OffsetsCalibration(profile, profile_path, method, beam, force, lost_motion)


def warn_weak(result: CalibrationResult[Any]) -> None:
    """A warning line per joint measured too weakly to write (kept at its profile value)."""
    for j, w in result.weak().items():
        warn(f"J{j} measured at {w.offset_deg:+.4f} ± {w.std_deg:.3g} deg: {w.reason}")


def show_outcome(outcome: Outcome[Calibrated]) -> None:
    """The result tables on stdout, of either level."""
    result = outcome.result
    if isinstance(result, FullResult):
        show_full_result(table_console(), result)
    else:
        show_result(table_console(), result)


# -- result tables -----------------------------------------------------------------------------


def show_result(console: Console, result: OffsetsResult) -> None:
    """The result as tables on stdout (without --json): offsets with σ, fit quality, residual
    per measurement."""
    solved, truth = result.solved, result.run.truth
    chosen, exact, paper = solved.chosen, solved.exact, solved.paper
    table = Table(title=f"Joint offsets ({chosen.method} method)")
    table.add_column("joint")
    table.add_column("offset (deg)", justify="right")
    table.add_column("σ (deg)", justify="right")
    if paper is not None and chosen is exact:
        table.add_column("paper method", justify="right")
        table.add_column("paper σ", justify="right")
    if truth is not None:
        table.add_column("simulator truth", justify="right")
        table.add_column("error", justify="right")
    weak = solved.weak
    for j in range(6):
        unobs = j + 1 in chosen.unobservable_joints
        kept_as = "weak" if j + 1 in weak else "unobservable"
        row = [
            f"J{j + 1}",
            f"{chosen.offsets_deg[j]:+.4f}" + (" (kept)" if unobs else ""),
            kept_as if unobs else f"{chosen.std_deg[j]:.4f}",
        ]
        if paper is not None and chosen is exact:
            row.append(f"{paper.offsets_deg[j]:+.4f}")
            row.append("—" if not np.isfinite(paper.std_deg[j]) else f"{paper.std_deg[j]:.4f}")
        if truth is not None:
            row.append(f"{truth.joint_offsets_deg[j]:+.4f}")
            row.append(
                "—" if unobs else f"{chosen.offsets_deg[j] - truth.joint_offsets_deg[j]:+.4f}"
            )
        table.add_row(*row)
    console.print(table)
    show_fit(console, exact.fit)
    console.print(
        f"{_sound_speed(result)} (fitted); condition number {chosen.condition_number:.1f}; "
        f"{_run_line(result)}"
    )
    for j, why in sorted(chosen.unobservable_reasons.items()):
        w = weak.get(j)
        if w is None:
            console.print(escape(f"J{j} unobservable, kept at its profile value: {why}"))
        else:
            console.print(
                escape(f"J{j} measured at {w.offset_deg:+.4f} ± {w.std_deg:.3g} deg: {why}")
            )
    show_approach(console, result)
    show_gauge(console, result)


def _sound_speed(result: CalibrationResult[Any]) -> str:
    sound = result.solved.sound
    return f"sound speed {sound.sound_speed_m_s:.2f} ± {sound.sound_speed_std_m_s:.2f} m/s"


def _run_line(result: CalibrationResult[Any]) -> str:
    run = result.run
    return (
        f"{run.moves} moves, {run.reads} pulser reads; profile "
        f"{'written' if run.written else 'not written'}: {run.profile_path}"
    )


def show_approach(console: Console, result: CalibrationResult[Any]) -> None:
    """The approach direction the offsets belong to, and what is not measured of it; what
    the unidentified quantities' tolerances allow at the tool centre."""
    budget = result.solved.budget
    if budget is not None:
        top = ", ".join(f"{k} {v:.3f}" for k, v in list(budget.by_quantity.items())[:3])
        console.print(
            escape(
                f"not identified: their tolerances allow {budget.mean_mm:.3f} mm mean, "
                f"{budget.max_mm:.3f} mm max at the tool centre over the scanning region "
                f"(one sigma{'; ' + top if top else ''})"
            )
        )
    console.print(
        escape(
            f"approach {APPROACH}: the offsets hold for postures reached with every "
            f"joint moving in its positive direction; {backlash_note(result.effects)}"
        )
    )
    load = load_posture(result.solved.chosen, result.solved.sound)
    if load is not None:
        console.print(
            escape(
                "load: the offsets hold the arm as its weight bends it at the load "
                f"posture ({', '.join(f'{v:.2f}' for v in load)} deg, written as "
                "load_posture_deg); another posture's sag from there is the joints' "
                "compliance times the change in gravity torque, which path --for-controller "
                "makes up for"
            )
        )


def show_gauge(console: Console, result: CalibrationResult[Any]) -> None:
    """How J1 is known (``ucal.model.gauge``) and the block the fit measured."""
    gauge = result.gauge
    if gauge is not None:
        console.print(escape(f"gauge ({gauge.frame}): {gauge.statement()}"))
    block = result.block
    if block:
        pos, std = block["position_mm"], block["position_std_mm"]
        console.print(
            escape(
                "block corner as measured: "
                + ", ".join(f"{p:.3f} ± {s:.3f}" for p, s in zip(pos, std, strict=True))
                + " mm, tilt "
                + ", ".join(f"{v:+.4f}" for v in block["rotation_deg"][:2])
                + " deg, yaw as placed"
                + (" (written to [sample])" if result.run.written else "")
            )
        )


def show_fit(console: Console, fit: FitQuality | None) -> None:
    """The fit's normalised residual per measurement, its verdict and the likely cause."""
    assert fit is not None
    res = Table(title="Fit: normalised residual per measurement (residual / its σ)")
    for col in ("measurement", "tilt a", "tilt b", "distance"):
        res.add_column(col, justify="right")
    for r in fit.residuals:
        res.add_row(r.label, f"{r.tilt[0]:+.2f}", f"{r.tilt[1]:+.2f}", f"{r.distance:+.2f}")
    console.print(res)
    console.print(
        escape(
            f"fit {fit.verdict}: χ²ᵣ {fit.chi2_reduced:.3g} on {fit.dof} degrees of "
            f"freedom; rms tilt {fit.rms_tilt_deg:.2e} deg, rms distance "
            f"{fit.rms_distance_mm:.2e} mm; worst {fit.worst}"
        )
    )
    if fit.cause:
        console.print(escape(f"likely cause: {fit.cause}"))


def show_full_result(console: Console, result: FullResult) -> None:
    """The identified parameters, offsets and fit of ``--level full`` as tables on stdout."""
    sol = result.solved.chosen
    table = Table(title="Kinematic parameters (calibrate --level full)")
    for col in ("parameter", "value", "σ", "nominal", "status"):
        table.add_column(col, justify="right" if col != "status" else "left")
    for j in range(6):
        unobs = j + 1 in sol.unobservable_joints
        table.add_row(
            f"J{j + 1} offset (deg)",
            f"{sol.offsets_deg[j]:+.5f}",
            "—" if unobs else f"{sol.std_deg[j]:.5f}",
            "",
            "unobservable (kept)" if unobs else "identified",
        )
    for name, p in sol.parameters.items():
        table.add_row(
            name,
            f"{p.value:.5f}",
            "—" if p.std is None else f"{p.std:.5f}",
            f"{p.nominal:.5f}",
            p.status,
        )
    console.print(table)
    show_stiffness(console, sol.stiffness)
    ident = sol.ident
    console.print(f"rank {ident.rank} of {ident.n_parameters} unknowns")
    for name, why in ident.redundant.items():
        console.print(escape(f"{name} not identifiable, carried with its tolerance: {why}"))
    if ident.scale_note:
        console.print(escape(f"scale: {ident.scale_note}"))
    if sol.length_standard is not None:
        s = sol.length_standard
        console.print(
            f"step height {s.step_mm:.4f} ± {s.std_mm:.4f} mm (certificate "
            f"{s.nominal_mm:g} ± {s.tolerance_mm:g} mm; {s.measurements} water paths)"
        )
    for j, why in sorted(sol.unobservable_reasons.items()):
        console.print(escape(f"J{j} unobservable, kept at its profile value: {why}"))
    show_approach(console, result)
    show_gauge(console, result)
    show_fit(console, sol.cell.quality)
    console.print(f"{_sound_speed(result)}; {_run_line(result)}")


def show_stiffness(console: Console, found: tuple[JointStiffness, ...]) -> None:
    """Each joint's stiffness as the full level found it (``ucal.model.stiffness``)."""
    if not found:
        return
    table = Table(title="Joint stiffness under gravity (calibrate --level full)")
    for col in (
        "joint",
        "stiffness (N·m/rad)",
        "σ (%)",
        "compliance (µrad/N·m)",
        "prior",
        "status",
    ):
        table.add_column(col, justify="left" if col == "status" else "right")
    for s in found:
        k = s.stiffness_nm_per_rad
        seen = s.compliance_std_urad_per_nm
        table.add_row(
            f"J{s.joint}",
            "—" if k is None else f"{k:.4g}",
            "—" if k is None or s.std_pct is None else f"{s.std_pct:.1f}",
            "—" if seen is None else f"{s.compliance_urad_per_nm:.3g} ± {seen:.2g}",
            f"{s.prior_urad_per_nm:.3g} ± {s.prior_std_urad_per_nm:.2g}",
            s.status,
        )
    console.print(table)
    for s in found:
        if not s.identified:
            console.print(escape(f"J{s.joint} stiffness not determined: {s.reason}"))
    note = stiffness_note(found)
    if note:
        console.print(escape(note))
