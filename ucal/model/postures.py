"""Postures for ``calibrate --level full``: candidates spread over what the block allows, chosen by
D-optimality.

Candidates. For each block face, beam normal to it (tool z = −n), the beam meeting the face on
a grid of points inside its edges (``EDGE_MARGIN_MM``), at water paths across
``STEPPED_PATH_RANGE_MM``, turned about the beam by several angles; every in-range branch of the
inverse kinematics (shoulder, elbow, wrist flip) of each such tool pose is a candidate. So the
candidates differ in J1 azimuth (where on a face), in J2/J3 (water path, height, elbow
branch) and in the wrist (turn about the beam, flip). Each passes the checks of the offsets
level before it is considered: joint ranges with room for the wrist search (and on joints 1-3
for the offsets' error, ``_arm_room``), the θ5 singularity
margin, the beam inside the face, and a tool that keeps ``CLEARANCE_MM`` from every face's
plane where the face is (no collision with the block), each with the room three sigma of the
declared tolerances can move a posture by (``ucal.model.safety.tolerance_margins``): a
block anywhere within its tolerance is measured without a posture leaving the checks.

Criterion. A candidate contributes three rows to the data Jacobian ``J`` (two tilts and the
water path, each in units of its σ; columns per prior σ, ``ucal.model.kinematic``). The
information of a plan is ``M = I + Σ JᵢᵀJᵢ`` (the identity: the priors); the D-criterion is
``log det M`` over the unknowns, and its value per unknown, ``D = log det M / (2n)``, is the
mean log of how many times the plan shrinks the prior's σ (geometric mean). Selection is
greedy (Fedorov's exchange without the exchange): the candidate that raises ``log det M`` most,
``log det(I₃ + Jᵢ M⁻¹ Jᵢᵀ)`` (matrix determinant lemma), is added until the next one adds less
than ``MIN_GAIN`` (then more postures buy little: fewer moves for the same criterion).

Order. The run moves each posture's arm so that the tool stands where the plan put it relative
to the cell as measured so far (``ucal.measure.postures.retarget``); what it does not know
yet moves the tool from there. Each posture, when the run gets to it, must keep room for three
sigma of that (``visit_order``): what the block's tolerance and the offsets' uncertainty move
the tool centre by along each block axis (``ucal.model.safety.offsets_margins_mm``: a
fresh cell's offsets are known to a degree, tens of millimetres on a TX90XL), times the share
of the posture's water-path std that the faces measured before it leave (the run's estimate,
prior-augmented, has error covariance ``M⁻¹(P + HᵀH)M⁻¹`` with ``M = I + HᵀH`` and ``P`` the
cell's real spread in units of the fit's priors). The water path stays between
``MIN_WATER_PATH_MM`` and the echo's ``STEPPED_PATH_RANGE_MM`` bound, the beam inside the
face's edges and the step's top. The postures are visited lowest J1 first, then nearest next,
among those that have the room; where none has it yet, the candidate that has it and adds most
information is visited first (a lead-in). The region check (``ucal.verify.region``), measured
by the same run, orders its spread postures here too.

Offsets first. On a profile whose offsets were never calibrated (no ``[calibration] std_deg``)
the plan's arm joints are the nominal offsets', and a fresh cell's are degrees from them: the
tool centre stands tens of millimetres from where the plan put it, the beam degrees off
normal. The run re-places each posture with the offsets measured so far, but the faces of two
or three postures far apart do not yet measure six offsets, the block and the tool: the
prior-augmented estimate puts the directions they leave free wherever their noise and what
the model lacks (the beam's squint) push it, degrees on J2-J5; the next posture is re-placed
tens of millimetres and degrees off, and its search, ±8° about that prediction, centres on a
side lobe, or near a face's edge on the neighbouring face's echo, and the run stops. So the
full level on such a profile first measures what the offsets level measures
(``offsets_first``: its plan, the calibration pose's faces with J3, J2 and J1 stepped, the
steps chosen as the run goes), the sequence made to find a fresh cell's faces from its nominal
offsets: every posture after it is placed with measured offsets, its room computed with their
information (``visit_order``'s ``known``). The model is identified from the postures' faces,
chosen as before (solved with them too, the calibration pose's faces pulled offsets beyond
three sigma of a simulated cell's truth: what the model lacks there outweighs their share of
the information). Where no calibration pose reaches the block (the offsets level would refuse
it), the plan says so and goes without, each posture keeping the room the unknown offsets
need as below.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, replace

import numpy as np

from ucal.cell import PAPER_CALIBRATION_POSE_DEG, CellProfile
from ucal.errors import SafetyError, UcalError
from ucal.kinematics.dh import fk_frames
from ucal.kinematics.ik import ik_solutions
from ucal.model.fit import BACKLASH, OFFSETS, CellPrior, prior_from_profile
from ucal.model.geometry import FACE_NAMES, Face
from ucal.model.kinematic import (
    Identifiability,
    data_jacobian,
    full_table,
    ideal_measurements,
    identifiability,
)
from ucal.model.safety import (
    EDGE_MARGIN_MM,
    MIN_WATER_PATH_MM,
    SEARCH_MARGIN_DEG,
    TOLERANCE_SIGMAS,
    check_joints,
    offsets_margins_mm,
    offsets_std_deg,
    reach_advice,
    step_blocked,
    tolerance_margins,
)
from ucal.model.targets import (
    STEPPED_PATH_RANGE_MM,
    CalibrationPlan,
    calibration_pose,
    geometry,
    plan_calibration,
)

log = logging.getLogger(__name__)

#: Grid of beam hit points across a face (per in-plane axis), water paths (mm), turns about the
#: beam (deg) of the candidates.
HIT_GRID = 4
WATER_PATHS_MM = (60.0, 100.0, 140.0)
TURNS_DEG = (-90.0, 0.0, 90.0, 180.0)
#: Least distance (mm) of the tool centre and the flange from the plane of a face they are over.
CLEARANCE_MM = 30.0
#: Candidates keep joint 1 within this of the calibration pose's (the shoulder branch the
#: block is set up for; the other would swing the arm over the robot's base).
SHOULDER_SPAN_DEG = 60.0
#: Selection stops when the next posture would raise log det M by less than this: it would
#: shrink the volume of the uncertainty ellipsoid by less than a factor e (the knee: beyond it
#: more postures mostly average noise).
MIN_GAIN = 1.0
#: At most this many postures (each is a face search: ~23 moves on a cell).
MAX_POSTURES = 60
#: Room (deg) kept beyond the wrist search's on joints 4-6: the run predicts each posture with
#: the cell as measured so far, which moves it by up to a few tenths of a degree.
PLAN_MARGIN_DEG = 2.0
#: Postures reached from above (``postures_from_above``) may raise an offset's planned std by
#: this factor at most, and must leave each lost motion they see this share of its prior's.
OFFSET_STD_GROWTH = 1.1
LOST_MOTION_SHARE = 0.25
#: σ assumed for planning: posture (deg) and water path (mm) of one measurement.
PLAN_TILT_STD_DEG = 1e-3
PLAN_DISTANCE_STD_MM = 1e-3
#: The beam meets the XY face at least this far (mm) from the step's sides (its footprint and
#: the search's tilts stay off the step), and the step's top this far inside its sides.
STEP_MARGIN_MM = 30.0
STEP_INSIDE_MM = 10.0


@dataclass(frozen=True)
class Posture:
    """One planned normal-incidence posture."""

    label: str
    face: Face
    joints_deg: np.ndarray
    water_path_mm: float
    #: The beam meets the top of the step on the XY face, not the face itself.
    step: bool = False

    @property
    def face_name(self) -> str:
        return "step" if self.step else FACE_NAMES[self.face]


@dataclass(frozen=True)
class FullPlan:
    """The chosen postures, in execution order, and what the criterion says of them."""

    postures: tuple[Posture, ...]
    candidates: int
    d_criterion: float  # log det M / (2n): mean log-shrink of the prior σ
    log_det: float
    azimuths_deg: tuple[float, float]  # J1 range covered
    #: What the data could identify from every candidate: what no posture the block allows
    #: can see (``solve_full``'s ``structure``).
    structure: Identifiability | None = None
    #: Labels of the postures reached from above on every joint (``postures_from_above``):
    #: each joint read from both sides, its lost motion measured.
    above: tuple[str, ...] = ()
    #: The offsets level's plan, measured before the postures on a profile whose offsets
    #: were never calibrated (``offsets_first``); None where ``calibrate`` wrote them.
    first: CalibrationPlan | None = None

    def describe(self) -> str:
        lo, hi = self.azimuths_deg
        first = (
            ""
            if self.first is None
            else f"the calibration pose's {len(self.first.targets)} faces first (the offsets "
            "never calibrated), then "
        )
        return (
            f"{first}{len(self.postures)} postures chosen from {self.candidates} candidates by "
            f"D-optimality: log det M = {self.log_det:.1f}, D = {self.d_criterion:.3f} "
            f"(prior σ shrunk {np.exp(self.d_criterion):.1f}× on geometric mean); J1 from "
            f"{lo:.1f} to {hi:.1f} deg"
        )


def _target_pose(
    s_rot: np.ndarray,
    corner: np.ndarray,
    face: int,
    u: float,
    v: float,
    path: float,
    turn_deg: float,
) -> np.ndarray:
    """Tool pose with the beam normal to ``face`` hitting it at in-plane (u, v), ``path`` away."""
    others = [i for i in range(3) if i != face]
    n = s_rot[:, face]
    hit = corner + u * s_rot[:, others[0]] + v * s_rot[:, others[1]]
    z = -n
    x0 = s_rot[:, others[0]]
    t = np.radians(turn_deg)
    x = np.cos(t) * x0 + np.sin(t) * np.cross(z, x0)
    pose = np.eye(4)
    pose[:3, :3] = np.column_stack([x, np.cross(z, x), z])
    pose[:3, 3] = hit + path * n
    return pose


def _arm_clear(profile: CellProfile, q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Which postures (n, 6) keep the arm ``CLEARANCE_MM`` from the block and its table; the
    checked points in the block frame (n, 11, 3; index 5: the tool centre); the tool frames.

    Checked points: the origins of frames 2-6, the midpoints of the links between them and the
    tool centre. None may be below the XY face's plane plus the clearance (the block stands on
    a table that extends beyond it), and none may be within the clearance of a wall (YZ, XZ
    face) it is over.
    """
    s = profile.sample_matrix
    frames = fk_frames(profile.model, q, profile.joint_offsets_deg)
    tcp = frames[:, 6] @ profile.tool_matrix
    size = profile.sample_face_size_mm
    origins = np.concatenate([frames[:, 2:7, :3, 3], tcp[:, None, :3, 3]], 1)  # (n, 6, 3)
    points = np.concatenate([origins, 0.5 * (origins[:, 1:] + origins[:, :-1])], 1)
    local = (points - s[:3, 3]) @ s[:3, :3]
    ok = np.all(local[..., 2] >= CLEARANCE_MM, 1)
    for k in (0, 1):
        others = [i for i in range(3) if i != k]
        over = np.all(
            (local[..., others] >= -CLEARANCE_MM) & (local[..., others] <= size + CLEARANCE_MM), -1
        )
        ok &= ~np.any(over & (local[..., k] < CLEARANCE_MM), 1)
    step = profile.step
    if step is not None:  # nothing within the clearance of the step's top, nor over its sides
        half = 0.5 * step.size_mm + CLEARANCE_MM
        over = np.all(np.abs(local[..., :2] - step.centre_mm) <= half, -1)
        ok &= ~np.any(over & (local[..., 2] < step.height_mm + CLEARANCE_MM), 1)
    return ok, local, tcp


