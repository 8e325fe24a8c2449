"""The tool-frame calibration with the rig: plan and check every target, then measure and solve.

Plate frame. The plane of the touched points (``ucal.toolframe.plane``) with its in-plane axes
``e1, e2`` and normal ``n``; the nominal plate centre is the points' centroid. The beam is
aimed along ``−n``; a tool orientation "φ" turns the tool frame's x axis from ``e1`` towards
``e2`` by φ (a rotation about the beam). Targets are tool poses; joint readings come from the
closed-form IK with the current tool estimate and the profile's joint offsets
(actual = reading + offset), and every flange pose that enters the solution is the forward
kinematics of the settled readings with those offsets.

Plan (before the first motion; ``SafetyError``, exit 4, without any motion):

* exact method (default): ``points`` normal-incidence postures at the plate centre, at
  orientations spread evenly over a turn, water path ``[procedure] water_path_mm``; edge
  scans along ``+e1`` and ``+e2`` (or ``−e1``/``−e2`` if those reach farther) at two lateral
  positions each, in orientations φ0 and φ0 + 180°, with ``EDGE_WATER_PATH_MM`` of water.
  The edge search starts inside the hull of the touched points and goes outward as far as the
  arm can follow in both orientations (at most ``EDGE_SEARCH_MM``);
* paper method: ``points`` incidence points (default 100, as paper 002) drawn inside the hull
  of the touched points (shrunk by 15 % about the centroid), water paths 0.6–1.4 × the
  profile's, orientations over ±150° (paper 002, §5: "scattered", "different distance",
  "different angles");

and every target is checked: inside the joint ranges (keeping ``WRIST_MARGIN_DEG`` on joints
4–6 for the posture searches), ``|sin θ5| ≥ sin(singularity margin)``, and — for the incidence
points — the beam meeting the plate inside the touched points' hull (the plate's edges are not
in the profile; the hull of points on it is certainly plate).

Measure (exact): noise floor with the beam off the plate; at each posture the peak search of
``ucal.calibration.search`` (acquisition raster only for the first; later postures are
predicted from the beam found so far), fitted, the water path read at the peak; the beam a_T
from all peaks (``exact`` eq. E1), a_T·p_T from the paths (E2); then the edge scans with the
tool estimate updated (the beam normal to the plate within the peak precision): a coarse search
outward from the plate until the echo falls below half, a fine scan of static probes across the
edge fitted with eq. E4, in both orientations; p_T from all paths and crossings (E3) as a
first estimate; finally the fit of ``ucal.toolframe.fit`` (offsets, plate, DH table, sound speed
and delay as prior-constrained unknowns), which is what the run reports. A posture whose probes
are below half of the first posture's echo is a side lobe (a prediction off by degrees when the
offsets are not yet calibrated): it is acquired again as the first.

Measure (paper): at each incidence point the quick main-lobe centring (or the acquisition
raster if no echo at the prediction) and the water path there; the beam estimate is refined
from the postures found so far to predict the next one (the solver uses only flange poses and
water paths, eqs. 12–15).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ucal.calibration.faces import acquire_and_centre, acquisition_gain
from ucal.calibration.fit import offsets_prior_std_deg, prior_from_profile
from ucal.calibration.model import CellGeometry
from ucal.calibration.safety import check_joints
from ucal.calibration.search import PeakResult, PeakSearch, ka_of, read_distance
from ucal.calibration.wrist import search_joints
from ucal.cell import PAPER_CALIBRATION_POSE_DEG, CellProfile, WorldTruth
from ucal.edges import coarse_edge_fall, fine_edge_scan
from ucal.errors import HardwareError, InputError, SafetyError
from ucal.kinematics.dh import fk, transform
from ucal.kinematics.ik import ik
from ucal.kinematics.rotations import angle_between_deg, rpy_to_matrix
from ucal.procedure import Measured, Outcome, ProfileJob
from ucal.profile import write_profile
from ucal.progress import MeasureStep, Report
from ucal.rig import Rig
from ucal.session import CellSession
from ucal.timing import EDGE_SCAN, NO_SEARCH, PLATE_PEAK, DurationEstimate, estimate_run
from ucal.toolframe.exact import (
    BeamEstimate,
    EdgeCrossing,
    EdgeFit,
    OffsetEstimate,
    TofRecord,
    along_beam_offset_mm,
    beam_from_normal_incidence,
    rotation_for_beam,
    solve_offsets,
    tangent_basis,
)
from ucal.toolframe.fit import (
    PlateCrossing,
    PlatePeak,
    ToolFrameFit,
    plate_prior,
    solve_tool_frame,
    truth_in_profile_flange,
)
from ucal.toolframe.paper import PaperSolution, solve_paper
from ucal.toolframe.plane import Plane, fit_plane, hull_reach_mm

log = logging.getLogger(__name__)

METHODS = ("exact", "paper")
DEFAULT_POINTS = {"exact": 4, "paper": 100}
MIN_POINTS = {"exact": 2, "paper": 7}

#: Room kept inside the ranges of joints 4–6 for the posture searches (deg).
WRIST_MARGIN_DEG = 10.0
#: Water path during edge scans (mm): short, so that a beam-direction error moves the axis
#: hit point little (Δl·δa) — it would otherwise look like an offset across the beam.
EDGE_WATER_PATH_MM = 50.0
#: Farthest the edge search goes beyond its start (mm).
EDGE_SEARCH_MM = 300.0
#: Coarse edge search step (mm): below the footprint's width (σ = D/4 = 1.5 mm → 4σ = 6 mm).
COARSE_STEP_MM = 2.0
#: Probes (the last ones) whose largest echo the coarse search compares each new one with.
COARSE_MEMORY = 4
#: Fine scan: half width (mm) and number of static probes across the 50 % point.
FINE_HALF_MM = 5.0
FINE_PROBES = 21
#: Pulser averages per amplitude reading on edge scans and per peak-fit probe.
EDGE_AVERAGES = 16
PEAK_AVERAGES = 8
#: Acquisition raster radius (deg of beam tilt) for the first posture, doubled up to the max;
#: its lines 1.5° apart (the plate is met at the planned water path).
ACQUIRE_RADIUS_DEG = 4.0
ACQUIRE_MAX_DEG = 8.0
ACQUIRE_LINE_SPACING_DEG = 1.5
#: Noise floor the acquisition gain puts the empty gate at (fraction of full screen height).
ACQUISITION_FLOOR_FSH = 0.05
#: A peak below this share of the first posture's amplitude (same plate, same water path) is
#: a side lobe: the piston's first side lobe is 17.6 dB (0.13) below the main lobe.
MAIN_LOBE_SHARE = 0.5
#: Margin (mm) kept between an incidence point and the hull of the touched points.
HULL_MARGIN_MM = 3.0


# ---------------------------------------------------------------------------------------------
# plan


@dataclass(frozen=True)
class Target:
    """One planned tool pose: the beam along −n meeting the plate at ``point_mm``."""

    label: str
    point_mm: np.ndarray  # (3,) on the plane
    water_path_mm: float
    phi_deg: float
    joints_deg: np.ndarray  # planned readings (nominal tool)


@dataclass(frozen=True)
class EdgePlan:
    """Scans across one plate edge: outward ``direction``, lines at ``lateral_mm`` along
    ``along``, search from ``start_mm`` to ``start_mm + search_mm`` (from the centre)."""

    index: int
    name: str
    direction: np.ndarray
    along: np.ndarray
    lateral_mm: tuple[float, float]
    start_mm: float
    search_mm: float


@dataclass(frozen=True)
class ToolFramePlan:
    method: str
    plane: Plane
    centre_mm: np.ndarray
    reference_deg: np.ndarray
    phi0_deg: float
    peaks: tuple[Target, ...]
    edges: tuple[EdgePlan, ...]
    incidence: tuple[Target, ...]
    notes: tuple[str, ...] = ()

    def summary(self) -> str:
        """Human-readable plan (for the confirmation before the first motion)."""
        c = np.round(self.centre_mm, 1).tolist()
        lines = [
            (
                f"tool-frame calibration ({self.method}); plate plane n = "
                f"{np.round(self.plane.normal, 4).tolist()}, centre {c} mm "
                f"({self.plane.n_points} touched points, rms {self.plane.rms_mm:.3f} mm)"
            )
        ]
        for t in self.peaks + self.incidence[:5]:
            lines.append(
                f"  {t.label}: beam at {np.round(t.point_mm, 1).tolist()} mm, "
                f"water {t.water_path_mm:.0f} mm, phi {t.phi_deg:+.0f} deg, joints "
                f"{np.round(t.joints_deg, 1).tolist()}"
            )
        if len(self.incidence) > 5:
            lines.append(f"  … {len(self.incidence) - 5} more incidence points")
        for e in self.edges:
            lines.append(
                f"  edge {e.name}: search {e.start_mm:.0f}–{e.start_mm + e.search_mm:.0f}"
                f" mm from the centre along {np.round(e.direction, 3).tolist()}, lines at"
                f" {e.lateral_mm[0]:+.0f}/{e.lateral_mm[1]:+.0f} mm, phi "
                f"{self.phi0_deg:+.0f}/{self.phi0_deg + 180:+.0f} deg, water "
                f"{EDGE_WATER_PATH_MM:.0f} mm"
            )
        lines.extend(f"  note: {n}" for n in self.notes)
        return "\n".join(lines)


def tcp_pose(
    plane: Plane, point_mm: np.ndarray, water_path_mm: float, phi_deg: float
) -> np.ndarray:
    """Tool pose (4, 4): beam (tool z) along −n meeting the plane at ``point_mm`` after
    ``water_path_mm``; tool x turned by ``phi_deg`` from e1 towards e2 about the beam."""
    z = -plane.normal
    ph = np.radians(phi_deg)
    x = np.cos(ph) * plane.e1 + np.sin(ph) * plane.e2
    y = np.cross(z, x)
    return transform(
        np.asarray(point_mm, float) + water_path_mm * plane.normal, np.column_stack([x, y, z])
    )


def reference_joints(profile: CellProfile) -> np.ndarray:
    """Reference configuration for the IK choice: the profile's calibration pose."""
    pose = profile.procedure.calibration_pose_deg
    return np.asarray(PAPER_CALIBRATION_POSE_DEG if pose is None else pose, float)


