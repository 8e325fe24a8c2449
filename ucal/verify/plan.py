"""Verify's plan: the nominal points, the commanded postures of both passes, checked before the
first motion.

``n`` points in up to three orientations of the tool (``point_groups``), each group a grid
spread over a plane parallel to the block's XY face: the beam straight down (paper 000's
points), ``VERIFY_HEIGHT_MM`` above it; the same beam with the tool turned 180° about it; and
the beam tilted ``TILT_DEG`` towards block +X over a patch ``TILTED_RAISE_MM`` higher. Each grid
stays ``EDGE_MARGIN_MM`` inside the XY face, with the wrist centre W ``WALL_PATH_MM`` of water
path from the YZ and XZ faces, so that each wall can be measured from every point. Coordinates
are block coordinates (mm). The "before" pass is commanded with the offsets and block pose the
profile had before its last calibration (``ucal.verify.inputs``), the "after" pass with its
current ones. The method: docs/method/commissioning.md.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from ucal.cell import PAPER_CALIBRATION_POSE_DEG, CellProfile
from ucal.errors import SafetyError, UcalError, UnreachableError
from ucal.kinematics.dh import fk_frames
from ucal.kinematics.ik import ik
from ucal.model import safety
from ucal.model.geometry import (
    FACE_NAMES,
    FACE_ORDER,
    CellGeometry,
    Face,
    FaceMeasurement,
    beam_and_tcp,
    distance_joints,
)
from ucal.model.readings import CalibrationReadings
from ucal.model.safety import EDGE_MARGIN_MM, MIN_WATER_PATH_MM, Margins
from ucal.model.spread import aim_spread, pose_spread
from ucal.model.targets import calibration_pose, geometry, tool_lever
from ucal.model.wrist import aim_wrist

log = logging.getLogger(__name__)

#: Paper 000, §5.2: the plane of the nominal points is 30 mm from the block's XY face.
VERIFY_HEIGHT_MM = 30.0
#: Paper 000, §5.2: twenty nominal points.
DEFAULT_POINTS = 20
#: Water path from the TCP to each wall (YZ, XZ face) when the wrist points at it (mm):
#: short enough for a strong echo at 25 MHz (−0.27 dB per mm), long enough for clearance.
WALL_PATH_MM = (50.0, 150.0)
PASSES = ("before", "after")
#: Tool check: the edge scans run this far beyond the XY face's far edge at most (mm).
EDGE_OVERSHOOT_MM = 15.0
#: The tilted group's beam: this far from straight down (deg), towards block +X ...
TILT_DEG = 15.0
#: ... its points this much higher above the XY face than the others (mm): a patch of its own.
TILTED_RAISE_MM = 30.0


def down_rotation_local() -> np.ndarray:
    """Tool orientation of the nominal points in block coordinates: tool z = −block z."""
    return np.diag([-1.0, 1.0, -1.0])


@dataclass(frozen=True)
class PointGroup:
    """Nominal points commanded in one tool orientation, over a patch of their own."""

    name: str  # "down", "turned", "tilted"
    description: str
    rotation_local: np.ndarray  # (3, 3) the tool's orientation, block coordinates
    height_mm: float  # the points' plane above the XY face


def point_groups(
    n_points: int, height_mm: float = VERIFY_HEIGHT_MM, turn_deg: float = 0.0
) -> list[tuple[PointGroup, int]]:
    """The orientations the points are commanded in and how many points each (module doc):
    the beam straight down (paper 000's), the tool turned 180° about that beam, and the beam
    tilted ``TILT_DEG`` towards block +X over a patch ``TILTED_RAISE_MM`` higher; one point
    takes the first, two the first two, more a third of them each for the others. Every
    group's tool is turned ``turn_deg`` more about its beam (the plan's choice of joint 6)."""
    if n_points < 1:
        raise ValueError(f"the number of points must be at least 1, got {n_points}")
    turn = Rotation.from_euler("z", turn_deg, degrees=True).as_matrix()
    about = f", the tool turned {turn_deg:g}° about it" if turn_deg else ""
    down = PointGroup("down", "beam straight down" + about, down_rotation_local() @ turn, height_mm)
    turned = PointGroup(
        "turned",
        f"beam straight down, the tool turned {(turn_deg + 180.0 + 180.0) % 360.0 - 180.0:g}° "
        "about it",
        down_rotation_local() @ np.diag([-1.0, -1.0, 1.0]) @ turn,
        height_mm,
    )
    tilted = PointGroup(
        "tilted",
        f"beam {TILT_DEG:g}° from straight down towards block +X" + about,
        Rotation.from_euler("y", -TILT_DEG, degrees=True).as_matrix()
        @ down_rotation_local()
        @ turn,
        height_mm + TILTED_RAISE_MM,
    )
    if n_points <= 2:
        return [(down, 1), (turned, 1)][:n_points]
    k = n_points // 3
    return [(down, n_points - 2 * k), (turned, k), (tilted, k)]


def grid_shape(n: int) -> tuple[int, int]:
    """Columns (along block X) and rows (along block Y) of an ``n``-point grid, most square
    first, more columns than rows (20 → 5 × 4, 4 → 2 × 2, 6 → 3 × 2, 7 → 7 × 1)."""
    if n < 1:
        raise ValueError(f"the number of points must be at least 1, got {n}")
    rows = max(r for r in range(1, math.isqrt(n) + 1) if n % r == 0)
    return n // rows, rows


@dataclass(frozen=True)
class Layout:
    """Where on the XY face the points go: ``wall_path_mm``, the water paths (mm) from W to the
    YZ and XZ faces the points span; ``side``, the block axis (0: X, 1: Y) along which they
    lie beyond a declared step."""

    wall_path_mm: tuple[float, float] = WALL_PATH_MM
    side: int = 0


def verify_region(
    profile: CellProfile,
    height_mm: float = VERIFY_HEIGHT_MM,
    rotation_local: np.ndarray | None = None,
    layout: Layout = Layout(),
) -> tuple[np.ndarray, np.ndarray]:
    """Lower and upper corner (block X, Y of the TCP, mm) of the area a grid spans with the tool
    turned ``rotation_local`` (block coordinates; default straight down).

    The TCP must lie ``EDGE_MARGIN_MM`` inside the XY face, and W must be ``wall_path_mm`` of
    water path (plus the lever a_T·v) from the YZ and XZ faces. With a ``[step]`` the area is
    the part beyond the step along block X (``side`` 0) or Y (1), clear of it by the block's
    tolerance margin: no point over the step, and the tool check's scans, which run from the
    points to the far edges, never cross it.
    """
    v, lever = tool_lever(profile)
    rot = down_rotation_local() if rotation_local is None else rotation_local
    r_flange = rot @ profile.tool_matrix[:3, :3].T
    w_from_tcp = -(r_flange @ v)  # W − TCP in block coordinates
    size = profile.sample_face_size_mm
    walls = layout.wall_path_mm
    side = layout.side
    lo = np.maximum(EDGE_MARGIN_MM, walls[0] + lever - w_from_tcp[:2])
    hi = np.minimum(size - EDGE_MARGIN_MM, walls[1] + lever - w_from_tcp[:2])
    if np.any(hi <= lo):
        raise SafetyError(
            f"no room for verification points on the XY face of the block "
            f"({size:g} mm faces, tool lever {lever:.1f} mm, walls "
            f"{walls[0]:g}–{walls[1]:g} mm away)"
        )
    step = profile.step
    if step is not None:
        clear = (
            step.centre_mm[side] + 0.5 * step.size_mm + safety.tolerance_margins(profile).block_mm
        )
        lo = lo.copy()
        lo[side] = max(lo[side], clear)
        if hi[side] <= lo[side]:
            raise SafetyError(
                f"no room for verification points on the XY face beyond the step along block "
                f"{'XY'[side]} (from {clear:.0f} mm, the points' area ends at {hi[side]:.0f} mm)"
            )
    return lo, hi


def nominal_points(
    profile: CellProfile,
    n: int,
    height_mm: float = VERIFY_HEIGHT_MM,
    rotation_local: np.ndarray | None = None,
    layout: Layout = Layout(),
) -> np.ndarray:
    """Nominal TCP positions (n, 3) in block coordinates (mm): a grid (``grid_shape``) over
    ``verify_region`` at ``height_mm`` above the XY face, in serpentine order (short moves)."""
    nx, ny = grid_shape(n)
    lo, hi = verify_region(profile, height_mm, rotation_local, layout)
    xs = np.linspace(lo[0], hi[0], nx) if nx > 1 else np.array([0.5 * (lo[0] + hi[0])])
    ys = np.linspace(lo[1], hi[1], ny) if ny > 1 else np.array([0.5 * (lo[1] + hi[1])])
    pts: list[list[float]] = []
    for j, y in enumerate(ys):
        row = xs if j % 2 == 0 else xs[::-1]
        pts.extend([x, y, height_mm] for x in row)
    return np.array(pts, float)


def target_matrix(
    profile: CellProfile, point_local_mm: np.ndarray, rotation_local: np.ndarray | None = None
) -> np.ndarray:
    """Tool pose (4, 4, base frame) of a nominal point given in block coordinates (mm), the
    tool turned ``rotation_local`` (block coordinates; default straight down)."""
    s_mat = profile.sample_matrix
    t = np.eye(4)
    t[:3, :3] = s_mat[:3, :3] @ (
        down_rotation_local() if rotation_local is None else rotation_local
    )
    t[:3, 3] = s_mat[:3, :3] @ np.asarray(point_local_mm, float) + s_mat[:3, 3]
    return t


@dataclass(frozen=True)
class VerifyTarget:
    """One commanded point of one pass, with the planned face postures."""

    pass_name: str  # "before" or "after"
    index: int  # 0-based point number
    joints_deg: np.ndarray  # (6,) commanded readings (TCP on the nominal point)
    face_joints_deg: np.ndarray  # (3, 6) planned normal-incidence postures, by face 0, 1, 2
    #: the tool's least water path to a face there as the profile's current offsets predict
    #: it (mm): a "before" point commanded with offsets degrees off may be in the block
    clearance_mm: float = np.inf

    @property
    def label(self) -> str:
        return f"{self.pass_name} {self.index + 1}"


@dataclass(frozen=True)
class IsoCube:
    """An ISO 9283 run's cube (``ucal.verify.iso9283``): centre (block coordinates, mm), side
    (mm) and the cycles its five poses are visited."""

    centre_mm: np.ndarray
    side_mm: float
    cycles: int


@dataclass(frozen=True)
class VerifyPlan:
    """Nominal points and the commanded postures of both passes."""

    nominal_mm: np.ndarray  # (n, 3) block coordinates
    height_mm: float  # of the points commanded straight down
    offsets_deg: dict[str, np.ndarray]  # offsets the IK of each pass used
    targets: tuple[VerifyTarget, ...]  # all "before" targets, then all "after"
    #: tool check: the block axis (0: X, 1: Y) of each edge scan and the point whose "after"
    #: posture it starts from (the down points' first, then the turned points')
    edge_points: tuple[tuple[int, int], ...] = ((0, 0), (1, 0))
    groups: tuple[PointGroup, ...] = ()
    group_of: tuple[int, ...] = ()  # each point's group
    #: calibrate's readings whose water paths are read again at the start and the end (one
    #: per face, ``ucal.verify.inputs.tank_reference``); None: none in the history
    tank: CalibrationReadings | None = None
    #: an ISO 9283 run (``verify --iso9283``): its cube; None: verify's points
    iso: IsoCube | None = None

    @property
    def tank_faces(self) -> tuple[FaceMeasurement, ...]:
        return () if self.tank is None else self.tank.faces

    @property
    def points(self) -> int:
        return len(self.nominal_mm)

    def rotation_local(self, index: int) -> np.ndarray:
        """The tool's commanded orientation at point ``index`` (block coordinates)."""
        return (
            self.groups[self.group_of[index]].rotation_local
            if self.groups
            else down_rotation_local()
        )