def _clear(
    profile: CellProfile, q: np.ndarray, faces: np.ndarray, margin_mm: float | np.ndarray
) -> np.ndarray:
    """Which postures (n, 6) keep the arm clear of the block (``_arm_clear``), with the beam
    meeting its face (n,) ``margin_mm`` more than ``EDGE_MARGIN_MM`` inside the edges (one
    value, or one per posture and block axis (n, 3): how far the tool centre may stand from
    where it is planned)."""
    s = profile.sample_matrix
    size = profile.sample_face_size_mm
    ok, local, tcp = _arm_clear(profile, q)
    here = local[:, 5]
    beam = tcp[:, :3, 2] @ s[:3, :3]
    hit = here + here[np.arange(len(q)), faces][:, None] * beam
    margin = np.broadcast_to(np.asarray(margin_mm, float), hit.shape)
    edge = EDGE_MARGIN_MM + margin
    inside = (hit >= edge) & (hit <= size - edge)
    inside[np.arange(len(q)), faces] = True
    ok &= np.all(inside, 1)
    step = profile.step
    if step is not None:
        # the beam meets the step's top well inside it, or passes the step well clear
        half = 0.5 * step.size_mm
        centre = np.abs(hit[:, :2] - step.centre_mm)
        on_top = (faces == 2) & np.all(centre <= half, 1)
        ok &= ~on_top | np.all(centre <= half - STEP_INSIDE_MM - margin[:, :2], 1)
        across = np.maximum(STEP_MARGIN_MM, margin[:, :2].max(1))
        crosses = step_blocked(step, here, beam, faces, across)
        ok &= ~crosses | on_top
    return ok


