"""The offsets level's plan (paper 000): the calibration pose, the joint steps, every target
checked before the first motion (``SafetyError``, exit 4).

Configurations: the calibration pose ("base"), joint 3 stepped ("j3"), joint 2 stepped ("j2")
and, where the cell leaves room, joint 1 stepped ("j1"); in each the wrist aims the beam normal
to the block's three faces (``ucal.measure.sequence`` measures them).

The calibration pose. The profile's (``[procedure] calibration_pose_deg``, or one computed from
the block) is tried first; where a target of it fails a check, poses are searched: the wrist
centre W placed in the block frame at water paths of ``POSE_PATHS_MM`` from each face plus the
tool's lever (so that the beam aimed at a face from W has that water path whatever the tool's
holder), the tool turned about the straight-down beam by ``POSE_TURNS_DEG`` (which sets joint 6
and, with a holder, the wrist), each in-range IK branch (shoulder, elbow, wrist flip) nearest
the paper's pose. With a ``[step]`` on the XY face, W's footprint moves off it: every beam must
pass the step clear (``ucal.model.safety.step_blocked``), so an XY echo is the face's and
never the step's top. Every check keeps the room the declared tolerances need
(``tolerance_margins``); the plan is refused only when no pose passes, naming what to move.
"""

from __future__ import annotations

import itertools
import logging
from collections.abc import Iterator
from dataclasses import dataclass, replace

import numpy as np

from ucal.cell import PAPER_CALIBRATION_POSE_DEG, CellProfile
from ucal.errors import SafetyError, UcalError
from ucal.kinematics.dh import fk_frames
from ucal.kinematics.ik import ik, ik_solutions
from ucal.kinematics.rotations import rot_z, rpy_to_matrix
from ucal.model.fit import OFFSETS, prior_from_profile, solve_cell
from ucal.model.geometry import (
    FACE_NAMES,
    FACE_ORDER,
    CellGeometry,
    Configuration,
    Face,
    FaceMeasurement,
    beam_and_tcp,
    beam_on_axis,
    face_basis,
)
from ucal.model.safety import (
    Margins,
    beam_on_flange_axis,
    check_face,
    check_joints,
    move_advice,
    tolerance_margins,
)
from ucal.model.spread import aim_spread
from ucal.model.wrist import aim_wrist, search_joints

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
    #: Read the first face's water path again at the end, where it was read (the tank's
    #: drift: ``ucal.measure.sequence``).
    path_again: bool = True
    #: Targets measured again from above at the end (each joint's lost motion:
    #: ``ucal.measure.sequence.with_lost_motion``); none by default.
    above: tuple[PlannedTarget, ...] = ()
    #: The signed steps (deg) of each stepped configuration whose wrist postures keep the
    #: room the declared tolerances need (``checked_steps``): the run steps by one of them
    #: only. None: any (a plan built without it).
    steps_checked: dict[Configuration, tuple[float, ...]] | None = None

    @property
    def configs(self) -> tuple[Configuration, ...]:
        return tuple(dict.fromkeys(t.config for t in self.targets))

    def step_candidates(self, config: Configuration) -> tuple[float, ...]:
        """Step magnitudes (deg) the run may take for ``config``, the planned one first,
        then smaller ones (not below ``min_step_deg`` on joints 2 and 3)."""
        planned = self.step_of(config)
        if config == Configuration.J1:
            pool = [s for s in AZIMUTH_STEPS_DEG if s <= planned]
        else:
            pool = [s for s in ARM_STEPS_DEG if self.min_step_deg <= s <= planned]
            pool.append(self.min_step_deg)
        return tuple(sorted(set(pool) | {planned}, reverse=True))

    def step_of(self, config: Configuration) -> float:
        """Planned step (deg) of ``config`` (0 for the base)."""
        if config == Configuration.BASE:
            return 0.0
        if config == Configuration.J1:
            return self.azimuth_step_deg or 0.0
        return self.step_deg


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
    margins: Margins,
) -> list[PlannedTarget]:
    """The three checked targets of one configuration (``SafetyError`` if one fails).

    Joint 6 turns between configurations (``THETA6_SHIFT_DEG``, the other way if that fails a
    check): with joint 6 the same in every measurement, a joint-5 offset is one rotation with
    the tool's orientation in the flange, which is itself an unknown (see
    ``ucal.model.fit``); the wrist aims the beam with joints 4 and 5 around it. Without
    the second azimuth a tilted beam's joint 5 may then be reported unobservable.
    """
    shift = THETA6_SHIFT_DEG["on-axis" if beam_on_axis(geom) else "tilted"][config]
    error: SafetyError | None = None
    for turn in dict.fromkeys((shift, -shift)):
        arm = config_arm(pose, config, step_deg)
        arm[5] += turn
        try:
            return [
                _checked_target(profile, geom, arm, config, face, margins) for face in FACE_ORDER
            ]
        except SafetyError as e:
            error = error or e
    assert error is not None
    raise error


