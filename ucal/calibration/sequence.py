"""The joint-offset calibration sequence of paper 000: plan, preflight, measure, solve.

Configurations: the calibration pose ("base"), joint 3 stepped by δθ3 ("j3"), back, joint 2
stepped by δθ2 ("j2"). In each, the beam is brought normal to the block's three faces (XY:
the beam straight down at the paper's pose), the normal-incidence posture found by the peak
search and the water path read by time of flight: 9 face measurements (order: see
``order_targets``). The arm stays
still during a configuration; only the wrist moves, so W stays put (arm–wrist separation).

Every target is planned and checked before the first motion (joint ranges with room for the
wrist search, the θ5 singularity margin, the beam meeting each face inside its edges at a
positive water path). During the run each new measurement refines the estimate of the offsets
and of the block corner (a regularised fit of the measurements so far), which predicts the next
posture: the first face may need a wide search, the others are found near their prediction.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ucal.calibration.exact import OffsetSolution, beam_on_axis, solve_exact
from ucal.calibration.faces import acquisition_gain, estimate_offsets, make_search, measure_face
from ucal.calibration.model import (
    FACE_NAMES,
    CellGeometry,
    FaceMeasurement,
    beam_and_tcp,
    face_basis,
)
from ucal.calibration.paper import solve_paper
from ucal.calibration.safety import check_joints
from ucal.calibration.search import Rig, ka_of
from ucal.calibration.wrist import aim_wrist, search_joints
from ucal.cell import CellProfile
from ucal.errors import SafetyError
from ucal.kinematics.rotations import rpy_to_matrix

log = logging.getLogger(__name__)

FACE_ORDER = (2, 0, 1)             # XY, YZ, XZ
MIN_WATER_PATH_MM = 20.0
EDGE_MARGIN_MM = 20.0


@dataclass(frozen=True)
class PlannedTarget:
    """One nominal normal-incidence posture of the plan."""

    config: str
    face: int
    joints_deg: np.ndarray
    search_joints: tuple[int, int]
    water_path_mm: float

    @property
    def label(self) -> str:
        return f"{self.config}/{FACE_NAMES[self.face]}"


@dataclass(frozen=True)
class CalibrationPlan:
    pose_deg: np.ndarray
    step_deg: float
    targets: tuple[PlannedTarget, ...]


@dataclass
class CalibrationRun:
    """What a run measured."""

    measurements: list[FaceMeasurement]
    moves: int
    reads: int


def geometry(profile: CellProfile) -> CellGeometry:
    """Known geometry for the solvers: model, tool, block orientation."""
    return CellGeometry(profile.model, profile.tool_matrix,
                        rpy_to_matrix(profile.sample_rotation_deg))


def calibration_pose(profile: CellProfile) -> np.ndarray:
    """The profile's calibration pose, or one computed with IK from the block pose.

    Computed: the beam straight down onto the XY face with the wrist centre at equal distances
    from the three faces (the tool centre ``water_path_mm`` above the XY face).
    """
    proc = profile.procedure
    if proc.calibration_pose_deg is not None:
        return np.asarray(proc.calibration_pose_deg, float)
    from ucal.kinematics.ik import ik

    s_mat = profile.sample_matrix
    reach = profile.model.d_mm[5] + profile.tool_position_mm[2] + proc.water_path_mm
    target = np.eye(4)
    target[:3, :3] = s_mat[:3, :3] @ np.diag([-1.0, 1.0, -1.0])  # tool z = −block z
    target[:3, 3] = s_mat[:3, :3] @ np.array([reach, reach, proc.water_path_mm]) + s_mat[:3, 3]
    from ucal.cell import PAPER_CALIBRATION_POSE_DEG

    return ik(profile.model, target, profile.tool_matrix, profile.joint_offsets_deg,
              near_deg=PAPER_CALIBRATION_POSE_DEG)


def config_arm(pose_deg: np.ndarray, config: str, step_deg: float) -> np.ndarray:
    """Joint readings of a configuration's arm (wrist as in ``pose_deg``)."""
    q = np.array(pose_deg, float)
    if config == "j3":
        q[2] += step_deg
    elif config == "j2":
        q[1] += step_deg
    return q


CONFIGS = ("base", "j3", "j2")
THETA6_SHIFT_DEG = {"base": 0.0, "j3": 90.0, "j2": -90.0}


