"""``ucal tool-frame``: the transducer's tool frame from echoes off the reflector plate."""

from __future__ import annotations

import contextlib
import logging
from pathlib import Path
from typing import Any

import click
import numpy as np

from ucal.cli.options import (
    cell_from_options,
    confirm_motion,
    controller_option,
    dry_run_option,
    emit_json,
    json_option,
    pulser_option,
    sim_option,
    yes_option,
)
from ucal.cli.progress import StepProgress

log = logging.getLogger(__name__)


@click.command(
    "tool-frame",
    epilog="""\b
Examples:
  ucal tool-frame cell.toml --sim --yes
  ucal tool-frame cell.toml --sim world.toml --method paper --points 100 --yes --json
  ucal tool-frame cell.toml --sim world.toml --dry-run
  ucal tool-frame cell.toml --controller tcp://192.168.0.254:11000 \\
      --pulser modbus-tcp://192.168.0.20:502
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
    help="exact: beam from normal-incidence postures, offset along the beam from "
    "time of flight, offsets across it from edge reversal; paper: paper 002's "
    "constrained least squares over incidence points.",
)
@click.option(
    "--points",
    type=click.IntRange(min=1),
    default=None,
    metavar="N",
    help="exact: normal-incidence postures (default 4, at least 2); paper: "
    "incidence points (default 100, at least 7).",
)
@click.option(
    "--force",
    is_flag=True,
    help="Write the result even when it is out of tolerance or a misfit (the reason "
    "is recorded in the profile history).",
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
    points: int | None,
    force: bool,
    yes: bool,
    dry_run: bool,
    as_json: bool,
) -> None:
    """Find the tool centre point and beam direction relative to the flange.

    Uses the reflector plate of [reflector] points_mm and the profile's [calibration] joint
    offsets (actual = reading + offset). The exact method fits the tool with the cell's other
    uncertain quantities as unknowns with the profile's tolerances as priors (joint offsets
    with [calibration] std_deg, or wide when not calibrated; the plate with [reflector]
    points_std_mm; DH table, sound speed, an electronic delay), so it works before or after
    `ucal calibrate`. Writes [tool] position_mm, rotation_deg and their position_std_mm,
    rotation_std_deg (mm, deg; the previous version is kept in the profile's history). Time of
    flight cannot tell the tool's length along the beam from the plate's height: that std
    carries the plate's tolerance. The beam fixes only the tool's z axis: the rotation about it
    keeps the profile's. Nothing is written with --dry-run, on failure, or when the result is
    out of tolerance (exit 1) unless --force.
    """
    from ucal.errors import OutOfToleranceError
    from ucal.profile import check_writable, load_profile, profile_lock, write_profile
    from ucal.session import check_status, open_cell
    from ucal.toolframe.procedure import plan_tool_frame, run_tool_frame

    cell = cell_from_options(sim_world, controller_url, pulser_url, yes=yes, dry_run=dry_run)
    profile = load_profile(profile_path)
    plan = plan_tool_frame(profile, method, points)
    # One run per profile, and room to write the result, checked before the first motion.
    with contextlib.nullcontext() if dry_run else profile_lock(profile_path):
        if not dry_run:
            check_writable(profile_path)
        confirm_motion(yes, plan.summary(), cell)
        with open_cell(profile, cell.sim_world, cell.controller_url, cell.pulser_url) as session:
            check_status(session.rig)
            with StepProgress("tool-frame") as progress:

                def report(what: str, i: int, n: int) -> None:
                    counters = session.rig.counters
                    progress.step(
                        what if what != "done" else "solving",
                        i,
                        n,
                        f"{counters.moves} moves, {counters.reads} reads",
                    )

                run = run_tool_frame(profile, plan, session.rig, report)
            truth = session.truth
        message = _refusal(run)
        written = False
        if (run.in_tolerance or force) and not dry_run:
            reason = f"tool-frame ({run.method})"
            keys, capped = _tool_keys(run)
            if not run.in_tolerance:
                message = message.replace(" (profile not written; --force writes it)", "")
                reason += f", written with --force: {message}"
                message += " (written with --force)"
            if capped:
                reason += f"; {capped}"
            write_profile(profile_path, {"tool": keys}, reason=reason)
            written = True
    out = _result(run, profile, profile_path, written, truth)
    if not as_json:
        _print(out)
    if not run.in_tolerance:
        raise OutOfToleranceError(message, out)
    if as_json:
        emit_json(out)


def _refusal(run: Any) -> str:
    if run.in_tolerance:
        return ""
    if run.fit is not None:
        cause = run.fit.refusal
    else:
        cause = "; ".join(
            n for n in run.notes if "tolerance" in n or "converge" in n or "second-order" in n
        )
    return f"tool frame out of tolerance: {cause} (profile not written; --force writes it)"


#: The largest tool tolerances a profile holds (``ucal.profile.read_tolerances``): mm, deg.
TOOL_STD_LIMITS = {"position_std_mm": 100.0, "rotation_std_deg": 10.0}


def _tool_keys(run: Any) -> tuple[dict[str, Any], str]:
    """``[tool]`` keys to write: the frame and, from the exact fit, its stds; and a note when a
    std beyond what a profile holds (a result written with --force, its stds scaled by a
    misfit's √χ²ᵣ) is written at that limit."""
    keys: dict[str, Any] = {
        "position_mm": [round(float(v), 6) for v in run.position_mm],
        "rotation_deg": [round(float(v), 6) for v in run.rotation_deg],
    }
    notes = []
    if run.fit is not None:
        for key, std in (
            ("position_std_mm", run.fit.position_std_mm),
            ("rotation_std_deg", run.fit.rotation_std_deg),
        ):
            limit = TOOL_STD_LIMITS[key]
            if max(std) > limit:
                notes.append(f"{key} {max(std):.3g} written as {limit:g}, the profile's limit")
            keys[key] = [round(min(max(float(v), 1e-6), limit), 6) for v in std]
    return keys, "; ".join(notes)


def _result(
    run: Any, profile: Any, profile_path: Path, written: bool, truth: Any
) -> dict[str, Any]:
    from ucal.kinematics.rotations import angle_between_deg

    tf = run.fit
    out: dict[str, Any] = {
        "position_mm": run.position_mm,
        "rotation_deg": run.rotation_deg,
        "beam_direction": run.beam,
        "position_std_mm": run.std_position_mm,
        "rotation_std_deg": None if tf is None else tf.rotation_std_deg,
        "beam_std_deg": run.std_beam_deg,
        "rms_residual_mm": run.rms_residual_mm,
        "points": run.points,
        "written": written,
        "method": run.method,
        "std": {"position_mm": run.std_position_mm, "beam_deg": run.std_beam_deg},
        "moves": run.moves,
        "pulser_reads": run.reads,
        "profile": str(profile_path),
        "notes": run.notes,
    }
    if tf is not None:
        out["fit"] = tf.quality.to_json()
        out["along_beam"] = {
            "position_mm": tf.along_beam_mm,
            "std_mm": tf.along_beam_std_mm,
            "limited_by": tf.along_beam_limited_by,
        }
        out["across_beam_std_mm"] = tf.across_beam_std_mm
        out["plate_height_mm"] = {"value": tf.plate_height_mm, "std": tf.plate_height_std_mm}
        out["delay_ns"] = {"value": tf.delay_ns, "std": tf.delay_std_ns}
        out["sound_speed_m_s"] = tf.sound_speed_m_s
        out["sound_speed_std_m_s"] = tf.sound_speed_std_m_s
    if run.method == "exact":
        out["normal_incidence_postures"] = len(run.peaks)
        out["edge_crossings"] = len(run.crossings)
    if run.paper is not None:
        out["paper"] = {
            "iterations": run.paper.iterations,
            "converged": run.paper.converged,
            "second_order_ok": run.paper.second_order_ok,
            "multiplier": run.paper.multiplier,
            "condition": run.paper.condition,
        }
    if truth is not None:  # the simulator's hidden truth: how far off the result is
        from ucal.toolframe.exact import tangent_basis
        from ucal.toolframe.fit import truth_in_profile_flange

        true_tool = truth_in_profile_flange(profile, truth)
        err = np.asarray(run.position_mm) - true_tool[:3, 3]
        beam = np.asarray(run.beam)
        out["simulated_error"] = {
            "position_mm": err,
            "along_beam_mm": float(beam @ err),
            "across_beam_mm": tangent_basis(beam) @ err,
            "beam_deg": float(angle_between_deg(beam, true_tool[:3, 2])),
            "frame": "flange of the profile's J6 offset and last DH link",
        }
    return out


def _print(out: dict[str, Any]) -> None:
    fmt = ", ".join
    std = out["std"]
    if "fit" in out:
        f = out["fit"]
        along = out["along_beam"]
        limited = ", ".join(f"{k} {100 * v:.0f} %" for k, v in along["limited_by"].items())
        click.echo(
            f"fit:             {f['verdict']}, chi2_r {f['chi2_reduced']:.3g} (dof "
            f"{f['dof']}), worst {f['worst']}"
        )
        click.echo(
            f"along the beam:  {along['position_mm']:.4f} ± {along['std_mm']:.4f} mm"
            + (f" (limited by {limited})" if limited else "")
        )
        click.echo(
            "across the beam: ± " + fmt(f"{v:.4f}" for v in out["across_beam_std_mm"]) + " mm"
        )
    click.echo(
        f"method:          {out['method']} ({out['points']} points, {out['moves']} moves, "
        f"{out['pulser_reads']} pulser reads)"
    )
    click.echo(
        "position (mm):   "
        + fmt(f"{v:.4f}" for v in out["position_mm"])
        + "   ± "
        + fmt(f"{v:.4f}" for v in std["position_mm"])
    )
    click.echo("rotation (deg):  " + fmt(f"{v:.4f}" for v in out["rotation_deg"]))
    click.echo(
        "beam (flange):   "
        + fmt(f"{v:.6f}" for v in out["beam_direction"])
        + f"   ± {std['beam_deg']:.4f} deg"
    )
    click.echo(f"rms residual:    {out['rms_residual_mm']:.4f} mm")
    if "simulated_error" in out:
        se = out["simulated_error"]
        click.echo(
            "simulated error: "
            + fmt(f"{v:+.4f}" for v in se["position_mm"])
            + f" mm (along the beam {se['along_beam_mm']:+.4f}, across "
            + fmt(f"{v:+.4f}" for v in se["across_beam_mm"])
            + f"), beam {se['beam_deg']:.4f} deg"
        )
    for n in out["notes"]:
        click.echo(f"note: {n}")
    click.echo(
        f"profile {out['profile']}: " + ("[tool] written" if out["written"] else "not written")
    )