def _checked_target(
    profile: CellProfile,
    geom: CellGeometry,
    arm: np.ndarray,
    config: Configuration,
    face: Face,
    margins: Margins,
) -> PlannedTarget:
    offsets = profile.joint_offsets_deg
    label = f"{config}/{FACE_NAMES[face]}"
    q = aim_wrist(geom, arm, -geom.normal(face), offsets)
    check_joints(profile, q, label, tolerance_deg=margins.wrist_deg)
    path = check_face(profile, geom, q, face, offsets, label, margins.block_mm)
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
    margins: Margins,
) -> tuple[float, list[PlannedTarget]]:
    """The largest candidate step whose targets pass every check; the first failure if none."""
    error: SafetyError | None = None
    for step in candidates:
        try:
            return step, _config_targets(profile, geom, pose, config, step, margins)
        except SafetyError as e:
            error = error or e
    assert error is not None
    raise error


#: Water paths (mm) from each face at which the pose search places the wrist centre (plus the
#: tool's lever), the profile's ``water_path_mm`` first; turns (deg) of the tool about the
#: straight-down beam; IK branches tried per such pose.
POSE_PATHS_MM = (100.0, 70.0, 130.0, 160.0, 50.0)
POSE_TURNS_DEG = (0.0, 90.0, -90.0, 180.0)
POSE_BRANCHES = 3


def tool_lever(profile: CellProfile) -> tuple[np.ndarray, float]:
    """The vector v from the wrist centre W to the TCP in the flange frame (mm) and a_T·v (mm):
    aimed at a face from W, the tool centre stands a_T·v nearer to it than W, whatever the
    holder turns the beam by.

    Constant for a spherical wrist; computed from the model at the zero pose.
    """
    frames = fk_frames(profile.model, np.zeros(6))
    flange = frames[6]
    tcp = (flange @ profile.tool_matrix)[:3, 3]
    v = flange[:3, :3].T @ (tcp - frames[4, :3, 3])
    return v, float(profile.tool_matrix[:3, 2] @ v)


def _searched_poses(profile: CellProfile) -> Iterator[np.ndarray]:
    """Calibration poses for the search (module docstring), the nearest the profile's first."""
    s_mat = profile.sample_matrix
    v, lever = tool_lever(profile)
    paths = tuple(dict.fromkeys((profile.procedure.water_path_mm, *POSE_PATHS_MM)))
    wp = paths[0]
    combos = sorted(itertools.product(paths, repeat=3), key=lambda c: sum(abs(x - wp) for x in c))
    down = s_mat[:3, :3] @ np.diag([-1.0, 1.0, -1.0])  # tool z = −block z
    flange_tool = profile.tool_matrix
    near = PAPER_CALIBRATION_POSE_DEG
    # an on-axis beam turned about itself turns joint 6 alone: the configurations turn it
    turns = POSE_TURNS_DEG[:1] if beam_on_flange_axis(profile) else POSE_TURNS_DEG
    # every combination's targets in one vectorised IK call (combination, turn)
    targets = np.tile(np.eye(4), (len(combos), len(turns), 1, 1))
    for k, turn in enumerate(turns):
        rot = down @ rot_z(np.radians(turn))
        targets[:, k, :3, :3] = rot
        wrists = (lever + np.array(combos)) @ s_mat[:3, :3].T + s_mat[:3, 3]
        targets[:, k, :3, 3] = wrists + rot @ flange_tool[:3, :3].T @ v
    sols, ok, _ = ik_solutions(profile.model, targets, flange_tool, profile.joint_offsets_deg, near)
    for c in range(len(combos)):
        for t in range(len(turns)):
            yield from sols[c, t][ok[c, t]][:POSE_BRANCHES]


def _pose_candidates(profile: CellProfile) -> Iterator[tuple[np.ndarray, bool]]:
    """The profile's calibration pose (or the computed one), then the searched ones (True)."""
    try:
        yield calibration_pose(profile), False
    except UcalError as e:
        log.info("the calibration pose: %s", e)
    for pose in _searched_poses(profile):
        yield pose, True


