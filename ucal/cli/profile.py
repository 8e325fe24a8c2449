"""``ucal profile``: create, print, check a cell profile; list and undo its recorded writes,
list its checks."""

from __future__ import annotations

from dataclasses import asdict
from pathlib import Path
from typing import Any

import click
from rich.table import Table

from ucal.check.history import read_checks
from ucal.cli.options import SuggestingGroup, emit_json, info, json_option, table_console
from ucal.profile import (
    create_profile,
    history_dir,
    load_profile,
    profile_history,
    profile_to_dict,
    profile_warnings,
    undo_profile,
)
from ucal.profile.by_hand import PANEL_KEYS
from ucal.profile.models import KNOWN_MODELS
from ucal.profile.urdf import FK_TOLERANCE_MM, model_from_urdf, read_urdf

profile_arg = click.argument(
    "path", metavar="PATH", type=click.Path(dir_okay=False, path_type=Path)
)


@click.group(
    "profile",
    cls=SuggestingGroup,
    epilog="""\b
Examples:
  ucal profile init tx90l cell.toml
  ucal profile show cell.toml --json
  ucal profile validate cell.toml
  ucal profile init tx90l cell.toml --force
  ucal profile history cell.toml
  ucal profile undo cell.toml
""",
)
def cli() -> None:
    """Cell profiles (TOML): nominal geometry of the cell and calibration results."""


@cli.command(
    "init",
    epilog="""\b
Examples:
  ucal profile init tx90l cell.toml
  ucal profile init tx2-90xl cell.toml --force
  ucal profile init --from-urdf tx90l.urdf arm.toml --name my_tx90l
""",
)
@click.argument("model", metavar="MODEL", required=False)
@click.argument(
    "path", metavar="PATH", required=False, type=click.Path(dir_okay=False, path_type=Path)
)
@click.option(
    "--from-urdf",
    "urdf",
    type=click.Path(dir_okay=False, exists=True, path_type=Path),
    help="Take the model from this URDF (six revolute joints, the same wrist structure); "
    "then give PATH alone.",
)
@click.option("--name", help="With --from-urdf: the model's name (default: the URDF's robot name).")
@click.option(
    "--force", is_flag=True, help="Replace an existing file (the old one is kept in PATH.history/)."
)
def init(
    model: str | None, path: Path | None, urdf: Path | None, name: str | None, force: bool
) -> None:
    """Write a new commented profile for a shipped MODEL at PATH, or with --from-urdf for the
    arm a URDF describes.

    MODEL is one of the shipped models (profiles/<model>.toml): the DH table, joint ranges and
    speeds are its own. With --from-urdf FILE the DH table is derived from the URDF's joints,
    the ranges and speeds from their <limit>, and checked against the URDF's own forward
    kinematics (within 1 µm) before anything is written. The calibration block and the
    reflector plate are placed for paper 000's calibration pose. Exit 2 if PATH exists and
    --force is not given, for an unknown MODEL, or for a URDF that cannot be expressed (the
    message names the file and the joint).
    """
    if urdf is not None:
        if path is not None:
            raise click.UsageError("with --from-urdf give PATH alone (the model's name: --name)")
        if model is None:
            raise click.UsageError("missing argument PATH")
        arm = read_urdf(urdf)
        robot = model_from_urdf(arm, name)
        create_profile(Path(model), robot, force=force, dh_source=f"{urdf.name}")
        info(
            f"wrote {model} ({robot.name}, from {urdf}: its forward kinematics reproduced within "
            f"{FK_TOLERANCE_MM * 1000:g} µm); measure the block and the reflector plate and edit "
            "[sample] and [reflector] before calibrating"
        )
        return
    if name is not None:
        raise click.UsageError("--name goes with --from-urdf")
    if model is None or path is None:
        raise click.UsageError(f"missing argument {'MODEL' if model is None else 'PATH'}")
    if model.lower() not in KNOWN_MODELS:
        raise click.BadParameter(
            f"{model!r} is not one of {', '.join(KNOWN_MODELS)}", param_hint="'MODEL'"
        )
    create_profile(path, model.lower(), force=force)
    info(
        f"wrote {path} ({model.lower()}); measure the block and the reflector plate and edit "
        "[sample] and [reflector] before calibrating"
    )


@cli.command("show")
@profile_arg
@json_option
def show(path: Path, as_json: bool) -> None:
    """Print the profile as ucal reads it (validated; mm, deg)."""

    data = profile_to_dict(load_profile(path))
    if as_json:
        emit_json(data)
        return
    _print_profile(data)