def _arm_room(profile: CellProfile, q: np.ndarray) -> np.ndarray:
    """Which postures (n, 6) keep joints 1-3 ``TOLERANCE_SIGMAS`` of the offsets' planning std
    (``offsets_std_deg``) inside their ranges: the run re-places each posture's arm with the
    offsets as measured (``ucal.measure.postures.retarget``), which moves those joints by
    the offsets' error in the profile; a posture at a limit would have no solution on its
    branch."""
    room = TOLERANCE_SIGMAS * offsets_std_deg(profile)[:3]
    model = profile.model
    arm = q[:, :3]
    return np.asarray(
        np.all((arm >= model.joint_min_deg[:3] + room) & (arm <= model.joint_max_deg[:3] - room), 1)
    )


def candidate_postures(profile: CellProfile) -> list[Posture]:
    """Every checked candidate (module docstring), labelled ``c<n>``."""
    s = profile.sample_matrix
    size = profile.sample_face_size_mm
    grid = np.linspace(EDGE_MARGIN_MM + 30.0, size - EDGE_MARGIN_MM - 30.0, HIT_GRID)
    lo, hi = STEPPED_PATH_RANGE_MM
    paths = [p for p in WATER_PATHS_MM if lo <= p <= hi]
    poses, keys = [], []
    for face in range(3):
        for u in grid:
            for v in grid:
                for path in paths:
                    for turn in TURNS_DEG:
                        poses.append(_target_pose(s[:3, :3], s[:3, 3], face, u, v, path, turn))
                        keys.append((face, path, False))
    step = profile.step
    if step is not None:  # the beam normal to the step's top, at its centre
        top = s[:3, 3] + step.height_mm * s[:3, 2]
        for path in paths:
            for turn in TURNS_DEG:
                u, v = step.centre_mm
                poses.append(_target_pose(s[:3, :3], top, 2, u, v, path, turn))
                keys.append((2, path, True))
    try:
        near = calibration_pose(profile)
    except UcalError:  # no computed pose reaches the block: the paper's as the reference
        near = PAPER_CALIBRATION_POSE_DEG
    sols, ok, _ = ik_solutions(
        profile.model,
        np.array(poses),
        profile.tool_matrix,
        profile.joint_offsets_deg,
        near_deg=near,
    )
    # the other shoulder would swing the arm over the robot's base
    ok &= np.abs(sols[..., 0] - near[0]) <= SHOULDER_SPAN_DEG
    pose_i, branch = np.nonzero(ok)
    q = sols[pose_i, branch]
    faces = np.array([keys[i][0] for i in pose_i], int)
    margins = tolerance_margins(profile)
    passed = _clear(profile, q, faces, margins.block_mm) & _arm_room(profile, q)
    out: list[Posture] = []
    for i in np.flatnonzero(passed):
        try:
            check_joints(
                profile,
                q[i],
                "candidate",
                SEARCH_MARGIN_DEG + PLAN_MARGIN_DEG,
                tolerance_deg=margins.wrist_deg,
            )
        except SafetyError:
            continue
        _, path, on_step = keys[pose_i[i]]
        if path < MIN_WATER_PATH_MM + margins.block_mm:  # a block 3σ nearer than declared
            continue
        out.append(Posture(f"c{len(out)}", Face(int(faces[i])), q[i].copy(), path, on_step))
    return out


