"""``ucal calibrate``: joint zero offsets (paper 000) → ``[calibration]`` in the profile."""

from __future__ import annotations

import contextlib
import datetime as dt
import tempfile
from pathlib import Path

import click
import numpy as np

from ucal.cli.options import (
    confirm_motion,
    controller_option,
    dry_run_option,
    emit_json,
    json_option,
    pulser_option,
    sim_option,
    yes_option,
)

#: A finished run whose observable offsets are less certain than this is out of tolerance.
TOLERANCE_STD_DEG = 0.02


@click.command("calibrate", epilog="""\b
Examples:
  ucal calibrate cell.toml --sim --yes
  ucal calibrate cell.toml --sim world.toml --method paper --json --yes
  ucal calibrate cell.toml --controller tcp://10.0.0.5:11000 --pulser modbus-tcp://10.0.0.6:502
""")
@click.argument("profile_path", metavar="PROFILE", type=click.Path(dir_okay=False, path_type=Path))
@sim_option
@controller_option
@pulser_option
@click.option("--method", type=click.Choice(["exact", "paper"]), default="exact", show_default=True,
              help="exact: nonlinear least squares over the full kinematics; paper: paper 000's "
                   "first-order equations 11-21.")
@click.option("--beam", type=click.Choice(["auto", "fit", "fixed"]), default="auto",
              show_default=True,
              help="Fit the beam direction in the flange frame with the offsets (auto: when the "
                   "profile's beam lies on the joint-6 axis).")
@yes_option
@dry_run_option
@json_option
def cli(profile_path: Path, sim_world: str | None, controller_url: str | None,
        pulser_url: str | None, method: str, beam: str, yes: bool, dry_run: bool,
        as_json: bool) -> None:
    """Find the six joint zero offsets with the ultrasonic transducer and write them.

    The beam is brought normal to the three faces of the calibration block in three arm
    configurations (the calibration pose, joint 3 stepped, joint 2 stepped); the peak-echo
    postures and time-of-flight distances give the offsets (actual = reading + offset).
    Every target is checked before the first motion. On any fault or Ctrl-C the robot is told
    to stop and the profile is left byte-for-byte unchanged.
    """
    from ucal.models import DEFAULT_MODEL
    from ucal.profile import (
        check_writable,
        create_profile,
        default_profile_text,
        load_profile,
        profile_lock,
    )

    if dry_run and sim_world is None:
        sim_world = ""  # --dry-run runs against the simulator
    created = False
    if not profile_path.exists() and sim_world is not None:
        if dry_run:
            tmp = Path(tempfile.mkdtemp(prefix="ucal-")) / profile_path.name
            tmp.write_text(default_profile_text(DEFAULT_MODEL), encoding="utf-8")
            profile = load_profile(tmp)
        else:
            create_profile(profile_path, DEFAULT_MODEL)
            created = True
            click.echo(f"created {profile_path} for the default model {DEFAULT_MODEL}", err=True)
            profile = load_profile(profile_path)
    else:
        profile = load_profile(profile_path)
    # One run per profile, and room to write the result, checked before the first motion.
    with contextlib.nullcontext() if dry_run else profile_lock(profile_path):
        if not dry_run:
            check_writable(profile_path)
        result = run(profile, profile_path, sim_world, controller_url, pulser_url, method, beam,
                     yes, dry_run, as_json)
    result["created"] = created
    if as_json:
        emit_json(result)
    if result["out_of_tolerance"]:
        from ucal.errors import OutOfToleranceError

        raise OutOfToleranceError(
            f"calibration out of tolerance: an observable offset has a standard deviation above "
            f"{TOLERANCE_STD_DEG} deg; the profile was not written")