def solve_target(
    profile: CellProfile,
    plane: Plane,
    tool: np.ndarray,
    point: np.ndarray,
    path: float,
    phi: float,
    near: np.ndarray,
    label: str,
    wrist_margin: float,
) -> np.ndarray:
    """Checked joint readings for a target (``SafetyError`` naming ``label``)."""
    try:
        q = ik(
            profile.model,
            tcp_pose(plane, point, path, phi),
            tool,
            profile.joint_offsets_deg,
            near_deg=near,
        )
    except SafetyError as e:
        raise SafetyError(f"plan {label}: {e}") from None
    check_joints(profile, q, label, wrist_margin)
    return q


def _inside_hull(plane: Plane, points: np.ndarray, x: np.ndarray, margin: float) -> bool:
    """``x`` (on the plane) lies inside the touched points' hull with ``margin`` (mm) to spare."""
    for ang in np.radians(np.arange(0.0, 360.0, 30.0)):
        d = np.cos(ang) * plane.e1 + np.sin(ang) * plane.e2
        if hull_reach_mm(plane, points, d, x) < margin:
            return False
    return True


def plan_tool_frame(
    profile: CellProfile, method: str = "exact", points: int | None = None
) -> ToolFramePlan:
    """Plan and check every target (see module docstring); nothing moves."""
    if method not in METHODS:
        raise InputError(f"--method must be one of {', '.join(METHODS)}, got {method!r}")
    n_pts = DEFAULT_POINTS[method] if points is None else int(points)
    if n_pts < MIN_POINTS[method]:
        raise InputError(
            f"--points must be at least {MIN_POINTS[method]} for the {method} method, got {n_pts}"
        )
    plane = fit_plane(profile.reflector_points_mm, profile.path)
    pts = np.asarray(profile.reflector_points_mm, float)
    centre = plane.project(plane.centroid_mm)
    tool = profile.tool_matrix
    ref = reference_joints(profile)
    path = profile.procedure.water_path_mm
    notes: list[str] = []
    if not _inside_hull(plane, pts, centre, HULL_MARGIN_MM):
        raise SafetyError(
            "plan: the touched points enclose no room for the beam (the plate's "
            "centre is within 3 mm of their hull)"
        )
    # φ0: the orientation whose joint 6 sits nearest the middle of its range at the centre.
    best = None
    for phi in np.arange(-180.0, 180.0, 15.0):
        try:
            q = solve_target(
                profile, plane, tool, centre, path, phi, ref, "centre", WRIST_MARGIN_DEG
            )
            q2 = solve_target(
                profile, plane, tool, centre, path, phi + 180.0, q, "centre", WRIST_MARGIN_DEG
            )
        except SafetyError:
            continue
        mid = 0.5 * (profile.model.joint_min_deg[5] + profile.model.joint_max_deg[5])
        cost = abs(q[5] - mid) + abs(q2[5] - mid) + 0.01 * abs(phi)
        if best is None or cost < best[0]:
            best = (cost, float(phi))
    if best is None:
        # report the reason for φ = 0
        solve_target(profile, plane, tool, centre, path, 0.0, ref, "centre", WRIST_MARGIN_DEG)
        solve_target(profile, plane, tool, centre, path, 180.0, ref, "centre", WRIST_MARGIN_DEG)
        raise SafetyError(
            "plan: no orientation about the beam reaches the plate centre in both senses"
        )
    phi0 = best[1]

    peaks: list[Target] = []
    edges: list[EdgePlan] = []
    incidence: list[Target] = []
    if method == "exact":
        near = ref
        for i in range(n_pts):
            phi = phi0 + 360.0 * i / n_pts
            phi = (phi + 180.0) % 360.0 - 180.0
            label = f"peak {i + 1}"
            q = solve_target(profile, plane, tool, centre, path, phi, near, label, WRIST_MARGIN_DEG)
            peaks.append(Target(label, centre, path, phi, q))
            near = q
        edges = _plan_edges(profile, plane, pts, centre, tool, phi0, ref, notes)
    else:
        incidence = _plan_incidence(profile, plane, pts, centre, tool, phi0, ref, n_pts, notes)
    return ToolFramePlan(
        method, plane, centre, ref, phi0, tuple(peaks), tuple(edges), tuple(incidence), tuple(notes)
    )


