"""``ucal path``: a Cartesian tool path (CSV) to a continuous joint path in one arm
configuration (CSV), paper 004 (``ucal.kinematics.path``); with ``--for-controller``, to
targets for the controller's nominal arm (``ucal.kinematics.filtering``), each made up for
the arm's sag under gravity at its own posture where the profile states how it gives. Each
output row carries its VAL3 configuration; a path that changes it, or whose joints jump, is
refused unless asked for."""

from __future__ import annotations

import csv
import io
import math
from pathlib import Path
from typing import Any

import click
import numpy as np

from ucal import files
from ucal.cell import CellProfile
from ucal.cli.options import (
    check_output,
    emit_json,
    existing_profile_argument,
    json_option,
    output_option,
    parse_floats,
    warn,
)
from ucal.errors import InputError, SafetyError
from ucal.kinematics.configuration import PARTS, ArmConfig
from ucal.kinematics.filtering import controller_targets
from ucal.kinematics.path import MAX_STEP_DEG, JointPath, PathChange, plan_joint_path
from ucal.model.load import Deflection
from ucal.model.priors import prior_from_profile
from ucal.profile import load_profile
from ucal.profile.models import controller_model

#: Column names of the output file: joint readings, or with ``--for-controller`` poses, then
#: the row's arm configuration as a VAL3 ``config`` names its fields.
JOINT_HEADER = ("J1", "J2", "J3", "J4", "J5", "J6")
POSE_HEADER = ("X", "Y", "Z", "RX", "RY", "RZ")
CONFIG_HEADER = PARTS
#: The last column of ``--for-controller``'s rows where the targets make up for the arm's sag
#: under gravity: how far that moved each target (mm).
DEFLECTION_HEADER = "deflection_mm"


def read_pose_csv(path: Path) -> tuple[np.ndarray, list[int]]:
    """Read rows ``X,Y,Z,RX,RY,RZ`` (mm, deg) → ``(poses (n, 6), line of each row)``; an
    optional header line is skipped.

    Blank lines and lines starting with ``#`` are ignored; the lines are 1-based, as an
    editor numbers them. Raises ``InputError`` (exit 2) naming the file and the line of the
    first bad row.
    """
    try:
        text = Path(path).read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as e:
        raise InputError(f"{path}: cannot read: {e}") from None
    rows: list[list[float]] = []
    lines: list[int] = []
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
        lines.append(lineno)
    if not rows:
        raise InputError(f"{path}: no pose rows (expected X,Y,Z,RX,RY,RZ per line)")
    return np.array(rows), lines


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def write_rows(
    path: Path,
    header: tuple[str, ...],
    rows: np.ndarray,
    configs: tuple[ArmConfig, ...],
    deflection_mm: np.ndarray | None = None,
) -> None:
    """Write ``rows`` (n, 6), 9 decimals, each followed by its configuration's words, under
    ``header`` and ``CONFIG_HEADER``, then where given each row's ``deflection_mm`` (n,)
    under ``DEFLECTION_HEADER``.

    Written to a temporary file beside ``path`` and renamed (a replaced file keeps its mode,
    a new one gets the umask's); raises ``InputError`` (exit 2) naming the file when it cannot
    be written (missing or unwritable directory, full disk).
    """
    text = io.StringIO(newline="")
    w = csv.writer(text)
    extra = () if deflection_mm is None else (DEFLECTION_HEADER,)
    w.writerow((*header, *CONFIG_HEADER, *extra))
    for i, (row, config) in enumerate(zip(rows, configs, strict=True)):
        more = () if deflection_mm is None else (_number(deflection_mm[i]),)
        w.writerow([*(_number(v) for v in row), *config.words(), *more])
    try:
        files.commit(files.stage(Path(path), text.getvalue().encode("utf-8")), Path(path))
    except OSError as e:
        raise InputError(f"{path}: cannot write: {e.strerror or e}") from None


def _number(v: float) -> str:
    """A value as the rows hold it: 9 decimals, no "-0"."""
    return f"{round(float(v), 9) + 0.0:.9f}"


def profile_deflection(profile: CellProfile) -> tuple[Deflection | None, str]:
    """How the profile's arm gives under gravity beyond what its offsets hold
    (``ucal.model.load.Deflection``), or None and why it is taken as rigid."""
    prior = prior_from_profile(profile)
    found = Deflection.of(
        prior.model,
        prior.bodies,
        prior.offsets_deg,
        prior.load_posture_deg,
        prior.compliance_urad_per_nm,
    )
    if found is not None:
        return found, ""
    if not np.any(prior.compliance_urad_per_nm > 0.0):
        return None, "the profile states a rigid arm ([robot] stiffness_nm_per_rad all 0)"
    if prior.bodies is None:
        return None, "nothing weighs (no link masses, [tool] mass_kg 0)"
    return None, UNLOADED_NOTE


#: Why an arm that gives is taken as rigid: its offsets do not say at which load they hold.
UNLOADED_NOTE = (
    "the offsets state no load posture ([calibration] load_posture_deg, written by "
    "calibrate), so the sag they hold is not known; calibrate again to have each target "
    "corrected for it"
)