@cli.command("validate")
@profile_arg
@json_option
def validate(path: Path, as_json: bool) -> None:
    """Check a profile; exit 2 with the file and key of the first problem.

    Keys ucal does not know are reported as warnings (they are allowed, but often typos).
    """

    profile = load_profile(path)
    warnings = profile_warnings(path)
    if as_json:
        emit_json(
            {"valid": True, "path": str(path), "model": profile.model.name, "warnings": warnings}
        )
        return
    for w in warnings:
        click.echo(f"warning: {path}: {w}", err=True)
    click.echo(f"{path}: valid ({profile.model.name})")


@cli.command("history")
@profile_arg
@json_option
def history(path: Path, as_json: bool) -> None:
    """List the recorded writes of a profile (kept in PATH.history/) and its checks
    (ucal check), oldest first."""

    entries = profile_history(path)
    checks = read_checks(path)
    if as_json:
        emit_json(
            {
                "history_dir": str(history_dir(path)),
                "entries": [asdict(e) for e in entries],
                # what each check measured stays in the history; the listing gives its results
                "checks": [
                    {k: v for k, v in asdict(c).items() if k not in ("faces", "echoes")}
                    for c in checks
                ],
            }
        )
        return

    table = Table(title=f"{path}: writes (copies in {history_dir(path)}) and checks")
    for col in ("#", "time (UTC)", "kind", "reason or result", "replaced version", "state"):
        table.add_column(col)
    rows = [
        (
            e.time,
            0,
            (
                str(e.id),
                e.time,
                "write",
                e.reason,
                e.before,
                f"undone {e.undone_time}" if e.undone else "applied",
            ),
        )
        for e in entries
    ] + [
        (
            c.time,
            1,
            (
                str(c.id),
                c.time,
                "check",
                f"{c.verdict}: {c.summary}",
                "—",
                "reference"
                if c.reference
                else f"against check {c.compared_with}"
                if c.compared_with is not None
                else "",
            ),
        )
        for c in checks
    ]
    for _, _, row in sorted(rows, key=lambda r: (r[0], r[1])):
        table.add_row(*row)
    table_console().print(table)


@cli.command("undo")
@profile_arg
@click.option(
    "--force",
    is_flag=True,
    help="Undo even if the profile was edited since the last recorded write.",
)
@json_option
def undo(path: Path, force: bool, as_json: bool) -> None:
    """Restore the version the last recorded write replaced (atomically).

    The version being replaced is kept in PATH.history/ too, so an undo loses nothing.
    """

    entry = undo_profile(path, force=force)
    if as_json:
        emit_json(
            {
                "undone": entry.id,
                "reason": entry.reason,
                "time": entry.time,
                "restored": entry.before,
                "kept": entry.after,
            }
        )
        return
    click.echo(
        f"{path}: undid write {entry.id} ({entry.reason}, {entry.time}); "
        f"the replaced version is kept as {entry.after}"
    )


def _fmt(values: object) -> str:
    if values is None:
        return "—"
    if isinstance(values, (list, tuple)):
        return ", ".join(_fmt(v) for v in values)
    if isinstance(values, float):
        return f"{values:g}"
    return str(values)


def _print_profile(data: dict[str, Any]) -> None:

    console = table_console()
    robot = data["robot"]
    dh = Table(title=f"{data['path']}: robot {robot['model']}")
    for col in (
        "joint",
        "θ offset (deg)",
        "d (mm)",
        "a (mm)",
        "α (deg)",
        "min (deg)",
        "max (deg)",
        "offset (deg)",
    ):
        dh.add_column(col, justify="right")
    offsets = data["calibration"]["joint_offsets_deg"]
    unobs = set(data["calibration"]["unobservable_joints"])
    for i, row in enumerate(robot["dh"]):
        dh.add_row(
            str(i + 1),
            *(f"{row[k]:g}" for k in ("theta_offset_deg", "d_mm", "a_mm", "alpha_deg")),
            f"{robot['joint_min_deg'][i]:g}",
            f"{robot['joint_max_deg'][i]:g}",
            f"{offsets[i]:.4f}" + (" (unobservable)" if i + 1 in unobs else ""),
        )
    console.print(dh)

    cell = Table(title="cell")
    cell.add_column("key")
    cell.add_column("value")
    for tname in ("tool", "sample", "reflector", "water", "transducer", "procedure"):
        table = data.get(tname)
        if table is None:
            cell.add_row(f"[{tname}]", "—")
            continue
        for key, value in table.items():
            if key == "points_mm":
                value = "; ".join(_fmt(p) for p in value)
            cell.add_row(f"{tname}.{key}", _fmt(value))
    pulser = data.get("pulser", {})
    if pulser.get("kind") == "manual":  # what a run is checked against: the panel set by hand
        for key in ("kind", *PANEL_KEYS, "input_noise_uv"):
            cell.add_row(f"pulser.{key}", _fmt(pulser[key]))
    console.print(cell)
