"""``ucal check``: a short check of the cell against its commissioning (``ucal.check``)."""

from __future__ import annotations

from pathlib import Path

import click
from rich.table import Table

from ucal.check.procedure import CheckJob
from ucal.check.result import CheckResult
from ucal.cli.options import (
    cell_from_options,
    controller_option,
    dry_run_option,
    json_option,
    pulser_option,
    record_options,
    sim_option,
    table_console,
    yes_option,
)
from ucal.cli.procedure import finish, recorded_run, replay_job, run_job
from ucal.procedure import Outcome, RunOptions
from ucal.profile import load_profile


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
@click.argument("profile_path", metavar="PROFILE", type=click.Path(dir_okay=False, path_type=Path))
@sim_option
@controller_option
@pulser_option
@click.option(
    "--baseline",
    is_flag=True,
    help="Record this check as the new reference, whatever the history holds (after a "
    "repair or a deliberate change); it is judged against the profile's calibration only.",
)
@record_options
@yes_option
@dry_run_option
@json_option
def cli(
    profile_path: Path,
    sim_world: str | None,
    controller_url: str | None,
    pulser_url: str | None,
    baseline: bool,
    record_path: Path | None,
    replay_path: Path | None,
    remeasure: bool,
    yes: bool,
    dry_run: bool,
    as_json: bool,
) -> None:
    """Check the cell against its commissioning in about a minute; name what moved.

    Six of calibrate's normal-incidence measurements (the three faces of the block in the
    calibration configuration and from a second joint-1 azimuth) and the echo chain at them
    (time of flight, amplitude at 0 dB gain, SNR; the centre frequency and -6 dB bandwidth from
    the pulser's A-scan where it gives one). The first check after the profile's model changed
    (a calibration, a tool frame, an edit), or one asked with --baseline, is the reference: it
    is judged against the profile's calibration and recorded. Later checks are fitted together
    with the reference on the profile's model: a joint's offset, the tool, the block or the
    water that changed beyond 3 sigma and its tolerance is named with its change (exit 1);
    the transducer likewise (amplitude 2 dB, SNR 6 dB, centre frequency 10 %, bandwidth 15 %).
    Every check is appended to the profile's history (ucal profile history); the profile
    itself is never written.
    """
    replayed = recorded_run(
        "check", profile_path, record_path, replay_path, remeasure, {"baseline": "baseline"}
    )
    if replayed is not None:
        record, recorded_profile = replayed
        job = CheckJob(recorded_profile, profile_path, bool(record.options.get("baseline")))
        finish(replay_job(job, record, remeasure), as_json, show_outcome)
        return
    cell = cell_from_options(sim_world, controller_url, pulser_url, dry_run=dry_run)
    profile = load_profile(profile_path)
    job = CheckJob(profile, profile_path, baseline)
    finish(run_job(job, RunOptions(cell, yes, dry_run, record_path)), as_json, show_outcome)


def show_outcome(outcome: Outcome) -> None:
    """The checked quantities, the verdict and the history entry on stdout."""
    result: CheckResult = outcome.shown
    out = outcome.result
    ref = result.reference
    title = (
        f"Check against the reference check {ref.id} ({ref.time})"
        if ref is not None
        else "Reference check (against the profile's calibration)"
    )
    table = Table(title=title)
    for col in ("quantity", "part", "value", "reference", "change", "σ", "tolerance", "verdict"):
        table.add_column(col, justify="left" if col in ("quantity", "part", "verdict") else "right")

    def num(v: float | None, unit: str = "") -> str:
        return "—" if v is None else f"{v:.4g}{(' ' + unit) if unit else ''}"

    for q in out["quantities"]:
        if q["verdict"] == "not measured":
            continue
        table.add_row(
            q["name"],
            q["part"],
            num(q["value"]),
            num(q["baseline"]),
            "—" if q["difference"] is None else f"{q['difference']:+.4g}",
            num(q["std"]),
            num(q["tolerance"]),
            q["verdict"],
            style="bold red" if q["verdict"] == "out of tolerance" else None,
        )
    table_console().print(table)
    click.echo(
        f"{out['moves']} moves, {out['pulser_reads']} pulser reads, {out['duration_s']:.0f} s "
        f"on the cell"
    )
    drifts = [
        q["name"] for q in out["quantities"] if q["verdict"] == "changed" and q["name"] != "tof_ns"
    ]
    if drifts:
        click.echo(
            f"changed beyond 3 sigma, within tolerance (a drift to watch): {', '.join(drifts)}"
        )
    if outcome.out_of_tolerance:
        click.echo("verdict: OUT OF TOLERANCE")
    elif ref is None:
        click.echo("verdict: ok; " + ("reference recorded" if out["recorded"] else "not recorded"))
    else:
        click.echo("verdict: as commissioned")
    if out["history_entry"] is not None:
        click.echo(f"history: check {out['history_entry']} of {outcome.result['profile']}")
