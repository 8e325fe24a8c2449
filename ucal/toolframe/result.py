"""The tool-frame run as the command reports it: the ``[tool]`` keys it writes, why a run is
out of tolerance, and the typed result (``ToolFrameResult``) the tables and ``--json`` are
drawn from."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ucal.cell import CellProfile, WorldTruth
from ucal.kinematics.rotations import angle_between_deg, tangent_basis
from ucal.measure.approach import APPROACH
from ucal.procedure import RunFacts
from ucal.toolframe.fit import ToolFrameFit, truth_in_profile_flange
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


@dataclass(frozen=True)
class SimulatedError:
    """How far the result is from the simulator's hidden truth (in the flange of the profile's
    J6 offset and last DH link)."""

    position_mm: np.ndarray
    along_beam_mm: float
    across_beam_mm: np.ndarray
    beam_deg: float

    @classmethod
    def of(cls, run: ToolFrameRun, profile: CellProfile, truth: WorldTruth) -> SimulatedError:
        true_tool = truth_in_profile_flange(profile, truth)
        err = np.asarray(run.position_mm) - true_tool[:3, 3]
        beam = np.asarray(run.beam)
        return cls(
            err,
            float(beam @ err),
            tangent_basis(beam) @ err,
            float(angle_between_deg(beam, true_tool[:3, 2])),
        )

    def to_json(self) -> dict[str, Any]:
        return {
            "position_mm": self.position_mm,
            "along_beam_mm": self.along_beam_mm,
            "across_beam_mm": self.across_beam_mm,
            "beam_deg": self.beam_deg,
            "frame": "flange of the profile's J6 offset and last DH link",
        }


@dataclass(frozen=True)
class ToolFrameResult:
    """``tool-frame``'s result: the tool frame and how it was found, what became of the run,
    and on a simulated cell how far off it is; the tables and ``--json`` are drawn from it."""

    tool: ToolFrameRun
    run: RunFacts
    simulated_error: SimulatedError | None = None

    def to_json(self) -> dict[str, Any]:
        """The ``tool-frame --json`` object of SPEC.md (and more)."""
        tool, tf = self.tool, self.tool.fit
        out: dict[str, Any] = {
            "position_mm": tool.position_mm,
            "rotation_deg": tool.rotation_deg,
            "beam_direction": tool.beam,
            "position_std_mm": tool.std_position_mm,
            "rotation_std_deg": None if tf is None else tf.rotation_std_deg,
            "beam_std_deg": tool.std_beam_deg,
            "rms_residual_mm": tool.rms_residual_mm,
            "points": tool.points,
            "written": self.run.written,
            "method": tool.method,
            "std": {"position_mm": tool.std_position_mm, "beam_deg": tool.std_beam_deg},
            "moves": self.run.moves,
            "pulser_reads": self.run.reads,
            # time the run took on the cell: simulated time on the simulated cell
            "duration_s": self.run.duration_s,
            "profile": str(self.run.profile_path),
            "notes": tool.notes,
        }
        if tf is not None:
            out |= fit_json(tf)
        # SPEC.md: the drift and the lost motion where the fit measures them (null elsewhere),
        # and the approach the tool frame holds for (every posture reached from below)
        out |= {
            "backlash_deg": [None] * 6,
            "backlash_std_deg": [None] * 6,
            "sound_speed_drift_m_s_per_min": None,
            "sound_speed_drift_m_s_per_min_std": None,
            "approach": APPROACH,
        }
        if tf is not None and tf.effects is not None:
            out |= tf.effects.to_json()
        if tool.method == "exact":
            out["normal_incidence_postures"] = len(tool.peaks)
            out["edge_crossings"] = len(tool.crossings)
        if tool.paper is not None:
            out["paper"] = {
                "iterations": tool.paper.iterations,
                "converged": tool.paper.converged,
                "second_order_ok": tool.paper.second_order_ok,
                "multiplier": tool.paper.multiplier,
                "condition": tool.paper.condition,
            }
        if self.simulated_error is not None:
            out["simulated_error"] = self.simulated_error.to_json()
        return out


def fit_json(tf: ToolFrameFit) -> dict[str, Any]:
    """The exact fit's fields of the ``--json`` object."""
    return {
        "fit": tf.quality.to_json(),
        "along_beam": {
            "position_mm": tf.along_beam_mm,
            "std_mm": tf.along_beam_std_mm,
            "limited_by": tf.along_beam_limited_by,
        },
        "across_beam_std_mm": tf.across_beam_std_mm,
        "plate_height_mm": {"value": tf.plate_height_mm, "std": tf.plate_height_std_mm},
        "delay_ns": {"value": tf.delay_ns, "std": tf.delay_std_ns},
        "sound_speed_m_s": tf.sound_speed_m_s,
        "sound_speed_std_m_s": tf.sound_speed_std_m_s,
    }
