"""``ucal verify PROFILE --region N``: the kinematic model against the block's faces over N
spread postures (``ucal.verify_region``); a hook of ``ucal verify``."""

from __future__ import annotations

from pathlib import Path

import click

from ucal.cli.options import CellChoice, confirm_motion, emit_json


def run(
    profile_path: Path,
    cell: CellChoice,
    n: int,
    tolerance_mm: float | None,
    yes: bool,
    as_json: bool,
) -> None:
    """Plan, confirm, measure and judge the region; print the result, exit 1 if it fails
    (χ² misfit, or a residual along a face normal above ``tolerance_mm``, default
    ``[procedure] verify_tolerance_mm``)."""
    from ucal.errors import OutOfToleranceError
    from ucal.profile import load_profile
    from ucal.session import check_status, open_cell
    from ucal.verify_region import plan_region, run_region

    profile = load_profile(profile_path)
    plan = plan_region(profile, n)  # every posture checked before any connection
    summary = [
        (
            f"Region check of {profile_path}: {len(plan.postures)} postures spread over "
            f"{plan.candidates} candidates, J1 {plan.azimuths_deg[0]:.1f} to "
            f"{plan.azimuths_deg[1]:.1f} deg; the model is held, only the block pose, the "
            "sound speed and the tool's orientation are fitted"
        )
    ]
    summary += [
        f"  {p.label} {p.face_name:<3}" + "".join(f"{v:9.2f}" for v in p.joints_deg)
        for p in plan.postures
    ]
    confirm_motion(yes, "\n".join(summary), cell)
    with open_cell(profile, cell.sim_world, cell.controller_url, cell.pulser_url) as session:
        check_status(session.rig)
        if tolerance_mm is None:
            tolerance_mm = profile.procedure.verify_tolerance_mm
        result = run_region(profile, plan, session.rig, tolerance_mm)
    out = result.to_json()
    out["profile"] = str(profile_path)
    message = (
        f"region check failed: the model leaves {result.max_distance_mm:.4f} mm (rms "
        f"{result.rms_distance_mm:.4f}) along the face normals and {result.max_tilt_deg:.4f}"
        f" deg of beam tilt over {result.postures} postures (χ²ᵣ "
        f"{result.chi2_reduced:.3g}, worst {result.worst}); calibrate with --level full"
    )
    if not as_json:
        click.echo(
            f"region: {result.postures} postures; along the face normals rms "
            f"{result.rms_distance_mm:.4f} mm, max {result.max_distance_mm:.4f} mm; beam "
            f"tilt rms {result.rms_tilt_deg:.4f} deg, max {result.max_tilt_deg:.4f} deg; "
            f"χ²ᵣ {result.chi2_reduced:.3g} ({result.verdict}, worst {result.worst})",
            err=True,
        )
    if not result.passed:
        raise OutOfToleranceError(message, out)
    if as_json:
        emit_json(out)
