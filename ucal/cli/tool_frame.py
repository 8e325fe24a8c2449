"""``ucal tool-frame``: the transducer's tool frame from echoes off the reflector plate."""

from __future__ import annotations

import logging
from pathlib import Path

import click

from ucal.cell import CellProfile
from ucal.cli.options import (
    MovingCall,
    choice_option,
    force_option,
    moving_options,
    thermometer_option,
)
from ucal.cli.procedure import run_command
from ucal.devices.record import Record
from ucal.procedure import Outcome
from ucal.toolframe.procedure import ToolFrameCalibration
from ucal.toolframe.result import ToolFrameResult

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
@moving_options(
    choice_option(
        "--method",
        ["exact", "paper"],
        "exact: beam from normal-incidence postures, offset along the beam from "
        "time of flight, offsets across it from edge reversal; paper: paper 002's "
        "constrained least squares over incidence points.",
    ),
    click.option(
        "--points",
        type=click.IntRange(min=1),
        default=None,
        metavar="N",
        help="exact: normal-incidence postures (default 4, at least 2); paper: "
        "incidence points (default 100, at least 7).",
    ),
    thermometer_option,
    force_option(
        "Write the result even when it is out of tolerance or a misfit (the reason "
        "is recorded in the profile history)."
    ),
)
def cli(
    call: MovingCall,
    method: str,
    points: int | None,
    thermometer: Path | None,
    force: bool,
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

    def job(profile: CellProfile, record: Record | None) -> ToolFrameCalibration:
        if record is None:
            return ToolFrameCalibration(profile, call.profile_path, method, points, force)
        options = record.options
        return ToolFrameCalibration(
            profile, call.profile_path, options.get("method", "exact"), options.get("points")
        )

    fixed = {"method": "method", "points": "points"}
    run_command(call, "tool-frame", fixed, job, show_outcome, thermometer)


def show_outcome(outcome: Outcome[ToolFrameResult]) -> None:
    """The tool frame and its fit on stdout."""
    result = outcome.result
    tool, tf, run = result.tool, result.tool.fit, result.run
    fmt = ", ".join
    if tf is not None:
        f = tf.quality
        limited = ", ".join(f"{k} {100 * v:.0f} %" for k, v in tf.along_beam_limited_by.items())
        click.echo(
            f"fit:             {f.verdict}, chi2_r {f.chi2_reduced:.3g} (dof "
            f"{f.dof}), worst {f.worst}"
        )
        click.echo(
            f"along the beam:  {tf.along_beam_mm:.4f} ± {tf.along_beam_std_mm:.4f} mm"
            + (f" (limited by {limited})" if limited else "")
        )
        click.echo("across the beam: ± " + fmt(f"{v:.4f}" for v in tf.across_beam_std_mm) + " mm")
    click.echo(
        f"method:          {tool.method} ({tool.points} points, {run.moves} moves, "
        f"{run.reads} pulser reads)"
    )
    click.echo(
        "position (mm):   "
        + fmt(f"{v:.4f}" for v in tool.position_mm)
        + "   ± "
        + fmt(f"{v:.4f}" for v in tool.std_position_mm)
    )
    click.echo("rotation (deg):  " + fmt(f"{v:.4f}" for v in tool.rotation_deg))
    click.echo(
        "beam (flange):   "
        + fmt(f"{v:.6f}" for v in tool.beam)
        + f"   ± {tool.std_beam_deg:.4f} deg"
    )
    click.echo(f"rms residual:    {tool.rms_residual_mm:.4f} mm")
    se = result.simulated_error
    if se is not None:
        click.echo(
            "simulated error: "
            + fmt(f"{v:+.4f}" for v in se.position_mm)
            + f" mm (along the beam {se.along_beam_mm:+.4f}, across "
            + fmt(f"{v:+.4f}" for v in se.across_beam_mm)
            + f"), beam {se.beam_deg:.4f} deg"
        )
    for n in tool.notes:
        click.echo(f"note: {n}")
    click.echo(
        f"profile {run.profile_path}: " + ("[tool] written" if run.written else "not written")
    )