def wrist_centre_local(
    profile: CellProfile, joints_deg: np.ndarray, offsets_deg: np.ndarray
) -> np.ndarray:
    """The profile's wrist centre W at readings (6,) with ``offsets_deg``, block coordinates."""
    s_mat = profile.sample_matrix
    w = fk_frames(profile.model, np.asarray(joints_deg, float), offsets_deg)[4, :3, 3]
    return np.asarray(s_mat[:3, :3].T @ (w - s_mat[:3, 3]))


def tool_clearance_mm(profile: CellProfile, w_local_mm: np.ndarray) -> float:
    """The least water path (mm) the tool can have to a face while the wrist turns it about W
    (block coordinates): W's distance to the nearest face less the tool's reach from W."""
    v, _ = tool_lever(profile)
    return float(np.min(w_local_mm) - np.linalg.norm(v))


def undetermined_joints(profile: CellProfile) -> tuple[int, ...]:
    """The arm joints (0-based, of 1–3) whose offset the profile's last calibration left
    undetermined (``[calibration] std_deg`` not positive): the "after" pass stands where their
    true offsets put it, which the profile does not know (``FRESH_OFFSET_STD_DEG``). None
    for a profile never calibrated, whose "after" pass is its "before" one."""
    std = profile.joint_offsets_std_deg
    if std is None:
        return ()
    std = np.asarray(std, float)
    return tuple(j for j in range(3) if not (np.isfinite(std[j]) and std[j] > 0))