def _face_hit_check(profile: CellProfile, geom: CellGeometry, q: np.ndarray, face: int,
                    offsets: np.ndarray, label: str) -> float:
    beam, tcp = beam_and_tcp(geom, q, offsets)
    s_mat = profile.sample_matrix
    local_tcp = s_mat[:3, :3].T @ (tcp - s_mat[:3, 3])
    path = float(local_tcp[face])
    if path < MIN_WATER_PATH_MM:
        raise SafetyError(f"plan {label}: the tool centre would be {path:.1f} mm from face "
                          f"{FACE_NAMES[face]} (minimum {MIN_WATER_PATH_MM:g} mm)")
    hit = local_tcp + path * (s_mat[:3, :3].T @ beam)
    size = profile.sample_face_size_mm
    inplane = [hit[i] for i in range(3) if i != face]
    edge = min(min(v, size - v) for v in inplane)
    if edge < EDGE_MARGIN_MM:
        raise SafetyError(f"plan {label}: the beam would meet face {FACE_NAMES[face]} "
                          f"{edge:.1f} mm from its edge (minimum {EDGE_MARGIN_MM:g} mm)")
    return path


def plan_calibration(profile: CellProfile) -> CalibrationPlan:
    """Plan and check every target before the first motion (``SafetyError``, exit 4)."""
    geom = geometry(profile)
    proc = profile.procedure
    pose = calibration_pose(profile)
    offsets = profile.joint_offsets_deg
    model = profile.model
    if not model.within_limits(pose):
        raise SafetyError(f"the calibration pose {np.round(pose, 2).tolist()} is outside the "
                          "joint ranges")
    targets = []
    on_axis = beam_on_axis(geom)
    for config in CONFIGS:
        arm = config_arm(pose, config, proc.step_deg)
        if on_axis:
            # θ6 does not aim an on-axis beam; turning it between configurations separates a
            # joint-5 offset from a tilt of the beam in the flange (see ucal.calibration.exact).
            shift = THETA6_SHIFT_DEG[config]
            if not model.joint_min_deg[5] + 10 <= arm[5] + shift <= model.joint_max_deg[5] - 10:
                shift = -shift
            arm[5] += shift
        for face in FACE_ORDER:
            label = f"{config}/{FACE_NAMES[face]}"
            q = aim_wrist(geom, arm, -geom.normal(face), offsets)
            check_joints(profile, q, label)
            path = _face_hit_check(profile, geom, q, face, offsets, label)
            js, _ = search_joints(geom, q, offsets, face_basis(geom, face))
            targets.append(PlannedTarget(config, face, q, js, path))
    return CalibrationPlan(pose, proc.step_deg, tuple(order_targets(targets)))


def order_targets(targets: list[PlannedTarget]) -> list[PlannedTarget]:
    """Execution order: XY and YZ in every configuration first, XZ last on the way back.

    After two faces two combinations of offsets are still free and a third face can be degrees
    from its prediction, while the same face in a stepped configuration is predicted almost
    exactly (the step is a known rotation). Measuring XY and YZ in all three configurations
    first pins the model down, so the XZ faces are found at their predictions.
    """
    by_key = {(t.config, t.face): t for t in targets}
    first = [by_key[(c, f)] for c in CONFIGS for f in FACE_ORDER[:2]]
    last = [by_key[(c, FACE_ORDER[2])] for c in reversed(CONFIGS)]
    return first + last


def choose_step(profile: CellProfile, geom: CellGeometry, plan: CalibrationPlan, config: str,
                est: np.ndarray, corner: np.ndarray, last_wrist: dict[int, np.ndarray]) -> float:
    """Signed joint step for ``config`` that keeps every face at a safe water path.

    With the offsets estimated from the faces measured so far, the water paths of the stepped
    configuration are predictable: the step goes the way (+ or −) whose smallest predicted water
    path is larger, provided all stay above ``MIN_WATER_PATH_MM`` and inside the joint ranges.
    Large offsets can put the wrist centre tens of millimetres lower than nominal; stepping the
    wrong way would then drive the tool into the block.
    """
    if config == "base":
        return plan.step_deg
    model = profile.model
    best, best_path = None, -np.inf
    why = []
    for sign in (1.0, -1.0):
        step = sign * plan.step_deg
        arm = config_arm(plan.pose_deg, config, step)
        paths = []
        ok = True
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
                ok = False
                break
            # The prediction is good to a fraction of a degree now: a small margin suffices.
            if not np.all((q >= model.joint_min_deg + 1.0) & (q <= model.joint_max_deg - 1.0)):
                why.append(f"{step:+g}°: face {FACE_NAMES[t.face]} needs joints "
                           f"{np.round(q, 1).tolist()} at a range limit")
                ok = False
                break
            _, tcp = beam_and_tcp(geom, q, est)
            paths.append(float(geom.normal(t.face) @ (tcp - corner)))
        if ok and min(paths) > best_path:
            best, best_path = step, min(paths)
        elif ok:
            why.append(f"{step:+g}°: {min(paths):.1f} mm of water")
    if best is None or best_path < MIN_WATER_PATH_MM:
        raise SafetyError(f"configuration {config}: with the offsets measured so far no joint "
                          f"step of ±{plan.step_deg:g} deg is safe ({'; '.join(why)})")
    if best != plan.step_deg:
        log.info("%s: stepping by %+g deg keeps the tool clear (%.1f mm)", config, best, best_path)
    return best


