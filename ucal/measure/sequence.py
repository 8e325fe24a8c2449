"""The joint-offset calibration sequence of paper 000: measure and solve what
``ucal.model.targets`` planned and checked.

Configurations: the calibration pose ("base"), joint 3 stepped by δθ3 ("j3"), back, joint 2
stepped by δθ2 ("j2") — paper 000's three — and, where the cell leaves room, joint 1 stepped
("j1"): seen from a second J1 azimuth, a tilt of the block is no longer one rotation with δ2
(``ucal.model.fit``). In each, the beam is brought normal to the block's three faces (XY:
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
then part of the offset instead of a configuration-dependent error. A plan ``with_lost_motion``
measures the calibration pose's three faces again at the end, every posture reached from
above: each joint read from both sides, its lost motion measured, the offsets still those of
the positive approach.

The tank's drift: each configuration's faces are read one after the other in about half a
minute, so their water paths barely tell a drifting sound speed from the configurations. The
run therefore ends where it began, reading the first face's water path again at the same
joint readings, gain and approach (``RunningEstimate.read_path_again``; ``CalibrationPlan.
path_again``): what changed is the tank. It costs no move (the run ends at that posture
anyway), only the water path's reads.

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

from ucal.cell import CellProfile
from ucal.devices.rig import Rig
from ucal.errors import SafetyError
from ucal.measure.face import SearchMode
from ucal.measure.running import RunningEstimate
from ucal.model.geometry import (
    FACE_NAMES,
    FACE_ORDER,
    CellGeometry,
    Configuration,
    FaceMeasurement,
)
from ucal.model.safety import (
    EDGE_MARGIN_MM,
    MIN_WATER_PATH_MM,
    beam_meets_step,
    face_hit,
)
from ucal.model.targets import (
    STEPPED_PATH_RANGE_MM,
    CalibrationPlan,
    config_arm,
    geometry,
)
from ucal.model.wrist import aim_wrist
from ucal.progress import MeasureStep, Report

log = logging.getLogger(__name__)


@dataclass
class CalibrationRun:
    """What a run measured."""

    measurements: list[FaceMeasurement]
    moves: int
    reads: int


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
    checked = None if plan.steps_checked is None else plan.steps_checked.get(config, ())
    # the steps the plan checked with the tolerances' room first; the others only where none
    # of those keeps the tool clear (the cell as measured then says where the wrist goes)
    rounds = [True] if checked is None else [True, False]
    for first_round, magnitude in ((r, m) for r in rounds for m in plan.step_candidates(config)):
        best, best_path = None, -np.inf
        for sign in (1.0, -1.0):
            step = sign * magnitude
            if checked is not None and (step in checked) != first_round:
                continue
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
        if beam_meets_step(profile, geom, q, est, corner, t.face, 0.0):
            why.append(f"{step:+g}°: the beam to face {FACE_NAMES[t.face]} would meet the step")
            return None
        paths.append(path)
    if min(paths) < MIN_WATER_PATH_MM:
        why.append(f"{step:+g}°: {min(paths):.1f} mm of water")
    if max(paths) > STEPPED_PATH_RANGE_MM[1]:
        why.append(f"{step:+g}°: {max(paths):.1f} mm of water (echo too weak)")
        return None
    return min(paths)


def measure_targets(
    running: RunningEstimate,
    plan: CalibrationPlan,
    progress: Report | None = None,
    total: int | None = None,
) -> dict[int, np.ndarray]:
    """Measure ``plan``'s targets with ``running``, configuration by configuration, each
    stepped as far as the offsets measured so far keep the tool clear (``choose_step``; a
    second azimuth that cannot be stepped is skipped), reporting each face as it starts (of
    ``total``, the plan's targets unless given). Returns each face's last peak posture (the
    start of its wrist for a later search of it)."""
    total = len(plan.targets) if total is None else total
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
                    running.profile,
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
                # in joints 2 and 3's stds (``ucal.model.fit``).
                log.warning("second J1 azimuth skipped: %s", e)
                skipped.add(target.config)
                continue
        start = config_arm(plan.pose_deg, target.config, steps[target.config])
        start[3:] = last_wrist.get(target.face, target.joints_deg)[3:]
        start[5] = target.joints_deg[5]
        label = f"face {FACE_NAMES[target.face]} ({target.label})"
        found = running.measure(target.face, start, label, target.config)
        last_wrist[target.face] = found.measurement.joints_deg
    return last_wrist


def start_running(profile: CellProfile, plan: CalibrationPlan, rig: Rig) -> RunningEstimate:
    """The running estimate of a run that begins with ``plan``'s first target (the noise
    floor read there, its second search joint turned)."""
    first = plan.targets[0]
    return RunningEstimate.start(
        profile, rig, geometry(profile), first.joints_deg, first.search_joints[1]
    )


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
    running = start_running(profile, plan, rig)
    total = len(plan.targets)
    last_wrist = measure_targets(running, plan, progress)
    meas = running.refit_peaks()
    meas += measure_above(running, plan, last_wrist)
    if plan.path_again and running.measurements:
        # the first water path again, where it was read: the robot ends at the calibration
        # pose's XY posture, as it began
        meas.append(running.read_path_again(0, f"{running.measurements[0].config}-{AGAIN}"))
    else:
        running.rig.move(first.joints_deg)  # leave the robot at the calibration pose's XY
    if progress:
        progress(MeasureStep("solving", total, total))
    return CalibrationRun(meas, rig.counters.moves, rig.counters.reads)


#: What the configuration label of a measurement read again says (``read_path_again``) and of
#: one approached from above (``with_lost_motion``), after the configuration's own.
AGAIN, ABOVE = "again", "above"


def with_lost_motion(plan: CalibrationPlan) -> CalibrationPlan:
    """``plan`` measuring each joint's lost motion: the calibration pose's three faces
    measured again at the end, every posture reached from above, in the order that ends the
    run where it began.

    Reached from above, each joint's link sits on the other side of its lost motion ``b``;
    the three faces see the beam turned about three axes and the tool centre moved along
    three normals, which separates ``b`` on joints 1-5 (joint 6 only where the beam is off its
    axis). Two of the faces leave joints 1 and 3 a few thousandths of a degree apart; the
    third brings every one to a few ten-thousandths (``tests/unit/calibration``).
    """
    base = [t for t in plan.targets if t.config == Configuration.BASE]
    above = sorted(base, key=lambda t: FACE_ORDER.index(t.face), reverse=True)
    return replace(plan, above=tuple(above))


def measure_above(
    running: RunningEstimate, plan: CalibrationPlan, last_wrist: dict[int, np.ndarray]
) -> list[FaceMeasurement]:
    """The plan's ``above`` targets measured again, every posture reached from above
    (``with_lost_motion``): fitted at the final estimate's prediction, without refitting it
    (the estimate's offsets are the positive approach's)."""
    out = []
    for target in plan.above:
        start = np.array(target.joints_deg, float)
        start[3:] = last_wrist.get(target.face, target.joints_deg)[3:]
        config = f"{target.config}-{ABOVE}"
        label = f"face {FACE_NAMES[target.face]} ({config})"
        found = running.measure(
            target.face, start, label, config, mode=SearchMode.DIRECT, keep=False, direction=-1
        )
        out.append(found.measurement)
    return out