#: How a refusal names the offsets the last calibration left undetermined.
UNDETERMINED_WORDS = "not determined by the last calibration"


@dataclass(frozen=True)
class Undetermined:
    """``TOLERANCE_SIGMAS`` of what the undetermined arm offsets (``undetermined_joints``)
    can move the wrist centre and the tool centre at one posture, along each block axis (mm,
    (3,)), and the joint that moves them most."""

    joints: tuple[int, ...]
    wrist_mm: np.ndarray
    tcp_mm: np.ndarray
    joint: int | None

    def words(self, moved_mm: float) -> str:
        """How much of the room (mm) the undetermined offsets take, in words."""
        names = ", ".join(str(j + 1) for j in self.joints)
        return (
            f"{moved_mm:.1f} mm of it within what the offsets of joint(s) {names} ("
            f"{UNDETERMINED_WORDS}: [calibration] std_deg, unobservable_joints; "
            f"a fresh cell's ±{safety.FRESH_OFFSET_STD_DEG:g} deg one sigma) can move it "
            f"({safety.TOLERANCE_SIGMAS:g} sigma)"
        )

    def cure(self) -> str:
        """What would lift a refusal they cause."""
        assert self.joint is not None
        return f"a calibration that determines joint {self.joint + 1}'s offset would lift it"


