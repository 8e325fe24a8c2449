"""``ucal export``: the calibrated cell in the formats a controller loads."""

from __future__ import annotations

from pathlib import Path

import click

from ucal.cli.options import emit_json, existing_profile_argument, info, json_option, output_option
from ucal.profile import load_profile
from ucal.ros2 import export_json, file_names, ros2_arm, write_ros2
from ucal.ros2_description import TCP_LINK
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
  ucal export ros2 cell.toml -o ros2
""",
)
def cli() -> None:
    """Export the calibrated cell for a robot controller (VAL3) or ROS 2."""


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
    DIR/ucal_cell.json holds the same. The joint offsets stay in the profile, and so does
    the arm's sag under gravity: for calibrated accuracy move to targets from `ucal path ...
    --for-controller`, which carry both for each target's posture.
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


@cli.command(
    "ros2",
    epilog="""\b
Examples:
  ucal export ros2 cell.toml -o ros2
  ucal export ros2 cell.toml -o ros2 --prefix arm_ --json
""",
)
@existing_profile_argument
@output_option(
    "directory",
    "DIR",
    click.Path(file_okay=False, path_type=Path),
    "Directory to write the URDF, its xacro and the YAML files into, named after the robot "
    "model (created if missing; files there are replaced).",
)
@click.option(
    "--prefix",
    default="",
    metavar="P",
    help="tf prefix of every link and joint of the rendered URDFs, and the xacro's default "
    "(e.g. arm_; default: none).",
)
@json_option
def ros2(profile_path: Path, directory: Path, prefix: str, as_json: bool) -> None:
    """Write the calibrated arm for ROS 2: URDF, xacro, kinematics, offsets, covariance.

    For model NAME: NAME_kinematics.yaml (each joint's origin from the identified DH table,
    ur_description's layout, with the profile's SHA-256), NAME_macro.xacro and
    NAME.urdf.xacro (the arm taking it; the tool as the fixed frame ucal_tcp on tool0),
    NAME.urdf (rendered: joint position = reading + offset) and NAME_offsets_in_urdf.urdf
    (the offsets folded in: joint position = the controller's reading),
    NAME_joint_offsets.yaml (rad; position = reading + offset) and NAME_covariance.yaml
    (one sigma of every parameter, covariance of every origin). Units m, rad (ROS's).
    Launch arguments and frames: docs/ros2.md. Exit 2 if DIR cannot be created or written
    (the message names it).
    """

    arm = ros2_arm(profile_path, prefix)
    written = write_ros2(arm, directory)
    if as_json:
        emit_json(export_json(arm, written))
        return
    names = file_names(arm.name)
    click.echo(f"wrote {directory}/: {', '.join(names.values())}")
    click.echo(
        f"  {arm.model.name}, kinematics from {arm.model.dh_source}; profile sha256 {arm.sha256}"
    )
    offsets = ", ".join(f"{v:.4f}" for v in arm.offsets_deg)
    click.echo(f"  joint offsets (deg): {offsets}; tool frame {prefix}{TCP_LINK} on {prefix}tool0")
    info(
        f"{names['urdf']}: joint position = reading + offset ({names['joint_offsets']}); "
        f"{names['urdf_offsets_in_urdf']}: joint position = the controller's reading"
    )


def _shown(trsf: Trsf) -> str:
    x, y, z = trsf.position_mm
    rx, ry, rz = trsf.rotation_deg
    return f"x {x:.3f}  y {y:.3f}  z {z:.3f} mm   rx {rx:.3f}  ry {ry:.3f}  rz {rz:.3f} deg"
