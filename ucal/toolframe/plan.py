"""Plate frame. The plane of the touched points (``ucal.toolframe.plane``) with its in-plane axes
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
  positions each, in orientations φ0 and φ0 + 180°, with ``EDGE_WATER_PATH_MM`` of water, and
  at φ0 + 90° and φ0 + 270° as well for a beam more than ``QUARTER_TURNS_TILT_DEG`` off the
  flange axis on a cell whose DH table is not identified (below). The edge search starts
  inside the hull of the touched points and goes outward as far as the arm can follow in
  every orientation (at most ``EDGE_SEARCH_MM``);
* paper method: ``points`` incidence points (default 100, as paper 002) drawn inside the hull
  of the touched points (shrunk by 15 % about the centroid), water paths 0.6–1.4 × the
  profile's, orientations over ±150° (paper 002, §5: "scattered", "different distance",
  "different angles");

Why quarter turns for a holder. The edge scans see the tool across the beam by turning it about
the beam: a tool centre off the beam by Δ moves the crossings by Δ one way and by −Δ half a turn
later. With the beam along the flange axis that turn is joint 6 alone. A holder tilting the beam
θ off that axis swings the flange axis through 2θ instead: joints 4 and 5 and the arm take
another posture, and the wrist's link lengths and twists within the DH table's tolerance (row
5's d and a, row 4's a: 0.2 mm each on a fresh cell) move the flange between the two postures as
a tool off the beam would. Two orientations cannot tell the two apart: on a fresh cell most of
a holder's variance across the beam is then the DH table's. Scans a quarter turn apart put the
wrist in four postures: a tool offset turns with the tool, a link error moves the flange as the
posture does, and the fit, with the DH table as unknowns, tells them apart (measured by
``benchmarks/drift.py --case tool-frame``, ``docs/benchmarks.md``). It costs twice the edge
scans, so a straight holder keeps two orientations, and so does a cell whose DH table the full
level has identified (``[calibration] dh_std``): its links are known to micrometres there, half
a turn measures the tool within the tolerance, and the quarter turns' wrist postures only test
the identified table where its stds, kept without their correlations, are least faithful
(measured by ``benchmarks/drift.py --case tool-frame --orders f-t``).
Where the arm cannot follow the scans a quarter turn apart the plan keeps two and says what
that costs.

and every target is checked: inside the joint ranges (keeping ``WRIST_MARGIN_DEG`` on joints
4–6 for the posture searches, ``tool_turn_deg`` more for the tool's declared tolerance),
``|sin θ5| ≥ sin(singularity margin)``, and — for the incidence
points — the beam meeting the plate inside the touched points' hull (the plate's edges are not
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ucal.cell import PAPER_CALIBRATION_POSE_DEG, CellProfile
from ucal.errors import InputError, SafetyError
from ucal.kinematics.dh import transform
from ucal.kinematics.ik import ik
from ucal.kinematics.rotations import angle_between_deg
from ucal.model.safety import check_joints, reach_advice
from ucal.toolframe.plane import Plane, fit_plane, hull_reach_mm

METHODS = ("exact", "paper")
DEFAULT_POINTS = {"exact": 4, "paper": 100}
MIN_POINTS = {"exact": 2, "paper": 7}

#: Room kept inside the ranges of joints 4–6 for the posture searches (deg).
WRIST_MARGIN_DEG = 10.0
#: ... and room for how far the tool's orientation may really be from the profile's: the
#: searches turn the wrist by that much to find the plate's normal (this many sigma of
#: ``[tool] rotation_std_deg``).
TOOL_SIGMAS = 3.0
#: What would lift a refusal the tool's declared orientation tolerance causes (tool-frame is
#: the command that measures it: the reader states it better).
TOOL_CURE = (
    "the tool's orientation known better ([tool] rotation_std_deg: its drawing or a fixture)"
)
#: Water path during edge scans (mm): short, so that a beam-direction error moves the axis
#: hit point little (Δl·δa) — it would otherwise look like an offset across the beam.
EDGE_WATER_PATH_MM = 50.0
#: Farthest the edge search goes beyond its start (mm).
EDGE_SEARCH_MM = 300.0
#: A beam more than this off the flange axis (the profile's tool orientation) is scanned across
#: the edges a quarter turn apart, four orientations, on a cell whose DH table is not identified
#: (module docstring; deg).
QUARTER_TURNS_TILT_DEG = 2.0
#: The turns about the beam of the edge scans from φ0: a quarter apart, or half.
QUARTER_TURNS = (0.0, 90.0, 180.0, 270.0)
HALF_TURNS = (0.0, 180.0)
#: Coarse edge search step (mm): below the footprint's width (σ = D/4 = 1.5 mm → 4σ = 6 mm).
#: Margin (mm) kept between an incidence point and the hull of the touched points.
HULL_MARGIN_MM = 3.0


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
    #: The edge scans' turns about the beam from ``phi0_deg`` (deg): ``QUARTER_TURNS`` or
    #: ``HALF_TURNS``.
    edge_turns_deg: tuple[float, ...] = HALF_TURNS

    @property
    def edge_lines(self) -> int:
        """How many edge lines the plan scans: two per edge in each orientation."""
        return 2 * len(self.edges) * len(self.edge_turns_deg)

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
                + "/".join(f"{self.phi0_deg + t:+.0f}" for t in self.edge_turns_deg)
                + f" deg, water "
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


def tool_turn_deg(profile: CellProfile) -> float:
    """How far the searches may turn the wrist from a planned posture to find the plate's
    normal: ``TOOL_SIGMAS`` of the tool orientation's declared tolerance (deg)."""
    return float(TOOL_SIGMAS * np.linalg.norm(profile.tool_rotation_std_deg))


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
    tolerance_deg: float = 0.0,
    turn: np.ndarray | None = None,
) -> np.ndarray:
    """Checked joint readings for a target (``SafetyError`` naming ``label``), ``wrist_margin``
    and ``tolerance_deg`` kept on the wrist (``check_joints``); ``turn``: a rotation (3, 3,
    base frame) of the tool about its centre from the planned orientation, a correction to
    normal incidence the wrist search reached on the way: the readings of the turned pose
    nearest the checked planned ones, inside the joint ranges."""
    q = _ik(profile, tcp_pose(plane, point, path, phi), tool, near, label)
    check_joints(
        profile, q, label, wrist_margin, tolerance_deg, block_tolerance=False, tool_cure=TOOL_CURE
    )
    if turn is None:
        return q
    pose = tcp_pose(plane, point, path, phi)
    pose[:3, :3] = turn @ pose[:3, :3]
    return _ik(profile, pose, tool, q, label)


