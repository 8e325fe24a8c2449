"""``ucal verify``: positioning error before and after calibration (paper 000, §5.2)."""

from __future__ import annotations

from pathlib import Path

import click
import numpy as np
from rich.table import Table

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
from ucal.errors import InputError
from ucal.procedure import Outcome, RunOptions
from ucal.profile import load_profile
from ucal.verify.measure import VerifyResult
from ucal.verify.picture import verify_picture_path
from ucal.verify.procedure import VerifyJob
from ucal.verify.region import RegionJob, RegionResult
from ucal.verify.result import VerifyShown


@click.command(
    "verify",
    epilog="""\b
Examples:
  ucal verify cell.toml --sim --yes
  ucal verify cell.toml --sim examples/world.toml --points 4 --json --yes
  ucal verify cell.toml --sim --region 12 --yes
  ucal verify cell.toml --sim --yes --points 2 --record verify.jsonl
  ucal verify cell.toml --replay verify.jsonl --json
  ucal verify cell.toml --controller tcp://192.168.0.254:11000 \\
      --pulser modbus-tcp://192.168.0.20:502 --plot report.png
""",
)
@click.argument("profile_path", metavar="PROFILE", type=click.Path(dir_okay=False, path_type=Path))
@sim_option
@controller_option
@pulser_option
@click.option(
    "--points",
    "n_points",
    type=click.IntRange(1, 100),
    default=20,
    show_default=True,
    help="Number of nominal points, shared by the three orientations (20 = 8 straight "
    "down, 6 turned 180 deg about the beam, 6 tilted 15 deg).",
)
@click.option(
    "--plot",
    "plot_path",
    type=click.Path(dir_okay=False, path_type=Path),
    help="Before/after picture to write [default: PROFILE with .verify.png].",
)
@click.option(
    "--tolerance-mm",
    type=click.FloatRange(min=0.0, min_open=True),
    default=None,
    metavar="MM",
    help="Largest deviation of any point on any axis after calibration that passes "
    "[default: [procedure] verify_tolerance_mm, 0.5 mm]; above it: exit 1.",
)
@click.option(
    "--region",
    "region",
    type=click.IntRange(3, 100),
    default=None,
    help="Instead: check the kinematic model against the block's faces from N "
    "postures spread like a full calibration's (ucal.verify.region).",
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
    n_points: int,
    plot_path: Path | None,
    tolerance_mm: float | None,
    region: int | None,
    record_path: Path | None,
    replay_path: Path | None,
    remeasure: bool,
    yes: bool,
    dry_run: bool,
    as_json: bool,
) -> None:
    """Measure the positioning error before and after calibration (paper 000, §5.2).

    N nominal points in three orientations of the tool, each a grid over the block's XY face:
    the beam straight down 30 mm above it (paper 000's points), the same with the tool turned
    180 deg about the beam, and the beam tilted 15 deg towards block +X 60 mm above the face (20
    points: 8, 6 and 6; 1 point: straight down; 2: one in each of the first two). Each point is
    visited twice: "before" commanded with the joint offsets and block pose the profile had
    before its last calibration (from its history; zero offsets without one), "after" with its
    current ones; every point is reached from below on each joint, as in the calibration. At
    each point the arm stays still while the wrist turns the beam normal to each of the block's
    three faces; the three water paths give the wrist centre, the three postures the flange
    orientation, hence the tool centre the robot would reach with the profile's tool. Then a
    tool check: the TCP is moved across the XY face's two far edges with the beam normal to it,
    from a point straight down and (2 points or more) one with the tool turned 180 deg; where
    the echo falls to half, the real TCP is on the edge, which gives the tool's error along and
    across the beam (which water paths cannot see) and is added to every point at its own
    orientation. Deviations are given per block axis X, Y, Z (mm): mean, max and standard
    deviation of the absolute values (paper 000, Table 5), and each orientation's largest. They
    are relative to the block (gauge: block): calibrate gives J1 relative to the block as
    placed, so in the robot's base frame the points are known only to the block's yaw tolerance
    (said in the output). The profile is never written; the picture is (--plot; not with
    --dry-run). The run passes when no point deviates more than the tolerance on any axis after
    calibration; otherwise exit 1 (within 0.05 mm of it: "marginal").
    """
    replayed = recorded_run(
        "verify",
        profile_path,
        record_path,
        replay_path,
        remeasure,
        {"points": "n_points", "region": "region"},
    )
    if replayed is not None:
        record, recorded_profile = replayed
        options = record.options
        if options.get("region") is not None:
            region_replay = RegionJob(
                recorded_profile, profile_path, options["region"], tolerance_mm
            )
            finish(replay_job(region_replay, record, remeasure), as_json, show_region)
            return
        verify = VerifyJob(
            recorded_profile,
            profile_path,
            options.get("points", n_points),
            tolerance_mm,
            recorded_inputs=record.header.get("inputs"),
        )
        finish(replay_job(verify, record, remeasure), as_json, show_outcome)
        return
    cell = cell_from_options(sim_world, controller_url, pulser_url, dry_run=dry_run)
    profile = load_profile(profile_path)
    run = RunOptions(cell, yes, dry_run, record_path)
    if region is not None:
        region_job = RegionJob(profile, profile_path, region, tolerance_mm)
        finish(run_job(region_job, run), as_json, show_region)
        return
    if plot_path is None:
        plot_path = verify_picture_path(profile_path)
    if not plot_path.parent.is_dir():
        raise InputError(f"--plot {plot_path}: directory {plot_path.parent} does not exist")
    _check_plot_format(plot_path)
    job = VerifyJob(profile, profile_path, n_points, tolerance_mm, plot_path)
    finish(run_job(job, run), as_json, show_outcome)