def undetermined_spread(
    profile: CellProfile, q: np.ndarray, offsets_deg: np.ndarray
) -> Undetermined:
    """What the undetermined arm offsets can move W and the TCP at readings ``q`` (block
    axes, ``TOLERANCE_SIGMAS``, the joints added in variance); zero with none."""
    joints = undetermined_joints(profile)
    geom = geometry(profile)
    rot = profile.sample_matrix[:3, :3]
    var_w, var_t = np.zeros(3), np.zeros(3)
    most, worst = None, 0.0
    for j in joints:
        h = np.zeros(6)
        h[j] = safety.FRESH_OFFSET_STD_DEG
        frames = fk_frames(
            profile.model, np.array([q, q]), np.array([offsets_deg + h, offsets_deg - h])
        )
        dw = rot.T @ (frames[0, 4, :3, 3] - frames[1, 4, :3, 3]) / 2
        _, tcp = beam_and_tcp(geom, np.array([q, q]), np.array([offsets_deg + h, offsets_deg - h]))
        dt = rot.T @ (tcp[0] - tcp[1]) / 2
        var_w += dw**2
        var_t += dt**2
        if np.max(np.abs(dw)) > worst:
            most, worst = j, float(np.max(np.abs(dw)))
    k = safety.TOLERANCE_SIGMAS
    return Undetermined(joints, k * np.sqrt(var_w), k * np.sqrt(var_t), most)


