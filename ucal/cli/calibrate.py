"""``ucal calibrate``: joint zero offsets (paper 000) → ``[calibration]`` in the profile.

Parses the options, loads (or, with ``--sim``, creates) the profile and runs the calibration
procedure (``ucal.calibration.procedure``) through the steps of ``ucal.procedure``; prints the
result. ``--level full`` runs ``ucal.cli.calibrate_full``, which shares this module's session
(``in_session``), progress (``measure_with_progress``) and result helpers.
"""

from __future__ import annotations

import contextlib
import logging
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import click
import numpy as np
import tomlkit
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from ucal import __version__
from ucal.calibration.procedure import (  # noqa: F401  (shared with ucal.cli.calibrate_full)
    TOLERANCE_STD_DEG,
    OffsetsCalibration,
    OffsetsShown,
    judge,
    result_fields,
    written_keys,
)
from ucal.cli import calibrate_full
from ucal.cli.options import (
    cell_from_options,
    cell_options_typed,
    check_output,
    controller_option,
    dry_run_option,
    emit_json,
    info,
    json_option,
    pulser_option,
    sim_option,
    yes_option,
)
from ucal.cli.procedure import finish, run_job
from ucal.cli.progress import StepProgress
from ucal.errors import InputError, OutOfToleranceError
from ucal.models import DEFAULT_MODEL
from ucal.procedure import Outcome, RunOptions
from ucal.profile import (
    check_writable,
    create_profile,
    default_profile_text,
    load_profile,
    profile_from_data,
    profile_lock,
)
from ucal.record import Record, Recorder, read_record, sha256_text
from ucal.session import CellSession, check_status, open_cell, replay_cell

log = logging.getLogger(__name__)


