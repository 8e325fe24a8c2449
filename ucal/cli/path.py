"""``ucal path``: a Cartesian tool path (CSV) to a continuous joint path (CSV), paper 004;
with ``--for-controller``, to targets for the controller's nominal arm
(``ucal.kinematics.filtering``)."""

from __future__ import annotations

import csv
import io
import math
from pathlib import Path
from typing import Any

import click
import numpy as np

from ucal import files
from ucal.cli.options import (
    check_output,
    emit_json,
    existing_profile_argument,
    json_option,
    output_option,
    parse_floats,
)
from ucal.errors import InputError
from ucal.kinematics.filtering import controller_targets
from ucal.kinematics.path import cartesian_path_to_joints
from ucal.models import controller_model
from ucal.profile import load_profile

#: Column names of the output file: joint readings, or with ``--for-controller`` poses.
JOINT_HEADER = ("J1", "J2", "J3", "J4", "J5", "J6")
POSE_HEADER = ("X", "Y", "Z", "RX", "RY", "RZ")


def read_pose_csv(path: Path) -> np.ndarray:
    """Read rows ``X,Y,Z,RX,RY,RZ`` (mm, deg) → (n, 6); an optional header line is skipped.

    Blank lines and lines starting with ``#`` are ignored. Raises ``InputError`` (exit 2)
    naming the file and the 1-based line of the first bad row.
    """
    try:
        text = Path(path).read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as e:
        raise InputError(f"{path}: cannot read: {e}") from None
    rows: list[list[float]] = []
    first = True
    for lineno, fields in enumerate(csv.reader(text.splitlines()), 1):
        if not fields or not "".join(fields).strip() or fields[0].lstrip().startswith("#"):
            continue
        try:
            values = [float(f) for f in fields]
        except ValueError:
            if first and not any(_is_number(f) for f in fields):
                first = False  # a header line
                continue
            raise InputError(
                f"{path}: row {lineno}: expected 6 numbers X,Y,Z,RX,RY,RZ, got {','.join(fields)!r}"
            ) from None
        first = False
        if len(values) != 6 or not all(math.isfinite(v) for v in values):
            raise InputError(
                f"{path}: row {lineno}: expected 6 finite numbers X,Y,Z,RX,RY,RZ, "
                f"got {len(values)} value(s)"
            )
        rows.append(values)
    if not rows:
        raise InputError(f"{path}: no pose rows (expected X,Y,Z,RX,RY,RZ per line)")
    return np.array(rows)


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def write_joint_csv(path: Path, joints_deg: np.ndarray) -> None:
    """Write joint readings (n, 6) in degrees with a ``J1..J6`` header (``write_rows``)."""
    write_rows(path, JOINT_HEADER, joints_deg)


def write_pose_csv(path: Path, poses: np.ndarray) -> None:
    """Write poses (n, 6) in mm and degrees with an ``X..RZ`` header (``write_rows``)."""
    write_rows(path, POSE_HEADER, poses)


def write_rows(path: Path, header: tuple[str, ...], rows: np.ndarray) -> None:
    """Write ``rows`` (n, 6) under ``header``, 9 decimals.

    Written to a temporary file beside ``path`` and renamed (a replaced file keeps its mode,
    a new one gets the umask's); raises ``InputError`` (exit 2) naming the file when it cannot
    be written (missing or unwritable directory, full disk).
    """
    text = io.StringIO(newline="")
    w = csv.writer(text)
    w.writerow(header)
    for row in rows:
        w.writerow([f"{v:.9f}" for v in row])
    try:
        files.commit(files.stage(Path(path), text.getvalue().encode("utf-8")), Path(path))
    except OSError as e:
        raise InputError(f"{path}: cannot write: {e.strerror or e}") from None


