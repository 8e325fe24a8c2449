"""``ucal export``: the calibrated cell in the formats a controller loads."""

from __future__ import annotations

from pathlib import Path

import click

from ucal.cli.options import emit_json, existing_profile_argument, info, json_option, output_option
from ucal.profile import load_profile
from ucal.val3 import (
    APPLICATION,
    BLOCK_NAME,
    TOOL_NAME,
    Trsf,
    calibration_text,
    cell_json,
    val3_cell,
    write_application,
)


@click.group(
    "export",
    epilog="""\b
Examples:
  ucal export val3 cell.toml -o val3
""",
)
def cli() -> None:
    """Export the profile's tool and block for a robot controller."""


@cli.command(
    "val3",
    epilog="""\b
Examples:
  ucal export val3 cell.toml -o val3
  ucal export val3 cell.toml -o val3 --json
""",
)
@existing_profile_argument
@output_option(
    "directory",
    "DIR",
    click.Path(file_okay=False, path_type=Path),
    f"Directory to write: the VAL3 application DIR/{APPLICATION}/ and DIR/ucal_cell.json "
    "(created if missing; files there are replaced).",
)
@json_option
def val3(profile_path: Path, directory: Path, as_json: bool) -> None:
    """Write the tool and the calibration block's frame as VAL3 data.

    DIR/ucalCell/ is a VAL3 library application (ucalCell.pjx, ucalCell.dtx, start.pgx,
    stop.pgx) holding the public data tUcalTool (tool on flange[0]: the profile's [tool])
    and fUcalBlock (frame on world[0]: [sample], the block in the robot's base frame), and
    both as trsf values (trUcalTool, trUcalBlock); mm and deg, rx, ry, rz as VAL3 reads them.
    DIR/ucal_cell.json holds the same. The joint offsets stay in the profile: for
    calibrated accuracy move to targets from `ucal path ... --for-controller`.
    Exit 2 if DIR cannot be created or written (the message names it).
    """

    profile = load_profile(profile_path)
    cell = val3_cell(profile, profile_path)
    written = write_application(cell, directory)
    if as_json:
        emit_json({**cell_json(cell), "files": [str(p) for p in written]})
        return
    click.echo(f"wrote {directory / APPLICATION}/ ({', '.join(p.name for p in written[:-1])})")
    click.echo(f"wrote {written[-1]}")
    for name, father, trsf in (
        (TOOL_NAME, "flange", cell.tool),
        (BLOCK_NAME, "world", cell.block),
    ):
        click.echo(f"  {name:<10} on {father:<6} {_shown(trsf)}")
    click.echo(f"last calibration: {calibration_text(cell)}")
    if profile.model.dh_source == "[calibration] dh" or any(profile.joint_offsets_deg):
        info(
            "the joint offsets and the DH table stay in the profile: send the controller "
            "targets from `ucal path PROFILE IN.csv -o OUT.csv --for-controller`"
        )


def _shown(trsf: Trsf) -> str:
    x, y, z = trsf.position_mm
    rx, ry, rz = trsf.rotation_deg
    return f"x {x:.3f}  y {y:.3f}  z {z:.3f} mm   rx {rx:.3f}  ry {ry:.3f}  rz {rz:.3f} deg"
