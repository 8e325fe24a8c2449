"""``ucal verify``: positioning error before and after calibration (paper 000, §5.2)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import click
import numpy as np
from rich.table import Table

from ucal.cell import CellProfile
from ucal.cli.options import MovingCall, file_option, moving_options, table_console
from ucal.cli.procedure import run_command
from ucal.devices.record import Record
from ucal.errors import InputError
from ucal.procedure import Job, Outcome
from ucal.verify.iso9283 import ISO_CYCLES, Iso9283
from ucal.verify.measure import VerifyResult
from ucal.verify.picture import verify_picture_path
from ucal.verify.procedure import VerifyJob
from ucal.verify.region import RegionJob
from ucal.verify.result import RegionCheck, Verification
from ucal.verify.solve import tool_offset


@click.command(
    "verify",
    epilog="""\b
Examples:
  ucal verify cell.toml --sim --yes
  ucal verify cell.toml --sim examples/world.toml --points 4 --json --yes
  ucal verify cell.toml --sim --region 12 --yes
  ucal verify cell.toml --sim --yes --iso9283 --cycles 5
  ucal verify cell.toml --sim --yes --points 2 --record verify.jsonl
  ucal verify cell.toml --replay verify.jsonl --json
  ucal verify cell.toml --controller tcp://192.168.0.254:11000 \\
      --pulser modbus-tcp://192.168.0.20:502 --plot report.png
""",
)
@moving_options(
    click.option(
        "--points",
        "n_points",
        type=click.IntRange(1, 100),
        default=20,
        show_default=True,
        help="Number of nominal points, shared by the three orientations (20 = 8 straight "
        "down, 6 turned 180 deg about the beam, 6 tilted 15 deg).",
    ),
    file_option(
        "--plot",
        "plot_path",
        "Before/after picture to write [default: PROFILE with .verify.png].",
    ),
    click.option(
        "--tolerance-mm",
        type=click.FloatRange(min=0.0, min_open=True),
        default=None,
        metavar="MM",
        help="Largest deviation of any point on any axis after calibration that passes "
        "[default: [procedure] verify_tolerance_mm, 0.5 mm]; above it: exit 1.",
    ),
    click.option(
        "--region",
        "region",
        type=click.IntRange(3, 100),
        default=None,
        help="Instead: check the kinematic model against the block's faces from N "
        "postures spread like a full calibration's (ucal.verify.region).",
    ),
    click.option(
        "--iso9283",
        "iso9283",
        is_flag=True,
        help="Instead of the points: ISO 9283's five poses in a cube over the block, "
        "visited --cycles times; adds pose accuracy (AP) and repeatability (RP) per pose, "
        "with their uncertainty.",
    ),
    click.option(
        "--cycles",
        type=click.IntRange(2, 100),
        default=None,
        help="Cycles of the ISO 9283 poses [default: 30, the standard's].",
    ),
)
def cli(
    call: MovingCall,
    n_points: int,
    plot_path: Path | None,
    tolerance_mm: float | None,
    region: int | None,
    iso9283: bool,
    cycles: int | None,
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
    calibration; otherwise exit 1 (within what verify measures to of it, 0.05 mm and what
    the DH table left unidentified allows: "marginal").

    --iso9283: in place of the points, ISO 9283's five poses in the largest cube the tank
    allows over the block, visited --cycles times (P1, P5, P4, P3, P2, each reached from
    below); pose accuracy AP and repeatability RP per pose, with their one-sigma uncertainty
    (docs/method/commissioning.md).
    """

    def job(profile: CellProfile, record: Record | None) -> Job[Any, Any, Any, Checked]:
        path = call.profile_path
        if record is not None:
            options = record.options
            if options.get("region") is not None:
                return RegionJob(profile, path, options["region"], tolerance_mm)
            points = options.get("points", n_points)
            inputs = record.header.get("inputs")
            return VerifyJob(
                profile,
                path,
                points,
                tolerance_mm,
                recorded_inputs=inputs,
                iso_cycles=options.get("iso9283"),
            )
        if cycles is not None and not iso9283:
            raise click.UsageError("--cycles goes with --iso9283")
        if iso9283 and region is not None:
            raise click.UsageError("--iso9283 and --region are two different runs: pick one")
        if region is not None:
            return RegionJob(profile, path, region, tolerance_mm)
        plot = verify_picture_path(path) if plot_path is None else plot_path
        if not plot.parent.is_dir():
            raise InputError(f"--plot {plot}: directory {plot.parent} does not exist")
        _check_plot_format(plot)
        iso_cycles = (ISO_CYCLES if cycles is None else cycles) if iso9283 else None
        return VerifyJob(profile, path, n_points, tolerance_mm, plot, iso_cycles=iso_cycles)

    fixed = {"points": "n_points", "region": "region", "iso9283": "cycles"}
    run_command(call, "verify", fixed, job, show)


#: What ``verify`` finds: the points before and after, or (``--region``) the model's residuals.
Checked = Verification | RegionCheck


def show(outcome: Outcome[Checked]) -> None:
    """The verification's tables, or the region check's, on stdout."""
    result = outcome.result
    if isinstance(result, RegionCheck):
        show_region(result)
    else:
        show_outcome(result)