def refit_peaks(rig: Rig, geom: CellGeometry, profile: CellProfile,
                meas: list[FaceMeasurement], ka: float, prior: np.ndarray,
                rounds: int = 2) -> list[FaceMeasurement]:
    """Fit every face's recorded probes again with the offsets of a full solution.

    The first faces were fitted with kinematics whose offsets could be degrees off, which
    distorts the fit model (beam direction and water path against the wrist joints) at the
    1e-4 degree level. No motion: only the recorded probes are used.
    """
    from dataclasses import replace as dc_replace

    for _ in range(rounds):
        est = solve_exact(geom, meas, prior).offsets_deg
        new = []
        for m in meas:
            probes = m.meta.get("probes")
            if probes is None:
                new.append(m)
                continue
            search = make_search(rig, geom, profile, m.joints_deg, m.face, est, ka,
                                 m.meta["search_joints"])
            peak = search.refit(probes)
            new.append(dc_replace(m, joints_deg=peak.joints_deg,
                                  tilt_std_deg=max(peak.tilt_std_deg, 1e-4)))
        meas = new
    return meas


def run_calibration(profile: CellProfile, plan: CalibrationPlan, rig: Rig,
                    progress: Callable[[str, int, int], None] | None = None) -> CalibrationRun:
    """Measure the nine faces (``solve`` turns them into offsets). The caller owns the
    connection, STOP and the profile."""
    geom = geometry(profile)
    temp = profile.water_temperature_c
    ka = ka_of(profile.frequency_mhz, profile.element_diameter_mm, temp)
    est = np.array(profile.joint_offsets_deg, float)
    corner = np.array(profile.sample_position_mm, float)
    prior = est.copy()
    meas: list[FaceMeasurement] = []

    # Noise floor with the beam in open water: the first target with the wrist turned 25°
    # away from normal (far outside every lobe that matters).
    first = plan.targets[0]
    away = first.joints_deg.copy()
    away[first.search_joints[1]] += 25.0
    acq_gain = acquisition_gain(rig, away)

    total = len(plan.targets)
    last_wrist: dict[int, np.ndarray] = {}
    steps: dict[str, float] = {}
    for i, target in enumerate(plan.targets):
        if progress:
            progress(target.label, i, total)
        if target.config not in steps:
            steps[target.config] = choose_step(profile, geom, plan, target.config, est, corner,
                                               last_wrist)
        start = config_arm(plan.pose_deg, target.config, steps[target.config])
        start[3:] = last_wrist.get(target.face, target.joints_deg)[3:]
        start[5] = target.joints_deg[5]
        # Three faces pin the model down: later predictions land within a few thousandths of a
        # degree, inside the fit's first grid; two faces leave a fraction of a degree.
        mode = "direct" if len(meas) >= 3 else "quick" if len(meas) == 2 else "acquire"
        res = measure_face(rig, geom, profile, start, target.face, est, ka, acq_gain,
                           f"face {FACE_NAMES[target.face]} ({target.label})", target.config,
                           mode, 16.0 if not meas else 8.0)
        meas.append(res.measurement)
        last_wrist[target.face] = res.measurement.joints_deg
        est, corner = estimate_offsets(geom, meas, prior, corner)
    # Leave the robot at the calibration pose's XY posture.
    rig.move(plan.targets[0].joints_deg)
    meas = refit_peaks(rig, geom, profile, meas, ka, prior)
    if progress:
        progress("done", total, total)
    return CalibrationRun(meas, rig.counters.moves, rig.counters.reads)


def solve(profile: CellProfile, run: CalibrationRun, beam: str = "auto"
          ) -> tuple[OffsetSolution, OffsetSolution | None]:
    """Both solutions from one run's measurements: exact, and paper 000's (None if it cannot
    be applied, e.g. a DH table of another structure)."""
    geom = geometry(profile)
    prior = np.asarray(profile.joint_offsets_deg, float)
    exact = solve_exact(geom, run.measurements, prior, beam=beam)
    try:
        paper = solve_paper(geom, run.measurements, prior, exact.unobservable_joints,
                            exact.condition_number)
    except Exception as e:  # noqa: BLE001 — the paper method is a comparison, never fatal
        log.warning("paper method failed: %s", e)
        paper = None
    return exact, paper