def run(profile, profile_path: Path, sim_world, controller_url, pulser_url, method: str,
        beam: str, yes: bool, dry_run: bool, as_json: bool) -> dict:
    """Plan, confirm, measure, solve, write; returns the JSON result of SPEC.md (+ extras)."""
    from rich.console import Console
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

    from ucal.calibration.sequence import plan_calibration, run_calibration, solve
    from ucal.profile import write_profile
    from ucal.session import check_status, open_cell

    console = Console(stderr=True)
    plan = plan_calibration(profile)
    confirm_motion(yes, plan_summary(plan, profile))
    with open_cell(profile, sim_world, controller_url, pulser_url) as cell:
        check_status(cell.rig)
        with Progress(TextColumn("{task.description}"), BarColumn(), TextColumn("{task.fields[info]}"),
                      TimeElapsedColumn(), console=console, disable=as_json) as progress:
            task = progress.add_task("calibrating", total=len(plan.targets), info="")

            def report(label: str, i: int, n: int) -> None:
                progress.update(task, completed=i, description=f"face {label}",
                                info=f"{cell.rig.counters.moves} moves")

            measurements = run_calibration(profile, plan, cell.rig, progress=report)
        truth = cell.truth
    exact, paper = solve(profile, measurements, beam)
    chosen = exact if method == "exact" else paper
    if chosen is None:
        from ucal.errors import UcalError

        raise UcalError("the paper's method could not be applied to these measurements")
    observable = [j for j in range(6) if j + 1 not in chosen.unobservable_joints]
    std = chosen.std_deg
    out_of_tol = bool(np.any(~np.isfinite(std[observable])) or
                      np.any(std[observable] > TOLERANCE_STD_DEG))
    written = False
    if not dry_run and not out_of_tol:
        write_profile(profile_path, {"calibration": {
            "joint_offsets_deg": [round(float(v), 6) for v in chosen.offsets_deg],
            "unobservable_joints": list(chosen.unobservable_joints),
            "method": chosen.method,
            "std_deg": [round(float(v), 6) if np.isfinite(v) else -1.0 for v in std],
            "condition_number": round(float(chosen.condition_number), 3),
            "date": dt.datetime.now(dt.UTC).isoformat(timespec="seconds"),
        }}, reason=f"calibrate --method {method}")
        written = True
    result = {
        "joint_offsets_deg": chosen.offsets_deg,
        "std_deg": [float(v) if np.isfinite(v) else None for v in std],
        "unobservable_joints": list(chosen.unobservable_joints),
        "method": chosen.method,
        "moves": measurements.moves,
        "pulser_reads": measurements.reads,
        "profile": str(profile_path),
        "written": written,
        "condition_number": chosen.condition_number,
        "out_of_tolerance": out_of_tol,
    }
    if exact.extra.get("beam_fitted"):
        result["beam_direction_flange"] = exact.extra["beam_flange"]
    if truth is not None:
        result["truth_offsets_deg"] = truth.joint_offsets_deg
    if not as_json:
        show_result(console, chosen, exact, paper, truth, result)
    return result


def plan_summary(plan, profile) -> str:
    """The plan as text for the confirmation prompt (stderr)."""
    from ucal.acoustics import sound_speed_m_s
    from ucal.calibration.model import FACE_NAMES

    temp = profile.water_temperature_c
    lines = [
        (f"Calibration plan for {profile.model.name}: {len(plan.targets)} normal-incidence "
        f"measurements, joint steps ±{plan.step_deg:g} deg (the sign is chosen on the way for "
        "clearance)"),
        (f"Water {temp:g} °C: sound speed {sound_speed_m_s(temp):.2f} m/s (Marczak); transducer "
        f"{profile.frequency_mhz:g} MHz, {profile.element_diameter_mm:g} mm"),
        "  target      J1       J2       J3       J4       J5       J6    water path",
    ]
    for t in plan.targets:
        lines.append(f"  {t.config:>4}/{FACE_NAMES[t.face]:<3}" +
                     "".join(f"{v:9.2f}" for v in t.joints_deg) + f"   {t.water_path_mm:6.1f} mm")
    lines.append("The wrist searches around each target for the echo (joints 4-6 only).")
    return "\n".join(lines)


def show_result(console, chosen, exact, paper, truth, result) -> None:
    from rich.table import Table

    table = Table(title=f"Joint offsets ({chosen.method} method)")
    table.add_column("joint")
    table.add_column("offset (deg)", justify="right")
    table.add_column("σ (deg)", justify="right")
    if paper is not None and chosen is exact:
        table.add_column("paper method", justify="right")
    if truth is not None:
        table.add_column("simulator truth", justify="right")
        table.add_column("error", justify="right")
    for j in range(6):
        unobs = j + 1 in chosen.unobservable_joints
        row = [f"J{j + 1}", f"{chosen.offsets_deg[j]:+.4f}" + (" (kept)" if unobs else ""),
               "unobservable" if unobs else f"{chosen.std_deg[j]:.4f}"]
        if paper is not None and chosen is exact:
            row.append(f"{paper.offsets_deg[j]:+.4f}")
        if truth is not None:
            row.append(f"{truth.joint_offsets_deg[j]:+.4f}")
            row.append("—" if unobs else f"{chosen.offsets_deg[j] - truth.joint_offsets_deg[j]:+.4f}")
        table.add_row(*row)
    console.print(table)
    console.print(f"condition number {chosen.condition_number:.1f}; {result['moves']} moves, "
                  f"{result['pulser_reads']} pulser reads; profile "
                  f"{'written' if result['written'] else 'not written'}: {result['profile']}")
    if chosen.unobservable_joints:
        console.print(f"joints {list(chosen.unobservable_joints)} cannot be determined from "
                      "these measurements (e.g. joint 6 with the beam on its axis) and keep "
                      "their profile values")
