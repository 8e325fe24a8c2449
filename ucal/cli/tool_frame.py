"""``ucal tool-frame``: the transducer's tool frame from echoes off the reflector plate."""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import click

from ucal.cli.options import (
    cell_from_options,
    controller_option,
    dry_run_option,
    json_option,
    pulser_option,
    record_options,
    sim_option,
    yes_option,
)
from ucal.cli.procedure import finish, recorded_run, replay_job, run_job
from ucal.procedure import Outcome, RunOptions
from ucal.profile import load_profile
from ucal.toolframe.procedure import ToolFrameCalibration

log = logging.getLogger(__name__)


@click.command(
    "tool-frame",
    epilog="""\b
Examples:
  ucal tool-frame cell.toml --sim --yes
  ucal tool-frame cell.toml --sim examples/world.toml --method paper --points 100 --yes --json
  ucal tool-frame cell.toml --sim examples/world.toml --dry-run
  ucal tool-frame cell.toml --sim --yes --record tool.jsonl
  ucal tool-frame cell.toml --replay tool.jsonl --json
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
@record_options
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
    record_path: Path | None,
    replay_path: Path | None,
    remeasure: bool,
    yes: bool,
    dry_run: bool,
    as_json: bool,
) -> None:
    """Find the tool centre point and beam direction relative to the flange.

    Uses the reflector plate of [reflector] points_mm and the profile's [calibration] joint
    offsets (actual = reading + offset). The exact method (default) finds the beam at normal
    incidence to the plate in --points orientations spread over a turn about it, reads the water
    path there (the tool's offset along the beam) and scans the TCP across two of the plate's
    edges in two senses about the beam (its offsets across the beam); it fits the tool with the
    cell's other uncertain quantities as unknowns with the profile's tolerances as priors (joint
    offsets with [calibration] std_deg, or wide when not calibrated; the plate with [reflector]
    points_std_mm; DH table, sound speed, an electronic delay), so it works before or after
    `ucal calibrate`. Writes [tool] position_mm, rotation_deg and their position_std_mm,
    rotation_std_deg (mm, deg; the previous version is kept in the profile's history). Time of
    flight cannot tell the tool's length along the beam from the plate's height: that std
    carries the plate's tolerance. The beam fixes only the tool's z axis: the rotation about it
    keeps the profile's. Nothing is written with --dry-run, on failure, or when the result is
    out of tolerance (exit 1) unless --force.
    """
    replayed = recorded_run(
        "tool-frame",
        profile_path,
        record_path,
        replay_path,
        remeasure,
        {"method": "method", "points": "points"},
    )
    if replayed is not None:
        record, recorded_profile = replayed
        options = record.options
        job = ToolFrameCalibration(
            recorded_profile, profile_path, options.get("method", "exact"), options.get("points")
        )
        finish(replay_job(job, record, remeasure), as_json, show_outcome)
        return
    cell = cell_from_options(sim_world, controller_url, pulser_url, dry_run=dry_run)
    profile = load_profile(profile_path)
    job = ToolFrameCalibration(profile, profile_path, method, points, force)
    finish(run_job(job, RunOptions(cell, yes, dry_run, record_path)), as_json, show_outcome)


def show_outcome(outcome: Outcome) -> None:
    """The tool frame and its fit on stdout."""
    _print(outcome.result)


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