def posture_jacobians(
    prior: CellPrior, profile: CellProfile, postures: list[Posture]
) -> tuple[np.ndarray, tuple[str, ...]]:
    """Data Jacobian of each posture (n, 3, p): its three rows (tilts, water path, per σ)
    against the unknowns of ``full_table`` (per prior σ), at the profile's values; and the
    unknowns' names. A posture over the step has only its water path row (its tilts are not
    used: ``ucal.model.kinematic.step_residuals``)."""
    meas = ideal_measurements(
        geometry(profile),
        profile.sample_position_mm,
        [(p.label, p.face, p.joints_deg) for p in postures],
        profile.joint_offsets_deg,
        PLAN_DISTANCE_STD_MM,
        PLAN_TILT_STD_DEG,
    )
    on_step = np.array([p.step for p in postures], bool)
    faces = [m for m, o in zip(meas, on_step, strict=True) if not o]
    # over the step the water path ends on its top (the Jacobian's sound speed column is the
    # path itself: the step's height is what sets the scale)
    height = 0.0 if profile.step is None else profile.step.height_mm
    steps = [
        replace(m, distance_mm=m.distance_mm - height)
        for m, o in zip(meas, on_step, strict=True)
        if o
    ]
    jac, names = data_jacobian(prior, faces, steps=steps)
    out = np.zeros((len(postures), 3, jac.shape[1]))
    out[~on_step] = jac[: 3 * len(faces)].reshape(len(faces), 3, -1)
    out[on_step, 2] = jac[3 * len(faces) :]
    return out, names