def _plan_edges(
    profile: CellProfile,
    plane: Plane,
    pts: np.ndarray,
    centre: np.ndarray,
    tool: np.ndarray,
    phi0: float,
    ref: np.ndarray,
    notes: list[str],
) -> list[EdgePlan]:
    out: list[EdgePlan] = []
    for axis, (e, name) in enumerate(((plane.e1, "e1"), (plane.e2, "e2"))):
        candidates = []
        for sign in (1.0, -1.0):
            u = sign * e
            w = np.cross(plane.normal, u)
            lat = 0.5 * min(
                hull_reach_mm(plane, pts, w, centre), hull_reach_mm(plane, pts, -w, centre)
            )
            if lat < 5.0:
                continue
            starts = [hull_reach_mm(plane, pts, u, centre + s * lat * w) for s in (-1, 1)]
            start = max(0.0, min(starts) - HULL_MARGIN_MM)
            reach = 0.0
            near = ref
            ok = True
            for dist in np.arange(0.0, EDGE_SEARCH_MM + 1e-9, 10.0):
                for s in (-1.0, 1.0):
                    for phi in (phi0, phi0 + 180.0):
                        p = centre + (start + dist) * u + s * lat * w
                        try:
                            near = solve_target(
                                profile,
                                plane,
                                tool,
                                p,
                                EDGE_WATER_PATH_MM,
                                phi,
                                near,
                                f"edge {name}",
                                0.0,
                            )
                        except SafetyError:
                            ok = False
                            break
                    if not ok:
                        break
                if not ok:
                    break
                reach = dist
            candidates.append((reach, sign, u, w, lat, start))
        if not candidates:
            raise SafetyError(
                f"plan edge {name}: the touched points are too close to a line "
                "across this direction to place two scan lines"
            )
        reach, sign, u, w, lat, start = max(candidates, key=lambda c: (c[0], c[1]))
        label = ("+" if sign > 0 else "-") + name
        if reach < 20.0:
            raise SafetyError(
                f"plan edge {label}: the arm cannot follow the edge search "
                f"beyond {reach:.0f} mm from the touched points' hull in both "
                "orientations"
            )
        if reach < EDGE_SEARCH_MM:
            notes.append(
                f"edge search {label} limited to {reach:.0f} mm beyond the touched "
                "points by the arm's reach"
            )
        out.append(EdgePlan(axis, label, u, w, (-lat, lat), start, float(reach)))
    return out


