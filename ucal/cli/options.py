"""Options shared by several commands, defined once."""

from __future__ import annotations

import json
from typing import Any

import click
import numpy as np

json_option = click.option("--json", "as_json", is_flag=True,
                           help="Print one JSON object on stdout and nothing else.")
yes_option = click.option("--yes", "-y", is_flag=True,
                          help="Skip the confirmation before the first motion "
                               "(required when stdin is not a terminal).")
dry_run_option = click.option("--dry-run", is_flag=True,
                              help="Run against the simulator and write nothing.")
sim_option = click.option(
    "--sim", "sim_world", is_flag=False, flag_value="", default=None, metavar="[WORLD]",
    help="Run against the built-in simulated cell; WORLD is an optional world TOML file "
         "(without it a demo truth with hidden offsets is used).")
controller_option = click.option("--controller", "controller_url", metavar="URL",
                                 help="Controller URL, tcp://HOST:PORT[?state=PORT].")
pulser_option = click.option("--pulser", "pulser_url", metavar="URL",
                             help="Pulser URL, modbus-tcp://HOST:PORT[?unit=N] or "
                                  "modbus-rtu://DEVICE[?baud=N&unit=N].")


def parse_floats(text: str, n: int, what: str) -> np.ndarray:
    """Parse ``"a,b,c"`` into n floats; ``click.BadParameter`` (exit 2) names the option."""
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        raise click.BadParameter(f"{what} must be {n} comma-separated numbers, got {text!r}")
    if len(values) != n or not np.all(np.isfinite(values)):
        raise click.BadParameter(f"{what} must be {n} finite comma-separated numbers, got {text!r}")
    return np.array(values)


def emit_json(obj: Any) -> None:
    """Print one JSON object on stdout (numpy values converted)."""
    click.echo(json.dumps(obj, default=_to_jsonable))


def _to_jsonable(o: Any) -> Any:
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, np.generic):
        return o.item()
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def confirm_motion(yes: bool, summary: str) -> None:
    """Ask before the first motion; ``--yes`` skips; no terminal and no ``--yes`` → refuse (exit 2).

    ``summary`` (the plan) goes to stderr so that ``--json`` keeps stdout clean.
    """
    import sys

    from ucal.errors import InputError

    click.echo(summary, err=True)
    if yes:
        return
    if not sys.stdin.isatty():
        raise InputError("refusing to move the robot without confirmation: stdin is not a "
                         "terminal; pass --yes")
    if not click.confirm("Move the robot now?", default=False, err=True):
        raise click.exceptions.Abort()