def show_outcome(result: Verification) -> None:
    """The deviation table, the tool check, the verdict and the simulation check on stdout."""
    solved = result.solved
    measured = solved.result
    _print_table(measured)
    if solved.iso is not None:
        show_iso(solved.iso, None if result.truth is None else result.truth.get("iso9283"))
    b = tool_offset(measured.edge_checks)
    click.echo(
        f"tool check (XY face's edges): real TCP minus the profile's, beam straight down: "
        f"X {b[0]:+.4f}  Y {b[1]:+.4f} mm, included above"
    )
    tool = measured.tool
    if tool is not None and tool.separated:
        d = tool.across_mm
        click.echo(
            f"  the tool: {tool.along_mm:+.4f} mm along the beam, "
            f"({d[0]:+.4f}, {d[1]:+.4f}, {d[2]:+.4f}) mm across it (flange frame), from the "
            f"scans in both senses about the beam (misfit {tool.misfit_mm:.4f} mm)"
        )
    plan = measured.plan
    for n, g in enumerate(plan.groups):
        after = measured.group_after_max_mm(n)
        if after is not None:
            points = [k for k in plan.group_of if k == n]
            click.echo(
                f"  after, {len(points)} points {g.description} "
                f"({g.height_mm:g} mm above the face): largest deviation {max(after):.4f} mm"
            )
    click.echo(f"before: {solved.before.source}")
    for skipped in measured.skipped:
        click.echo(skipped.reason())
    click.echo(f"sound speed: {solved.sound.source}")
    click.echo(
        f"after: largest deviation {solved.worst_mm:.4f} mm, tolerance "
        f"{solved.tolerance_mm:g} mm: "
        + ("passed" if solved.passed else "FAILED")
        + (
            f" (marginal: within what verify measures to, ±{solved.measured_within_mm:.2f} mm,"
            " of the tolerance)"
            if result.marginal
            else ""
        )
    )
    note = solved.gauge.statement()
    click.echo(note[:1].upper() + note[1:])
    if result.truth is not None:
        chk = result.truth
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
            + _xyz(measured.stats("after")["max"])
            + ")"
        )
        if "absolute_after_max_mm" in chk:
            click.echo(
                "  in the robot's base frame (not checked by verify): "
                + _xyz(chk["absolute_after_max_mm"])
            )
    click.echo(f"picture: {result.plot_path}" if result.plot_path else "picture: not written")
    for note in result.notes:
        click.echo(f"note: {note}")


def _xyz(values: list[float]) -> str:
    """Three figures per block axis (mm)."""
    return ", ".join(f"{a} {v:.4f}" for a, v in zip("XYZ", values, strict=True)) + " mm"


def show_region(result: RegionCheck) -> None:
    """The region check's residuals and verdict on stdout."""
    r = result.region
    click.echo(
        f"region: {r.postures} postures; along the face normals rms {r.rms_distance_mm:.4f} mm, "
        f"max {r.max_distance_mm:.4f} mm; beam tilt rms {r.rms_tilt_deg:.4f} deg, max "
        f"{r.max_tilt_deg:.4f} deg; χ²ᵣ {r.chi2_reduced:.3g} ({r.verdict}, worst {r.worst}); "
        f"tolerance {r.tolerance_mm:g} mm: " + ("passed" if r.passed else "FAILED")
    )
    if r.unidentified_tcp_mm is not None:
        mean, top = r.unidentified_tcp_mm
        click.echo(
            "not seen: across the beam the calibration's unidentified quantities"
            + (f" ({', '.join(r.unidentified_names)})" if r.unidentified_names else "")
            + f" allow {mean:.3f} mm mean, {top:.3f} mm max at the tool centre (one sigma), "
            "besides these residuals"
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
            cells = [f"{v:.4f}" if np.isfinite(v) else "-" for v in st[key]]
            table.add_row(p if key == "mean" else "", name, *cells)
        table.add_section()
    before = np.array(result.stats("before")["mean"])
    after = np.array(result.stats("after")["mean"])
    gain = [
        f"{100 * (1 - a / b):.1f} %" if b > 0 else "-" for a, b in zip(after, before, strict=True)
    ]
    table.add_row("", "mean improved by", *gain)
    table_console().print(table)
    click.echo(f"{result.moves} moves, {result.reads} pulser readings")


def show_iso(iso: Iso9283, truth: dict[str, Any] | None) -> None:
    """ISO 9283's figures per pose on stdout, with the simulator's truth where there is one."""
    cube = iso.cube
    table = Table(
        title=f"ISO 9283 pose accuracy and repeatability, {cube.cycles} cycles, "
        f"{cube.side_mm:.0f} mm cube (block axes; ± one sigma)"
    )
    for name in ("pose", "AP (mm)", "APx, APy, APz (mm)", "RP (mm)", "APa, APb, APc (deg)"):
        table.add_column(name, justify="left" if name == "pose" else "right")
    if truth is not None:
        table.add_column("true AP, RP (mm)", justify="right")
    for i, pose in enumerate(iso.poses):
        cells = [
            pose.name,
            f"{pose.ap_mm:.4f} ± {pose.ap_std_mm:.4f}",
            ", ".join(f"{v:+.4f}" for v in pose.ap_xyz_mm),
            f"{pose.rp_mm:.4f} ± {pose.rp_std_mm:.4f}",
            ", ".join(f"{v:+.4f}" if np.isfinite(v) else "-" for v in pose.ap_abc_deg),
        ]
        if truth is not None:
            cells.append(f"{truth['ap_mm'][i]:.4f}, {truth['rp_mm'][i]:.4f}")
        table.add_row(*cells)
    table_console().print(table)
    for note in iso.notes:
        click.echo(f"note: {note}")