@click.command(
    "path",
    epilog="""\b
Examples:
  ucal path cell.toml scan.csv -o scan_joints.csv
  ucal path cell.toml scan.csv -o scan_joints.csv --near 0,30,110,0,40,0 --json
  ucal path cell.toml scan.csv -o scan_joints.csv --max-step-deg 10 --allow-config-change
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
    "X,Y,Z,RX,RY,RZ targets (mm, deg), then the row's configuration: shoulder, elbow, wrist.",
)
@click.option(
    "--near",
    metavar="J1,...,J6",
    help="Joint readings (deg) the robot starts from; the first point takes the "
    "solution nearest them, in any configuration (default all zeros).",
)
@click.option(
    "--max-step-deg",
    "limit_deg",
    type=click.FloatRange(min=0.0, min_open=True),
    default=MAX_STEP_DEG,
    show_default=True,
    metavar="DEG",
    help="Largest change of any joint between consecutive points (deg); a larger one is "
    "refused as a configuration change is.",
)
@click.option(
    "--allow-config-change",
    "allow",
    is_flag=True,
    help="Write a path whose configuration changes, or whose joints step more than "
    "--max-step-deg, with a warning on stderr naming each such point (else exit 4, nothing "
    "written).",
)
@click.option(
    "--for-controller",
    is_flag=True,
    help="Write targets for the controller's nominal arm (shipped DH table, zero offsets) "
    "carrying the profile's tool (as `ucal export val3` writes it), which land the calibrated "
    "robot on IN's poses, each made up for the arm's sag under gravity at its own posture "
    "where the profile states its joints' stiffness and load posture (then a last column "
    "deflection_mm).",
)
@json_option
def cli(
    profile_path: Path,
    in_path: Path,
    out_path: Path,
    near: str | None,
    limit_deg: float,
    allow: bool,
    for_controller: bool,
    as_json: bool,
) -> None:
    """Turn tool poses X,Y,Z,RX,RY,RZ (mm, deg) into a joint path in one arm configuration.

    \b
    IN.csv: one pose per line; a header line, blank lines and lines
    starting with # are skipped.
      X, Y, Z     the tool centre point (the profile's [tool]) in the robot
                  base frame, mm: origin on axis 1 at shoulder height, +Z up,
                  +X where J1 = 0 points the arm
      RX, RY, RZ  the tool frame's orientation, deg, as the controller's:
                  Rot(x,RX) Rot(y,RY) Rot(z,RZ) about the moving axes; the
                  beam leaves along tool +Z (180,0,180: straight down)

    \b
    OUT.csv: a header line, then one row per pose:
      J1..J6      joint readings, deg, as the controller reads them (the
                  profile's joint offsets taken out); with --for-controller
                  X,Y,Z,RX,RY,RZ targets for the nominal arm instead
      shoulder    lefty (wrist centre in front of axis 1) or righty (behind)
      elbow       epositive (J3 >= 0) or enegative
      wrist       wpositive (J5 >= 0) or wnegative
      deflection_mm  with --for-controller on an arm that gives under
                  gravity only: how far the sag correction moved the target
    The configuration words are the row's VAL3 config, in the controller's words.

    Each point takes the solution nearest the previous one (paper 004's weighted shortest
    distance) in the previous point's configuration. Where no solution in that configuration
    is inside the joint ranges and within --max-step-deg (the arm would swing round the back,
    the wrist flip, the path cross a singularity), the path is refused: exit 4 naming the
    point, its line, the joint and the step; --allow-config-change writes it with a warning
    per point. Exit 2 for a bad CSV row, 4 if a point is unreachable. A sample scan for
    `ucal profile init tx90l` ships as examples/scan.csv; docs/path.md has the details.

    With --for-controller each row is instead the pose to send a VAL3 movel (tool as
    exported) in the row's configuration: the controller solves it with its own nominal
    model into the joint readings that put the calibrated robot on the pose asked for.
    Where the profile states how its joints give ([robot] stiffness_nm_per_rad, the links'
    and [tool] masses) and the posture whose load its offsets hold ([calibration]
    load_posture_deg, written by calibrate), each target also makes up for the sag of its
    own posture under gravity relative to that one: the bent arm lands on the pose (--json's
    gravity_corrected says whether it does, gravity_note why not). Start the path in the
    configuration --near gives; a movel keeps it.
    """

    near_v = parse_floats(near, 6, "--near") if near is not None else None
    check_output(out_path)
    profile = load_profile(profile_path)
    poses, lines = read_pose_csv(in_path)
    result: dict[str, Any] = {}
    deflection_mm = None
    if for_controller:
        nominal = controller_model(profile.model, profile_path)
        bend, rigid_why = profile_deflection(profile)
        filtered = controller_targets(
            profile.model,
            nominal,
            poses,
            profile.tool_matrix,
            profile.joint_offsets_deg,
            start_deg=near_v,
            limit_deg=limit_deg,
            sag_deg=None if bend is None else bend.sag_deg,
        )
        path, header, rows = filtered.path, POSE_HEADER, filtered.targets
        deflection_mm = filtered.deflection_mm
        if rigid_why == UNLOADED_NOTE:
            warn(f"targets not corrected for the arm's sag under gravity: {rigid_why}")
        result = {
            "for_controller": True,
            "nominal_model": nominal.name,
            "kinematics": profile.model.dh_source,
            "max_correction_mm": float(np.max(filtered.correction_mm)),
            "max_correction_deg": float(np.max(filtered.correction_deg)),
            **gravity_keys(bend, filtered.sag_deg, deflection_mm, rigid_why),
        }
    else:
        path = plan_joint_path(
            profile.model,
            poses,
            profile.tool_matrix,
            profile.joint_offsets_deg,
            start_deg=near_v,
            limit_deg=limit_deg,
        )
        header, rows = JOINT_HEADER, path.joints_deg
    refuse_or_warn(path, in_path, lines, allow)
    write_rows(out_path, header, rows, path.configs, deflection_mm)
    report(path, lines, out_path, result, as_json)


def gravity_keys(
    bend: Deflection | None,
    sag_deg: np.ndarray | None,
    deflection_mm: np.ndarray | None,
    rigid_why: str,
) -> dict[str, Any]:
    """``--json``'s keys of the sag correction: whether it was made, and its size or why not."""
    if bend is None or sag_deg is None or deflection_mm is None:
        return {"gravity_corrected": False, "gravity_note": rigid_why}
    return {
        "gravity_corrected": True,
        "load_posture_deg": bend.load.load_posture_deg.tolist(),
        "max_sag_deg": float(np.max(np.abs(sag_deg))),
        "max_deflection_mm": float(np.max(deflection_mm)),
    }


def where(in_path: Path, lines: list[int], change: PathChange) -> str:
    """``IN.csv point N (line L)``: the point a change leads into, as the user finds it."""
    return f"{in_path} point {change.point} (line {lines[change.point - 1]})"


def refuse_or_warn(path: JointPath, in_path: Path, lines: list[int], allow: bool) -> None:
    """Refuse (``SafetyError``, exit 4) a path with a configuration change or a jump, naming the
    first; with ``allow``, a warning line per such point instead."""
    if path.changes and not allow:
        first = path.changes[0]
        more = len(path.changes) - 1
        others = f" ({more} more point(s) after it)" if more else ""
        raise SafetyError(
            f"{where(in_path, lines, first)}: {first.describe()}{others}; refused, nothing "
            "written (--allow-config-change writes the path anyway)"
        )
    for change in path.changes:
        warn(f"{where(in_path, lines, change)}: {change.describe()}")


def report(
    path: JointPath, lines: list[int], out_path: Path, result: dict[str, Any], as_json: bool
) -> None:
    """Print what was written: the points, their configuration and the largest joint step."""
    joints = path.joints_deg
    if len(joints) > 1:
        d = np.abs(np.diff(joints, axis=0))
        row, joint = np.unravel_index(int(np.argmax(d)), d.shape)
        step_at: dict[str, int | None] = {"joint": int(joint) + 1, "row": int(row) + 2}
    else:
        step_at = {"joint": None, "row": None}
    if as_json:
        emit_json(
            {
                "points": len(joints),
                "max_step_deg": path.max_step_deg,
                "max_step_joint": step_at["joint"],
                "max_step_row": step_at["row"],
                "output": str(out_path),
                **result,
                "step_limit_deg": path.limit_deg,
                "configurations": [c.to_json() for c in path.configs],
                "configuration_changes": [
                    {**c.to_json(), "line": lines[c.point - 1]} for c in path.changes
                ],
            }
        )
        return
    if result:
        click.echo(
            f"wrote {len(joints)} controller targets to {out_path} "
            f"(nominal {result['nominal_model']} arm, the profile's tool)"
        )
        click.echo(
            f"largest correction: {result['max_correction_mm']:.4f} mm, "
            f"{result['max_correction_deg']:.4f} deg"
        )
        if result["gravity_corrected"]:
            click.echo(
                "gravity: each target made up for its posture's sag relative to the load "
                f"posture the offsets hold: up to {result['max_deflection_mm']:.4f} mm "
                f"({result['max_sag_deg']:.4f} deg at a joint)"
            )
    else:
        click.echo(f"wrote {len(joints)} joint rows to {out_path}")
    if path.changes:
        points = ", ".join(str(c.point) for c in path.changes)
        click.echo(
            f"configuration: {path.configs[0]} at point 1; changed or jumped into point(s) "
            f"{points} (warned above)"
        )
    else:
        click.echo(f"configuration: {path.configs[0]} (every point)")
    if step_at["joint"] is None:
        click.echo("largest joint step: 0 deg (one point)")
    else:
        click.echo(
            f"largest joint step: {path.max_step_deg:.4f} deg "
            f"(J{step_at['joint']}, into point {step_at['row']})"
        )
