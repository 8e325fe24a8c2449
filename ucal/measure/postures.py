"""The measuring run of ``calibrate --level full``: the planned postures, one face search each.

Read top to bottom: noise floor and acquisition gain once; on a profile whose offsets were
never calibrated, the offsets level's faces first (``FullPlan.first``,
``ucal.measure.sequence.measure_targets``: the calibration pose, J3, J2 and J1 stepped),
the running estimate carried on from them (they place the postures; the model is identified
from the postures' faces, ``FullRun.first`` keeps them apart); then for every planned posture
(``ucal.model.postures``, visiting order) the face measured by the running estimate of
``ucal.measure.running`` (the posture predicted with the cell as measured so far, checked
before moving, searched as the one trust policy says, the estimate refitted), every move
ending from below on each joint (``FinalApproachRig``: backlash), or from above on the
postures the plan turns (``FullPlan.above``: each joint read from both sides, its lost motion
measured; the offsets stay those of the positive approach). At the end the early faces'
probes are fitted again with the final estimate, and ``ucal.model.kinematic.solve_full``
identifies the model.

Each posture is moved first so that the tool centre stands where the plan put it relative to
the block as the run has measured it so far (``retarget``): the plan's arm joints on a cell
whose offsets are a degree off would put it tens of millimetres from there on a TX90XL, which
the wrist's aim alone does not correct (the plan keeps room for what the run does not know yet,
``ucal.model.postures.visit_order``). The prediction holds the DH table at the profile's
(a few tenths of a millimetre move a posture by hundredths of a degree): the search around
each prediction absorbs that. A face whose peak
came out uncertain (``ucal.measure.running.UNCERTAIN_TILT_DEG``) is left out of the
predictions and measured again at the end.

A posture over the step of known height (``[step]``, the length standard) is measured like one
on the XY face, its top being parallel to it; its water path is kept apart (``FullRun.steps``:
the running estimate and the peaks' refit know only the faces) and enters the identification
with the step's height (``ucal.model.kinematic.step_residuals``).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np

from ucal.cell import CellProfile
from ucal.devices.rig import Rig
from ucal.errors import UcalError
from ucal.kinematics.dh import fk, transform
from ucal.kinematics.ik import ik
from ucal.measure.face import SearchMode
from ucal.measure.running import UNCERTAIN_TILT_DEG, RunningEstimate
from ucal.measure.sequence import measure_targets, start_running
from ucal.model.geometry import FACE_NAMES, Face, FaceMeasurement
from ucal.model.postures import FullPlan, Posture, first_postures
from ucal.model.targets import geometry
from ucal.profile.models import joint_speeds_deg_s
from ucal.progress import MeasureStep, Report
from ucal.timing import DurationEstimate, estimate_run

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class FullRun:
    """What the full level's run measured: the postures' faces (what is identified from), the
    water paths over the step, and the offsets level's faces measured first where the plan
    has them (``FullPlan.first``: they placed the postures)."""

    measurements: list[FaceMeasurement]
    steps: list[FaceMeasurement]
    moves: int
    reads: int
    first: list[FaceMeasurement] = field(default_factory=list)


def direction(plan: FullPlan, label: str) -> int:
    """How the posture ``label`` is reached: from above (−1) if the plan says so
    (``FullPlan.above``: the lost motion), else from below (+1)."""
    return -1 if label in plan.above else 1


#: A re-placed posture's joints 1-3 further than this (deg) from the plan's are on another
#: branch of the inverse kinematics (the offsets and the block move them by a few degrees).
BRANCH_DEG = 20.0


def retarget(profile: CellProfile, running: RunningEstimate, posture: Posture) -> np.ndarray:
    """The readings (6,) that put the tool where ``posture`` puts it relative to the block on
    the profile's cell, on the cell as ``running`` has measured it so far (its offsets,
    block and tool), joint 6 as planned (the turn about the beam is free: near the wrist's
    singularity the estimated tool's orientation would swing joints 4 and 6 by degrees out
    of the room planned for the search; the run aims joints 4 and 5); the planned readings
    where no solution on the planned branch reaches that pose (``BRANCH_DEG``)."""
    rel = np.linalg.inv(profile.sample_matrix) @ fk(
        profile.model, posture.joints_deg, profile.tool_matrix, profile.joint_offsets_deg
    )
    geom = running.geometry
    block = transform(running.corner_mm, geom.block_rotation)
    try:
        q = ik(geom.model, block @ rel, geom.tool_matrix, running.offsets_deg, posture.joints_deg)
    except UcalError as e:
        log.info("%s: kept as planned (%s)", posture.label, e)
        return posture.joints_deg
    arm = np.abs(q[:3] - posture.joints_deg[:3])
    if np.max(arm) > BRANCH_DEG:
        # its own branch out of range: the nearest in range is another shoulder or elbow,
        # the arm swung over the base or folded to reach it; the plan's stays
        log.info("%s: kept as planned (another branch, joints 1-3 %s° away)", posture.label, arm)
        return posture.joints_deg
    q[5] = posture.joints_deg[5]
    return q


def run_full(
    profile: CellProfile,
    plan: FullPlan,
    rig: Rig,
    progress: Report | None = None,
) -> FullRun:
    """Measure every planned posture (module docstring), reporting each as it starts and the
    final refit. The caller owns the connection, STOP and the profile."""
    lead = 0 if plan.first is None else len(plan.first.targets)
    total = lead + len(plan.postures)
    if plan.first is None:
        home = plan.postures[0].joints_deg
        # the noise floor off the first posture, J5 turned (the beam in open water)
        running = RunningEstimate.start(profile, rig, geometry(profile), home, 4)
    else:  # the offsets measured first (module docstring), as the offsets level does
        home = plan.first.targets[0].joints_deg
        running = start_running(profile, plan.first, rig)
        measure_targets(running, plan.first, progress, total)
    # plan index of each face measurement after the offsets level's (theirs: -1)
    taken: list[int] = [-1] * len(running.measurements)
    steps: list[FaceMeasurement] = []
    top = 0.0 if profile.step is None else profile.step.height_mm
    for i, posture in enumerate(plan.postures):
        if progress:
            progress(
                MeasureStep(
                    f"posture {posture.label}", lead + i, total, posture.label, posture.face_name
                )
            )
        label = f"face {posture.face_name} ({posture.label})"
        above = top if posture.step else 0.0
        found = running.measure(
            posture.face,
            retarget(profile, running, posture),
            label,
            posture.label,
            above,
            keep=not posture.step,
            direction=direction(plan, posture.label),
        )
        if posture.step:
            steps.append(found.measurement)
        else:
            taken.append(i)
    # Faces whose peak came out uncertain (found from a poor early prediction, where side
    # lobes and a neighbouring face's echo crowd the search) are measured again, now that the
    # prediction is good to hundredths of a degree.
    # (an offsets level's face is measured again where its peak was found)
    for i, m in enumerate(list(running.measurements)):
        if m.tilt_std_deg <= UNCERTAIN_TILT_DEG:
            continue
        if taken[i] < 0:
            face, name, config, sign = Face(m.face), FACE_NAMES[m.face], m.config, 1
            q = np.array(m.joints_deg, float)
        else:
            posture = plan.postures[taken[i]]
            face, name, config = posture.face, posture.face_name, posture.label
            q, sign = retarget(profile, running, posture), direction(plan, posture.label)
        label = f"face {name} ({config}, again)"
        log.info(
            "%s: tilt σ %.3f° above %g°, measuring again", label, m.tilt_std_deg, UNCERTAIN_TILT_DEG
        )
        again = running.measure(
            face, q, label, config, mode=SearchMode.QUICK, keep=False, direction=sign
        )
        running.replace(i, again.measurement)
    running.rig.move(home)
    meas = running.refit_peaks()
    if progress:
        progress(MeasureStep("solving", total, total))
    n = taken.count(-1)  # the offsets level's faces come first
    return FullRun(meas[n:], steps, rig.counters.moves, rig.counters.reads, meas[:n])


def estimate_postures(plan: FullPlan, profile: CellProfile) -> DurationEstimate:
    """The real-cell duration of measuring each of ``plan``'s postures as ``run_full`` does
    (the offsets level's faces first where the plan has them)."""
    targets = [p.joints_deg for p in first_postures(plan.first) + list(plan.postures)]
    return estimate_run(
        targets,
        targets[0],
        profile.procedure.speed,
        speeds_deg_s=joint_speeds_deg_s(profile.model),
    )