def select_postures(
    jacs: np.ndarray, min_gain: float = MIN_GAIN, max_postures: int = MAX_POSTURES
) -> tuple[list[int], float]:
    """Greedy D-optimal choice (module docstring): indices in the order chosen, log det M."""
    p = jacs.shape[-1]
    m_inv = np.eye(p)
    log_det = 0.0
    chosen: list[int] = []
    available = np.ones(len(jacs), bool)
    while len(chosen) < max_postures and available.any():
        # gain of each candidate: log det(I3 + J M⁻¹ Jᵀ)
        s = (jacs @ m_inv) @ jacs.transpose(0, 2, 1) + np.eye(3)
        gain = np.where(available, np.linalg.slogdet(s)[1], -np.inf)
        best = int(np.argmax(gain))
        if gain[best] < min_gain:
            break
        j = jacs[best]
        # Woodbury: (M + JᵀJ)⁻¹ = M⁻¹ − M⁻¹Jᵀ (I + J M⁻¹ Jᵀ)⁻¹ J M⁻¹
        mj = m_inv @ j.T
        m_inv = m_inv - mj @ np.linalg.solve(s[best], mj.T)
        log_det += float(gain[best])
        chosen.append(best)
        available[best] = False
    return chosen, log_det


#: Weights of each joint's travel in the visiting order (J1 first: the longest moves).
TRAVEL_WEIGHTS = np.array([3.0, 2.0, 2.0, 1.0, 1.0, 0.5])


def _next(options: list[Posture], last: Posture | None) -> int:
    """Index in ``options`` of the posture to visit next: the lowest J1 first, then the
    nearest (``TRAVEL_WEIGHTS``)."""
    if last is None:
        return int(np.argmin([p.joints_deg[0] for p in options]))
    here = last.joints_deg
    return int(np.argmin([np.sum(TRAVEL_WEIGHTS * np.abs(p.joints_deg - here)) for p in options]))


def order_postures(postures: list[Posture]) -> list[Posture]:
    """Visit order: nearest next in J1, then the other joints (fewer, shorter moves)."""
    left = list(postures)
    out: list[Posture] = []
    while left:
        out.append(left.pop(_next(left, out[-1] if out else None)))
    return out


