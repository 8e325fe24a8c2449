"""``ucal report``: one self-contained HTML page of the cell, its calibrations and its writes."""

from __future__ import annotations

from pathlib import Path

import click

from ucal.cli.options import (
    check_output,
    emit_json,
    info,
    json_option,
    output_option,
    profile_argument,
)
from ucal.report import gather_report, render_page, write_report


@click.command(
    "report",
    epilog="""\b
Examples:
  ucal report cell.toml -o report.html
  ucal report cell.toml -o report.html --json
""",
)
@profile_argument
@output_option(
    "out_path",
    "FILE.html",
    click.Path(dir_okay=False, path_type=Path),
    "The page to write (replaced if it exists).",
)
@click.option(
    "--record",
    "records",
    multiple=True,
    metavar="FILE",
    type=click.Path(dir_okay=False, path_type=Path),
    help="The --record file of a calibrate run that wrote into PROFILE: adds the residual of "
    "each measurement and why a joint was unobservable (repeatable).",
)
@json_option
def cli(profile_path: Path, out_path: Path, records: tuple[Path, ...], as_json: bool) -> None:
    """Write one HTML page of the cell as PROFILE and its history hold it.

    First the verdict: what was calibrated and at which level, how well (each quantity's one
    sigma against its tolerance), what was verified and its verdict, what is not determined
    and what would determine it. Then the robot model and its DH table (identified or
    shipped), the tool, block, plate, water and transducer; each calibration in the history
    with its offsets, stds, unobservable joints and fit; each tool-frame result; the picture
    of the last verify of this cell (a verify against a world file, --sim WORLD, is a
    rehearsal on another cell: named in the verdict, not shown); lost motion and drift; every
    recorded write as what changed, when and why. The page is self-contained (figures and
    style inline, nothing loaded from elsewhere) and prints to A4 without forced page breaks.
    Moves nothing and writes nothing but FILE.html. Exit 2 for a missing or invalid profile,
    an unreadable record or an output that cannot be written.
    """

    check_output(out_path)
    report = gather_report(profile_path, records)
    write_report(out_path, render_page(report))
    if as_json:
        emit_json(
            {
                "output": str(out_path),
                "profile": str(profile_path),
                "writes": len(report.writes),
                "calibrations": len(report.calibrations),
                "tool_frames": len(report.tools),
                "verify_picture": None if report.verify is None else str(report.verify.path),
                "rehearsal_pictures": [str(v.path) for v in report.rehearsals],
            }
        )
        return
    info(
        f"wrote {out_path}: {len(report.calibrations)} calibrations, "
        f"{len(report.tools)} tool frames, {len(report.writes)} writes"
    )
