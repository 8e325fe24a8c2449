"""The joint-offset calibration sequence of paper 000: plan, preflight, measure, solve.

Configurations: the calibration pose ("base"), joint 3 stepped by δθ3 ("j3"), back, joint 2
stepped by δθ2 ("j2") — paper 000's three — and, where the cell leaves room, joint 1 stepped
("j1"): seen from a second J1 azimuth, a tilt of the block is no longer one rotation with δ2
(``ucal.calibration.fit``). In each, the beam is brought normal to the block's three faces (XY:
the beam straight down at the paper's pose), the normal-incidence posture found by the peak
search and the water path read by time of flight: 9 or 12 face measurements (order: see
``order_targets``). The arm stays still during a configuration; only the wrist moves, so W
stays put (arm–wrist separation).

Step sizes come from the room the cell leaves: a joint step Δ displaces the wrist centre by
about L·Δ, and a water-path error δ becomes an angle error of about δ/(L·Δ), so the largest
step whose targets pass the checks is taken (``ARM_STEPS_DEG``, ``AZIMUTH_STEPS_DEG``, never
below ``[procedure] step_deg``); the plan summary prints the amplification the plan implies.

Backlash: every move ends with a short final approach from the negative side of each joint
(``FinalApproachRig``), so the links always lag the encoders the same way; a constant lag is
then part of the offset instead of a configuration-dependent error.

Every target is planned and checked before the first motion (joint ranges with room for the
wrist search, the θ5 singularity margin, the beam meeting each face inside its edges at a
positive water path). During the run each new measurement refines the estimate of the offsets
and of the block corner, which predicts the next posture (``ucal.measure.running``): the first
face may need a wide search, the others are found near their prediction.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, replace

import numpy as np

from ucal.calibration.exact import OffsetSolution, beam_on_axis, solve_exact_with_priors
from ucal.calibration.fit import (
    OFFSETS,
    TOOL,
    prior_from_profile,
    solve_cell,
)
from ucal.calibration.model import (
    FACE_NAMES,
    FACE_ORDER,
    CellGeometry,
    Configuration,
    Face,
    FaceMeasurement,
    beam_and_tcp,
    face_basis,
)
from ucal.calibration.paper import solve_paper
from ucal.calibration.safety import (
    EDGE_MARGIN_MM,
    MIN_WATER_PATH_MM,
    check_face,
    check_joints,
    face_hit,
)
from ucal.calibration.wrist import aim_wrist, search_joints
from ucal.cell import PAPER_CALIBRATION_POSE_DEG, CellProfile
from ucal.errors import SafetyError
from ucal.kinematics.ik import ik
from ucal.kinematics.rotations import rpy_to_matrix
from ucal.measure.running import RunningEstimate
from ucal.progress import MeasureStep, Report
from ucal.rig import Rig

log = logging.getLogger(__name__)

#: Candidate joint-2/3 steps (deg), largest first: bigger steps amplify distance errors less.
ARM_STEPS_DEG = (5.0, 4.0, 3.0, 2.0)
#: Candidate joint-1 steps (deg) of the second azimuth, largest first.
AZIMUTH_STEPS_DEG = (10.0, 8.0, 6.0, 4.0)
#: Water paths a stepped configuration must keep (mm): room for the offsets' uncertainty below,
#: a strong enough echo above (water absorbs ~0.27 dB per mm at 25 MHz).
STEPPED_PATH_RANGE_MM = (40.0, 180.0)


@dataclass(frozen=True)
class PlannedTarget:
    """One nominal normal-incidence posture of the plan."""

    config: Configuration
    face: Face
    joints_deg: np.ndarray
    search_joints: tuple[int, int]
    water_path_mm: float

    @property
    def label(self) -> str:
        return f"{self.config}/{FACE_NAMES[self.face]}"


@dataclass(frozen=True)
class CalibrationPlan:
    pose_deg: np.ndarray
    step_deg: float  # joint-2/3 step (deg, sign chosen during the run)
    targets: tuple[PlannedTarget, ...]
    azimuth_step_deg: float | None = None  # joint-1 step of the "j1" configuration, if any
    min_step_deg: float = 2.0  # the run may step less than planned, not below this
    #: Offset change (deg) per 1 m/s of sound speed if it were not fitted, per joint.
    sound_speed_gain_deg_per_m_s: np.ndarray | None = None
    #: Offset std (deg) per 1 µm of water-path noise on every measurement, per joint.
    distance_noise_gain_deg_per_um: np.ndarray | None = None

    @property
    def configs(self) -> tuple[Configuration, ...]:
        return tuple(dict.fromkeys(t.config for t in self.targets))

    def step_of(self, config: Configuration) -> float:
        """Planned step (deg) of ``config`` (0 for the base)."""
        if config == Configuration.BASE:
            return 0.0
        if config == Configuration.J1:
            return self.azimuth_step_deg or 0.0
        return self.step_deg


@dataclass
class CalibrationRun:
    """What a run measured."""

    measurements: list[FaceMeasurement]
    moves: int
    reads: int


def geometry(profile: CellProfile) -> CellGeometry:
    """Known geometry for the solvers: model, tool, block orientation."""
    return CellGeometry(
        profile.model, profile.tool_matrix, rpy_to_matrix(profile.sample_rotation_deg)
    )


def calibration_pose(profile: CellProfile) -> np.ndarray:
    """The profile's calibration pose, or one computed with IK from the block pose.

    Computed: the beam straight down onto the XY face with the wrist centre at equal distances
    from the three faces (the tool centre ``water_path_mm`` above the XY face).
    """
    proc = profile.procedure
    if proc.calibration_pose_deg is not None:
        return np.asarray(proc.calibration_pose_deg, float)
    s_mat = profile.sample_matrix
    reach = profile.model.d_mm[5] + profile.tool_position_mm[2] + proc.water_path_mm
    target = np.eye(4)
    target[:3, :3] = s_mat[:3, :3] @ np.diag([-1.0, 1.0, -1.0])  # tool z = −block z
    target[:3, 3] = s_mat[:3, :3] @ np.array([reach, reach, proc.water_path_mm]) + s_mat[:3, 3]
    return ik(
        profile.model,
        target,
        profile.tool_matrix,
        profile.joint_offsets_deg,
        near_deg=PAPER_CALIBRATION_POSE_DEG,
    )


#: The joint each stepped configuration steps (0-based).
STEPPED_JOINT = {Configuration.J3: 2, Configuration.J2: 1, Configuration.J1: 0}


def config_arm(pose_deg: np.ndarray, config: Configuration, step_deg: float) -> np.ndarray:
    """Joint readings of a configuration's arm (wrist as in ``pose_deg``)."""
    q = np.array(pose_deg, float)
    if config in STEPPED_JOINT:
        q[STEPPED_JOINT[config]] += step_deg
    return q


