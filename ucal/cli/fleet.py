"""``ucal fleet``: the cells that publish to a broker, their last results, due dates and trends."""

from __future__ import annotations

from datetime import UTC, datetime

import click
from rich.table import Table

from ucal.cli.options import ENV_PUBLISH, emit_json, json_option, table_console, warn
from ucal.errors import HardwareError, InputError
from ucal.fleet.message import QUALITY_OUT, SCHEMA_VERSION
from ucal.fleet.mqtt import CONNECT_TIMEOUT_S, BrokerError, read_states
from ucal.fleet.url import parse_broker_url
from ucal.fleet.view import CellRow, fleet_rows, newer_schema


@click.command(
    "fleet",
    epilog="""\b
Examples:
  ucal fleet mqtt://broker.plant:1883/ucal
  ucal fleet mqtt://127.0.0.1:1883/plant/ucal --json
  UCAL_PUBLISH=mqtt://broker.plant/ucal ucal fleet
""",
)
@click.argument("url", metavar="URL", envvar=ENV_PUBLISH, required=True)
@click.option(
    "--timeout",
    "timeout_s",
    type=click.FloatRange(min=0.1, max=600.0),
    default=CONNECT_TIMEOUT_S,
    show_default=True,
    help="How long the broker may take to send the cells' states (s).",
)
@json_option
def cli(url: str, timeout_s: float, as_json: bool) -> None:
    """List the cells that publish to a broker: last results, due dates, trends.

    Reads every cell's retained state (PREFIX/CELL/state, written by --publish on calibrate,
    tool-frame, verify and check) from the broker at URL, mqtt://HOST[:PORT]/PREFIX (also
    UCAL_PUBLISH), and lists each cell: its last result (command, time, exit code, quality),
    its last validation (the newest result of quality ok) and the next one due (the profile's
    [cell] validation_interval_days after it), the days left (negative: overdue) and its trend
    (the qualities of its latest results, oldest first: + ok, x out of tolerance, . not
    determined). Moves nothing, writes nothing. --json: {"broker": URL, "cells": [...]}.
    """
    try:
        broker = parse_broker_url(url)
    except ValueError as e:
        raise InputError(f"URL: {e}") from None
    try:
        states = read_states(broker, timeout_s)
    except BrokerError as e:
        raise HardwareError(f"broker {broker}: {e}") from None
    rows = fleet_rows(states, datetime.now(UTC))
    newer = newer_schema(rows)
    if newer:
        warn(
            f"{', '.join(newer)}: published with a schema newer than {SCHEMA_VERSION} (a newer "
            "ucal): the fields this version knows are shown"
        )
    if as_json:
        emit_json({"broker": str(broker), "cells": [r.to_json() for r in rows]})
        return
    show(rows, str(broker))


def _due(row: CellRow) -> str:
    if row.due_in_days is None:
        return "—"
    days = row.due_in_days
    return f"overdue {-days:.0f} d" if days < 0 else f"in {days:.0f} d"


def show(rows: list[CellRow], broker: str) -> None:
    """The fleet's table on stdout."""
    if not rows:
        click.echo(f"no cell has published to {broker}")
        return
    table = Table(title=f"Cells publishing to {broker}")
    for col in (
        "cell",
        "last result",
        "time (UTC)",
        "exit",
        "quality",
        "last validation",
        "next validation",
        "due",
        "trend",
    ):
        table.add_column(col)
    for r in rows:
        table.add_row(
            r.cell,
            r.command,
            r.time,
            "—" if r.exit_code is None else str(r.exit_code),
            r.quality,
            r.last_validation or "—",
            r.next_validation or "—",
            _due(r),
            r.trend_marks,
            style="bold red" if r.quality == QUALITY_OUT or (r.due_in_days or 0) < 0 else None,
        )
    table_console().print(table)
