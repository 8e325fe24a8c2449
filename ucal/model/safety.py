"""Checks every planned target passes before the first motion (``SafetyError``, exit 4).

The limits are the procedures' common ones: room for the wrist search inside the joint ranges,
the θ5 singularity margin of the profile, a water path that keeps the tool clear of the face it
measures, a beam that meets the face inside its edges and clear of a declared step.

Margins. A plan is made on the profile's nominal values, but the run follows the cell as it
is: a block within its declared tolerances moves each posture's wrist (its faces turn) and its
water path and hit point (its faces shift). ``tolerance_margins`` turns the profile's declared
tolerances into what three sigma of them can move a posture, and the plans keep that much
room beyond the wrist search's and the clearances above, so that a block anywhere within its
tolerance plans and is measured without a check failing on the way.

The joint offsets. A plan's arm joints are the ones the run commands; the run re-aims the wrist
with the cell as measured so far, but the arm stands where the true offsets put it. A profile
that ``calibrate`` has not written knows its offsets to a degree or so
(``FRESH_OFFSET_STD_DEG``), which moves the tool centre by each joint's lever arm:
``offsets_margins_mm`` gives three sigma of that along the block's axes, posture by posture,
for the water path and the hit point of a plan that may run before the offsets are calibrated
(``ucal.model.postures``).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ucal.cell import CellProfile, Step
from ucal.errors import SafetyError
from ucal.kinematics.dh import fk_frames
from ucal.model.geometry import FACE_NAMES, CellGeometry, beam_and_tcp

# the planning margins' sigmas and the offsets' std are the spread's, named here as well
from ucal.model.spread import FRESH_OFFSET_STD_DEG as FRESH_OFFSET_STD_DEG
from ucal.model.spread import TOLERANCE_SIGMAS as TOLERANCE_SIGMAS
from ucal.model.spread import Spread, declared_spread
from ucal.model.spread import offsets_std_deg as offsets_std_deg

#: Room kept inside the joint ranges of joints 4–6 for a wrist search around a planned posture.
SEARCH_MARGIN_DEG = 8.0
#: Closest the tool centre may come to a face it measures (mm of water path).
MIN_WATER_PATH_MM = 20.0
#: Distance kept between the beam's hit point on a face and the face's edges (mm).
EDGE_MARGIN_MM = 20.0


@dataclass(frozen=True)
class Margins:
    """Room a plan keeps for what the declared tolerances can move a posture by (3σ)."""

    wrist_deg: float  # on joints 4-6, beyond the wrist search's ``SEARCH_MARGIN_DEG``
    block_mm: float  # on the water path, the distance to a face's edges and to a step


def tolerance_margins(profile: CellProfile) -> Margins:
    """What ``TOLERANCE_SIGMAS`` of the profile's declared tolerances can move a posture.

    The wrist turns the beam onto a face as the block's and the tool's orientations really
    are: by up to their tolerances' resultant (root sum of squares, deg). The water path and
    the hit point move with the block's corner and the tool centre, and with the block's tilt
    over the half face from the corner to the middle of a face (mm).
    """
    k = TOLERANCE_SIGMAS
    rot = np.hypot(
        np.linalg.norm(profile.sample_rotation_std_deg),
        np.linalg.norm(profile.tool_rotation_std_deg),
    )
    tilt_mm = (
        0.5 * profile.sample_face_size_mm * np.radians(np.max(profile.sample_rotation_std_deg))
    )
    shift = np.sqrt(
        np.max(profile.sample_position_std_mm) ** 2
        + np.max(profile.tool_position_std_mm) ** 2
        + tilt_mm**2
    )
    return Margins(float(k * rot), float(k * shift))


def offsets_margins_mm(profile: CellProfile, q: np.ndarray) -> np.ndarray:
    """``TOLERANCE_SIGMAS`` of the tool centre's displacement (mm) along each block axis
    (n, 3) that the offsets' uncertainty (``offsets_std_deg``) causes at readings ``q``
    (n, 6): per joint its std times the tool centre's motion per degree of it (the joint's
    lever arm), the joints' contributions added in variance."""
    geom = CellGeometry(profile.model, profile.tool_matrix, profile.sample_matrix[:3, :3])
    offsets = np.asarray(profile.joint_offsets_deg, float)
    q = np.atleast_2d(np.asarray(q, float))
    var = np.zeros((len(q), 3))
    for j, std in enumerate(offsets_std_deg(profile)):
        h = np.zeros(6)
        h[j] = 1e-3
        _, ahead = beam_and_tcp(geom, q, offsets + h)
        _, behind = beam_and_tcp(geom, q, offsets - h)
        var += ((ahead - behind) @ geom.block_rotation * (std / 2e-3)) ** 2
    return TOLERANCE_SIGMAS * np.sqrt(var)


