"""``ucal calibrate --level full``: the kinematic model → ``[calibration] dh`` in the profile.

Plan (``ucal.calibration.full_plan``), confirm, measure (``ucal.calibration.full_run``),
identify (``ucal.calibration.full``), judge and write; the same cell session, record and
replay as the offsets level (``ucal.cli.calibrate``).
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, cast

from ucal.cli.options import CellChoice, confirm_motion

if TYPE_CHECKING:
    from ucal.calibration.exact import OffsetSolution


def plan_summary(plan, profile) -> str:
    """The full plan as text for the confirmation prompt (stderr)."""
    from ucal.calibration.fit import prior_from_profile
    from ucal.timing import estimate_run

    c_std = prior_from_profile(profile).sound_speed_std_m_s
    step = profile.step
    scale = (
        f"with the DH length tolerance ({profile.dh_length_std_mm:g} mm) it sets the scale of "
        "every length"
        if step is None
        else f"the step of {step.height_mm:g} ± {step.height_std_mm:g} mm on the XY face sets "
        "the scale of every length (its water paths against the face's)"
    )
    lines = [
        f"Full kinematic calibration plan for {profile.model.name}: {plan.describe()}",
        (
            f"Water {profile.water_temperature_c:g} ± {profile.water_temperature_std_c:g} °C "
            f"(sound speed ± {c_std:.2f} m/s); {scale}"
        ),
        "  posture face     J1       J2       J3       J4       J5       J6    water path",
    ]
    for p in plan.postures:
        lines.append(
            f"  {p.label:>7} {p.face_name:<3}"
            + "".join(f"{v:9.2f}" for v in p.joints_deg)
            + f"   {p.water_path_mm:6.1f} mm"
        )
    lines.append(
        estimate_run(
            [p.joints_deg for p in plan.postures],
            plan.postures[0].joints_deg,
            profile.procedure.speed,
        ).describe()
    )
    lines.append(
        "Each posture: the wrist searches for the echo (joints 4-6 only); every move "
        "ends approaching from below on each joint (backlash)."
    )
    return "\n".join(lines)


def run(
    profile,
    profile_path: Path,
    sim_world,
    controller_url,
    pulser_url,
    beam: str,
    yes: bool,
    dry_run: bool,
    as_json: bool,
    force: bool = False,
    record_path: Path | None = None,
    record=None,
    max_postures: int | None = None,
) -> dict:
    """Plan, confirm, measure, identify, write; the JSON result of SPEC.md (+ extras).

    ``max_postures`` caps the plan (default: the D-optimal criterion's knee)."""
    from rich.console import Console

    from ucal.calibration.full_plan import plan_full
    from ucal.cli.calibrate import in_session

    console = Console()  # the result on stdout; the plan and progress go to stderr
    plan = (
        plan_full(profile)
        if max_postures is None
        else plan_full(profile, max_postures=max_postures)
    )
    if record is None:
        confirm_motion(
            yes, plan_summary(plan, profile), CellChoice(sim_world, controller_url, pulser_url)
        )
    return in_session(
        profile,
        sim_world,
        controller_url,
        pulser_url,
        record_path,
        record,
        {"method": "exact", "beam": beam, "level": "full", "max_postures": max_postures},
        [
            {
                "label": p.label,
                "joints_deg": p.joints_deg.tolist(),
                "water_path_mm": p.water_path_mm,
            }
            for p in plan.postures
        ],
        lambda cell: _measure_and_identify(
            profile,
            profile_path,
            plan,
            cell,
            console,
            beam,
            dry_run or record is not None,
            as_json,
            force,
        ),
    )


def _measure_and_identify(
    profile,
    profile_path: Path,
    plan,
    cell,
    console,
    beam: str,
    dry_run: bool,
    as_json: bool,
    force: bool,
) -> dict:
    from ucal.calibration.fit import prior_from_profile
    from ucal.calibration.full import solve_full
    from ucal.calibration.full_run import run_full
    from ucal.cli.calibrate import judge, measure_with_progress, result_fields, written_keys
    from ucal.profile import write_profile

    measurements = measure_with_progress(
        cell, "posture", lambda report: run_full(profile, plan, cell.rig, progress=report)
    )
    fixed = ("tool_rx_deg", "tool_ry_deg", "tool_rz_deg") if beam == "fixed" else ()
    sol = solve_full(
        prior_from_profile(profile),
        measurements.measurements,
        fixed=fixed,
        structure=plan.structure,
        steps=measurements.steps,
    )
    fit = sol.cell.quality
    # judge reads what both levels' solutions have: unobservable joints, std, the fit
    verdict = judge(cast("OffsetSolution", sol), fit)
    written = False
    if not dry_run and (verdict.ok or force):
        reason = f"calibrate --level full: fit {fit.verdict} (χ²ᵣ {fit.chi2_reduced:.3g})"
        if not verdict.ok:
            reason += f", written with --force: {verdict.message}"
        write_profile(
            profile_path,
            {
                "calibration": {
                    **written_keys(sol, sol.sound_speed_m_s, fit),
                    "level": "full",
                    "dh": sol.dh_rows(),
                }
            },
            reason=reason,
        )
        written = True
    result = {
        **result_fields(sol, "full", measurements, cell.elapsed_s, profile_path, written, sol, fit),
        "dh": sol.dh_rows(),
        "identification": sol.to_json(),
        "plan": {
            "postures": len(plan.postures),
            "candidates": plan.candidates,
            "log_det": plan.log_det,
            "d_criterion": plan.d_criterion,
        },
        "out_of_tolerance": not verdict.ok,
        "_message": verdict.message if not verdict.ok else None,
    }
    if cell.truth is not None:
        result["truth_offsets_deg"] = cell.truth.joint_offsets_deg
    if not as_json:
        show_result(console, sol, result)
    return result


def show_result(console, sol, result) -> None:
    """The identified parameters, offsets and fit as tables on stdout (without --json)."""
    from rich.markup import escape
    from rich.table import Table

    from ucal.cli.calibrate import show_fit

    table = Table(title="Kinematic parameters (calibrate --level full)")
    for col in ("parameter", "value", "σ", "nominal", "status"):
        table.add_column(col, justify="right" if col != "status" else "left")
    for j in range(6):
        unobs = j + 1 in sol.unobservable_joints
        table.add_row(
            f"J{j + 1} offset (deg)",
            f"{sol.offsets_deg[j]:+.5f}",
            "—" if unobs else f"{sol.std_deg[j]:.5f}",
            "",
            "unobservable (kept)" if unobs else "identified",
        )
    for name, p in sol.parameters.items():
        table.add_row(
            name,
            f"{p['value']:.5f}",
            "—" if p["std"] is None else f"{p['std']:.5f}",
            f"{p['nominal']:.5f}",
            p["status"],
        )
    console.print(table)
    ident = sol.ident
    console.print(f"rank {ident.rank} of {ident.n_parameters} unknowns")
    for name, why in ident.redundant.items():
        console.print(escape(f"{name} not identifiable, kept at its nominal value: {why}"))
    if ident.scale_note:
        console.print(escape(f"scale: {ident.scale_note}"))
    if sol.length_standard is not None:
        s = sol.length_standard
        console.print(
            f"step height {s['step_mm']:.4f} ± {s['std_mm']:.4f} mm (certificate "
            f"{s['nominal_mm']:g} ± {s['tolerance_mm']:g} mm; {s['measurements']} water paths)"
        )
    for j, why in sorted(sol.unobservable_reasons.items()):
        console.print(escape(f"J{j} unobservable, kept at its profile value: {why}"))
    show_fit(console, sol.cell.quality)
    console.print(
        f"sound speed {result['sound_speed_m_s']:.2f} ± "
        f"{result['sound_speed_std_m_s']:.2f} m/s; {result['moves']} moves, "
        f"{result['pulser_reads']} pulser reads; profile "
        f"{'written' if result['written'] else 'not written'}: {result['profile']}"
    )