def unknown_spread(profile: CellProfile, prior: CellPrior, names: tuple[str, ...]) -> np.ndarray:
    """Per unknown of the planning Jacobian (``names``), how far the cell may really be from
    the profile over the prior σ the fit gives it: the offsets' planning std
    (``ucal.model.spread.offsets_std_deg``: a fresh cell's degree, not the fit's broad
    prior) over the fit's; 1 for every other unknown (its prior is the declared tolerance)."""
    table = full_table(prior)
    spread = np.ones(len(names))
    planning = offsets_std_deg(profile)
    for j, name in enumerate(OFFSETS):
        if name in names:
            spread[names.index(name)] = planning[j] / table.prior_stds[table.index(name)]
    return spread


def visit_order(
    profile: CellProfile,
    cands: list[Posture],
    jacs: np.ndarray,
    spread: np.ndarray,
    chosen: list[int],
    max_postures: int = MAX_POSTURES,
    command: str = "plan --level full",
    known: np.ndarray | None = None,
) -> list[int]:
    """The order the run visits the ``chosen`` candidates (indices into ``cands``, in the
    order chosen), each with the room the run needs when it gets there (module docstring:
    the room the tolerances and the offsets give, ``offsets_margins_mm``, times the share of
    its water path's prior std the faces measured before it leave, ``known``: the information
    of the faces measured before the first posture, ``offsets_first``); where no chosen posture
    has that room yet, the candidate with it that adds most information is visited first (a
    lead-in, added to the plan; at ``max_postures`` it takes the place of the last chosen).
    ``SafetyError`` naming what to do when no candidate has it (its message begins with
    ``command``, the plan refused)."""
    q = np.array([c.joints_deg for c in cands])
    faces = np.array([int(c.face) for c in cands])
    paths = np.array([c.water_path_mm for c in cands])
    on_step = np.array([c.step for c in cands], bool)
    room_prior = np.hypot(tolerance_margins(profile).block_mm, offsets_margins_mm(profile, q))
    rows = jacs[:, 2, :]  # each posture's water path (per σ) against the unknowns (per prior σ)
    spread_cov = np.diag(spread**2)
    prior_var = np.einsum("np,pq,nq->n", rows, spread_cov, rows)
    p = jacs.shape[-1]
    info = np.eye(p) if known is None else known.copy()
    left = list(chosen)
    out: list[int] = []
    used = np.zeros(len(cands), bool)
    while left:
        # the run's estimate after the faces so far: error M⁻¹(P + HᵀH)M⁻¹ (P: the spread)
        m_inv = np.linalg.inv(info)
        a = rows @ m_inv
        var = np.einsum("np,pq,nq->n", a, spread_cov + info - np.eye(p), a)
        share = np.sqrt(np.clip(var / np.maximum(prior_var, 1e-300), 0.0, 1.0))
        room = room_prior * share[:, None]
        along = room[np.arange(len(cands)), faces]
        ok = (
            (paths - along >= MIN_WATER_PATH_MM)
            & (paths + along <= STEPPED_PATH_RANGE_MM[1])
            & _clear(profile, q, faces, room)
        )
        passing = [i for i in left if ok[i]]
        if passing:
            k = passing[_next([cands[i] for i in passing], cands[out[-1]] if out else None)]
            left.remove(k)
        else:
            spare = np.flatnonzero(ok & ~used & ~on_step)
            if not spare.size:
                raise SafetyError(_unroomy(profile, room_prior, faces, command))
            s = (jacs[spare] @ m_inv) @ jacs[spare].transpose(0, 2, 1) + np.eye(3)
            k = int(spare[np.argmax(np.linalg.slogdet(s)[1])])
            log.info("%s: %s first, where the offsets leave room", command, cands[k].label)
            if len(out) + len(left) >= max_postures:
                left.pop()  # the last chosen: the least information
        out.append(k)
        used[k] = True
        if not on_step[k]:  # a water path over the step does not refit the run's estimate
            info = info + jacs[k].T @ jacs[k]
    return out