def _plan_at(
    profile: CellProfile, geom: CellGeometry, pose: np.ndarray, margins: Margins
) -> CalibrationPlan:
    """Every configuration's targets from calibration pose ``pose`` (``SafetyError`` if the
    base or both arm steps fail)."""
    proc = profile.procedure
    if not profile.model.within_limits(pose):
        raise SafetyError(
            f"the calibration pose {np.round(pose, 2).tolist()} is outside the joint ranges"
        )
    targets = _config_targets(profile, geom, pose, Configuration.BASE, 0.0, margins)
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
                profile, geom, pose, Configuration.J3, cand, margins
            ) + _config_targets(profile, geom, pose, Configuration.J2, cand, margins)
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
        azimuth, j1 = _largest_step(
            profile, geom, pose, Configuration.J1, AZIMUTH_STEPS_DEG, margins
        )
        targets += j1
    except SafetyError as e:
        log.info("no second J1 azimuth (%s): J2 carries the block's tilt tolerance", e)
    return CalibrationPlan(
        pose, step, tuple(order_targets(targets)), azimuth, min_step_deg=proc.step_deg
    )


def checked_steps(
    profile: CellProfile, geom: CellGeometry, plan: CalibrationPlan
) -> dict[Configuration, tuple[float, ...]]:
    """The signed steps of each stepped configuration of ``plan`` (``step_candidates``, each
    way) whose wrist postures, the beam aimed at each face with joint 6 as planned, keep the
    room the wrist search and the declared tolerances need (``check_joints`` with the
    posture's ``aim_spread``). The run chooses the sign and may step less (``ucal.calibration.
    sequence.choose_step``): each step it may take is checked here, before the first motion."""
    offsets = profile.joint_offsets_deg
    out: dict[Configuration, tuple[float, ...]] = {}
    for config in plan.configs:
        if config == Configuration.BASE:
            continue
        targets = [t for t in plan.targets if t.config == config]
        passing = []
        for magnitude in plan.step_candidates(config):
            for step in (magnitude, -magnitude):
                arm = config_arm(plan.pose_deg, config, step)
                try:
                    for t in targets:
                        start = arm.copy()
                        start[3:] = t.joints_deg[3:]
                        q = aim_wrist(geom, start, -geom.normal(t.face), offsets)
                        spread = aim_spread(profile, geom, q, t.face, offsets)
                        check_joints(profile, q, f"{config} by {step:+g} deg", spread=spread)
                except SafetyError as e:
                    log.info("%s: not stepped by %+g deg (%s)", config, step, e)
                    continue
                passing.append(step)
        out[config] = tuple(passing)
    return out


def plan_calibration(profile: CellProfile) -> CalibrationPlan:
    """Plan and check every target before the first motion (``SafetyError``, exit 4).

    The calibration pose: the profile's, else the first searched one that passes (module
    docstring). The joint-2/3 step is the largest of ``ARM_STEPS_DEG`` (not below
    ``[procedure] step_deg``) whose targets pass; the "j1" configuration is planned with the
    largest of ``AZIMUTH_STEPS_DEG`` that passes, and left out (with a log line) if none does.
    """
    geom = geometry(profile)
    margins = tolerance_margins(profile)
    first: SafetyError | None = None
    tried = 0
    for pose, searched in _pose_candidates(profile):
        tried += 1
        try:
            plan = _plan_at(profile, geom, pose, margins)
        except SafetyError as e:
            first = first or e
            continue
        if searched:
            log.warning(
                "calibration pose %s: the profile's fails a check (%s)",
                np.round(pose, 2).tolist(),
                first,
            )
        gains = plan_amplification(profile, plan)
        return replace(
            plan,
            sound_speed_gain_deg_per_m_s=gains[0],
            distance_noise_gain_deg_per_um=gains[1],
            steps_checked=checked_steps(profile, geom, plan),
        )
    _, lever = tool_lever(profile)
    w = profile.sample_matrix[:3, :3] @ np.full(3, lever + profile.procedure.water_path_mm)
    advice = move_advice(
        profile, lambda moved: _plans_somewhere(moved, margins), w + profile.sample_matrix[:3, 3]
    )
    raise SafetyError(
        f"{first or 'no calibration pose reaches the block'}; none of the {tried} calibration "
        f"poses tried passes either: {advice}"
    )


#: Searched poses a moved block is tried with when a refusal says how far to move it.
ADVICE_POSES = 12


def _plans_somewhere(profile: CellProfile, margins: Margins) -> bool:
    """Whether one of the first ``ADVICE_POSES`` searched calibration poses plans (the
    refusal's advice: would the block, moved, do?)."""
    geom = geometry(profile)
    for pose in itertools.islice(_searched_poses(profile), ADVICE_POSES):
        try:
            _plan_at(profile, geom, pose, margins)
        except SafetyError:
            continue
        return True
    return False


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