def _plan_incidence(
    profile: CellProfile,
    plane: Plane,
    pts: np.ndarray,
    centre: np.ndarray,
    tool: np.ndarray,
    phi0: float,
    ref: np.ndarray,
    n_pts: int,
    notes: list[str],
) -> list[Target]:
    rng = np.random.default_rng(2023)  # paper 002's year: a fixed, reproducible draw
    path0 = profile.procedure.water_path_mm
    uv = plane.to_plane(pts)
    lo, hi = uv.min(0), uv.max(0)
    out: list[Target] = []
    skipped = 0
    near = ref
    for _ in range(50 * n_pts):
        if len(out) == n_pts:
            break
        a, b = rng.uniform(lo, hi)
        x = centre + 0.85 * (a * plane.e1 + b * plane.e2)
        if not _inside_hull(plane, pts, x, HULL_MARGIN_MM):
            continue
        path = float(rng.uniform(0.6, 1.4) * path0)
        phi = float(phi0 + rng.uniform(-150.0, 150.0))
        label = f"point {len(out) + 1}"
        try:
            q = solve_target(profile, plane, tool, x, path, phi, near, label, WRIST_MARGIN_DEG)
        except SafetyError:
            skipped += 1
            continue
        out.append(Target(label, x, path, phi, q))
        near = q
    if len(out) < n_pts:
        raise SafetyError(
            f"plan: only {len(out)} of {n_pts} incidence points inside the "
            "touched points' hull are reachable"
        )
    if skipped:
        notes.append(f"{skipped} drawn incidence points were unreachable and drawn again")
    return out


# ---------------------------------------------------------------------------------------------
# run


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


