"""The joint-offset calibration sequence of paper 000: plan, preflight, measure, solve.

Configurations: the calibration pose ("base"), joint 3 stepped by δθ3 ("j3"), back, joint 2
stepped by δθ2 ("j2"). In each, the beam is brought normal to the block's three faces (XY
first: the beam straight down at the paper's pose), the normal-incidence posture found by the
peak search and the water path read by time of flight: 9 face measurements. The arm stays
still during a configuration; only the wrist moves, so W stays put (arm–wrist separation).

Every target is planned and checked before the first motion (joint ranges with room for the
wrist search, the θ5 singularity margin, the beam meeting each face inside its edges at a
positive water path). During the run each new measurement refines the estimate of the offsets
and of the block corner (a regularised fit of the measurements so far), which predicts the next
posture: the first face may need a wide search, the others are found near their prediction.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Callable

import numpy as np
from scipy.optimize import least_squares

from ucal.calibration.exact import OffsetSolution, beam_on_axis, residuals, solve_exact
from ucal.calibration.model import (FACE_NAMES, CellGeometry, FaceMeasurement, beam_and_tcp,
                                    face_basis)
from ucal.calibration.paper import solve_paper
from ucal.calibration.search import PeakSearch, Rig, ka_of, read_distance
from ucal.calibration.wrist import aim_wrist, search_joints
from ucal.sim.acoustics import water_absorption_np_per_mm
from ucal.cell import CellProfile
from ucal.errors import HardwareError, SafetyError
from ucal.kinematics.dh import wrist_centre
from ucal.kinematics.rotations import rpy_to_matrix

log = logging.getLogger(__name__)

FACE_ORDER = (2, 0, 1)             # XY, YZ, XZ
SEARCH_MARGIN_DEG = 8.0            # room kept inside the joint ranges for the wrist search
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
    notes: list[str] = field(default_factory=list)


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
            lo = model.joint_min_deg.copy()
            hi = model.joint_max_deg.copy()
            lo[3:] += SEARCH_MARGIN_DEG
            hi[3:] -= SEARCH_MARGIN_DEG
            bad = [j + 1 for j in range(6) if not lo[j] <= q[j] <= hi[j]]
            if bad:
                raise SafetyError(f"plan {label}: joint(s) {bad} at "
                                  f"{np.round(q[np.array(bad) - 1], 2).tolist()} deg leave the "
                                  f"joint range (keeping {SEARCH_MARGIN_DEG:g} deg for the "
                                  "wrist search)")
            theta5 = q[4] + model.theta_offset_deg[4]
            if abs(np.sin(np.radians(theta5))) < np.sin(np.radians(proc.singularity_margin_deg)):
                raise SafetyError(f"plan {label}: joint 5 at {theta5:.2f} deg is within "
                                  f"{proc.singularity_margin_deg:g} deg of the wrist singularity")
            path = _face_hit_check(profile, geom, q, face, offsets, label)
            js, _ = search_joints(geom, q, offsets, face_basis(geom, face))
            targets.append(PlannedTarget(config, face, q, js, path))
    return CalibrationPlan(pose, proc.step_deg, tuple(targets))


def _estimate(geom: CellGeometry, meas: list[FaceMeasurement], prior: np.ndarray,
              corner_prior: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Regularised fit of offsets and block corner to the measurements so far (for prediction).

    With fewer than the full set the problem is under-determined; weak priors (5° on the
    offsets, 50 mm on the corner) keep the unseen directions at their prior.
    """
    def fun(x: np.ndarray) -> np.ndarray:
        r = residuals(geom, meas, x[:6], x[6:])
        return np.concatenate([r, (x[:6] - prior) / 5.0, (x[6:] - corner_prior) / 50.0])

    sol = least_squares(fun, np.concatenate([prior, corner_prior]), method="trf",
                        xtol=1e-12, ftol=1e-12, max_nfev=400)
    return sol.x[:6], sol.x[6:]


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
                ok = False
                break
            lo, hi = model.joint_min_deg.copy(), model.joint_max_deg.copy()
            lo[3:] += SEARCH_MARGIN_DEG
            hi[3:] -= SEARCH_MARGIN_DEG
            ok &= bool(np.all((q >= lo) & (q <= hi)))
            _, tcp = beam_and_tcp(geom, q, est)
            paths.append(float(geom.normal(t.face) @ (tcp - corner)))
        if ok and paths and min(paths) > best_path:
            best, best_path = step, min(paths)
    if best is None or best_path < MIN_WATER_PATH_MM:
        raise SafetyError(f"configuration {config}: with the offsets measured so far no joint "
                          f"step of ±{plan.step_deg:g} deg keeps the tool {MIN_WATER_PATH_MM:g} mm "
                          f"from every face (best {best_path:.1f} mm); check the block position")
    if best != plan.step_deg:
        log.info("%s: stepping by %+g deg keeps the tool clear (%.1f mm)", config, best, best_path)
    return best