def show_outcome(outcome: Outcome) -> None:
    """The deviation table, the tool check, the verdict and the simulation check on stdout."""
    shown: VerifyShown = outcome.shown
    out = outcome.result
    _print_table(shown.result)
    tool = out["tool_check"]
    b = tool["offset_mm"]
    click.echo(
        f"tool check (XY face's edges): real TCP minus the profile's, beam straight down: "
        f"X {b[0]:+.4f}  Y {b[1]:+.4f} mm, included above"
    )
    if tool["separated"]:
        d = tool["across_beam_flange_mm"]
        click.echo(
            f"  the tool: {tool['along_beam_mm']:+.4f} mm along the beam, "
            f"({d[0]:+.4f}, {d[1]:+.4f}, {d[2]:+.4f}) mm across it (flange frame), from the "
            f"scans in both senses about the beam (misfit {tool['misfit_mm']:.4f} mm)"
        )
    for g in out["groups"]:
        if g["after_max_mm"] is not None:
            worst = max(g["after_max_mm"])
            click.echo(
                f"  after, {len(g['points'])} points {g['orientation']} "
                f"({g['height_mm']:g} mm above the face): largest deviation {worst:.4f} mm"
            )
    click.echo(f"before: {shown.before.source}")
    for why in out["skipped"]:
        click.echo(why)
    click.echo(f"sound speed: {shown.sound.source}")
    click.echo(
        f"after: largest deviation {shown.worst_mm:.4f} mm, tolerance {shown.tolerance_mm:g} mm: "
        + ("passed" if out["passed"] else "FAILED")
        + (
            " (marginal: within what verify measures to of the tolerance)"
            if out["marginal"]
            else ""
        )
    )
    click.echo(out["gauge_note"][:1].upper() + out["gauge_note"][1:])
    if shown.truth is not None:
        chk = shown.truth
        click.echo(
            "simulation check, measured minus true reached points: common bias "
            + ", ".join(
                f"{a} {v:+.4f}" for a, v in zip("XYZ", chk["measurement_bias_mm"], strict=True)
            )
            + " mm, then within "
            + ", ".join(
                f"{a} {v:.4f}"
                for a, v in zip("XYZ", chk["measurement_scatter_max_mm"], strict=True)
            )
            + " mm"
        )
        click.echo(
            "  true largest deviation after, relative to the block: "
            + _xyz(chk["after_mm"]["max"])
            + " (reported: "
            + _xyz(out["after_mm"]["max"])
            + ")"
        )
        if "absolute_after_max_mm" in chk:
            click.echo(
                "  in the robot's base frame (not checked by verify): "
                + _xyz(chk["absolute_after_max_mm"])
            )
    click.echo(f"picture: {shown.plot_path}" if shown.plot_path else "picture: not written")
    for note in out["notes"]:
        click.echo(f"note: {note}")


def _xyz(values: list[float]) -> str:
    """Three figures per block axis (mm)."""
    return ", ".join(f"{a} {v:.4f}" for a, v in zip("XYZ", values, strict=True)) + " mm"


def show_region(outcome: Outcome) -> None:
    """The region check's residuals and verdict on stdout."""
    r: RegionResult = outcome.shown
    click.echo(
        f"region: {r.postures} postures; along the face normals rms {r.rms_distance_mm:.4f} mm, "
        f"max {r.max_distance_mm:.4f} mm; beam tilt rms {r.rms_tilt_deg:.4f} deg, max "
        f"{r.max_tilt_deg:.4f} deg; χ²ᵣ {r.chi2_reduced:.3g} ({r.verdict}, worst {r.worst}); "
        f"tolerance {r.tolerance_mm:g} mm: " + ("passed" if r.passed else "FAILED")
    )
    if r.unidentified_tcp_mm is not None:
        mean, top = r.unidentified_tcp_mm
        click.echo(
            f"not seen: across the beam the calibration's unidentified quantities allow {mean:.3f}"
            f" mm mean, {top:.3f} mm max at the tool centre (one sigma), besides these residuals"
        )


def _check_plot_format(path: Path) -> None:
    # matplotlib only here: importing it costs the command's start-up a second
    from matplotlib.backend_bases import FigureCanvasBase

    fmt = path.suffix.lstrip(".").lower()
    known = FigureCanvasBase.get_supported_filetypes()
    if fmt not in known:
        raise InputError(
            f"--plot {path}: unknown picture format {path.suffix or '(none)'!r} "
            f"(use one of {', '.join('.' + k for k in sorted(known))})"
        )


def _print_table(result: VerifyResult) -> None:
    table = Table(
        title=f"Deviation from the nominal points, {result.plan.points} points (mm, "
        "block axes; paper 000, Table 5)"
    )
    table.add_column("")
    table.add_column("statistic")
    for axis in ("ΔX", "ΔY", "ΔZ"):
        table.add_column(axis, justify="right")
    for p in ("before", "after"):
        st = result.stats(p)
        for key, name in (
            ("mean", "mean |Δ|"),
            ("max", "max |Δ|"),
            ("std", "std |Δ|"),
            ("signed_mean", "mean Δ (bias)"),
        ):
            table.add_row(p if key == "mean" else "", name, *[f"{v:.4f}" for v in st[key]])
        table.add_section()
    before = np.array(result.stats("before")["mean"])
    after = np.array(result.stats("after")["mean"])
    gain = [
        f"{100 * (1 - a / b):.1f} %" if b > 0 else "-" for a, b in zip(after, before, strict=True)
    ]
    table.add_row("", "mean improved by", *gain)
    table_console().print(table)
    click.echo(f"{result.moves} moves, {result.reads} pulser readings")