CONFIGS = tuple(Configuration)
#: Joint-6 turn per configuration (deg). An on-axis beam keeps its direction and tool centre
#: when joint 6 turns, so the stepped configurations turn it; a tilted beam would swing the
#: tool centre around the wrist (tens of mm, coupling the wrist-centre displacement with the
#: tool's unknown pose), so only the second azimuth turns it.
THETA6_SHIFT_DEG = {
    "on-axis": {
        Configuration.BASE: 0.0,
        Configuration.J3: 90.0,
        Configuration.J2: -90.0,
        Configuration.J1: 0.0,
    },
    "tilted": {
        Configuration.BASE: 0.0,
        Configuration.J3: 0.0,
        Configuration.J2: 0.0,
        Configuration.J1: 90.0,
    },
}


def _config_targets(
    profile: CellProfile,
    geom: CellGeometry,
    pose: np.ndarray,
    config: Configuration,
    step_deg: float,
) -> list[PlannedTarget]:
    """The three checked targets of one configuration (``SafetyError`` if one fails).

    Joint 6 turns between configurations (``THETA6_SHIFT_DEG``, the other way if that fails a
    check): with joint 6 the same in every measurement, a joint-5 offset is one rotation with
    the tool's orientation in the flange, which is itself an unknown (see
    ``ucal.calibration.fit``); the wrist aims the beam with joints 4 and 5 around it. Without
    the second azimuth a tilted beam's joint 5 may then be reported unobservable.
    """
    shift = THETA6_SHIFT_DEG["on-axis" if beam_on_axis(geom) else "tilted"][config]
    error: SafetyError | None = None
    for turn in dict.fromkeys((shift, -shift)):
        arm = config_arm(pose, config, step_deg)
        arm[5] += turn
        try:
            return [_checked_target(profile, geom, arm, config, face) for face in FACE_ORDER]
        except SafetyError as e:
            error = error or e
    assert error is not None
    raise error


