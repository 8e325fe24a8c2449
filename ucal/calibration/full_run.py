"""The measuring run of ``calibrate --level full``: the planned postures, one face search each.

Read top to bottom: noise floor and acquisition gain once; then for every planned posture
(``ucal.calibration.full_plan``, visiting order) predict the normal-incidence posture with the
cell as measured so far, check it (joint ranges with room for the wrist search, the θ5
singularity margin, a safe water path) before moving, and measure the face there
(``ucal.calibration.faces.measure``: peak search and water path); each measurement refines
the estimate that predicts the next posture. Every move ends approaching from below on each
joint (``FinalApproachRig``: backlash). At the end the early faces' probes are fitted again
with the final estimate, and ``ucal.calibration.full.solve_full`` identifies the model.

The prediction holds the DH table at the profile's (a few tenths of a millimetre move a posture
by hundredths of a degree): the search around each prediction absorbs that. A prediction that
landed within ``DIRECT_FIT_DEG`` lets the next face be fitted at once, otherwise the search
centres first. A face whose peak came out uncertain is left out of the predictions and
measured again at the end (``REMEASURE_TILT_DEG``).

A posture over the step of known height (``[step]``, the length standard) is measured like one
on the XY face, its top being parallel to it; its water path is kept apart (``FullRun.steps``:
the running estimate and the peaks' refit know only the faces) and enters the identification
with the step's height (``ucal.calibration.full.step_residuals``).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import cast

import numpy as np

from ucal.calibration.faces import (
    FaceRequest,
    FaceResult,
    FaceSetup,
    SearchMode,
    acquisition_gain,
    measure,
)
from ucal.calibration.fit import prior_from_profile
from ucal.calibration.full_plan import FullPlan, Posture
from ucal.calibration.model import CellGeometry, FaceMeasurement, beam_and_tcp
from ucal.calibration.safety import check_joints
from ucal.calibration.search import Rig, ka_of
from ucal.calibration.sequence import (
    MIN_WATER_PATH_MM,
    FinalApproachRig,
    estimate_cell,
    geometry,
    refit_peaks,
)
from ucal.calibration.wrist import aim_wrist
from ucal.cell import CellProfile
from ucal.errors import SafetyError
from ucal.progress import MeasureStep, Report

log = logging.getLogger(__name__)

#: A prediction this close (deg of beam tilt) to the posture found lets the next face be
#: fitted without centring first.
DIRECT_FIT_DEG = 0.02
#: A face whose peak posture is less certain than this (deg of tilt) is left out of the
#: predictions and measured again at the end (a good one is a few thousandths).
REMEASURE_TILT_DEG = 0.01


@dataclass(frozen=True)
class FullRun:
    """What the full level's run measured: the faces, the water paths over the step."""

    measurements: list[FaceMeasurement]
    steps: list[FaceMeasurement]
    moves: int
    reads: int


