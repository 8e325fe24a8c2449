"""``ucal echo``: time of flight and amplitude of the echo in each A-scan of a CSV file."""

from __future__ import annotations

from pathlib import Path

import click
from rich.console import Console
from rich.table import Table

from ucal.cli.options import emit_json, json_option
from ucal.echo import (
    METHOD_ENVELOPE,
    METHOD_REFERENCE,
    AScan,
    EchoEstimate,
    estimate_echo,
)
from ucal.echo.files import read_columns, read_reference
from ucal.errors import InputError


@click.command(
    "echo",
    epilog="""\b
Examples:
  ucal echo scans.csv --reference ref.csv
  ucal echo scans.csv --reference ref.csv --json
  ucal echo scans.csv
""",
)
@click.argument("file", metavar="FILE.csv", type=click.Path(dir_okay=False, path_type=Path))
@click.option(
    "--reference",
    "reference_path",
    metavar="REF.csv",
    type=click.Path(dir_okay=False, path_type=Path),
    help="The cell's reference echo: t_ns and one column, its arrival at t_ns = 0.",
)
@json_option
def cli(file: Path, reference_path: Path | None, as_json: bool) -> None:
    """Time of flight and amplitude of the echo in each A-scan of FILE.

    FILE has a column t_ns (uniform sampling, ns), then one column per A-scan. Each echo is
    timed against the reference echo by correlation, to a fraction of a sample without bias,
    with a std of the Cramér–Rao form from the A-scan's own SNR and the reference's bandwidth.
    Without --reference the time is the peak of the echo's envelope: coarse, with a std to
    match, and not the reference's arrival. A clipped echo is timed by its unclipped flanks
    and flagged.
    """
    reference = read_reference(reference_path) if reference_path is not None else None
    t0_ns, dt_ns, names, columns = read_columns(file)
    if reference is not None:
        try:
            reference = reference.resampled(dt_ns)
        except ValueError as e:
            raise InputError(f"{reference_path}: {e}") from None
    estimates = []
    for name, samples in zip(names, columns, strict=True):
        try:
            estimates.append(estimate_echo(AScan(t0_ns, dt_ns, samples), reference))
        except ValueError as e:
            raise InputError(f"{file}: column {name!r}: {e}") from None
    if as_json:
        emit_json({"echoes": [e.as_json() for e in estimates]})
        return
    _print_table(file, reference_path, names, estimates)


def _print_table(
    file: Path, reference_path: Path | None, names: list[str], estimates: list[EchoEstimate]
) -> None:
    table = Table(title=f"Echoes in {file}")
    table.add_column("A-scan")
    for heading in ("TOF (ns)", "σ (ns)", "amplitude", "SNR (dB)", "f_c (MHz)", "BW (MHz)"):
        table.add_column(heading, justify="right")
    table.add_column("clipped")
    for name, e in zip(names, estimates, strict=True):
        table.add_row(
            name,
            f"{e.tof_ns:.4f}",
            f"{e.tof_std_ns:.4f}",
            f"{e.amplitude:.4g}",
            f"{e.snr_db:.1f}",
            f"{e.centre_frequency_mhz:.2f}",
            f"{e.bandwidth_mhz:.2f}",
            "yes" if e.clipped else "",
        )
    console = Console()
    if not console.is_terminal:  # a pipe or a file: the whole table, not rich's 80 columns
        console = Console(width=120)
    console.print(table)
    if reference_path is not None:
        click.echo(f"method: {METHOD_REFERENCE} ({reference_path}, arrival at its t_ns = 0)")
    else:
        click.echo(f"method: {METHOD_ENVELOPE}: the envelope's peak, not an arrival")
