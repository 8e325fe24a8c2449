"""``ucal verify``: positioning error before and after calibration (paper 000, §5.2)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import click
import numpy as np

from ucal.cli.options import (
    cell_from_options,
    confirm_motion,
    controller_option,
    emit_json,
    json_option,
    pulser_option,
    sim_option,
    yes_option,
)
from ucal.cli.progress import StepProgress

if TYPE_CHECKING:
    from ucal.cell import WorldTruth
    from ucal.verify import PointResult, VerifyPlan, VerifyResult


@click.command(
    "verify",
    epilog="""\b
Examples:
  ucal verify cell.toml --sim --yes
  ucal verify cell.toml --sim world.toml --points 4 --json --yes
  ucal verify cell.toml --sim --region 12 --yes
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
    help="Number of nominal points (a grid, e.g. 20 = 5 x 4).",
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
    "postures spread like a full calibration's (ucal.verify_region).",
)
@yes_option
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
    yes: bool,
    as_json: bool,
) -> None:
    """Measure the positioning error before and after calibration (paper 000, §5.2).

    N nominal points on a grid 30 mm above the block's XY face, the tool pointing straight down,
    are visited twice: "before" commanded with the joint offsets the profile had before its last
    calibration (from its history; zero without one), "after" with its [calibration] offsets; every
    point is reached from below on each joint, as in the calibration. At each point the arm stays
    still while the wrist turns the beam normal to each of the block's three faces; the three water
    paths give the wrist centre, the three postures the flange orientation, hence the tool centre
    the robot would reach with the profile's tool. Then a tool check: the TCP is moved across the
    XY face's two far edges with the beam normal to it; where the echo falls to half, the real
    TCP is on the edge, which gives the real TCP against the profile's in X and Y (a tool error
    that water paths cannot see) and is added to every point. Deviations are given per block
    axis X, Y, Z (mm): mean, max and standard deviation of the absolute values (paper 000,
    Table 5). A block-position error in the profile shows as a common bias in both passes. The
    profile is never written. The run passes when no point deviates more than the tolerance on
    any axis after calibration; otherwise exit 1.
    """
    from ucal.errors import InputError, OutOfToleranceError
    from ucal.profile import load_profile
    from ucal.session import check_status, open_cell
    from ucal.verify import (
        offsets_before_calibration,
        plan_verify,
        plot_verify,
        run_verify,
        sound_speed_for_verify,
    )

    cell = cell_from_options(sim_world, controller_url, pulser_url, yes=yes)
    if region is not None:
        from ucal.cli import verify_region

        verify_region.run(profile_path, cell, region, tolerance_mm, yes, as_json)
        return
    profile = load_profile(profile_path)
    if plot_path is None:
        plot_path = profile_path.with_name(profile_path.stem + ".verify.png")
    if not plot_path.parent.is_dir():
        raise InputError(f"--plot {plot_path}: directory {plot_path.parent} does not exist")
    _check_plot_format(plot_path)

    tolerance = profile.procedure.verify_tolerance_mm if tolerance_mm is None else tolerance_mm
    before = offsets_before_calibration(profile_path)
    sound = sound_speed_for_verify(profile, profile_path)
    # every target checked before any connection
    plan = plan_verify(profile, n_points, before_offsets_deg=before.offsets_deg)
    confirm_motion(yes, _summary(plan, profile_path), cell)
    with open_cell(profile, cell.sim_world, cell.controller_url, cell.pulser_url) as session:
        check_status(session.rig)
        with StepProgress("verify") as progress:

            def report(res: PointResult, done: int, total: int) -> None:
                d = res.deviation_mm
                progress.step(
                    f"{res.pass_name} point {res.index + 1}",
                    done,
                    total,
                    f"deviation X {d[0]:+.3f}  Y {d[1]:+.3f}  Z {d[2]:+.3f} mm with the "
                    "profile's tool",
                )

            # times of flight converted with the measured sound speed (as a water temperature)
            measuring = profile.replace(water_temperature_c=sound.temperature_c)
            result = run_verify(measuring, plan, session.rig, report)
        truth = session.truth
    plot_verify(
        result,
        plot_path,
        title=f"{profile_path.name}: positioning error before and after calibration",
    )
    out = result.to_json(tolerance)
    out["before_source"] = before.source
    out["sound_speed_m_s"] = sound.m_s
    out["sound_speed_source"] = sound.source
    out["profile"] = str(profile_path)
    out["plot"] = str(plot_path)
    worst = float(np.max(result.stats("after")["max"]))
    message = (
        f"verify: a point deviates {worst:.3f} mm after calibration, above the "
        f"tolerance of {tolerance:g} mm"
    )
    if as_json:
        if truth is not None:
            out["truth"] = _truth_check(result, truth)
        if not out["passed"]:
            raise OutOfToleranceError(message, out)
        emit_json(out)
        return
    _print_table(result)
    b = out["tool_check"]["offset_mm"]
    click.echo(
        f"tool check (XY face's edges): real TCP minus the profile's X {b[0]:+.4f}  "
        f"Y {b[1]:+.4f} mm, included above"
    )
    click.echo(f"before: {before.source}")
    click.echo(f"sound speed: {sound.source}")
    click.echo(
        f"after: largest deviation {worst:.4f} mm, tolerance {tolerance:g} mm: "
        + ("passed" if out["passed"] else "FAILED")
    )
    if truth is not None:
        chk = _truth_check(result, truth)
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
    click.echo(f"picture: {plot_path}")
    if not out["passed"]:
        raise OutOfToleranceError(message, out)