def run_full(
    profile: CellProfile,
    plan: FullPlan,
    rig: Rig,
    progress: Report | None = None,
) -> FullRun:
    """Measure every planned posture (module docstring), reporting each as it starts and the
    final refit. The caller owns the connection, STOP and the profile."""
    geom = geometry(profile)
    ka = ka_of(profile.frequency_mhz, profile.element_diameter_mm, profile.water_temperature_c)
    prior = prior_from_profile(profile)
    approach = cast(Rig, FinalApproachRig(rig))  # a Rig whose moves end from below
    first = plan.postures[0]
    away = first.joints_deg.copy()
    away[4] += 25.0 if away[4] < 0 else -25.0  # the beam in open water: the noise floor
    setup = FaceSetup(profile, ka, acquisition_gain(rig, away))

    est = np.array(profile.joint_offsets_deg, float)
    corner = np.array(profile.sample_position_mm, float)
    fitted = geom
    vector = None
    last_error = np.inf
    meas: list[FaceMeasurement] = []
    taken: list[int] = []  # plan index of each face measurement
    steps: list[FaceMeasurement] = []
    top = 0.0 if profile.step is None else profile.step.height_mm
    total = len(plan.postures)

    def measure_posture(
        posture: Posture, label: str, mode: SearchMode, radius_deg: float
    ) -> FaceResult:
        """The face of ``posture``, its posture predicted with the cell as estimated so far."""
        request = FaceRequest(
            posture.face, posture.joints_deg, fitted, est, label, posture.label, mode, radius_deg
        )
        return measure(approach, setup, request)

    for i, posture in enumerate(plan.postures):
        if progress:
            progress(
                MeasureStep(f"posture {posture.label}", i, total, posture.label, posture.face_name)
            )
        label = f"face {posture.face_name} ({posture.label})"
        plane = corner + top * fitted.normal(2) if posture.step else corner
        check_prediction(profile, fitted, posture.joints_deg, posture.face, est, plane, label)
        mode = (
            SearchMode.ACQUIRE
            if not meas
            else SearchMode.DIRECT
            if last_error < DIRECT_FIT_DEG
            else SearchMode.QUICK
        )
        res = measure_posture(posture, label, mode, 16.0 if not meas else 8.0)
        last_error = res.prediction_error_deg
        if posture.step:
            steps.append(res.measurement)
            continue
        meas.append(res.measurement)
        taken.append(i)
        good = [m for m in meas if m.tilt_std_deg <= REMEASURE_TILT_DEG] or meas
        cell = estimate_cell(prior, good, vector)
        est, corner, vector, fitted = (cell.offsets_deg, cell.corner_mm, cell.vector, cell.geometry)
    # Faces whose peak came out uncertain (found from a poor early prediction, where side
    # lobes and a neighbouring face's echo crowd the search) are measured again, now that the
    # prediction is good to hundredths of a degree.
    for i, m in enumerate(meas):
        if m.tilt_std_deg <= REMEASURE_TILT_DEG:
            continue
        posture = plan.postures[taken[i]]
        label = f"face {posture.face_name} ({posture.label}, again)"
        log.info(
            "%s: tilt σ %.3f° above %g°, measuring again", label, m.tilt_std_deg, REMEASURE_TILT_DEG
        )
        check_prediction(profile, fitted, posture.joints_deg, posture.face, est, corner, label)
        res = measure_posture(posture, label, SearchMode.QUICK, 8.0)
        meas[i] = res.measurement
        good = [m for m in meas if m.tilt_std_deg <= REMEASURE_TILT_DEG] or meas
        cell = estimate_cell(prior, good, vector)
        est, corner, vector, fitted = (cell.offsets_deg, cell.corner_mm, cell.vector, cell.geometry)
    approach.move(first.joints_deg)
    meas = refit_peaks(approach, profile, meas, ka, prior)
    if progress:
        progress(MeasureStep("solving", total, total))
    return FullRun(meas, steps, rig.counters.moves, rig.counters.reads)


def check_prediction(
    profile: CellProfile,
    geom: CellGeometry,
    joints_deg: np.ndarray,
    face: int,
    offsets_deg: np.ndarray,
    corner_mm: np.ndarray,
    label: str,
) -> None:
    """Check the posture predicted for ``face`` from the planned one before moving there
    (``SafetyError``, exit 4): joint ranges with room for the wrist search, the singularity
    margin, and a water path of at least ``MIN_WATER_PATH_MM``."""
    q = aim_wrist(geom, joints_deg, -geom.normal(face), offsets_deg)
    check_joints(profile, q, label)
    _, tcp = beam_and_tcp(geom, q, offsets_deg)
    path = float(geom.normal(face) @ (tcp - corner_mm))
    if path < MIN_WATER_PATH_MM:
        raise SafetyError(
            f"{label}: with the cell as measured so far the tool centre would be "
            f"{path:.1f} mm from the face (minimum {MIN_WATER_PATH_MM:g} mm)"
        )