def _ik(
    profile: CellProfile, pose: np.ndarray, tool: np.ndarray, near: np.ndarray, label: str
) -> np.ndarray:
    """Readings inside the joint ranges for a tool pose, nearest ``near`` (``SafetyError``
    naming ``label``)."""
    try:
        return ik(profile.model, pose, tool, profile.joint_offsets_deg, near_deg=near)
    except SafetyError as e:
        raise SafetyError(f"plan {label}: {e}") from None


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
    turn = tool_turn_deg(profile)
    if not _inside_hull(plane, pts, centre, HULL_MARGIN_MM):
        raise SafetyError(
            "plan: the touched points enclose no room for the beam (the plate's "
            "centre is within 3 mm of their hull)"
        )
    # φ0: the orientation whose joint 6 sits nearest the middle of its range at the centre,
    # then the others by that cost, until one whose every target passes.
    costs = []
    for phi in np.arange(-180.0, 180.0, 15.0):
        try:
            q = solve_target(
                profile, plane, tool, centre, path, phi, ref, "centre", WRIST_MARGIN_DEG, turn
            )
            q2 = solve_target(
                profile, plane, tool, centre, path, phi + 180.0, q, "centre", WRIST_MARGIN_DEG, turn
            )
        except SafetyError:
            continue
        mid = 0.5 * (profile.model.joint_min_deg[5] + profile.model.joint_max_deg[5])
        costs.append((abs(q[5] - mid) + abs(q2[5] - mid) + 0.01 * abs(phi), float(phi)))
    if not costs:
        # report the reason for φ = 0
        solve_target(profile, plane, tool, centre, path, 0.0, ref, "centre", WRIST_MARGIN_DEG, turn)
        solve_target(
            profile, plane, tool, centre, path, 180.0, ref, "centre", WRIST_MARGIN_DEG, turn
        )
        raise SafetyError(
            "plan: no orientation about the beam reaches the plate centre in both senses"
        )
    first: SafetyError | None = None
    notes: list[str] = []
    plate = _Plate(profile, plane, pts, centre, tool, ref)
    tilt = beam_tilt_deg(profile)
    quarter = tilt > QUARTER_TURNS_TILT_DEG and profile.dh_std is None
    choices = [QUARTER_TURNS, HALF_TURNS] if quarter else [HALF_TURNS]
    for turns in choices:
        for _, phi0 in sorted(costs):
            notes = []
            try:
                peaks, edges, incidence = _plan_targets(plate, phi0, method, n_pts, notes, turns)
            except SafetyError as e:
                first = first or e
                continue
            break
        else:
            continue
        break
    else:
        assert first is not None
        raise SafetyError(
            f"{first}; no other orientation of the tool about the beam ({len(costs)} tried) "
            "passes either: "
            + reach_advice(profile, centre + path * plane.normal, "the plate (touch it again)")
        )
    if turns != choices[0]:
        notes.append(
            f"edge scans in two orientations only: the arm cannot follow them a quarter turn "
            f"apart. With the beam {tilt:.0f}° off the flange axis, the wrist's link lengths "
            "within the DH table's tolerance then carry the tool across the beam (ucal "
            "calibrate first narrows them)"
        )
    return ToolFramePlan(
        method,
        plane,
        centre,
        ref,
        phi0,
        tuple(peaks),
        tuple(edges),
        tuple(incidence),
        tuple(notes),
        turns if method == "exact" else HALF_TURNS,
    )