def joints_for(
    profile: CellProfile,
    pose: np.ndarray,
    offsets_deg: np.ndarray,
    near_deg: np.ndarray,
    label: str,
    tolerance_deg: float = 0.0,
) -> np.ndarray:
    """Joint readings (deg) that put the profile's tool at ``pose`` (4, 4, base frame), nearest
    ``near_deg``, checked against the ranges with ``tolerance_deg`` more room on the wrist
    (``SafetyError`` naming ``label`` otherwise)."""
    try:
        q = ik(profile.model, pose, profile.tool_matrix, offsets_deg, near_deg=near_deg)
    except UnreachableError as e:
        raise SafetyError(f"{label}: {e}") from None
    safety.check_joints(profile, q, label, tolerance_deg=tolerance_deg)
    return q


def plan_verify(
    profile: CellProfile,
    n_points: int = DEFAULT_POINTS,
    height_mm: float = VERIFY_HEIGHT_MM,
    before_offsets_deg: np.ndarray | None = None,
    before_placed: CellProfile | None = None,
) -> VerifyPlan:
    """Plan and check every posture of both passes before the first motion.

    The "before" points are commanded with ``before_offsets_deg`` (zero if not given) in the
    block frame of ``before_placed`` (the block where the profile had it then; the current one
    if not given), the "after" points with the profile's offsets and block.

    Checks (``SafetyError``, exit 4): IK reaches each point inside the joint ranges; every
    commanded and planned face posture keeps ``SEARCH_MARGIN_DEG`` inside the wrist ranges and
    the θ5 singularity margin of the profile; each beam meets its face inside the edges; the
    wrist centre is far enough from each face that the TCP, turning about W, stays
    ``MIN_WATER_PATH_MM`` away from it; every check with the room the declared tolerances
    need (``tolerance_margins``); the "after" points' wrist centre and the tool check's ends
    with the room the arm offsets the last calibration left undetermined can take
    (``undetermined_spread``: the "after" pass stands where the true ones put it).

    Where the points as paper 000 places them fail a check, the plan's free choices are
    searched: the tool turned about the beam (``PLAN_TURNS_DEG``: joint 6 and, with a holder,
    the wrist), the points raised above the face (``PLAN_RAISES_MM``: room for a long tool
    or a holder turning about W), and with a ``[step]`` the side of it the points take.
    Refused only when no choice passes, naming what to move.
    """
    first: SafetyError | None = None
    sides = (0,) if profile.step is None else (0, 1)
    # turning an on-axis beam about itself turns joint 6 alone
    turns = PLAN_TURNS_DEG[:1] if safety.beam_on_flange_axis(profile) else PLAN_TURNS_DEG
    tried = 0
    # a choice refused for the offsets the calibration left undetermined, named beside the
    # first refusal (the other choices' checks may fail for other causes)
    undetermined: SafetyError | None = None
    for raise_mm in PLAN_RAISES_MM:
        for walls in PLAN_WALL_PATHS_MM:
            for turn in turns:
                for side in sides:
                    tried += 1
                    try:
                        return plan_choice(
                            profile,
                            n_points,
                            height_mm + raise_mm,
                            turn,
                            Layout(walls, side),
                            before_offsets_deg,
                            before_placed,
                        )
                    except SafetyError as e:
                        first = first or e
                        if undetermined is None and UNDETERMINED_WORDS in str(e):
                            undetermined = e
    s_mat = profile.sample_matrix
    _, lever = tool_lever(profile)
    w = s_mat[:3, :3] @ np.array([100.0, 100.0, height_mm + lever]) + s_mat[:3, 3]
    advice = safety.move_advice(profile, lambda moved: _plans_at_all(moved, height_mm), w)
    also = "" if undetermined in (None, first) else f"; another choice: {undetermined}"
    raise SafetyError(
        f"{first}{also}; none of the {tried - 1} other choices of the points' height, their area, "
        f"the tool's turn about the beam (and their side of the step) passes either: {advice}"
    )