@click.command(
    "calibrate",
    epilog="""\b
Examples:
  ucal calibrate cell.toml --sim --yes
  ucal calibrate cell.toml --sim world.toml --method paper --json --yes
  ucal calibrate cell.toml --controller tcp://10.0.0.5:11000 --pulser modbus-tcp://10.0.0.6:502
  ucal calibrate cell.toml --sim --yes --level full
  ucal calibrate cell.toml --sim --yes --record run.jsonl
  ucal calibrate cell.toml --replay run.jsonl --method paper --json
""",
)
@click.argument("profile_path", metavar="PROFILE", type=click.Path(dir_okay=False, path_type=Path))
@sim_option
@controller_option
@pulser_option
@click.option(
    "--method",
    type=click.Choice(["exact", "paper"]),
    default="exact",
    show_default=True,
    help="exact: nonlinear least squares over the full kinematics; paper: paper 000's "
    "first-order equations 11-21.",
)
@click.option(
    "--beam",
    type=click.Choice(["auto", "fit", "fixed"]),
    default="auto",
    show_default=True,
    help="auto/fit: the beam direction in the flange frame is an unknown with the "
    "profile's tool tolerance as prior; fixed: take the profile's tool as exact.",
)
@click.option(
    "--level",
    type=click.Choice(["offsets", "full"]),
    default="offsets",
    show_default=True,
    help="offsets: the six joint offsets; full: the identifiable kinematic parameters "
    "as well, from many postures, written as [calibration] dh.",
)
@click.option(
    "--postures",
    type=click.IntRange(3, 200),
    default=None,
    help="--level full: at most N postures (default: as many as the D-optimal "
    "criterion finds worth measuring).",
)
@click.option(
    "--force",
    is_flag=True,
    help="Write the result even when the fit is a misfit (the verdict is recorded in "
    "the profile history).",
)
@click.option(
    "--record",
    "record_path",
    type=click.Path(dir_okay=False, path_type=Path),
    help="Write every device call of the run (joint readings, moves, gain, amplitude, "
    "TOF, times), the plan and the profile to FILE as JSON lines, as it goes.",
)
@click.option(
    "--replay",
    "replay_path",
    type=click.Path(dir_okay=False, path_type=Path),
    help="Solve a recorded run again (any --method) without moving anything; writes nothing.",
)
@yes_option
@dry_run_option
@json_option
def cli(
    profile_path: Path,
    sim_world: str | None,
    controller_url: str | None,
    pulser_url: str | None,
    method: str,
    beam: str,
    level: str,
    postures: int | None,
    force: bool,
    record_path: Path | None,
    replay_path: Path | None,
    yes: bool,
    dry_run: bool,
    as_json: bool,
) -> None:
    """Find the six joint zero offsets with the ultrasonic transducer and write them.

    The beam is brought normal to the three faces of the calibration block in three arm
    configurations (the calibration pose, joint 3 stepped, joint 2 stepped); the peak-echo
    postures and time-of-flight distances give the offsets (actual = reading + offset).
    Every target is checked before the first motion. On any fault or Ctrl-C the robot is told
    to stop and the profile is left byte-for-byte unchanged.
    """
    if level == "full" and method != "exact":
        raise InputError(
            "--level full identifies the kinematic model by least squares: it "
            "takes --method exact only"
        )
    if replay_path is not None:
        if cell_options_typed(click.get_current_context()) or record_path is not None:
            raise InputError(
                "--replay solves a recorded run: it takes no --sim, --controller, "
                "--pulser or --record"
            )
        _replay(profile_path, replay_path, method, beam, as_json)
        return
    cell = cell_from_options(sim_world, controller_url, pulser_url, yes=yes, dry_run=dry_run)
    if record_path is not None:
        check_output(record_path)
    created = False
    scratch = contextlib.ExitStack()  # holds a dry run's default profile until the run ends
    if not profile_path.exists() and cell.sim_world is not None:
        if dry_run:
            tmp = Path(scratch.enter_context(tempfile.TemporaryDirectory(prefix="ucal-")))
            (tmp / profile_path.name).write_text(
                default_profile_text(DEFAULT_MODEL), encoding="utf-8"
            )
            profile = load_profile(tmp / profile_path.name)
        else:
            create_profile(profile_path, DEFAULT_MODEL)
            created = True
            info(f"created {profile_path} for the default model {DEFAULT_MODEL}")
            profile = load_profile(profile_path)
    else:
        profile = load_profile(profile_path)
    if level == "full":
        # One run per profile, and room to write the result, checked before the first motion.
        with scratch, contextlib.nullcontext() if dry_run else profile_lock(profile_path):
            if not dry_run:
                check_writable(profile_path)
            result = calibrate_full.run(
                profile,
                profile_path,
                cell.sim_world,
                cell.controller_url,
                cell.pulser_url,
                beam,
                yes,
                dry_run,
                as_json,
                force,
                record_path,
                max_postures=postures,
            )
        result["created"] = created
        finish_dict(result, as_json)
        return
    with scratch:
        job = OffsetsCalibration(profile, profile_path, method, beam, force)
        outcome = run_job(job, RunOptions(cell, yes, dry_run, record_path))
    outcome.result["created"] = created
    finish(outcome, as_json, show_outcome)


def _replay(profile_path: Path, record_path: Path, method: str, beam: str, as_json: bool) -> None:
    """Solve a recorded run again: its profile, plan and device traffic; nothing moves."""
    record = read_record(record_path)
    profile = profile_from_data(
        tomlkit.parse(record.profile_text), f"{record_path} (recorded profile)"
    )
    if record.result is None:
        log.warning("%s has no end line: the recorded run was cut off", record_path)
    if record.options.get("level") == "full":
        result = calibrate_full.run(
            profile,
            profile_path,
            None,
            None,
            None,
            beam,
            True,
            True,
            as_json,
            record=record,
            max_postures=record.options.get("max_postures"),
        )
        result["replayed"] = str(record_path)
        finish_dict(result, as_json)
        return
    job = OffsetsCalibration(profile, profile_path, method, beam)
    outcome = run_job(job, RunOptions(None, yes=True, dry_run=True, replay=record))
    outcome.result["replayed"] = str(record_path)
    finish(outcome, as_json, show_outcome)