def _unroomy(profile: CellProfile, room_mm: np.ndarray, faces: np.ndarray, command: str) -> str:
    """The refusal when no posture keeps the room the unknown offsets need (``visit_order``)."""
    along = room_mm[np.arange(len(faces)), faces]
    std = offsets_std_deg(profile)
    return (
        f"{command}: with the joint offsets known to "
        f"±{TOLERANCE_SIGMAS * np.max(std):.3g}° ({TOLERANCE_SIGMAS:g}σ; "
        + ("not calibrated" if profile.joint_offsets_std_deg is None else "[calibration] std_deg")
        + f") the tool centre may stand {np.min(along):.0f}-{np.max(along):.0f} mm from where "
        f"it is planned, and no posture keeps it {MIN_WATER_PATH_MM:g} mm from the face, the "
        f"echo within {STEPPED_PATH_RANGE_MM[1]:g} mm and the beam inside the face's edges: "
        "calibrate the offsets first (`ucal calibrate PROFILE`), or " + _block_advice(profile)
    )


def _block_advice(profile: CellProfile) -> str:
    """Where to move the block for the arm to reach over its XY face's middle."""
    s_mat = profile.sample_matrix
    middle = s_mat[:3, :3] @ np.array([0.5, 0.5, 0.0]) * profile.sample_face_size_mm
    point = middle + s_mat[:3, 3] + WATER_PATHS_MM[1] * s_mat[:3, 2]
    return reach_advice(profile, point, "the block")


def no_candidates(profile: CellProfile, command: str) -> SafetyError:
    """The refusal of a plan (``command``) when the block leaves no candidate posture."""
    return SafetyError(
        f"{command}: no posture normal to a block face passes the checks (joint ranges, "
        "singularity margin, clearance, face edges, with the room the declared tolerances "
        "need): " + _block_advice(profile)
    )


def offsets_first(profile: CellProfile) -> CalibrationPlan | None:
    """The offsets level's plan, measured before the full level's postures on a profile whose
    offsets were never calibrated (module docstring, "Offsets first"), its tank read by the
    postures that follow (no water path read again); None on a profile ``calibrate`` wrote,
    and where no calibration pose reaches the block (said: the postures then keep the room
    the offsets need, ``visit_order``)."""
    if profile.joint_offsets_std_deg is not None:
        return None
    try:
        plan = plan_calibration(profile)
    except SafetyError as e:
        log.warning(
            "plan --level full: the offsets were never calibrated and no calibration pose "
            "measures them first (%s); each posture keeps the room they need",
            e,
        )
        return None
    return replace(plan, path_again=False)


def first_postures(first: CalibrationPlan | None) -> list[Posture]:
    """The targets of ``offsets_first``'s plan as postures (none without it)."""
    if first is None:
        return []
    return [Posture(t.label, t.face, t.joints_deg, t.water_path_mm) for t in first.targets]


def plan_full(
    profile: CellProfile, min_gain: float = MIN_GAIN, max_postures: int = MAX_POSTURES
) -> FullPlan:
    """Plan ``calibrate --level full`` (``SafetyError`` if the block leaves no candidate, or
    no calibration pose where the offsets must be measured first)."""
    cands = candidate_postures(profile)
    if not cands:
        raise no_candidates(profile, "plan --level full")
    first = offsets_first(profile)
    lead = first_postures(first)
    prior = prior_from_profile(profile)
    jacs, names = posture_jacobians(prior, profile, cands + lead)
    jacs, lead_jacs = jacs[: len(cands)], jacs[len(cands) :].reshape(-1, jacs.shape[-1])
    known = np.eye(jacs.shape[-1]) + lead_jacs.T @ lead_jacs
    idx, _ = select_postures(jacs, min_gain, max_postures)
    spread = unknown_spread(profile, prior, names)
    order = visit_order(profile, cands, jacs, spread, idx, max_postures, known=known)
    chosen = [
        Posture(
            f"p{i + 1:02d}",
            cands[k].face,
            cands[k].joints_deg,
            cands[k].water_path_mm,
            cands[k].step,
        )
        for i, k in enumerate(order)
    ]
    taken = jacs[order].reshape(-1, jacs.shape[-1])  # lead-ins add their information
    log_det = float(np.linalg.slogdet(np.eye(jacs.shape[-1]) + taken.T @ taken)[1])
    j1 = [p.joints_deg[0] for p in chosen]
    # R of the candidates' Jacobian (J = QR): the same column norms, regressions and singular
    # values as J, in p rows instead of three per candidate
    every = jacs.reshape(-1, jacs.shape[-1])
    structure = identifiability(np.linalg.qr(every).R, names)
    return FullPlan(
        tuple(chosen),
        len(cands),
        log_det / (2 * jacs.shape[-1]),
        log_det,
        (float(min(j1)), float(max(j1))),
        structure,
        postures_from_above(prior, profile, chosen),
        first,
    )