class _Runner:
    """Measurement helpers sharing the rig, the plane and the running tool estimate."""

    def __init__(
        self,
        profile: CellProfile,
        plan: ToolFramePlan,
        rig: Rig,
        progress: Report | None,
    ):
        self.profile = profile
        self.plan = plan
        self.plane = plan.plane
        self.rig = rig
        self.progress = progress
        self.offsets = np.asarray(profile.joint_offsets_deg, float)
        self.temp = profile.water_temperature_c
        self.ka = ka_of(profile.frequency_mhz, profile.element_diameter_mm, self.temp)
        self.position = np.asarray(profile.tool_position_mm, float).copy()
        self.beam = np.asarray(profile.tool_matrix[:3, 2], float).copy()
        self.acq_gain = 40.0
        self.q = np.asarray(plan.reference_deg, float)

    # -- kinematics ------------------------------------------------------------------------------
    def tool(self) -> np.ndarray:
        rot = rpy_to_matrix(rotation_for_beam(self.beam, self.profile.tool_rotation_deg))
        return transform(self.position, rot)

    def flange(self, q: np.ndarray) -> np.ndarray:
        return fk(self.profile.model, q, offsets_deg=self.offsets)

    def joints(
        self, point: np.ndarray, path: float, phi: float, label: str, wrist_margin: float = 0.0
    ) -> np.ndarray:
        return solve_target(
            self.profile, self.plane, self.tool(), point, path, phi, self.q, label, wrist_margin
        )

    def move(self, q: np.ndarray) -> np.ndarray:
        self.q = np.asarray(q, float)
        return self.rig.move(q)

    # -- pulser ----------------------------------------------------------------------------------
    def set_gain(self, averages: int) -> float:
        """Gain for an echo at 40–85 % of full screen at the current posture; its amplitude
        (0 dB normalised)."""
        self.rig.level_gain(averages)
        return self.rig.normalised_amplitude(averages)

    def noise_floor(self, target: Target) -> None:
        """Noise floor with the beam 25° off the plate's normal; sets the acquisition gain."""
        away = target.joints_deg.copy()
        away[4] += 25.0 if away[4] + 25.0 < self.profile.model.joint_max_deg[4] else -25.0
        self.acq_gain = acquisition_gain(self.rig, away, ACQUISITION_FLOOR_FSH)
        self.q = self.rig.clip(away)

    # -- posture search --------------------------------------------------------------------------
    def _search(self, q_pred: np.ndarray) -> PeakSearch:
        geom = CellGeometry(self.profile.model, self.tool(), self.plane.rotation)
        js, tilt_map = search_joints(geom, q_pred, self.offsets, self.plane.rotation[:, :2].T)
        return PeakSearch(self.rig, self.ka, js, tilt_map, self.temp)

    def centred(self, target: Target, quick: bool) -> tuple[PeakSearch, np.ndarray]:
        """Main-lobe posture near the target (acquisition raster if no echo is predicted)."""
        q_pred = self.joints(
            target.point_mm, target.water_path_mm, target.phi_deg, target.label, 0.0
        )
        return self.normal_near(q_pred, target.label, quick)

    def normal_near(
        self, q_pred: np.ndarray, label: str, quick: bool
    ) -> tuple[PeakSearch, np.ndarray]:
        """Main-lobe posture (wrist only) near ``q_pred``: a quick centring, else (or when
        ``quick`` is False) the acquisition raster, widened up to ``ACQUIRE_MAX_DEG``."""
        search = self._search(q_pred)
        q_c = search.quick_centre(q_pred) if quick else None
        if q_c is None:
            q_c = acquire_and_centre(
                search,
                self.rig,
                q_pred,
                label,
                ACQUIRE_RADIUS_DEG,
                self.acq_gain,
                max_moves=None,
                spacings_deg=(ACQUIRE_LINE_SPACING_DEG,),
                max_radius_deg=ACQUIRE_MAX_DEG,
                no_echo=_no_plate_echo,
            )
        self.q = np.asarray(q_c, float)
        return search, q_c

    def update_beam(self, rots: list[np.ndarray], stds: list[float]) -> BeamEstimate:
        est = beam_from_normal_incidence(np.array(rots), self.plane.normal, np.array(stds))
        self.beam = est.direction
        return est

    # -- edge scans ------------------------------------------------------------------------------
    def edge_scan(
        self, ep: EdgePlan, lateral: float, phi: float, guess: float | None
    ) -> tuple[EdgeCrossing, EdgeFit, float, PlateCrossing]:
        """Coarse search and fine scan across edge ``ep`` on the line at ``lateral``; returns
        the crossing, its profile fit, the coarse crossing (mm from the centre) and the
        crossing as readings (for the fit with the offsets as unknowns)."""
        u, w = ep.direction, ep.along
        origin = self.plan.centre_mm + lateral * w
        tool = self.tool()
        label = f"edge {ep.name}"
        rows: list[tuple[float, float, np.ndarray]] = []
        aim = np.zeros(6)  # wrist correction to normal incidence on this line

        def probe(t: float, averages: int) -> float:
            q = self.joints(origin + t * u, EDGE_WATER_PATH_MM, phi, label) + aim
            settled = self.move(q)
            a = self.rig.normalised_amplitude(averages)
            rows.append((t, a, np.asarray(settled, float)))
            return a

        hi = ep.start_mm + ep.search_mm
        if guess is None:
            t = ep.start_mm
            step = COARSE_STEP_MM
        else:
            t = max(ep.start_mm, guess - 20.0)
            step = 0.75 * COARSE_STEP_MM
        # normal incidence at the line's start: with joint offsets not yet calibrated the
        # beam turns differently in this arm configuration than at the plate centre (a few
        # tenths of a degree can put it in the first null); the wrist correction found here
        # holds along the short line. Then gain on the plate, and outward until the echo falls
        # below half.
        q0 = self.joints(origin + t * u, EDGE_WATER_PATH_MM, phi, label)
        _, q_n = self.normal_near(q0, label, quick=True)
        aim = np.asarray(q_n, float) - q0
        self.move(q0 + aim)
        self.set_gain(EDGE_AVERAGES)
        # the edge: a fall to half within a few steps (the footprint's 4σ = 6 mm); a beam that
        # drifts off normal along the line (offsets not yet calibrated) fades slowly
        first = probe(t, EDGE_AVERAGES)
        t_c = coarse_edge_fall(lambda t: probe(t, EDGE_AVERAGES), t, first, hi, step, COARSE_MEMORY)
        if t_c is None:
            raise HardwareError(
                f"{self.rig.pulser.endpoint}: the echo did not fall at any "
                f"edge along {ep.name} within {hi:.0f} mm of the plate centre"
            )
        # fine scan across the coarse crossing; once more twice as wide if it does not cross
        # (the coarse fall was a dip of the echo on the plate, e.g. a bow or a scratch)
        # normal incidence again just inside the edge, for the fine scan
        q1 = self.joints(origin + (t_c - FINE_HALF_MM - 2.0) * u, EDGE_WATER_PATH_MM, phi, label)
        _, q_n = self.normal_near(q1, label, quick=True)
        aim = np.asarray(q_n, float) - q1
        ts: list[float] = []
        flanges: list[np.ndarray] = []

        def fine(t: float) -> tuple[float, float]:
            """A fine probe's scan coordinate, from its actual flange pose (the estimated
            tool centre), and amplitude."""
            a = probe(t, EDGE_AVERAGES)
            f = self.flange(rows[-1][2])
            c = (f @ tool)[:3, 3]
            ts.append(float(u @ (self.plane.project(c) - origin)))
            flanges.append(f)
            return ts[-1], a

        for half in (FINE_HALF_MM, 2.0 * FINE_HALF_MM):
            rows.clear()
            ts.clear()
            flanges.clear()
            try:
                fit = fine_edge_scan(fine, t_c, half, FINE_PROBES)
                break
            except ValueError as e:
                log.info("edge %s: %s (±%.0f mm)", ep.name, e, half)
        else:
            raise HardwareError(
                f"{self.rig.pulser.endpoint}: the fine scan across edge "
                f"{ep.name} near {t_c:.0f} mm from the plate centre does not "
                "show the echo falling to half: is the edge straight and "
                "clean?"
            )
        ts_arr = np.array(ts)
        i = int(np.argmin(np.abs(ts_arr - fit.crossing)))
        f = flanges[i].copy()
        shift = (fit.crossing - ts_arr[i]) * u
        f[:3, 3] += shift
        log.info(
            "edge %s lateral %+.1f phi %+.0f: crossing %.4f ± %.4f mm (σ %.3f mm, rms %.2g)",
            ep.name,
            lateral,
            phi,
            fit.crossing,
            fit.crossing_std,
            fit.width_mm,
            fit.rms,
        )
        std = max(fit.crossing_std, 1e-4)
        return (
            EdgeCrossing(f, ep.index, std, u.copy()),
            fit,
            float(t_c),
            PlateCrossing(
                f"edge {ep.name} {lateral:+.0f} mm phi {phi:+.0f}",
                rows[i][2].copy(),
                shift,
                ep.index,
                std,
            ),
        )