def _plans_at_all(profile: CellProfile, height_mm: float) -> bool:
    """Whether two points in the first choice of every kind plan (the refusal's advice:
    would the block, moved, do?)."""
    try:
        plan_choice(profile, 2, height_mm, 0.0, Layout(), None, None)
    except SafetyError:
        return False
    return True


#: Raises of the points above ``height_mm`` (mm), areas (water paths from W to the walls, mm)
#: and turns of the tool about the beam (deg) the plan tries, in order, where the points as
#: paper 000 places them fail a check.
PLAN_RAISES_MM = (0.0, 20.0, 40.0)
PLAN_WALL_PATHS_MM = (WALL_PATH_MM, (45.0, 100.0), (40.0, 75.0))
PLAN_TURNS_DEG = (0.0, 90.0, -90.0, 45.0, -45.0, 135.0, -135.0, 180.0)


def plan_choice(
    profile: CellProfile,
    n_points: int,
    height_mm: float,
    turn_deg: float,
    layout: Layout,
    before_offsets_deg: np.ndarray | None,
    before_placed: CellProfile | None,
    given: tuple[PointGroup, np.ndarray] | None = None,
) -> VerifyPlan:
    """``plan_verify`` for one choice of height, turn and layout (``SafetyError`` if a check
    fails); ``given``: in place of the grids, these points (n, 3; block coordinates) in this
    group's orientation, commanded in the "after" pass alone (``ucal.verify.iso9283``)."""
    geom = geometry(profile)
    margins = safety.tolerance_margins(profile)
    if given is None:
        groups = point_groups(n_points, height_mm, turn_deg)
        nominal = np.concatenate(
            [nominal_points(profile, n, g.height_mm, g.rotation_local, layout) for g, n in groups]
        )
    else:
        groups = [(given[0], len(given[1]))]
        nominal = np.asarray(given[1], float)
        before_offsets_deg = np.array(profile.joint_offsets_deg, float)
    group_of = tuple(i for i, (_, n) in enumerate(groups) for _ in range(n))
    rotations = [groups[g][0].rotation_local for g in group_of]
    v, _ = tool_lever(profile)
    reach = float(np.linalg.norm(v))
    before = np.zeros(6) if before_offsets_deg is None else np.asarray(before_offsets_deg, float)
    offsets = {"before": before, "after": np.array(profile.joint_offsets_deg, float)}
    # each pass as its profile saw the cell (the block calibrate measured, or the one before)
    placed = {"before": before_placed or profile, "after": profile}
    geoms = {"before": geometry(placed["before"]), "after": geom}
    try:
        near = calibration_pose(profile)
    except UcalError:  # no computed pose reaches the block: the paper's as the reference
        near = PAPER_CALIBRATION_POSE_DEG
    targets: list[VerifyTarget] = []
    for pass_name in PASSES if given is None else PASSES[1:]:
        off = offsets[pass_name]
        seen, seen_geom = placed[pass_name], geoms[pass_name]
        prev = near
        for i, p in enumerate(nominal):
            label = f"{pass_name} point {i + 1}"
            pose = target_matrix(seen, p, rotations[i])
            q = joints_for(profile, pose, off, prev, f"plan {label}", margins.wrist_deg)
            w_local = wrist_centre_local(seen, q, off)
            # the "after" pass stands where the true offsets put it: those the calibration
            # left undetermined can bring W nearer a face than the profile says (a point in
            # the block, found only once the arm is there)
            unknown = undetermined_spread(profile, q, off) if pass_name == "after" else None
            kept = w_local if unknown is None else w_local - unknown.wrist_mm
            if tool_clearance_mm(profile, kept) < MIN_WATER_PATH_MM:
                k = int(np.argmin(kept))
                if unknown is None or unknown.joint is None or not unknown.wrist_mm[k] > 0:
                    raise SafetyError(
                        f"plan {label}: the wrist centre would be "
                        f"{np.min(w_local):.1f} mm from a face; the tool ({reach:.1f} "
                        f"mm from it) needs {MIN_WATER_PATH_MM:g} mm more"
                    )
                raise SafetyError(
                    f"plan {label}: the wrist centre would be {w_local[k]:.1f} mm from face "
                    f"{FACE_NAMES[k]}, {unknown.words(float(unknown.wrist_mm[k]))}; the tool "
                    f"({reach:.1f} mm from it) needs {MIN_WATER_PATH_MM:g} mm more: "
                    f"{unknown.cure()}"
                )
            faces = np.empty((3, 6))
            for k in FACE_ORDER:
                faces[k] = _face_posture(
                    profile, seen, seen_geom, q, Face(k), off, label, margins, geom
                )
            # where the robot really goes there, as best known: the profile's current offsets
            # and block
            w_now = wrist_centre_local(profile, q, offsets["after"])
            clear = tool_clearance_mm(profile, w_now)
            targets.append(VerifyTarget(pass_name, i, q, faces, clear))
            prev = q
    # tool check: each scan line, from the point of its group nearest the far edge to beyond
    # it, in the two senses about the beam (the down and the turned points) where there are
    edge_points: list[tuple[int, int]] = []
    for g in range(min(len(groups), 2)):
        members = np.flatnonzero(np.array(group_of) == g)
        edge_points += [(axis, int(members[np.argmax(nominal[members, axis])])) for axis in (0, 1)]
    after = [t for t in targets if t.pass_name == "after"]
    for axis, i in edge_points:
        end = nominal[i].copy()
        end[axis] = profile.sample_face_size_mm + EDGE_OVERSHOOT_MM
        # the scan runs on to where the edge really is (the block and the tool within their
        # tolerances) and holds the true beam on the face's normal (the tool's orientation
        # within its own): both ends checked with the room those need
        end[axis] += margins.block_mm
        # and on to where the point really is: the arm offsets the calibration left
        # undetermined move it as far (the run scans from the point as measured)
        end[axis] += undetermined_spread(profile, after[i].joints_deg, offsets["after"]).tcp_mm[
            axis
        ]
        label = edge_label(axis, groups[group_of[i]][0])
        for where, point in (("start", nominal[i]), ("end", end)):
            pose = target_matrix(profile, point, rotations[i])
            q = joints_for(profile, pose, offsets["after"], after[i].joints_deg, f"plan {label}")
            spread = pose_spread(profile, geom, pose, q, offsets["after"])
            safety.check_joints(profile, q, f"{label} ({where})", spread=spread)
    return VerifyPlan(
        nominal,
        float(height_mm),
        offsets,
        tuple(targets),
        tuple(edge_points),
        tuple(g for g, _ in groups),
        group_of,
    )