def finish_dict(result: dict[str, Any], as_json: bool) -> None:
    """Print the full level's JSON result; out of tolerance, exit 1 (with ``--json`` the CLI
    prints the result with the error fields)."""
    message = result.pop("_message", None)
    if result["out_of_tolerance"]:
        raise OutOfToleranceError(message, result)
    if as_json:
        emit_json(result)


def show_outcome(outcome: Outcome) -> None:
    """The offsets level's result tables on stdout."""
    shown: OffsetsShown = outcome.shown
    solved = shown.solved
    show_result(Console(), solved.chosen, solved.exact, solved.paper, shown.truth, outcome.result)


# -- the full level's session and progress (``ucal.cli.calibrate_full``) -------------------------


def in_session(
    profile: Any,
    sim_world: str | None,
    controller_url: str | None,
    pulser_url: str | None,
    record_path: Path | None,
    record: Record | None,
    options: dict[str, Any],
    plan_rows: list[dict[str, Any]],
    body: Callable[[CellSession], dict[str, Any]],
) -> dict[str, Any]:
    """Open the cell (or the replayed one), record its traffic if asked, run ``body(cell)`` and
    return its result (also the record's end line)."""
    recorder = None
    if record_path is not None:
        text = profile.path.read_text(encoding="utf-8")
        recorder = Recorder(record_path).open(
            {
                "command": "calibrate",
                "ucal": __version__,
                "profile_path": str(profile.path),
                "profile_sha256": sha256_text(text),
                "profile_text": text,
                "cell": "simulated cell" if sim_world is not None else controller_url,
                "options": options,
                "plan": plan_rows,
            }
        )
    with contextlib.ExitStack() as stack:
        if recorder is not None:
            stack.enter_context(recorder)
        cell = stack.enter_context(
            replay_cell(profile, record)
            if record is not None
            else open_cell(profile, sim_world, controller_url, pulser_url, recorder)
        )
        result = body(cell)
        if recorder is not None:
            recorder.end({k: v for k, v in result.items() if not k.startswith("_")})
    return result


def measure_with_progress(cell: CellSession, what: str, measure: Callable[[Any], Any]) -> Any:
    """``measure(report)`` with one progress line per step (``StepProgress``), after checking
    the controller's status."""
    check_status(cell.rig)
    with StepProgress("calibrate") as progress:

        def report(label: str, i: int, n: int) -> None:
            counters = cell.rig.counters
            progress.step(
                f"{what} {label}" if label != "done" else "solving",
                i,
                n,
                f"{counters.moves} moves, {counters.reads} reads",
            )

        return measure(report)


# -- result tables -----------------------------------------------------------------------------


def show_result(
    console: Console, chosen: Any, exact: Any, paper: Any, truth: Any, result: dict[str, Any]
) -> None:
    """The result as tables on stdout (without --json): offsets with σ, fit quality, residual
    per measurement."""
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
    for j in range(6):
        unobs = j + 1 in chosen.unobservable_joints
        row = [
            f"J{j + 1}",
            f"{chosen.offsets_deg[j]:+.4f}" + (" (kept)" if unobs else ""),
            "unobservable" if unobs else f"{chosen.std_deg[j]:.4f}",
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
        f"sound speed {result['sound_speed_m_s']:.2f} ± "
        f"{result['sound_speed_std_m_s']:.2f} m/s (fitted); condition number "
        f"{chosen.condition_number:.1f}; {result['moves']} moves, "
        f"{result['pulser_reads']} pulser reads; profile "
        f"{'written' if result['written'] else 'not written'}: {result['profile']}"
    )
    for j, why in sorted(chosen.unobservable_reasons.items()):
        console.print(escape(f"J{j} unobservable, kept at its profile value: {why}"))


def show_fit(console: Console, fit: Any) -> None:
    """The fit's normalised residual per measurement, its verdict and the likely cause."""
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