def _no_plate_echo(rig: Rig, label: str, reached_deg: float, moves: int) -> HardwareError:
    return HardwareError(
        f"{rig.pulser.endpoint}: no echo from the reflector plate within {reached_deg:g} deg "
        f"of the predicted posture ({label}); check [reflector] points_mm and [tool] in the "
        "profile"
    )


def _report(r: _Runner, what: str, i: int, n: int, phi_deg: float | None = None) -> None:
    if r.progress:
        orientation = None if phi_deg is None else f"phi {phi_deg:+.0f}"
        r.progress(MeasureStep(what, i, n, orientation, "plate" if what != "solving" else None))


@dataclass
class ExactMeasurements:
    """What the exact method measured: peaks and their water paths, edge crossings."""

    peaks: list[PeakResult]
    tofs: list[TofRecord]
    crossings: list[EdgeCrossing]
    plate_crossings: list[PlateCrossing]
    edge_fits: list[EdgeFit]
    beam_estimate: BeamEstimate
    position_mm: np.ndarray  # the tool centre estimated on the way (start of the first solve)
    moves: int
    reads: int


@dataclass
class PaperMeasurements:
    """What paper 002's method measured: flange poses and water paths at incidence points."""

    rotations: list[np.ndarray]
    positions_mm: list[np.ndarray]
    paths_mm: list[float]
    path_stds_mm: list[float]
    moves: int
    reads: int


ToolFrameMeasurements = ExactMeasurements | PaperMeasurements


def measure_tool_frame(
    profile: CellProfile, plan: ToolFramePlan, rig: Rig, progress: Report | None = None
) -> ToolFrameMeasurements:
    """Measure the plan (module docstring), reporting each posture and edge scan as it starts.
    The caller owns the connection, STOP and the profile."""
    r = _Runner(profile, plan, rig, progress)
    if plan.method == "paper":
        return _measure_paper(r)
    return _measure_exact(r)


def solve_measured(
    profile: CellProfile, plan: ToolFramePlan, measured: ToolFrameMeasurements
) -> ToolFrameRun:
    """The tool frame from a run's measurements (module docstring); nothing moves."""
    if isinstance(measured, PaperMeasurements):
        return _solve_paper(profile, plan, measured)
    return _solve_exact(profile, plan, measured)


def run_tool_frame(
    profile: CellProfile, plan: ToolFramePlan, rig: Rig, progress: Report | None = None
) -> ToolFrameRun:
    """Measure and solve (see module docstring). The caller owns connection, STOP, profile."""
    return solve_measured(profile, plan, measure_tool_frame(profile, plan, rig, progress))


def _tof(r: _Runner) -> tuple[float, float]:
    return read_distance(r.rig, r.temp, max(r.profile.procedure.tof_averages, 1))


