"""``ucal echo``: time of flight and amplitude of the echo in each A-scan of a CSV file."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import click
from rich.console import Console
from rich.table import Table

from ucal.cli.options import emit_json, json_option
from ucal.echo import (
    METHOD_ENVELOPE,
    METHOD_REFERENCE,
    AScan,
    EchoEstimate,
    NoEcho,
    estimate_echo,
)
from ucal.echo.files import read_columns, read_reference
from ucal.errors import HardwareError, InputError


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
    and flagged; another echo 1.5 periods or more from it is fitted with it (separated),
    one closer is flagged (overlapped), its std widened. A record with no echo
    to time (a constant, noise alone, an echo of the other polarity or cut by the record's
    ends) is never given a time: exit 3 naming the file and the column (with --json, that
    record's tof_ns is null and no_echo says why).
    """
    reference = read_reference(reference_path) if reference_path is not None else None
    t0_ns, dt_ns, names, columns = read_columns(file)
    if reference is not None:
        try:
            reference = reference.resampled(dt_ns)
        except ValueError as e:
            raise InputError(f"{reference_path}: {e}") from None
    method = METHOD_REFERENCE if reference is not None else METHOD_ENVELOPE
    estimates: list[EchoEstimate | NoEcho] = []
    for name, samples in zip(names, columns, strict=True):
        try:
            estimates.append(estimate_echo(AScan(t0_ns, dt_ns, samples), reference))
        except NoEcho as e:
            estimates.append(e)
        except ValueError as e:
            raise InputError(f"{file}: column {name!r}: {e}") from None
    missing = [(n, e) for n, e in zip(names, estimates, strict=True) if isinstance(e, NoEcho)]
    result = {"echoes": [_as_json(e, method) for e in estimates]}
    if not missing:
        if as_json:
            emit_json(result)
        else:
            _print_table(file, reference_path, names, estimates)
        return
    if not as_json:
        _print_table(file, reference_path, names, estimates)
    name, first = missing[0]
    more = f" (and {len(missing) - 1} more column(s))" if len(missing) > 1 else ""
    raise NoEchoInFile(f"{file}: column {name!r}: no echo: {first.reason}{more}", result)


class NoEchoInFile(HardwareError):
    """A record of the file holds no echo to time (exit 3, SPEC.md); ``result`` is the
    file's echoes, the record without one ``"tof_ns": null`` with its reason."""

    def __init__(self, message: str, result: dict[str, Any]):
        super().__init__(message)
        self.result = result


def _as_json(e: EchoEstimate | NoEcho, method: str) -> dict[str, Any]:
    """One record's fields of ``--json``: the echo's, or nulls and the reason there is none."""
    if isinstance(e, EchoEstimate):
        return e.as_json()
    return {
        **dict.fromkeys(_NUMBERS),
        "method": method,
        "clipped": False,
        "overlapped": False,
        "separated": False,
        "no_echo": e.reason,
    }


_NUMBERS = ("tof_ns", "tof_std_ns", "amplitude", "snr_db", "centre_frequency_mhz", "bandwidth_mhz")


def _print_table(
    file: Path,
    reference_path: Path | None,
    names: list[str],
    estimates: list[EchoEstimate | NoEcho],
) -> None:
    table = Table(title=f"Echoes in {file}")
    table.add_column("A-scan")
    for heading in ("TOF (ns)", "σ (ns)", "amplitude", "SNR (dB)", "f_c (MHz)", "BW (MHz)"):
        table.add_column(heading, justify="right")
    table.add_column("flags")
    for name, e in zip(names, estimates, strict=True):
        if isinstance(e, NoEcho):
            table.add_row(name, *["—"] * 6, f"no echo: {e.reason}")
            continue
        flags = [
            f
            for f, on in (
                ("clipped", e.clipped),
                ("overlapped", e.overlapped),
                ("separated", e.separated),
            )
            if on
        ]
        table.add_row(
            name,
            f"{e.tof_ns:.4f}",
            f"{e.tof_std_ns:.4f}",
            f"{e.amplitude:.4g}",
            f"{e.snr_db:.1f}",
            f"{e.centre_frequency_mhz:.2f}",
            f"{e.bandwidth_mhz:.2f}",
            ", ".join(flags),
        )
    console = Console()
    if not console.is_terminal:  # a pipe or a file: the whole table, not rich's 80 columns
        console = Console(width=120)
    console.print(table)
    if reference_path is not None:
        click.echo(f"method: {METHOD_REFERENCE} ({reference_path}, arrival at its t_ns = 0)")
    else:
        click.echo(f"method: {METHOD_ENVELOPE}: the envelope's peak, not an arrival")