def beam_tilt_deg(profile: CellProfile) -> float:
    """How far the profile's beam (its tool frame's z) is from the flange axis (deg)."""
    return float(angle_between_deg(profile.tool_matrix[:3, 2], np.array([0.0, 0.0, 1.0])))


@dataclass(frozen=True)
class _Plate:
    """What every target is placed with: the profile, the touched points' plane, the points
    (n, 3), the plate centre, the tool (4, 4) and the reference joints of the IK choice."""

    profile: CellProfile
    plane: Plane
    points: np.ndarray
    centre: np.ndarray
    tool: np.ndarray
    ref: np.ndarray

    def parts(self) -> tuple[CellProfile, Plane, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(profile, plane, points, centre, tool, ref), for a function that uses them all."""
        return self.profile, self.plane, self.points, self.centre, self.tool, self.ref


def _plan_targets(
    plate: _Plate,
    phi0: float,
    method: str,
    n_pts: int,
    notes: list[str],
    turns: tuple[float, ...] = HALF_TURNS,
) -> tuple[list[Target], list[EdgePlan], list[Target]]:
    """The peaks and edge scans (exact method; the edges in orientations ``phi0`` turned by
    each of ``turns``) or the incidence points (paper method) in orientation ``phi0``
    (``SafetyError`` if one fails)."""
    profile, plane, _, centre, tool, ref = plate.parts()
    path = profile.procedure.water_path_mm
    turn = tool_turn_deg(profile)
    peaks: list[Target] = []
    if method != "exact":
        return [], [], _plan_incidence(plate, phi0, n_pts, notes)
    near = ref
    for i in range(n_pts):
        phi = phi0 + 360.0 * i / n_pts
        phi = (phi + 180.0) % 360.0 - 180.0
        label = f"peak {i + 1}"
        q = solve_target(
            profile, plane, tool, centre, path, phi, near, label, WRIST_MARGIN_DEG, turn
        )
        peaks.append(Target(label, centre, path, phi, q))
        near = q
    return peaks, _plan_edges(plate, phi0, notes, turns), []


def _plan_edges(
    plate: _Plate, phi0: float, notes: list[str], turns: tuple[float, ...]
) -> list[EdgePlan]:
    profile, plane, pts, centre, tool, ref = plate.parts()
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
                    for phi in (phi0 + t for t in turns):
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
                f"beyond {reach:.0f} mm from the touched points' hull in every "
                "orientation"
            )
        if reach < EDGE_SEARCH_MM:
            notes.append(
                f"edge search {label} limited to {reach:.0f} mm beyond the touched "
                "points by the arm's reach"
            )
        out.append(EdgePlan(axis, label, u, w, (-lat, lat), start, float(reach)))
    return out


def _plan_incidence(plate: _Plate, phi0: float, n_pts: int, notes: list[str]) -> list[Target]:
    profile, plane, pts, centre, tool, ref = plate.parts()
    rng = np.random.default_rng(2023)  # paper 002's year: a fixed, reproducible draw
    path0 = profile.procedure.water_path_mm
    turn = tool_turn_deg(profile)
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
            q = solve_target(
                profile, plane, tool, x, path, phi, near, label, WRIST_MARGIN_DEG, turn
            )
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