@click.command(
    "path",
    epilog="""\b
Examples:
  ucal path cell.toml scan.csv -o scan_joints.csv
  ucal path cell.toml scan.csv -o scan_joints.csv --near 0,30,110,0,40,0 --json
  ucal path cell.toml scan.csv -o scan_targets.csv --for-controller
""",
)
@existing_profile_argument
@click.argument(
    "in_path", metavar="IN.csv", type=click.Path(exists=True, dir_okay=False, path_type=Path)
)
@output_option(
    "out_path",
    "OUT.csv",
    click.Path(dir_okay=False, writable=True, path_type=Path),
    "File to write, one row per pose: J1..J6 readings (deg), or with --for-controller "
    "X,Y,Z,RX,RY,RZ targets (mm, deg).",
)
@click.option(
    "--near",
    metavar="J1,...,J6",
    help="Joint readings (deg) the robot starts from; the first point takes the "
    "solution nearest them (default all zeros).",
)
@click.option(
    "--for-controller",
    is_flag=True,
    help="Write targets for the controller's nominal arm (shipped DH table, zero offsets) "
    "carrying the profile's tool (as `ucal export val3` writes it), which land the calibrated "
    "robot on IN's poses.",
)
@json_option
def cli(
    profile_path: Path,
    in_path: Path,
    out_path: Path,
    near: str | None,
    for_controller: bool,
    as_json: bool,
) -> None:
    """Turn tool poses X,Y,Z,RX,RY,RZ (mm, deg) into a continuous joint path.

    Each point takes the solution nearest the previous one (paper 004's weighted shortest
    distance), so a path through a wrist singularity does not flip joint 4 by 180 deg.
    Prints the largest joint step. Exit 2 for a bad CSV row, 4 if a point is unreachable.

    With --for-controller each row is instead the pose to send a VAL3 movel (tool as
    exported): the controller solves it with its own nominal model into the joint readings
    that put the calibrated robot on the pose asked for. Start the path in the configuration
    --near gives; a movel keeps it.
    """

    near_v = parse_floats(near, 6, "--near") if near is not None else None
    check_output(out_path)
    profile = load_profile(profile_path)
    poses = read_pose_csv(in_path)
    result: dict[str, Any] = {}
    if for_controller:
        nominal = controller_model(profile.model, profile_path)
        filtered = controller_targets(
            profile.model,
            nominal,
            poses,
            profile.tool_matrix,
            profile.joint_offsets_deg,
            start_deg=near_v,
        )
        joints, step = filtered.joints_deg, filtered.max_step_deg
        write_pose_csv(out_path, filtered.targets)
        result = {
            "for_controller": True,
            "nominal_model": nominal.name,
            "kinematics": profile.model.dh_source,
            "max_correction_mm": float(np.max(filtered.correction_mm)),
            "max_correction_deg": float(np.max(filtered.correction_deg)),
        }
    else:
        joints, step = cartesian_path_to_joints(
            profile.model, poses, profile.tool_matrix, profile.joint_offsets_deg, start_deg=near_v
        )
        write_joint_csv(out_path, joints)
    if len(joints) > 1:
        d = np.abs(np.diff(joints, axis=0))
        row, joint = np.unravel_index(int(np.argmax(d)), d.shape)
        where: dict[str, int | None] = {"joint": int(joint) + 1, "row": int(row) + 2}
    else:
        where = {"joint": None, "row": None}
    if as_json:
        emit_json(
            {
                "points": len(joints),
                "max_step_deg": step,
                "max_step_joint": where["joint"],
                "max_step_row": where["row"],
                "output": str(out_path),
                **result,
            }
        )
        return
    if for_controller:
        click.echo(
            f"wrote {len(joints)} controller targets to {out_path} "
            f"(nominal {result['nominal_model']} arm, the profile's tool)"
        )
        click.echo(
            f"largest correction: {result['max_correction_mm']:.4f} mm, "
            f"{result['max_correction_deg']:.4f} deg"
        )
    else:
        click.echo(f"wrote {len(joints)} joint rows to {out_path}")
    if where["joint"] is None:
        click.echo("largest joint step: 0 deg (one point)")
    else:
        click.echo(
            f"largest joint step: {step:.4f} deg (J{where['joint']}, into point {where['row']})"
        )
