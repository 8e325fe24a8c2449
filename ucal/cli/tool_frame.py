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

log = logging.getLogger(__name__)


@click.command("tool-frame", epilog="""\b
Examples:
  ucal tool-frame cell.toml --sim --yes
  ucal tool-frame cell.toml --sim world.toml --method paper --points 100 --yes --json
  ucal tool-frame cell.toml --sim world.toml --dry-run
  ucal tool-frame cell.toml --controller tcp://192.168.0.254:11000 \\
      --pulser modbus-tcp://192.168.0.20:502
""")
@click.argument("profile_path", metavar="PROFILE",
                type=click.Path(dir_okay=False, path_type=Path))
@sim_option
@controller_option
@pulser_option
@click.option("--method", type=click.Choice(["exact", "paper"]), default="exact",
              show_default=True,
              help="exact: beam from normal-incidence postures, offset along the beam from "
                   "time of flight, offsets across it from edge reversal; paper: paper 002's "
                   "constrained least squares over incidence points.")
@click.option("--points", type=click.IntRange(min=1), default=None, metavar="N",
              help="exact: normal-incidence postures (default 4, at least 2); paper: "
                   "incidence points (default 100, at least 7).")
@yes_option
@dry_run_option
@json_option
def cli(profile_path: Path, sim_world: str | None, controller_url: str | None,
        pulser_url: str | None, method: str, points: int | None, yes: bool, dry_run: bool,
        as_json: bool) -> None:
    """Find the tool centre point and beam direction relative to the flange.

    Uses the reflector plate of [reflector] points_mm and the profile's [calibration] joint
    offsets (actual = reading + offset); writes [tool] position_mm and rotation_deg (mm, deg;
    the previous version is kept in the profile's history). The beam fixes only the tool's z
    axis: rotation_deg is the rotation closest to the profile's that maps z onto the measured
    beam. Nothing is written with --dry-run, on failure, or when the result is out of
    tolerance (exit 1).
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
            run = run_tool_frame(profile, plan, session.rig, _progress(as_json))
            truth = session.truth
        written = False
        if run.in_tolerance and not dry_run:
            write_profile(profile_path, {"tool": {
                "position_mm": [round(float(v), 6) for v in run.position_mm],
                "rotation_deg": [round(float(v), 6) for v in run.rotation_deg]}},
                reason=f"tool-frame ({run.method})")
            written = True
    out = _result(run, profile_path, written, truth)
    if not as_json:
        _print(out)
    if not run.in_tolerance:
        raise OutOfToleranceError("tool frame out of tolerance: " + "; ".join(
            n for n in run.notes if "tolerance" in n or "converge" in n or "second-order" in n)
            + " (profile not written)", out)
    if as_json:
        emit_json(out)


def _progress(quiet: bool) -> Any:
    def show(what: str, i: int, n: int) -> None:
        log.info("%s (%d/%d)", what, i, n)
        if not quiet:
            click.echo(f"[{i}/{n}] {what}", err=True)
    return show


def _result(run: Any, profile_path: Path, written: bool, truth: Any) -> dict[str, Any]:
    from ucal.kinematics.rotations import angle_between_deg

    out: dict[str, Any] = {
        "position_mm": run.position_mm,
        "rotation_deg": run.rotation_deg,
        "beam_direction": run.beam,
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
    if run.method == "exact":
        out["normal_incidence_postures"] = len(run.peaks)
        out["edge_crossings"] = len(run.crossings)
    if run.paper is not None:
        out["paper"] = {"iterations": run.paper.iterations, "converged": run.paper.converged,
                        "second_order_ok": run.paper.second_order_ok,
                        "multiplier": run.paper.multiplier, "condition": run.paper.condition}
    if truth is not None:  # the simulator's hidden truth: how far off the result is
        out["simulated_error"] = {
            "position_mm": np.asarray(run.position_mm) - truth.tool_position_mm,
            "beam_deg": float(angle_between_deg(run.beam, truth.tool_matrix[:3, 2]))}
    return out


def _print(out: dict[str, Any]) -> None:
    fmt = ", ".join
    std = out["std"]
    click.echo(f"method:          {out['method']} ({out['points']} points, {out['moves']} moves, "
               f"{out['pulser_reads']} pulser reads)")
    click.echo("position (mm):   " + fmt(f"{v:.4f}" for v in out["position_mm"]) + "   ± "
               + fmt(f"{v:.4f}" for v in std["position_mm"]))
    click.echo("rotation (deg):  " + fmt(f"{v:.4f}" for v in out["rotation_deg"]))
    click.echo("beam (flange):   " + fmt(f"{v:.6f}" for v in out["beam_direction"])
               + f"   ± {std['beam_deg']:.4f} deg")
    click.echo(f"rms residual:    {out['rms_residual_mm']:.4f} mm")
    if "simulated_error" in out:
        se = out["simulated_error"]
        click.echo("simulated error: " + fmt(f"{v:+.4f}" for v in se["position_mm"])
                   + f" mm, beam {se['beam_deg']:.4f} deg")
    for n in out["notes"]:
        click.echo(f"note: {n}")
    click.echo(f"profile {out['profile']}: " + ("[tool] written" if out["written"]
                                                 else "not written"))