def _measure_exact(r: _Runner) -> ExactMeasurements:
    plan = r.plan
    total = len(plan.peaks) + 4 * len(plan.edges)
    r.noise_floor(plan.peaks[0])
    rots: list[np.ndarray] = []
    stds: list[float] = []
    peaks: list[PeakResult] = []
    tofs: list[TofRecord] = []
    for i, target in enumerate(plan.peaks):
        _report(r, target.label, i, total, target.phi_deg)
        search, q_c = r.centred(target, quick=i > 0)
        peak = search.fit(q_c, averages=PEAK_AVERAGES, distance=lambda: _tof(r))
        if peak.tilt_std_deg > 0.02:
            log.info("%s: poor fit (σ %.3f°), centring again", target.label, peak.tilt_std_deg)
            q_again = search.quick_centre(peak.joints_deg)
            if q_again is not None:
                peak = search.fit(q_again, averages=PEAK_AVERAGES, distance=lambda: _tof(r))
        if peaks and _probe_level(peak) < MAIN_LOBE_SHARE * _probe_level(peaks[0]):
            # A prediction off by degrees (joint offsets not yet calibrated turn the beam
            # differently at each orientation) can centre on a side lobe (−17.6 dB and less):
            # acquire and centre as for the first posture.
            log.info(
                "%s: %.2g of the first peak's echo, a side lobe: acquiring",
                target.label,
                _probe_level(peak) / _probe_level(peaks[0]),
            )
            search, q_c = r.centred(target, quick=False)
            peak = search.fit(q_c, averages=PEAK_AVERAGES, distance=lambda: _tof(r))
            level = _probe_level(peak) / _probe_level(peaks[0])
            if level < MAIN_LOBE_SHARE:
                raise HardwareError(
                    f"{r.rig.pulser.endpoint}: {target.label}: only a side lobe "
                    f"of the plate's echo found ({level:.2g} of the first "
                    "posture's); is the plate flat and still?"
                )
        assert peak.distance is not None and peak.distance_joints_deg is not None
        peaks.append(peak)
        rots.append(r.flange(peak.joints_deg)[:3, :3])
        stds.append(max(peak.tilt_std_deg, 1e-4))
        path, path_std = peak.distance
        tofs.append(TofRecord(r.flange(peak.distance_joints_deg), path, max(path_std, 1e-4)))
        r.q = np.asarray(rig_joints(r), float)
        beam_est = r.update_beam(rots, stds)
        log.info(
            "%s: beam %s (%d postures), water path %.4f mm",
            target.label,
            np.round(beam_est.direction, 6).tolist(),
            len(rots),
            path,
        )
    beam_est = r.update_beam(rots, stds)
    # a_T·p_T from the water paths alone (E2) before the edge scans
    s, _ = along_beam_offset_mm(beam_est.direction, tofs, r.plane)
    r.position = r.position + (s - beam_est.direction @ r.position) * beam_est.direction
    crossings: list[EdgeCrossing] = []
    plate_crossings: list[PlateCrossing] = []
    fits: list[EdgeFit] = []
    guesses: dict[tuple[int, int], float] = {}
    k = len(plan.peaks)
    for phi in (plan.phi0_deg, plan.phi0_deg + 180.0):
        for ep in plan.edges:
            for j, lateral in enumerate(ep.lateral_mm):
                turned = "" if phi == plan.phi0_deg else ", tool turned 180°"
                _report(r, f"edge {ep.name}{turned}", k, total, phi)
                k += 1
                guess = guesses.get((ep.index, j), guesses.get((ep.index, 0)))
                cr, fit, t_c, pc = r.edge_scan(ep, lateral, phi, guess)
                guesses.setdefault((ep.index, j), t_c)
                crossings.append(cr)
                plate_crossings.append(pc)
                fits.append(fit)
    # leave the robot above the plate centre
    r.move(r.joints(plan.centre_mm, plan.peaks[0].water_path_mm, plan.phi0_deg, "centre"))
    _report(r, "solving", total, total)
    return ExactMeasurements(
        peaks,
        tofs,
        crossings,
        plate_crossings,
        fits,
        beam_est,
        r.position,
        r.rig.counters.moves,
        r.rig.counters.reads,
    )


def _solve_exact(profile: CellProfile, plan: ToolFramePlan, m: ExactMeasurements) -> ToolFrameRun:
    peaks, tofs, crossings, beam_est = m.peaks, m.tofs, m.crossings, m.beam_estimate
    # First estimate with the profile's offsets and the touched plane taken as exact (the
    # formulation of ucal.toolframe.exact): the start of the fit with the priors.
    offsets = solve_offsets(beam_est, tofs, crossings, plan.plane, m.position_mm)
    first_rot = rotation_for_beam(beam_est.direction, profile.tool_rotation_deg)
    tf = solve_plate_fit(
        profile,
        plan.plane,
        peaks,
        m.plate_crossings,
        offsets,
        np.concatenate([offsets.position_mm, first_rot]),
    )
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
    first: OffsetEstimate,
    tool_start: np.ndarray,
) -> ToolFrameFit:
    """The fit of ``ucal.toolframe.fit`` on a run's peaks and crossings (priors from the
    profile; edges and tool started from the first estimate)."""
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
            )
        )
    edge_start = np.column_stack([first.edge_angles_deg, first.edge_offsets_mm]).ravel()
    assert profile.reflector_points_mm is not None
    return solve_tool_frame(
        prior_from_profile(profile),
        plate_prior(plane, profile.reflector_points_mm, profile.reflector_points_std_mm),
        offsets_prior_std_deg(profile),
        plate_peaks,
        crossings,
        edge_start,
        tool_start,
    )