def _checked_target(
    profile: CellProfile, geom: CellGeometry, arm: np.ndarray, config: Configuration, face: Face
) -> PlannedTarget:
    offsets = profile.joint_offsets_deg
    label = f"{config}/{FACE_NAMES[face]}"
    q = aim_wrist(geom, arm, -geom.normal(face), offsets)
    check_joints(profile, q, label)
    path = check_face(profile, geom, q, face, offsets, label)
    lo, hi = STEPPED_PATH_RANGE_MM
    if config != Configuration.BASE and not lo <= path <= hi:
        raise SafetyError(
            f"plan {label}: a water path of {path:.1f} mm is outside "
            f"{lo:g}-{hi:g} mm for a stepped configuration"
        )
    js, _ = search_joints(geom, q, offsets, face_basis(geom, face))
    return PlannedTarget(config, face, q, js, path)


def _largest_step(
    profile: CellProfile,
    geom: CellGeometry,
    pose: np.ndarray,
    config: Configuration,
    candidates: tuple[float, ...],
) -> tuple[float, list[PlannedTarget]]:
    """The largest candidate step whose targets pass every check; the last failure if none."""
    error: SafetyError | None = None
    for step in candidates:
        try:
            return step, _config_targets(profile, geom, pose, config, step)
        except SafetyError as e:
            error = error or e
    assert error is not None
    raise error


def plan_calibration(profile: CellProfile) -> CalibrationPlan:
    """Plan and check every target before the first motion (``SafetyError``, exit 4).

    The joint-2/3 step is the largest of ``ARM_STEPS_DEG`` (not below ``[procedure]
    step_deg``) whose targets pass; the "j1" configuration is planned with the largest of
    ``AZIMUTH_STEPS_DEG`` that passes, and left out (with a log line) if none does.
    """
    geom = geometry(profile)
    proc = profile.procedure
    pose = calibration_pose(profile)
    model = profile.model
    if not model.within_limits(pose):
        raise SafetyError(
            f"the calibration pose {np.round(pose, 2).tolist()} is outside the joint ranges"
        )
    targets = _config_targets(profile, geom, pose, Configuration.BASE, 0.0)
    arm_steps = tuple(
        sorted({s for s in ARM_STEPS_DEG if s >= proc.step_deg} | {proc.step_deg}, reverse=True)
    )
    # One step for both arm joints: the run may reduce it for clearance, never below
    # [procedure] step_deg.
    step = None
    error: SafetyError | None = None
    for cand in arm_steps:
        try:
            stepped = _config_targets(
                profile, geom, pose, Configuration.J3, cand
            ) + _config_targets(profile, geom, pose, Configuration.J2, cand)
        except SafetyError as e:
            error = error or e
            continue
        step = cand
        targets += stepped
        break
    if step is None:
        assert error is not None
        raise error
    azimuth = None
    try:
        azimuth, j1 = _largest_step(profile, geom, pose, Configuration.J1, AZIMUTH_STEPS_DEG)
        targets += j1
    except SafetyError as e:
        log.info("no second J1 azimuth (%s): J2 carries the block's tilt tolerance", e)
    plan = CalibrationPlan(
        pose, step, tuple(order_targets(targets)), azimuth, min_step_deg=proc.step_deg
    )
    gains = plan_amplification(profile, plan)
    return replace(
        plan, sound_speed_gain_deg_per_m_s=gains[0], distance_noise_gain_deg_per_um=gains[1]
    )


def nominal_measurements(
    profile: CellProfile,
    targets: tuple[PlannedTarget, ...],
    distance_std_mm: float = 1e-3,
    tilt_std_deg: float = 1e-3,
) -> list[FaceMeasurement]:
    """Ideal measurements at the planned targets of a cell exactly as the profile says."""
    geom = geometry(profile)
    corner = np.asarray(profile.sample_position_mm, float)
    out = []
    for t in targets:
        _, tcp = beam_and_tcp(geom, t.joints_deg, profile.joint_offsets_deg)
        out.append(
            FaceMeasurement(
                t.config,
                t.face,
                t.joints_deg,
                float(geom.normal(t.face) @ (tcp - corner)),
                distance_std_mm,
                tilt_std_deg,
            )
        )
    return out