def beam_on_flange_axis(profile: CellProfile, tol_deg: float = 1.0) -> bool:
    """The beam leaves the tool along the flange axis within ``tol_deg``: turning the tool
    about the beam then turns joint 6 alone (a plan need not try it for the wrist's sake)."""
    return bool(profile.tool_matrix[2, 2] > np.cos(np.radians(tol_deg)))


def check_joints(
    profile: CellProfile,
    q: np.ndarray,
    label: str,
    wrist_margin_deg: float = SEARCH_MARGIN_DEG,
    tolerance_deg: float = 0.0,
    spread: Spread | None = None,
    block_tolerance: bool = True,
    tool_cure: str | None = None,
) -> None:
    """Joint readings ``q`` (deg) inside the ranges, with ``wrist_margin_deg`` kept on joints
    4–6, and θ5 (kinematic, offsets applied) at least the profile's singularity margin from 0;
    ``tolerance_deg`` more on both (``Margins.wrist_deg``: what the declared tolerances can
    turn the wrist by; ``block_tolerance`` False: the tool's alone), or, given ``spread``
    (``ucal.model.spread``), each joint's own share of it. A refusal names the quantity
    that takes the room and the tolerance that would lift it (``tool_cure``: what would, for
    the tool, where not ``spread``'s words)."""
    model = profile.model
    if spread is None and tolerance_deg > 0:
        declared = declared_spread(profile, tolerance_deg, block_tolerance, tool_cure)
        if declared.parts:
            spread, tolerance_deg = declared, 0.0
    room = np.zeros(6)
    room[3:] = wrist_margin_deg + (tolerance_deg if spread is None else 0.0)
    if spread is not None:
        room = room + spread.deg
    lo = model.joint_min_deg + room
    hi = model.joint_max_deg - room
    bad = [j + 1 for j in range(6) if not lo[j] <= q[j] <= hi[j]]
    if bad and spread is not None:
        j = bad[0] - 1
        limit = model.joint_max_deg[j] if q[j] > hi[j] else model.joint_min_deg[j]
        left = abs(limit - q[j]) - (wrist_margin_deg if j >= 3 else 0.0)
        search = f"{wrist_margin_deg:g} deg for the wrist search and " if j >= 3 else ""
        raise SafetyError(
            f"plan {label}: joint {j + 1} at {q[j]:.2f} deg is {abs(limit - q[j]):.1f} deg "
            f"from its limit ({limit:g} deg), short of the {room[j]:.3g} deg kept: "
            f"{search}{spread.words(j, left)}"
        )
    why = "for the wrist search" + (" and the declared tolerances" if tolerance_deg else "")
    if bad:
        raise SafetyError(
            f"plan {label}: joint(s) {bad} at "
            f"{np.round(q[np.array(bad) - 1], 2).tolist()} deg leave the joint "
            f"range (keeping {wrist_margin_deg + tolerance_deg:.3g} deg on joints 4-6 {why})"
        )
    theta5 = q[4] + model.theta_offset_deg[4] + profile.joint_offsets_deg[4]
    singular = profile.procedure.singularity_margin_deg
    margin = singular + (tolerance_deg if spread is None else float(spread.deg[4]))
    if abs(np.sin(np.radians(theta5))) < np.sin(np.radians(margin)):
        if spread is not None:
            left = float(np.degrees(np.arcsin(abs(np.sin(np.radians(theta5)))))) - singular
            raise SafetyError(
                f"plan {label}: joint 5 at {theta5:.2f} deg is within {margin:.3g} deg of the "
                f"wrist singularity: {singular:g} deg the profile's margin ([procedure] "
                f"singularity_margin_deg) and {spread.words(4, left)}"
            )
        raise SafetyError(
            f"plan {label}: joint 5 at {theta5:.2f} deg is within {margin:.3g} deg "
            "of the wrist singularity"
        )