#: Turns of joint 6 (deg) a face posture may take from its point's, in order: with the beam
#: off the flange axis (a holder) joint 6 changes how far joint 5 must turn to aim it.
FACE_J6_TURNS_DEG = (0.0, 90.0, -90.0, 180.0, 45.0, -45.0, 135.0, -135.0)


def _face_posture(
    profile: CellProfile,
    seen: CellProfile,
    geom: CellGeometry,
    q: np.ndarray,
    face: Face,
    offsets_deg: np.ndarray,
    label: str,
    margins: Margins,
    now: CellGeometry,
) -> np.ndarray:
    """The checked normal-incidence posture of ``face`` from point readings ``q``: the wrist
    aims the beam with joint 6 at its reading, or turned by ``FACE_J6_TURNS_DEG`` where that
    fails a check and the beam is off the flange axis (``SafetyError``: the first failure).

    The posture returned is the pass's (``offsets_deg``, the block as ``seen``: where its
    search starts); the one checked is where the run aims the wrist, the cell as the profile
    now knows it (``now``, its current offsets: a "before" point's arm stands where the true
    offsets put it), with the room what the profile does not know can turn it by there
    (``aim_spread``)."""
    name = f"{label}/{FACE_NAMES[face]}"
    # the XY face at the paper's height: the run skips a point the cell as measured puts too
    # near it (``clearance_mm``); the walls keep the tolerances' room
    margin = 0.0 if face == Face.XY else margins.block_mm
    first: SafetyError | None = None
    turns = FACE_J6_TURNS_DEG if not safety.beam_on_flange_axis(profile) else FACE_J6_TURNS_DEG[:1]
    for turn in turns:
        start = q.copy()
        start[5] += turn
        try:
            qf = aim_wrist(geom, start, -geom.normal(face), offsets_deg)
            current = profile.joint_offsets_deg
            qr = aim_wrist(now, start, -now.normal(face), current)
            spread = aim_spread(profile, now, qr, face, current)
            safety.check_joints(profile, qr, name, spread=spread)
            safety.check_face(seen, geom, qf, face, offsets_deg, name, margin)
        except SafetyError as e:
            first = first or e
            continue
        return qf
    assert first is not None
    raise first


