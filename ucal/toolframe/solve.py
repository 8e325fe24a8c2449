"""The tool frame from a run's measurements; nothing moves.

Exact method: the beam a_T from all peaks (``ucal.toolframe.exact`` eq. E1), a_T·p_T from the
paths (E2), p_T from all paths and crossings (E3) as a first estimate, then the fit of
``ucal.toolframe.fit`` (offsets, plate, DH table, sound speed and delay as prior-constrained
unknowns), which is what the run reports. Paper method: paper 002's constrained least squares
over the flange poses and water paths (eqs. 12–15, ``ucal.toolframe.paper``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ucal.cell import CellProfile
from ucal.devices.rig import Rig
from ucal.kinematics.dh import transform
from ucal.measure.edges import EdgeFit
from ucal.measure.search import PeakResult
from ucal.model.fit import offsets_prior_std_deg, prior_from_profile
from ucal.progress import Report
from ucal.toolframe.exact import (
    BeamEstimate,
    EdgeCrossing,
    OffsetEstimate,
    TofRecord,
    planned_edges,
    rotation_for_beam,
    solve_offsets,
)
from ucal.toolframe.fit import (
    PlateCrossing,
    PlatePeak,
    ToolFrameFit,
    plate_prior,
    solve_tool_frame,
)
from ucal.toolframe.measure import (
    ExactMeasurements,
    PaperMeasurements,
    ToolFrameMeasurements,
    measure_tool_frame,
)
from ucal.toolframe.paper import PaperSolution, solve_paper
from ucal.toolframe.plan import ToolFramePlan
from ucal.toolframe.plane import Plane


@dataclass
class ToolFrameRun:
    """What a run measured and concluded (tool frame relative to the flange)."""

    method: str
    position_mm: np.ndarray
    rotation_deg: np.ndarray
    beam: np.ndarray
    std_position_mm: np.ndarray
    std_beam_deg: float
    rms_residual_mm: float
    points: int
    moves: int
    reads: int
    peaks: list[PeakResult] = field(default_factory=list)
    tofs: list[TofRecord] = field(default_factory=list)
    crossings: list[EdgeCrossing] = field(default_factory=list)
    edge_fits: list[EdgeFit] = field(default_factory=list)
    beam_estimate: BeamEstimate | None = None
    offsets: OffsetEstimate | None = None
    paper: PaperSolution | None = None
    in_tolerance: bool = True
    notes: list[str] = field(default_factory=list)
    fit: ToolFrameFit | None = None


def solve_measured(
    profile: CellProfile,
    plan: ToolFramePlan,
    measured: ToolFrameMeasurements,
    fixed: tuple[str, ...] = (),
) -> ToolFrameRun:
    """The tool frame from a run's measurements (module docstring); nothing moves. ``fixed``:
    unknowns of the exact method's fit held at their priors (``solve_tool_frame``)."""
    if isinstance(measured, PaperMeasurements):
        return _solve_paper(profile, plan, measured)
    return _solve_exact(profile, plan, measured, fixed)


def run_tool_frame(
    profile: CellProfile, plan: ToolFramePlan, rig: Rig, progress: Report | None = None
) -> ToolFrameRun:
    """Measure and solve (see module docstring). The caller owns connection, STOP, profile."""
    return solve_measured(profile, plan, measure_tool_frame(profile, plan, rig, progress))