def postures_from_above(
    prior: CellPrior, profile: CellProfile, postures: list[Posture], min_gain: float = MIN_GAIN
) -> tuple[str, ...]:
    """The postures to reach from above on every joint, so that each joint's lost motion
    is measured (labels, in plan order; none where the plan cannot spare them).

    A joint's link lags its encoder by half its lost motion ``b`` against its last motion;
    the offsets are those of postures reached from below, and a posture reached from above
    sees every joint at ``offset + b``: its rows gain the offsets' columns as ``b``'s
    (scaled to ``b``'s prior σ). Greedy as the selection, on the information about ``b``
    (``log det`` of its marginal information): the face posture that raises it most is
    turned, while that raises it by ``min_gain`` or more and leaves every offset's std within
    ``OFFSET_STD_GROWTH`` of the all-from-below plan's (the rest still carry the offsets).
    The turn is kept only if it measures ``b`` where it sees it (std below ``LOST_MOTION_SHARE``
    of the prior's on every joint it moves off the prior): a lost motion half measured would
    pass its prior's mean (0, for a quantity that is never negative) on to the offsets. A
    short plan turns none. Postures over the step stay from below (only their water path is
    used).
    """
    if not postures:
        return ()
    jacs, names = posture_jacobians(prior, profile, postures)
    table = full_table(prior)
    stds = np.array([table.prior_stds[table.index(n)] for n in OFFSETS + BACKLASH])
    if not np.all(np.isfinite(stds) & (stds > 0)) or not set(OFFSETS) <= set(names):
        return ()  # no lost motion to measure (a tolerance of 0), or offsets held
    cols = [names.index(n) for n in OFFSETS]
    lost = jacs[:, :, cols] * (stds[6:] / stds[:6])  # the b columns of a posture from above
    below = np.concatenate([jacs, np.zeros_like(lost)], axis=2)
    info = np.eye(below.shape[2]) + np.einsum("nki,nkj->ij", below, below)
    offsets_var = np.diag(np.linalg.inv(info))[cols]
    b = slice(below.shape[2] - 6, None)

    def judged(m: np.ndarray) -> tuple[float, bool, np.ndarray]:
        """Information on b (log det of its marginal), the offsets' std kept, b's std/prior."""
        cov = np.linalg.inv(m)
        kept = bool(np.all(np.diag(cov)[cols] <= OFFSET_STD_GROWTH**2 * offsets_var))
        return -float(np.linalg.slogdet(cov[b, b])[1]), kept, np.sqrt(np.diag(cov)[b])

    turnable = [i for i, p in enumerate(postures) if not p.step]
    turned: list[int] = []
    score, _, b_std = judged(info)
    while True:
        best, best_gain, best_info = -1, min_gain, info
        for i in turnable:
            if i in turned:
                continue
            above = np.concatenate([jacs[i], lost[i]], axis=1)
            trial = info - below[i].T @ below[i] + above.T @ above
            new, kept, _ = judged(trial)
            if kept and new - score >= best_gain:
                best, best_gain, best_info = i, new - score, trial
        if best < 0:
            break
        turned.append(best)
        info = best_info
        score, _, b_std = judged(info)
    seen = b_std < 0.9  # the joints whose lost motion the turned postures see at all
    if not seen.any() or np.max(b_std[seen]) > LOST_MOTION_SHARE:
        return ()
    return tuple(postures[i].label for i in sorted(turned))