def _make_search(rig: Rig, geom: CellGeometry, profile: CellProfile, q: np.ndarray, face: int,
                 est: np.ndarray, ka: float, joints: tuple[int, int] | None = None
                 ) -> PeakSearch:
    """A peak search across ``face`` whose fit uses the kinematics with offsets ``est``."""
    basis = face_basis(geom, face)
    normal = geom.normal(face)
    js, tilt_map = search_joints(geom, q, est, basis)
    if joints is not None and tuple(joints) != js:
        idx = [3, 4, 5]
        from ucal.calibration.wrist import beam_jacobian

        tilt_map = (basis @ beam_jacobian(geom, q, est))[:, [idx.index(j) for j in joints]]
        js = tuple(joints)

    def components(qq: np.ndarray) -> np.ndarray:
        beam, tcp = beam_and_tcp(geom, qq, est)
        return np.column_stack([beam @ basis.T, tcp @ normal])

    return PeakSearch(rig, ka, js, tilt_map, profile.water_temperature_c, components,
                      water_absorption_np_per_mm(profile.frequency_mhz))


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
            search = _make_search(rig, geom, profile, m.joints_deg, m.face, est, ka,
                                  m.meta["search_joints"])
            peak = search.refit(probes)
            new.append(dc_replace(m, joints_deg=peak.joints_deg,
                                  tilt_std_deg=max(peak.tilt_std_deg, 1e-4)))
        meas = new
    return meas


def _acquire_and_centre(search: PeakSearch, rig: Rig, q_pred: np.ndarray,
                        target: PlannedTarget, radius: float, gain_db: float) -> np.ndarray:
    """Raster outward from the prediction, then centre on the main lobe.

    Lines 2.5° apart first (at acquisition gain the side lobes show several degrees around
    normal at the nominal water path), the radius widening up to 20°; if that finds nothing (a
    long water path leaves little more than the main lobe above the noise), lines 0.5° apart.
    """
    for spacing in (2.5, 0.5):
        r = radius
        while True:
            found = search.acquire(q_pred, r, gain_db, spacing_tilt_deg=spacing)
            if found is not None:
                return search.centre(found[0], 3.0, gain_db)
            if r >= 20.0:
                break
            r = min(2 * r, 20.0)
    raise HardwareError(f"{rig.pulser.endpoint}: no echo from face {FACE_NAMES[target.face]} "
                        f"({target.label}) within 20 deg of the predicted posture")


