"""``ucal ik``: joint readings for a tool pose (closed-form, paper 004)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import click
import numpy as np
from rich.table import Table

from ucal.cli.options import (
    emit_json,
    existing_profile_argument,
    json_option,
    parse_floats,
    table_console,
)
from ucal.kinematics.ik import IkBranch, ik, ik_branches
from ucal.kinematics.rotations import pose_to_matrix
from ucal.profile import load_profile


@click.command(
    "ik",
    epilog="""\b
Examples:
  ucal ik cell.toml --pose 600,300,100,180,0,0
  ucal ik cell.toml --pose 600,300,100,180,0,0 --near 30,30,110,0,40,30
  ucal ik cell.toml --pose 600,300,100,180,0,0 --all --json
""",
)
@existing_profile_argument
@click.option(
    "--pose",
    required=True,
    metavar="X,Y,Z,RX,RY,RZ",
    help="Tool centre point in the base frame (mm, deg; Staubli rx, ry, rz).",
)
@click.option(
    "--near",
    metavar="J1,...,J6",
    help="Reference joint readings (deg); the nearest solution comes first (default all zeros).",
)
@click.option(
    "--all",
    "all_solutions",
    is_flag=True,
    help="Every solution inside the joint ranges (up to 8), nearest first, and for each of "
    "the others of the 8 why it is not offered.",
)
@json_option
def cli(
    profile_path: Path, pose: str, near: str | None, all_solutions: bool, as_json: bool
) -> None:
    """Joint readings (deg) that put the tool at a pose, with the profile's offsets taken out.

    Solutions are ranked by paper 004's weighted shortest distance to --near. With --all,
    every one of the 8 arm configurations: those inside the joint ranges as rows, and for
    each of the others why it is not offered (a joint out of range and by how much, or the
    pose out of that configuration's reach); --json lists them under "rejected".
    Exit 4 if the pose is unreachable inside the joint ranges.
    """

    pose_v = parse_floats(pose, 6, "--pose")
    near_v = parse_floats(near, 6, "--near") if near is not None else None
    profile = load_profile(profile_path)
    target, tool, offsets = pose_to_matrix(pose_v), profile.tool_matrix, profile.joint_offsets_deg
    sols = ik(profile.model, target, tool, offsets, near_deg=near_v, all_solutions=all_solutions)
    sols = np.atleast_2d(sols)
    rejected: list[IkBranch] = []
    names: list[str] | None = None
    if all_solutions:
        branches = ik_branches(profile.model, target, tool, offsets, near_deg=near_v)
        names = [b.configuration for b in branches if b.reason is None]
        rejected = [b for b in branches if b.reason is not None]
    if as_json:
        out: dict[str, Any] = {"solutions": sols}
        if all_solutions:
            out["rejected"] = [_rejected_json(b) for b in rejected]
        emit_json(out)
        return
    _print_table(sols, pose_v, profile.model.name, names)
    if rejected:
        _print_rejected(rejected)


def _rejected_json(branch: IkBranch) -> dict[str, Any]:
    """A solution not offered: its configuration, readings (null where the pose has no such
    solution) and why."""
    joints = branch.joints_deg
    return {
        "configuration": branch.configuration,
        "joints_deg": None if np.isnan(joints).any() else joints,
        "reason": branch.reason,
    }


def _print_rejected(rejected: list[IkBranch]) -> None:
    table = Table(title="Not offered")
    table.add_column("configuration")
    table.add_column("why")
    for b in rejected:
        table.add_row(b.configuration, b.reason)
    table_console().print(table)


def _print_table(
    sols: np.ndarray, pose: np.ndarray, model_name: str, names: list[str] | None = None
) -> None:

    title = (
        f"{model_name}: "
        + ", ".join(f"{v:g}" for v in pose[:3])
        + " mm, "
        + ", ".join(f"{v:g}" for v in pose[3:])
        + " deg"
    )
    table = Table(title=title)
    table.add_column("#", justify="right")
    if names is not None:
        table.add_column("configuration")
    for j in range(1, 7):
        table.add_column(f"J{j} (deg)", justify="right")
    for i, row in enumerate(sols, 1):
        label = [] if names is None else [names[i - 1]]
        table.add_row(str(i), *label, *(f"{v:.4f}" for v in row))
    table_console().print(table)
