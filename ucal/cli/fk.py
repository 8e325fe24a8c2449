"""``ucal fk``: tool pose for joint readings, with the profile's offsets and tool frame."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import click
import numpy as np

from ucal.cli.options import emit_json, json_option, parse_floats, profile_argument
from ucal.kinematics.dh import fk
from ucal.kinematics.rotations import matrix_to_pose
from ucal.profile import load_profile

if TYPE_CHECKING:
    from ucal.cell import CellProfile


@click.command(
    "fk",
    epilog="""\b
Examples:
  ucal fk cell.toml --joints 30.53,31.15,109.49,0,39.36,30.54
  ucal fk cell.toml --joints 0,0,90,0,90,0 --json
""",
)
@profile_argument
@click.option(
    "--joints",
    required=True,
    metavar="J1,...,J6",
    help="Joint readings as the controller shows them (deg).",
)
@json_option
def cli(profile_path: Path, joints: str, as_json: bool) -> None:
    """Tool centre point X,Y,Z (mm), RX,RY,RZ (deg, Staubli) in the base frame.

    The profile's [calibration] joint offsets are added to the readings
    (actual = reading + offset) and its [tool] frame is applied. Readings outside the joint
    ranges are computed but flagged on stderr.
    """

    joints_deg = parse_floats(joints, 6, "--joints")
    profile = load_profile(profile_path)
    pose = tool_pose(profile, joints_deg)
    if not profile.model.within_limits(joints_deg):
        click.echo(
            f"warning: --joints {joints} is outside the joint ranges of {profile.model.name}",
            err=True,
        )
    if as_json:
        emit_json({"joints_deg": joints_deg, "pose": pose})
        return
    click.echo("X,Y,Z (mm):    " + ", ".join(f"{v:.4f}" for v in pose[:3]))
    click.echo("RX,RY,RZ (deg): " + ", ".join(f"{v:.4f}" for v in pose[3:]))


def tool_pose(profile: CellProfile, joints_deg: np.ndarray) -> np.ndarray:
    """Pose ``[X, Y, Z, RX, RY, RZ]`` (mm, deg) of the TCP for joint readings (deg)."""

    t = fk(
        profile.model, joints_deg, tool=profile.tool_matrix, offsets_deg=profile.joint_offsets_deg
    )
    return matrix_to_pose(t)