def run_calibration(profile: CellProfile, plan: CalibrationPlan, rig: Rig,
                    progress: Callable[[str, int, int], None] | None = None) -> CalibrationRun:
    """Measure the nine faces and solve. The caller owns connection, STOP and the profile."""
    geom = geometry(profile)
    proc = profile.procedure
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
    rig.configure(gain_db=20.0, averages=1)
    rig.move(rig.clip(away))
    rig.measure_floor()
    # Acquisition gain: noise floor at 2.5 % of full screen (threshold at 10 %), where the
    # side lobes of a normal echo show a degree or more around normal.
    acq_gain = float(np.clip(20 * np.log10(0.025 / rig.floor_per_gain), 20.0, 80.0))

    total = len(plan.targets)
    last_wrist: dict[int, np.ndarray] = {}
    steps: dict[str, float] = {}
    for i, target in enumerate(plan.targets):
        if progress:
            progress(target.label, i, total)
        if target.config not in steps:
            steps[target.config] = choose_step(profile, geom, plan, target.config, est, corner,
                                               last_wrist)
        arm = config_arm(plan.pose_deg, target.config, steps[target.config])
        arm[5] = target.joints_deg[5]
        start = arm.copy()
        start[3:] = last_wrist.get(target.face, target.joints_deg)[3:]
        start[5] = target.joints_deg[5]
        q_pred = aim_wrist(geom, start, -geom.normal(target.face), est)
        js, tilt_map = search_joints(geom, q_pred, est, face_basis(geom, target.face))
        basis = face_basis(geom, target.face)

        normal = geom.normal(target.face)

        def components(qq: np.ndarray, est=est, basis=basis, normal=normal) -> np.ndarray:
            beam, tcp = beam_and_tcp(geom, qq, est)
            return np.column_stack([beam @ basis.T, tcp @ normal])

        search = PeakSearch(rig, ka, js, tilt_map, temp, components,
                            water_absorption_np_per_mm(profile.frequency_mhz))
        def tof() -> tuple[float, float]:
            return read_distance(rig, temp, max(proc.tof_averages, 1))

        peak = None
        if len(meas) >= 3:
            # Three faces pin the model down: predictions land within a few thousandths of a
            # degree, inside the fit's first grid. The quality gate below catches a miss.
            try:
                peak = search.fit(q_pred, averages=8, distance=tof)
            except HardwareError as e:
                log.info("%s: direct fit failed (%s)", target.label, e)
        if peak is None or peak.tilt_std_deg > 0.02:
            q_c = search.quick_centre(q_pred) if len(meas) >= 2 else None
            if q_c is None:
                q_c = _acquire_and_centre(search, rig, q_pred, target,
                                          16.0 if not meas else 8.0, acq_gain)
            peak = search.fit(q_c, averages=8, distance=tof)
        if peak.tilt_std_deg > 0.02:
            log.info("%s: poor fit (σ %.3f°), centring again", target.label, peak.tilt_std_deg)
            q_c = search.quick_centre(peak.joints_deg)
            if q_c is None:
                q_c = _acquire_and_centre(search, rig, q_pred, target, 8.0, acq_gain)
            peak = search.fit(q_c, averages=8, distance=tof)
        assert peak.distance is not None
        path, path_std = peak.distance
        pred_err = float(np.degrees(np.linalg.norm(
            tilt_map @ (peak.joints_deg[list(js)] - q_pred[list(js)]))))
        log.info("%s: prediction was %.3f° of tilt off (%d moves so far)", target.label, pred_err,
                 rig.counters.moves)
        m = FaceMeasurement(target.config, target.face, peak.joints_deg, path,
                            distance_std_mm=max(path_std, 1e-4),
                            tilt_std_deg=max(peak.tilt_std_deg, 1e-4),
                            amplitude=peak.amplitude,
                            distance_joints_deg=peak.distance_joints_deg,
                            meta={"gain_db": rig.settings.gain_db, "probes": peak.probes,
                                  "search_joints": search.ja_jb})
        meas.append(m)
        last_wrist[target.face] = peak.joints_deg
        log.info("%s: posture %s, water path %.4f ± %.4f mm, tilt σ %.4f°", target.label,
                 np.round(peak.joints_deg, 4).tolist(), path, path_std, peak.tilt_std_deg)
        est, corner = _estimate(geom, meas, prior, corner)
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