def plan_amplification(
    profile: CellProfile, plan: CalibrationPlan
) -> tuple[np.ndarray, np.ndarray]:
    """What the plan does to errors: offsets (deg) per 1 m/s of sound speed left unfitted, and
    offset std (deg) per 1 µm of water-path noise, per joint.

    Linearised at the nominal cell: with ``K = Cov·Jᵀ`` of the prior-augmented problem (sound
    speed held), a change ``Δr`` of the residuals moves the estimate by ``−K·Δr``; a sound
    speed wrong by Δc scales every water path by Δc/c, i.e. ``Δr_i = −(Δc/c)·d_i/σ_d``.
    """
    meas = nominal_measurements(profile, plan.targets)
    prior = prior_from_profile(profile)
    cell = solve_cell(prior, meas, fixed=("sound_speed_m_s",))
    assert cell.jac is not None
    k = cell.cov @ cell.jac.T
    free = cell.table.free_names
    rows = np.arange(2, cell.n_data, 3)  # the distance rows
    d_over_sigma = np.array([m.distance_mm / m.distance_std_mm for m in meas])
    c0 = prior.sound_speed_m_s
    cols = np.array([free.index(n) for n in OFFSETS])
    speed_gain = np.abs(k[np.ix_(cols, rows)] @ d_over_sigma / c0)
    noise_gain = np.sqrt(np.sum(k[np.ix_(cols, rows)] ** 2, axis=1))  # σ_d = 1 µm
    return speed_gain, noise_gain


def order_targets(targets: list[PlannedTarget]) -> list[PlannedTarget]:
    """Execution order: XY and YZ in every configuration first, XZ last on the way back.

    After two faces two combinations of offsets are still free and a third face can be degrees
    from its prediction, while the same face in a stepped configuration is predicted almost
    exactly (the step is a known rotation). Measuring XY and YZ in all three configurations
    first pins the model down, so the XZ faces are found at their predictions.
    """
    by_key = {(t.config, t.face): t for t in targets}
    configs = [c for c in CONFIGS if (c, FACE_ORDER[0]) in by_key]
    first = [by_key[(c, f)] for c in configs for f in FACE_ORDER[:2]]
    last = [by_key[(c, FACE_ORDER[2])] for c in reversed(configs)]
    return first + last


def _step_candidates(plan: CalibrationPlan, config: Configuration) -> tuple[float, ...]:
    """Step magnitudes to try for ``config``, the planned one first, then smaller ones."""
    planned = plan.step_of(config)
    if config == Configuration.J1:
        pool = [s for s in AZIMUTH_STEPS_DEG if s <= planned]
    else:
        pool = [s for s in ARM_STEPS_DEG if plan.min_step_deg <= s <= planned]
        pool.append(plan.min_step_deg)
    return tuple(sorted(set(pool) | {planned}, reverse=True))


def choose_step(
    profile: CellProfile,
    geom: CellGeometry,
    plan: CalibrationPlan,
    config: Configuration,
    est: np.ndarray,
    corner: np.ndarray,
    last_wrist: dict[int, np.ndarray],
) -> float:
    """Signed joint step for ``config`` that keeps every face at a safe water path.

    With the offsets estimated from the faces measured so far, the water paths of the stepped
    configuration are predictable: for the largest step magnitude (the planned one first) the
    step goes the way (+ or −) whose smallest predicted water path is larger, provided all stay
    above ``MIN_WATER_PATH_MM``, inside the joint ranges and with the beam inside each face.
    Large offsets can put the wrist centre tens of millimetres lower than nominal; stepping the
    wrong way would then drive the tool into the block.
    """
    if config == Configuration.BASE:
        return 0.0
    why: list[str] = []
    for magnitude in _step_candidates(plan, config):
        best, best_path = None, -np.inf
        for sign in (1.0, -1.0):
            step = sign * magnitude
            path = _stepped_clearance(
                profile, geom, plan, config, step, est, corner, last_wrist, why
            )
            if path is not None and path > best_path:
                best, best_path = step, path
        if best is not None and best_path >= MIN_WATER_PATH_MM:
            if best != plan.step_of(config):
                log.info(
                    "%s: stepping by %+g deg keeps the tool clear (%.1f mm)",
                    config,
                    best,
                    best_path,
                )
            return best
    raise SafetyError(
        f"configuration {config}: with the offsets measured so far no joint "
        f"step of ±{plan.step_of(config):g} deg or less is safe "
        f"({'; '.join(why[-4:])})"
    )