def shift_words(profile: CellProfile, margin_mm: float, kept_mm: float, found_mm: float) -> str:
    """What takes ``margin_mm`` (``Margins.block_mm``) beyond the ``kept_mm`` a check keeps,
    where it found ``found_mm``, in words: the declared tolerance with the largest share (the
    block's position, the tool's, the block's tilt over half a face, as ``tolerance_margins``
    adds them) and the one that would lift the refusal; "" without a margin."""
    if not margin_mm > 0:
        return ""
    k = TOLERANCE_SIGMAS
    half = 0.5 * profile.sample_face_size_mm
    quantities = [
        (
            float(np.max(profile.sample_position_std_mm)),
            1.0,
            "mm",
            "the block's position known to ±{std:g} mm one sigma ([sample] position_std_mm)",
            "the block placed better (a fixture, [sample] position_std_mm)",
        ),
        (
            float(np.max(profile.tool_position_std_mm)),
            1.0,
            "mm",
            "the tool's position known to ±{std:g} mm one sigma ([tool] position_std_mm)",
            "the tool's position known better (`ucal tool-frame`, [tool] position_std_mm)",
        ),
        (
            float(np.max(profile.sample_rotation_std_deg)),
            half * np.pi / 180.0,
            "deg",
            "the block's tilt known to ±{std:g} deg one sigma over half a face ([sample] "
            "rotation_std_deg)",
            "the block's orientation known better (a fixture, [sample] rotation_std_deg)",
        ),
    ]
    parts = [k * std * per for std, per, *_ in quantities]
    total = float(np.sqrt(np.sum(np.square(parts))))
    if not total > 0:
        return ""
    parts = [margin_mm * x / total for x in parts]  # as the caller's margin adds them
    i = int(np.argmax(parts))
    std, _, unit, what, cure = quantities[i]
    said = (
        f": {kept_mm:g} mm and {margin_mm:.3g} mm for where the declared tolerances can put "
        f"it ({k:g} sigma), {parts[i]:.3g} mm of that from {what.format(std=std)}"
    )
    room = found_mm - kept_mm
    rest = float(np.sqrt(max(margin_mm**2 - parts[i] ** 2, 0.0)))
    if room <= rest:
        return f"{said}; no tolerance of it would lift this: another posture or block placement"
    lifted = std * np.sqrt(room**2 - rest**2) / parts[i]
    return f"{said}; {cure} to ±{float(lifted):.2g} {unit} or less would lift it"


def face_hit(
    geom: CellGeometry,
    q: np.ndarray,
    offsets_deg: np.ndarray,
    corner_mm: np.ndarray,
    face: int,
    face_size_mm: float,
) -> tuple[float, float]:
    """Where the beam at readings ``q`` meets ``face`` of a block with its corner at
    ``corner_mm``: the water path (mm, tool centre to the face along its normal) and the hit
    point's distance from the face's nearest edge (mm)."""
    beam, tcp = beam_and_tcp(geom, q, offsets_deg)
    local = geom.block_rotation.T @ (tcp - corner_mm)
    path = float(local[face])
    hit = local + path * (geom.block_rotation.T @ beam)
    edge = min(min(hit[i], face_size_mm - hit[i]) for i in range(3) if i != face)
    return path, float(edge)


def check_face(
    profile: CellProfile,
    geom: CellGeometry,
    q: np.ndarray,
    face: int,
    offsets_deg: np.ndarray,
    label: str,
    margin_mm: float = 0.0,
) -> float:
    """The beam at ``q`` meets ``face`` of the profile's block inside its edges
    (``EDGE_MARGIN_MM``) with the tool at least ``MIN_WATER_PATH_MM`` from it, each with
    ``margin_mm`` more, and passes a declared step ``margin_mm`` clear (``step_blocked``); the
    water path (mm). ``SafetyError`` naming ``label`` otherwise."""
    corner = profile.sample_matrix[:3, 3]
    path, edge = face_hit(geom, q, offsets_deg, corner, face, profile.sample_face_size_mm)
    name = FACE_NAMES[face]
    least = MIN_WATER_PATH_MM + margin_mm
    if path < least:
        raise SafetyError(
            f"plan {label}: the tool centre would be {path:.1f} mm from face {name} "
            f"(minimum {least:.3g} mm{shift_words(profile, margin_mm, MIN_WATER_PATH_MM, path)})"
        )
    if edge < EDGE_MARGIN_MM + margin_mm:
        raise SafetyError(
            f"plan {label}: the beam would meet face {name} {edge:.1f} mm from its edge "
            f"(minimum {EDGE_MARGIN_MM + margin_mm:.3g} mm"
            f"{shift_words(profile, margin_mm, EDGE_MARGIN_MM, edge)})"
        )
    if beam_meets_step(profile, geom, q, offsets_deg, corner, face, margin_mm):
        assert profile.step is not None
        raise SafetyError(
            f"plan {label}: the beam to face {name} would pass within {margin_mm:.3g} mm "
            f"of the step (block x, y {np.round(profile.step.centre_mm, 1).tolist()} mm, "
            f"{profile.step.height_mm:g} mm high)"
        )
    return path


def beam_meets_step(
    profile: CellProfile,
    geom: CellGeometry,
    q: np.ndarray,
    offsets_deg: np.ndarray,
    corner_mm: np.ndarray,
    face: int,
    margin_mm: float,
) -> bool:
    """Whether the beam at readings ``q``, aimed at ``face`` of a block with its corner at
    ``corner_mm``, comes within ``margin_mm`` of the profile's step (``step_blocked``; False
    without a step)."""
    if profile.step is None:
        return False
    beam, tcp = beam_and_tcp(geom, q, offsets_deg)
    rot = geom.block_rotation
    local = (rot.T @ (tcp - corner_mm))[None]
    return bool(
        step_blocked(profile.step, local, (rot.T @ beam)[None], np.array([face]), margin_mm)[0]
    )


