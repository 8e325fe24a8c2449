"""``ucal check``: a short check of the cell against its commissioning (``ucal.check``)."""

from __future__ import annotations

from pathlib import Path

import click
import numpy as np
from rich.table import Table

from ucal.cell import CellProfile
from ucal.check.judge import CHANGED, NOT_MEASURED, OUT
from ucal.check.procedure import CheckJob
from ucal.check.result import CheckResult
from ucal.cli.options import MovingCall, moving_options, table_console, thermometer_option
from ucal.cli.procedure import run_command
from ucal.devices.record import Record
from ucal.procedure import Outcome


@click.command(
    "check",
    epilog="""\b
Examples:
  ucal check cell.toml --sim --yes
  ucal check cell.toml --sim world.toml --json --yes
  ucal check cell.toml --sim --baseline --yes
  ucal check cell.toml --sim --yes --record check.jsonl
  ucal check cell.toml --replay check.jsonl --json
  ucal check cell.toml --controller tcp://192.168.0.254:11000 \\
      --pulser modbus-tcp://192.168.0.20:502
""",
)
@moving_options(
    click.option(
        "--baseline",
        is_flag=True,
        help="Record this check as the new reference, whatever the history holds (after a "
        "repair or a deliberate change); it is judged against the profile's calibration only.",
    ),
    thermometer_option,
)
def cli(call: MovingCall, baseline: bool, thermometer: Path | None) -> None:
    """Check the cell against its commissioning in about a minute; name what moved.

    Six of calibrate's normal-incidence measurements (the three faces of the block in the
    calibration configuration and from a second joint-1 azimuth), the echo chain at them
    (time of flight, amplitude at 0 dB gain, SNR; the centre frequency and -6 dB bandwidth from
    the pulser's A-scan where it gives one), and four scans across the XY face's far edges
    (the tool across the beam, which no water path sees). The plan says what each
    measurement sees and which quantities the postures determine; a quantity whose sigma
    exceeds its tolerance is "not determined", with what would determine it, never "ok".
    The first check after the profile's model changed (a calibration, a tool frame, an
    edit), or one asked with --baseline, is the reference: it is judged against the profile's
    calibration and recorded. Later checks are fitted together
    with the reference on the profile's model: a joint's offset, the tool (across or along
    its beam) or the block that changed beyond 3 sigma and its tolerance is named with its
    change (exit 1); the transducer likewise (amplitude 2 dB, SNR 6 dB, centre frequency
    10 %, bandwidth 15 %). The water's change is reported as its own cause, not as a failure
    of the cell: every measurement uses the sound speed it measures.
    With --thermometer, the tank thermometer's log is read before anything moves and again
    when the check is solved, as calibrate reads it: its slope over the check is the prior of
    the check's drift, and a turn of the tank beyond the log's noise is taken out of the
    check's water paths. The history keeps what the log gave, so that a later check, with a log
    or without, fits the reference's run as it was measured. A tank whose rate turned during
    either run looks, over six faces, like the block or the water moved: where it explains the
    data as well, it is named beside them, and a misfit it explains is named as such.
    Every check is appended to the profile's history (ucal profile history); the profile
    itself is never written.
    """

    def job(profile: CellProfile, record: Record | None) -> CheckJob:
        chosen = baseline if record is None else bool(record.options.get("baseline"))
        return CheckJob(profile, call.profile_path, chosen)

    run_command(call, "check", {"baseline": "baseline"}, job, show_outcome, thermometer)


def show_outcome(outcome: Outcome[CheckResult]) -> None:
    """The checked quantities, the verdict and the history entry on stdout."""
    result = outcome.result
    found, run = result.findings, result.run
    ref = found.reference
    title = (
        f"Check against the reference check {ref.id} ({ref.time})"
        if ref is not None
        else "Reference check (against the profile's calibration)"
    )
    table = Table(title=title)
    for col in ("quantity", "part", "value", "reference", "change", "σ", "tolerance", "verdict"):
        table.add_column(col, justify="left" if col in ("quantity", "part", "verdict") else "right")

    def known(v: float | None) -> bool:
        return v is not None and bool(np.isfinite(v))

    def num(v: float | None) -> str:
        return f"{v:.4g}" if known(v) else "—"

    for q in found.quantities:
        if q.verdict == NOT_MEASURED:
            continue
        table.add_row(
            q.name,
            q.part,
            num(q.value),
            num(q.baseline),
            f"{q.difference:+.4g}" if known(q.difference) else "—",
            num(q.std),
            num(q.tolerance),
            q.verdict,
            style="bold red" if q.verdict == OUT else None,
        )
    table_console().print(table)
    click.echo(f"{run.moves} moves, {run.reads} pulser reads, {run.duration_s:.0f} s on the cell")
    drifts = [q.name for q in found.quantities if q.verdict == CHANGED and q.name != "tof_ns"]
    if drifts:
        click.echo(
            f"changed beyond 3 sigma, within tolerance (a drift to watch): {', '.join(drifts)}"
        )
    for line in found.noted:
        click.echo(line)
    for name, why in found.undetermined.items():
        click.echo(f"not determined: {name} (its sigma above its tolerance); {why}")
    if outcome.out_of_tolerance:
        click.echo("verdict: OUT OF TOLERANCE")
    elif ref is None:
        click.echo("verdict: ok; " + ("reference recorded" if run.written else "not recorded"))
    else:
        click.echo("verdict: as commissioned")
    if found.entry is not None:
        click.echo(f"history: check {found.entry.id} of {run.profile_path}")