def _solve_exact(
    profile: CellProfile, plan: ToolFramePlan, m: ExactMeasurements, fixed: tuple[str, ...]
) -> ToolFrameRun:
    peaks, tofs, crossings, beam_est = m.peaks, m.tofs, m.crossings, m.beam_estimate
    # First estimate with the profile's offsets and the touched plane taken as exact (the
    # formulation of ucal.toolframe.exact): the start of the fit with the priors.
    offsets = solve_offsets(beam_est, tofs, crossings, plan.plane, m.position_mm)
    first_rot = rotation_for_beam(beam_est.direction, profile.tool_rotation_deg)

    def fit(
        edges_deg: np.ndarray, edge_offsets_mm: np.ndarray, position_mm: np.ndarray
    ) -> ToolFrameFit:
        edge_start = np.column_stack([edges_deg, edge_offsets_mm]).ravel()
        tool_start = np.concatenate([position_mm, first_rot])
        return solve_plate_fit(
            profile, plan.plane, peaks, m.plate_crossings, edge_start, tool_start, fixed
        )

    tf = fit(offsets.edge_angles_deg, offsets.edge_offsets_mm, offsets.position_mm)
    if tf.quality.verdict == "misfit":
        # The first estimate holds the profile's offsets exact: on a fresh cell with a tool
        # far off the flange axis it can turn the edges tens of degrees from where the scans
        # met them, too far a start. Start again from the edges as scanned and the tool the
        # run estimated on its way, and keep the better fit.
        psi, d = planned_edges(crossings, plan.plane, m.position_mm, beam_est.direction)
        again = fit(np.degrees(psi), d, m.position_mm)
        assert tf.solution is not None and again.solution is not None
        if again.solution.chi2 < tf.solution.chi2:
            tf = again
    notes = list(offsets.notes) + list(tf.notes)
    if tf.refusal:
        notes.append(f"out of tolerance: {tf.refusal}")
    return ToolFrameRun(
        "exact",
        tf.position_mm,
        tf.rotation_deg,
        tf.beam,
        tf.position_std_mm,
        tf.beam_std_deg,
        tf.rms_residual_mm,
        len(peaks) + len(crossings),
        m.moves,
        m.reads,
        peaks,
        tofs,
        crossings,
        m.edge_fits,
        beam_est,
        offsets,
        None,
        tf.in_tolerance,
        notes,
        fit=tf,
    )


def solve_plate_fit(
    profile: CellProfile,
    plane: Plane,
    peaks: list[PeakResult],
    crossings: list[PlateCrossing],
    edge_start: np.ndarray,
    tool_start: np.ndarray,
    fixed: tuple[str, ...] = (),
) -> ToolFrameFit:
    """The fit of ``ucal.toolframe.fit`` on a run's peaks and crossings (priors from the
    profile; edges (ψ deg, d mm per edge, flattened) and tool started as given; ``fixed`` held
    at their priors)."""
    plate_peaks = []
    for i, p in enumerate(peaks):
        assert p.distance is not None and p.distance_joints_deg is not None
        plate_peaks.append(
            PlatePeak(
                f"peak {i + 1}",
                p.joints_deg,
                max(p.tilt_std_deg, 1e-4),
                p.distance_joints_deg,
                p.distance[0],
                max(p.distance[1], 1e-4),
                p.time_min,
                p.approach,
            )
        )
    assert profile.reflector_points_mm is not None
    return solve_tool_frame(
        prior_from_profile(profile),
        plate_prior(plane, profile.reflector_points_mm, profile.reflector_points_std_mm),
        offsets_prior_std_deg(profile),
        plate_peaks,
        crossings,
        edge_start,
        tool_start,
        fixed=fixed,
    )


def _solve_paper(profile: CellProfile, plan: ToolFramePlan, m: PaperMeasurements) -> ToolFrameRun:
    rots, poss, paths, path_stds = m.rotations, m.positions_mm, m.paths_mm, m.path_stds_mm
    sol = solve_paper(
        np.array(rots),
        np.array(poss),
        np.array(paths),
        plan.plane,
        np.asarray(profile.tool_position_mm, float),
        profile.tool_matrix[:3, 2],
        float(np.median(path_stds)),
    )
    rot = rotation_for_beam(sol.beam, profile.tool_rotation_deg)
    notes = list(sol.notes)
    ok = bool(sol.converged and sol.second_order_ok)
    if not sol.converged:
        notes.append("Newton's method on the KKT conditions did not converge")
    return ToolFrameRun(
        "paper",
        sol.position_mm,
        rot,
        sol.beam,
        sol.std_position_mm,
        sol.std_beam_deg,
        sol.rms_residual_mm,
        len(paths),
        m.moves,
        m.reads,
        tofs=[
            TofRecord(transform(p, R), d, s)
            for p, R, d, s in zip(poss, rots, paths, path_stds, strict=True)
        ],
        paper=sol,
        in_tolerance=ok,
        notes=notes,
    )