def step_blocked(
    step: Step,
    tcp_local: np.ndarray,
    beam_local: np.ndarray,
    faces: np.ndarray,
    margin_mm: float | np.ndarray,
) -> np.ndarray:
    """Which beams (n,) come within ``margin_mm`` (one value, or one per beam) of ``step``
    between the tool centre and the face they are aimed at: the step's top and sides, grown
    by the margin, against points along each beam (tool centres (n, 3) and beam directions
    (n, 3) in block coordinates, ``faces`` (n,) the face each meets). A beam aimed at the XY
    face beside the step, a tool over it or a beam to a wall that grazes it are all blocked."""
    n = len(tcp_local)
    depth = tcp_local[np.arange(n), faces]
    t = np.linspace(0.0, 1.0, 24)
    path = tcp_local[:, None, :] + t[None, :, None] * depth[:, None, None] * beam_local[:, None]
    margin = np.reshape(np.asarray(margin_mm, float), (-1, 1))
    half = 0.5 * step.size_mm + margin[..., None]
    near = np.all(np.abs(path[..., :2] - step.centre_mm) <= half, -1)
    return np.asarray(np.any(near & (path[..., 2] < step.height_mm + margin), 1))


def reach_advice(profile: CellProfile, point_mm: np.ndarray, what: str) -> str:
    """What to move, and by how much, for the wrist centre to reach ``point_mm`` (base frame)
    with room to spare: ``what`` (e.g. "the block") towards the robot or away from it when
    the point is beyond or inside the arm's reach (shoulder to wrist centre, mm), otherwise
    towards the middle of that reach, or a shorter tool or holder."""
    model = profile.model
    azimuth = np.degrees(np.arctan2(point_mm[1], point_mm[0]))
    shoulder = fk_frames(model, np.array([azimuth, 0.0, 0.0, 0.0, 0.0, 0.0]))[1, :3, 3]
    upper = abs(model.a_mm[1])
    fore = float(np.hypot(model.a_mm[2], model.d_mm[3]))
    far, near = upper + fore, abs(upper - fore)
    r = float(np.linalg.norm(np.asarray(point_mm, float) - shoulder))
    middle = 0.5 * (near + far)
    room = 0.1 * (far - near)  # a wrist at the edge of the reach leaves the arm no freedom
    if r > far - room:
        return (
            f"the wrist would be {r:.0f} mm from the shoulder, the arm reaches {far:.0f} mm: "
            f"move {what} about {r - far + room:.0f} mm towards the robot"
        )
    if r < near + room:
        return (
            f"the wrist would be {r:.0f} mm from the shoulder, within {near + room:.0f} mm: "
            f"move {what} about {near + room - r:.0f} mm away from the robot"
        )
    return (
        f"within the arm's reach ({r:.0f} mm from the shoulder), the joint ranges, the wrist "
        f"and the clearances leave no posture: move {what} about {abs(r - middle):.0f} mm "
        f"{'towards' if r > middle else 'away from'} the robot, or mount a shorter tool or a "
        "straighter holder"
    )


#: Shifts of the block (mm) ``block_shift_advice`` tries, nearest first.
SHIFTS_MM = tuple(range(25, 625, 25))


def block_shift_advice(
    profile: CellProfile, passes: Callable[[CellProfile], bool], what: str = "the block"
) -> str | None:
    """The least move of the block, towards or away from the robot (horizontally, along the
    line from joint 1's axis to its corner) or up or down, with which ``passes`` holds for the
    profile with the block moved, in words; None if no move of up to 600 mm does."""
    corner = np.asarray(profile.sample_position_mm, float)
    radial = np.array([corner[0], corner[1], 0.0])
    radial = radial / max(float(np.linalg.norm(radial)), 1e-9)
    directions = (
        (-radial, "towards the robot"),
        (radial, "away from the robot"),
        (np.array([0.0, 0.0, 1.0]), "up"),
        (np.array([0.0, 0.0, -1.0]), "down"),
    )
    for shift in SHIFTS_MM:
        for direction, words in directions:
            moved = profile.replace(sample_position_mm=corner + shift * direction)
            if passes(moved):
                return f"move {what} about {shift} mm {words}"
    return None


def move_advice(
    profile: CellProfile,
    passes: Callable[[CellProfile], bool],
    wrist_mm: np.ndarray,
    what: str = "the block",
) -> str:
    """What a refusal tells to move: the least move of ``what`` with which ``passes`` holds
    (``block_shift_advice``), else where the arm's reach puts the wrist centre ``wrist_mm``
    the plan needs (``reach_advice``)."""
    return block_shift_advice(profile, passes, what) or reach_advice(profile, wrist_mm, what)