def _truth_check(result: VerifyResult, truth: WorldTruth) -> dict:
    """Simulation only: the true reached TCPs and how far the measurement was from them.

    The error splits into a common bias and
    what remains point by point.
    """

    from ucal.verify import true_reached_local

    reached: dict[str, list] = {"before": [], "after": []}
    err = []
    for p in sorted(result.points, key=lambda r: (r.pass_name != "before", r.index)):
        t = true_reached_local(truth, p.commanded_deg)
        reached[p.pass_name].append(t.tolist())
        err.append(p.reached_mm - t)
    err_arr = np.array(err)
    bias = err_arr.mean(0)
    n_before = len(reached["before"])
    return {
        "joint_offsets_deg": truth.joint_offsets_deg.tolist(),
        "reached_mm": reached,
        "measurement_error_max_mm": np.abs(err_arr).max(0).tolist(),
        "after_error_max_mm": np.abs(err_arr[n_before:]).max(0).tolist(),
        "measurement_bias_mm": bias.tolist(),
        "measurement_scatter_max_mm": np.abs(err_arr - bias).max(0).tolist(),
    }


def _check_plot_format(path: Path) -> None:
    from matplotlib.backend_bases import FigureCanvasBase

    from ucal.errors import InputError

    fmt = path.suffix.lstrip(".").lower()
    known = FigureCanvasBase.get_supported_filetypes()
    if fmt not in known:
        raise InputError(
            f"--plot {path}: unknown picture format {path.suffix or '(none)'!r} "
            f"(use one of {', '.join('.' + k for k in sorted(known))})"
        )


def _summary(plan: VerifyPlan, profile_path: Path) -> str:
    lo = plan.nominal_mm.min(0)
    hi = plan.nominal_mm.max(0)
    return (
        f"verify {profile_path}: {plan.points} points x 2 passes (before/after calibration), "
        f"block X {lo[0]:.0f}-{hi[0]:.0f} mm, Y {lo[1]:.0f}-{hi[1]:.0f} mm, "
        f"{plan.height_mm:g} mm above the XY face; 3 face searches per point "
        f"({6 * plan.points} in all), then 2 edge scans (tool check)."
    )


def _print_table(result: VerifyResult) -> None:
    from rich.console import Console
    from rich.table import Table

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
    Console().print(table)
    click.echo(f"{result.moves} moves, {result.reads} pulser readings")