def _stepped_clearance(
    profile: CellProfile,
    geom: CellGeometry,
    plan: CalibrationPlan,
    config: Configuration,
    step: float,
    est: np.ndarray,
    corner: np.ndarray,
    last_wrist: dict[int, np.ndarray],
    why: list[str],
) -> float | None:
    """Smallest predicted water path (mm) of ``config`` stepped by ``step``; None if a face
    cannot be reached inside the joint ranges or its beam would leave the face."""
    model = profile.model
    arm = config_arm(plan.pose_deg, config, step)
    paths = []
    size = profile.sample_face_size_mm
    for t in plan.targets:
        if t.config != config:
            continue
        start = arm.copy()
        start[3:] = last_wrist.get(t.face, t.joints_deg)[3:]
        start[5] = t.joints_deg[5]
        try:
            q = aim_wrist(geom, start, -geom.normal(t.face), est)
        except SafetyError:
            why.append(f"{step:+g}°: the wrist cannot face {FACE_NAMES[t.face]}")
            return None
        # The prediction is good to a fraction of a degree now: a small margin suffices.
        if not np.all((q >= model.joint_min_deg + 1.0) & (q <= model.joint_max_deg - 1.0)):
            why.append(
                f"{step:+g}°: face {FACE_NAMES[t.face]} needs joints "
                f"{np.round(q, 1).tolist()} at a range limit"
            )
            return None
        path, edge = face_hit(geom, q, est, corner, t.face, size)
        if edge < EDGE_MARGIN_MM:
            why.append(
                f"{step:+g}°: the beam would meet face {FACE_NAMES[t.face]} "
                f"{edge:.0f} mm from its edge"
            )
            return None
        paths.append(path)
    if min(paths) < MIN_WATER_PATH_MM:
        why.append(f"{step:+g}°: {min(paths):.1f} mm of water")
    if max(paths) > STEPPED_PATH_RANGE_MM[1]:
        why.append(f"{step:+g}°: {max(paths):.1f} mm of water (echo too weak)")
        return None
    return min(paths)


def run_calibration(
    profile: CellProfile,
    plan: CalibrationPlan,
    rig: Rig,
    progress: Report | None = None,
) -> CalibrationRun:
    """Measure the planned faces (``solve`` turns them into offsets) with the running estimate
    of ``ucal.measure.running``, reporting each face as it starts and the final refit. The
    caller owns the connection, STOP and the profile."""
    first = plan.targets[0]
    geom = geometry(profile)
    running = RunningEstimate.start(profile, rig, geom, first.joints_deg, first.search_joints[1])
    total = len(plan.targets)
    last_wrist: dict[int, np.ndarray] = {}
    steps: dict[Configuration, float] = {}
    skipped: set[Configuration] = set()
    for i, target in enumerate(plan.targets):
        if progress:
            progress(
                MeasureStep(
                    f"face {target.label}", i, total, target.config, FACE_NAMES[target.face]
                )
            )
        if target.config in skipped:
            continue
        if target.config not in steps:
            try:
                steps[target.config] = choose_step(
                    profile,
                    running.geometry,
                    plan,
                    target.config,
                    running.offsets_deg,
                    running.corner_mm,
                    last_wrist,
                )
            except SafetyError as e:
                if target.config != Configuration.J1:
                    raise
                # The second azimuth is a bonus: without it the block's tilt tolerance stays
                # in joints 2 and 3's stds (``ucal.calibration.fit``).
                log.warning("second J1 azimuth skipped: %s", e)
                skipped.add(target.config)
                continue
        start = config_arm(plan.pose_deg, target.config, steps[target.config])
        start[3:] = last_wrist.get(target.face, target.joints_deg)[3:]
        start[5] = target.joints_deg[5]
        label = f"face {FACE_NAMES[target.face]} ({target.label})"
        found = running.measure(target.face, start, label, target.config)
        last_wrist[target.face] = found.measurement.joints_deg
    # Leave the robot at the calibration pose's XY posture.
    running.rig.move(first.joints_deg)
    meas = running.refit_peaks()
    if progress:
        progress(MeasureStep("solving", total, total))
    return CalibrationRun(meas, rig.counters.moves, rig.counters.reads)


def beam_fixed(beam: str) -> tuple[str, ...]:
    """The unknowns ``--beam fixed`` holds at the profile's values: the tool's orientation
    (and so the beam direction); none otherwise."""
    return TOOL[3:] if beam == "fixed" else ()


def solve(
    profile: CellProfile, run: CalibrationRun, beam: str = "auto"
) -> tuple[OffsetSolution, OffsetSolution | None]:
    """Both solutions from one run's measurements: exact with the cell's tolerances as priors,
    and paper 000's (None if it cannot be applied, e.g. a DH table of another structure).

    ``beam``: "fixed" holds the tool orientation (and so the beam direction) at the profile's
    value; otherwise it is an unknown with the profile's tolerance as prior.
    """
    prior = prior_from_profile(profile)
    exact = solve_exact_with_priors(prior, run.measurements, fixed=beam_fixed(beam))
    try:
        paper = solve_paper(
            geometry(profile),
            run.measurements,
            profile.joint_offsets_deg,
            exact.unobservable_joints,
            exact.condition_number,
            prior=prior,
            reasons=exact.unobservable_reasons,
        )
    except Exception as e:
        log.warning("paper method failed: %s", e)
        paper = None
    return exact, paper
