"""The tool-frame run as the command reports it: the ``[tool]`` keys it writes, why a run is
out of tolerance, and the ``--json`` object."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from ucal.cell import CellProfile, WorldTruth
from ucal.kinematics.rotations import angle_between_deg
from ucal.toolframe.exact import (
    tangent_basis,
)
from ucal.toolframe.fit import (
    truth_in_profile_flange,
)
from ucal.toolframe.solve import ToolFrameRun

TOOL_STD_LIMITS = {"position_std_mm": 100.0, "rotation_std_deg": 10.0}
#: The end of a refusal's message, dropped when ``--force`` writes the result all the same.
NOT_WRITTEN = " (profile not written; --force writes it)"


def refusal(run: ToolFrameRun) -> str:
    """Why a run is out of tolerance, as the one-line error (empty when in tolerance)."""
    if run.in_tolerance:
        return ""
    if run.fit is not None:
        cause = run.fit.refusal
    else:
        cause = "; ".join(
            n for n in run.notes if "tolerance" in n or "converge" in n or "second-order" in n
        )
    return f"tool frame out of tolerance: {cause}{NOT_WRITTEN}"


def tool_keys(run: ToolFrameRun) -> tuple[dict[str, Any], str]:
    """``[tool]`` keys to write: the frame and, from the exact fit, its stds; and a note when a
    std beyond what a profile holds (a result written with --force, its stds scaled by a
    misfit's √χ²ᵣ) is written at that limit."""
    keys: dict[str, Any] = {
        "position_mm": [round(float(v), 6) for v in run.position_mm],
        "rotation_deg": [round(float(v), 6) for v in run.rotation_deg],
    }
    notes = []
    if run.fit is not None:
        for key, std in (
            ("position_std_mm", run.fit.position_std_mm),
            ("rotation_std_deg", run.fit.rotation_std_deg),
        ):
            limit = TOOL_STD_LIMITS[key]
            if max(std) > limit:
                notes.append(f"{key} {max(std):.3g} written as {limit:g}, the profile's limit")
            keys[key] = [round(min(max(float(v), 1e-6), limit), 6) for v in std]
    return keys, "; ".join(notes)


def result_object(
    run: ToolFrameRun,
    profile: CellProfile,
    profile_path: Path,
    written: bool,
    truth: WorldTruth | None,
    duration_s: float,
) -> dict[str, Any]:
    """The ``tool-frame --json`` object of SPEC.md (and more)."""
    tf = run.fit
    out: dict[str, Any] = {
        "position_mm": run.position_mm,
        "rotation_deg": run.rotation_deg,
        "beam_direction": run.beam,
        "position_std_mm": run.std_position_mm,
        "rotation_std_deg": None if tf is None else tf.rotation_std_deg,
        "beam_std_deg": run.std_beam_deg,
        "rms_residual_mm": run.rms_residual_mm,
        "points": run.points,
        "written": written,
        "method": run.method,
        "std": {"position_mm": run.std_position_mm, "beam_deg": run.std_beam_deg},
        "moves": run.moves,
        "pulser_reads": run.reads,
        # time the run took on the cell: simulated time on the simulated cell
        "duration_s": duration_s,
        "profile": str(profile_path),
        "notes": run.notes,
    }
    if tf is not None:
        out["fit"] = tf.quality.to_json()
        out["along_beam"] = {
            "position_mm": tf.along_beam_mm,
            "std_mm": tf.along_beam_std_mm,
            "limited_by": tf.along_beam_limited_by,
        }
        out["across_beam_std_mm"] = tf.across_beam_std_mm
        out["plate_height_mm"] = {"value": tf.plate_height_mm, "std": tf.plate_height_std_mm}
        out["delay_ns"] = {"value": tf.delay_ns, "std": tf.delay_std_ns}
        out["sound_speed_m_s"] = tf.sound_speed_m_s
        out["sound_speed_std_m_s"] = tf.sound_speed_std_m_s
    if run.method == "exact":
        out["normal_incidence_postures"] = len(run.peaks)
        out["edge_crossings"] = len(run.crossings)
    if run.paper is not None:
        out["paper"] = {
            "iterations": run.paper.iterations,
            "converged": run.paper.converged,
            "second_order_ok": run.paper.second_order_ok,
            "multiplier": run.paper.multiplier,
            "condition": run.paper.condition,
        }
    if truth is not None:  # the simulator's hidden truth: how far off the result is
        true_tool = truth_in_profile_flange(profile, truth)
        err = np.asarray(run.position_mm) - true_tool[:3, 3]
        beam = np.asarray(run.beam)
        out["simulated_error"] = {
            "position_mm": err,
            "along_beam_mm": float(beam @ err),
            "across_beam_mm": tangent_basis(beam) @ err,
            "beam_deg": float(angle_between_deg(beam, true_tool[:3, 2])),
            "frame": "flange of the profile's J6 offset and last DH link",
        }
    return out