def _probe_level(peak: PeakResult) -> float:
    """Strongest echo (normalised to 0 dB) among a peak fit's probes."""
    return float(np.max(peak.probes[1])) if peak.probes is not None else peak.amplitude


def rig_joints(r: _Runner) -> np.ndarray:
    """Current joint readings of the robot."""
    return r.rig.controller.read_joints()


def _measure_paper(r: _Runner) -> PaperMeasurements:
    plan = r.plan
    total = len(plan.incidence)
    r.noise_floor(plan.incidence[0])
    rots: list[np.ndarray] = []
    poss: list[np.ndarray] = []
    paths: list[float] = []
    path_stds: list[float] = []
    for i, target in enumerate(plan.incidence):
        _report(r, target.label, i, total, target.phi_deg)
        _, q_c = r.centred(target, quick=i > 0)
        settled = r.move(q_c)
        path, std = _tof(r)
        f = r.flange(settled)
        rots.append(f[:3, :3])
        poss.append(f[:3, 3])
        paths.append(path)
        path_stds.append(std)
        # predict the next incidence posture from the postures found so far (E1)
        r.update_beam(rots, [0.01] * len(rots))
    _report(r, "solving", total, total)
    return PaperMeasurements(
        rots, poss, paths, path_stds, r.rig.counters.moves, r.rig.counters.reads
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


#: The largest tool tolerances a profile holds (``ucal.profile.read_tolerances``): mm, deg.
TOOL_STD_LIMITS = {"position_std_mm": 100.0, "rotation_std_deg": 10.0}
#: The end of a refusal's message, dropped when ``--force`` writes the result all the same.
NOT_WRITTEN = " (profile not written; --force writes it)"


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


# ---------------------------------------------------------------------------------------------
# the tool-frame command's job in the procedure of ``ucal.procedure``


class ToolFrameCalibration(ProfileJob):
    """``tool-frame``: the tool frame → ``[tool]`` (with its stds from the exact fit)."""

    command = "tool-frame"

    def __init__(
        self,
        profile: CellProfile,
        profile_path: Path,
        method: str = "exact",
        points: int | None = None,
        force: bool = False,
    ) -> None:
        super().__init__(profile, profile_path)
        self.method = method
        self.points = points
        self.force = force

    def plan(self) -> ToolFramePlan:
        return plan_tool_frame(self.profile, self.method, self.points)

    def summary(self, plan: ToolFramePlan) -> str:
        return plan.summary()

    def estimate(self, plan: ToolFramePlan) -> DurationEstimate:
        speed = self.profile.procedure.speed
        postures = [t.joints_deg for t in plan.peaks + plan.incidence]
        at_postures = estimate_run(
            postures, plan.reference_deg, speed, search=PLATE_PEAK, first=NO_SEARCH
        )
        # each edge scan starts near the plate centre, where the first posture looks from
        scans = [postures[0]] * (4 * len(plan.edges))
        return at_postures + estimate_run(
            scans, postures[0], speed, search=EDGE_SCAN, first=NO_SEARCH
        )

    def record_header(self, plan: ToolFramePlan) -> dict[str, Any]:
        return {"options": {"method": self.method, "points": self.points}, "plan": []}

    def measure(
        self, plan: ToolFramePlan, session: CellSession, report: Report
    ) -> ToolFrameMeasurements:
        return measure_tool_frame(self.profile, plan, session.rig, report)

    def solve(self, plan: ToolFramePlan, measured: Measured[ToolFrameMeasurements]) -> ToolFrameRun:
        return solve_measured(self.profile, plan, measured.data)

    def may_write(self, run: ToolFrameRun) -> bool:
        return run.in_tolerance or self.force

    def write(self, run: ToolFrameRun) -> None:
        reason = f"tool-frame ({run.method})"
        keys, capped = tool_keys(run)
        if not run.in_tolerance:
            reason += f", written with --force: {refusal(run).replace(NOT_WRITTEN, '')}"
        if capped:
            reason += f"; {capped}"
        write_profile(self.profile_path, {"tool": keys}, reason=reason)

    def result(
        self,
        plan: ToolFramePlan,
        measured: Measured[ToolFrameMeasurements],
        run: ToolFrameRun,
        written: bool,
    ) -> Outcome:
        out = result_object(
            run, self.profile, self.profile_path, written, measured.truth, measured.duration_s
        )
        message = refusal(run)
        if written and not run.in_tolerance:
            message = message.replace(NOT_WRITTEN, "") + " (written with --force)"
        return Outcome(
            self.command,
            out,
            written,
            out_of_tolerance=not run.in_tolerance,
            message=message,
            shown=run,
        )