def edge_label(axis: int, group: PointGroup) -> str:
    """A scan of the tool check in words: "tool check along block X" (down points), "..., tool
    turned" (the turned points)."""
    return f"tool check along block {'XY'[axis]}" + (
        ", tool turned" if group.name == "turned" else ""
    )


def with_tank(plan: VerifyPlan, profile: CellProfile, tank: CalibrationReadings) -> VerifyPlan:
    """``plan`` reading calibrate's water paths ``tank.faces`` again at its start and end,
    each posture checked inside the joint ranges and the θ5 margin (no wrist search there, so
    no search margin); a posture that fails keeps the plan as it was, with a warning."""
    for m in tank.faces:
        try:
            safety.check_joints(profile, distance_joints(m), f"tank {m.config}", 0.0)
        except SafetyError as e:
            log.warning("the tank's sound speed is not read again: %s", e)
            return plan
    return replace(plan, tank=tank)


def plan_summary(plan: VerifyPlan, profile_path: Path) -> str:
    """The plan in words for the confirmation (stderr)."""
    lines = [
        f"verify {profile_path}: {plan.points} points x 2 passes (before/after calibration), "
        f"3 face searches per point ({6 * plan.points} in all):"
    ]
    for n, g in enumerate(plan.groups):
        pts = plan.nominal_mm[np.array(plan.group_of) == n]
        lo, hi = pts.min(0), pts.max(0)
        lines.append(
            f"  {len(pts)} points, {g.description}: block X {lo[0]:.0f}-{hi[0]:.0f} mm, "
            f"Y {lo[1]:.0f}-{hi[1]:.0f} mm, {g.height_mm:g} mm above the XY face"
        )
    senses = "in both senses about the beam" if len(plan.edge_points) > 2 else "straight down"
    lines.append(f"then a tool check across the XY face's two far edges, {senses}.")
    if plan.tank_faces:
        where = ", ".join(f"{m.config}/{FACE_NAMES[m.face]}" for m in plan.tank_faces)
        lines.append(
            f"The tank's sound speed: {len(plan.tank_faces)} of calibrate's water paths read "
            f"again where it read them ({where}), at the start and at the end "
            f"({2 * len(plan.tank_faces)} moves more)."
        )
    return "\n".join(lines)
