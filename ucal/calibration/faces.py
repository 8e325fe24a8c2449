"""Measuring one face at normal incidence, shared by ``calibrate`` and ``verify``.

A face measurement starts from a predicted posture (the kinematics with the offsets estimated
so far), finds the echo and its peak posture with ``ucal.calibration.search`` and reads the water
path there. How hard it searches depends on how good the prediction is expected to be:

* ``direct``: the prediction is trusted to a few hundredths of a degree; fit at once;
* ``quick``: within about half a degree; centre on the main lobe first;
* otherwise acquire from scratch within ``radius_deg``.

A fit that comes out imprecise is redone after centring (the quality gate).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from ucal.acoustics import water_absorption_np_per_mm
from ucal.calibration.exact import residuals
from ucal.calibration.model import CellGeometry, FaceMeasurement, beam_and_tcp, face_basis
from ucal.calibration.search import PeakSearch, Rig, read_distance
from ucal.calibration.wrist import aim_wrist, beam_jacobian, search_joints
from ucal.cell import CellProfile
from ucal.errors import HardwareError

log = logging.getLogger(__name__)

#: A fit whose peak posture is less certain than this (deg of tilt) is redone after centring.
FIT_GATE_DEG = 0.02
#: Largest beam tilt from the predicted posture the acquisition raster reaches (deg).
ACQUIRE_MAX_DEG = 20.0
#: Moves one acquisition (``acquire_and_centre``) may use before it gives up: the coarse raster
#: to ACQUIRE_MAX_DEG and a fine raster about ±6° around the prediction. A block where the
#: profile says is found within a few lines; without this bound a missing echo kept the robot
#: sweeping for hundreds of moves.
MAX_ACQUISITION_MOVES = 100


def make_search(
    rig: Rig,
    geom: CellGeometry,
    profile: CellProfile,
    q: np.ndarray,
    face: int,
    est: np.ndarray,
    ka: float,
    joints: tuple[int, int] | None = None,
) -> PeakSearch:
    """A peak search across ``face`` whose fit uses the kinematics with offsets ``est``."""
    basis = face_basis(geom, face)
    normal = geom.normal(face)
    js, tilt_map = search_joints(geom, q, est, basis)
    if joints is not None and tuple(joints) != js:
        cols = [(3, 4, 5).index(j) for j in joints]
        tilt_map = (basis @ beam_jacobian(geom, q, est))[:, cols]
        js = tuple(joints)

    def components(qq: np.ndarray) -> np.ndarray:
        beam, tcp = beam_and_tcp(geom, qq, est)
        return np.column_stack([beam @ basis.T, tcp @ normal])

    return PeakSearch(
        rig,
        ka,
        js,
        tilt_map,
        profile.water_temperature_c,
        components,
        water_absorption_np_per_mm(profile.frequency_mhz),
    )


def acquisition_gain(rig: Rig, q_away: np.ndarray) -> float:
    """Measure the noise floor with the beam in open water at ``q_away``; return the gain (dB)
    that puts the floor at 2.5 % of full screen (threshold 10 %), where the side lobes of a
    normal echo show a degree or more around normal."""
    rig.configure(gain_db=20.0, averages=1)
    rig.move(rig.clip(q_away))
    rig.measure_floor()
    return float(np.clip(20 * np.log10(0.025 / rig.floor_per_gain), 20.0, 80.0))


def acquire_and_centre(
    search: PeakSearch,
    rig: Rig,
    q_pred: np.ndarray,
    label: str,
    radius_deg: float,
    gain_db: float,
    max_moves: int = MAX_ACQUISITION_MOVES,
) -> np.ndarray:
    """Raster outward from the prediction, then centre on the main lobe.

    Lines 2.5° apart first (at acquisition gain the side lobes show several degrees around
    normal at the nominal water path), the radius widening up to ``ACQUIRE_MAX_DEG``; if that
    finds nothing (a long water path leaves little more than the main lobe above the noise),
    lines 0.5° apart. After ``max_moves`` moves without an echo it gives up with a
    ``HardwareError`` (exit 3) naming the pulser and the face: the block is not where
    ``[sample]`` says, or the beam does not reach it (water, transducer, gate).
    """
    first_move = rig.counters.moves
    reached = 0.0
    for spacing in (2.5, 0.5):
        r = min(radius_deg, ACQUIRE_MAX_DEG)
        while True:
            left = max_moves - (rig.counters.moves - first_move)
            if left <= 0:
                break
            found = search.acquire(q_pred, r, gain_db, spacing_tilt_deg=spacing, max_moves=left)
            if found is not None:
                return search.centre(found[0], 3.0, gain_db)
            reached = max(reached, r)
            if r >= ACQUIRE_MAX_DEG:
                break
            r = min(2 * r, ACQUIRE_MAX_DEG)
    config, _, face = label.rpartition("/")
    where = f"face {face}" + (f" ({config})" if config else "")
    moves = rig.counters.moves - first_move
    raise HardwareError(
        f"pulser at {rig.pulser.endpoint}: no echo from {where} within "
        f"±{reached:g}° of the predicted posture ({moves} moves): is the block "
        "where [sample] says?"
    )


@dataclass(frozen=True)
class FaceResult:
    measurement: FaceMeasurement
    prediction_error_deg: float  # beam tilt between the predicted and the found posture


def measure_face(
    rig: Rig,
    geom: CellGeometry,
    profile: CellProfile,
    start: np.ndarray,
    face: int,
    est: np.ndarray,
    ka: float,
    acq_gain: float,
    label: str,
    config: str,
    mode: str = "acquire",
    radius_deg: float = 16.0,
) -> FaceResult:
    """Find normal incidence on ``face`` near the posture predicted from ``start`` and read the
    water path; ``mode`` is "direct", "quick" or "acquire" (see module docstring)."""
    q_pred = aim_wrist(geom, start, -geom.normal(face), est)
    search = make_search(rig, geom, profile, q_pred, face, est, ka)
    averages = max(profile.procedure.tof_averages, 1)

    def tof() -> tuple[float, float]:
        return read_distance(rig, profile.water_temperature_c, averages)

    peak = None
    if mode == "direct":
        try:
            peak = search.fit(q_pred, averages=8, distance=tof)
        except HardwareError as e:
            log.info("%s: direct fit failed (%s)", label, e)
    if peak is None or peak.tilt_std_deg > FIT_GATE_DEG:
        q_c = search.quick_centre(q_pred) if mode in ("direct", "quick") else None
        if q_c is None:
            q_c = acquire_and_centre(search, rig, q_pred, label, radius_deg, acq_gain)
        peak = search.fit(q_c, averages=8, distance=tof)
    if peak.tilt_std_deg > FIT_GATE_DEG:
        log.info("%s: poor fit (σ %.3f°), centring again", label, peak.tilt_std_deg)
        q_c = search.quick_centre(peak.joints_deg)
        if q_c is None:
            q_c = acquire_and_centre(search, rig, q_pred, label, 8.0, acq_gain)
        peak = search.fit(q_c, averages=8, distance=tof)
    assert peak.distance is not None
    path, path_std = peak.distance
    js = list(search.ja_jb)
    err = float(np.degrees(np.linalg.norm(search.m @ (peak.joints_deg[js] - q_pred[js]))))
    log.info(
        "%s: posture %s, water path %.4f ± %.4f mm, tilt σ %.4f°; prediction %.3f° off "
        "(%d moves, %d reads so far)",
        label,
        np.round(peak.joints_deg, 4).tolist(),
        path,
        path_std,
        peak.tilt_std_deg,
        err,
        rig.counters.moves,
        rig.counters.reads,
    )
    m = FaceMeasurement(
        config,
        face,
        peak.joints_deg,
        path,
        distance_std_mm=max(path_std, 1e-4),
        tilt_std_deg=max(peak.tilt_std_deg, 1e-4),
        amplitude=peak.amplitude,
        distance_joints_deg=peak.distance_joints_deg,
        meta={
            "gain_db": rig.settings.gain_db,
            "probes": peak.probes,
            "search_joints": search.ja_jb,
        },
    )
    return FaceResult(m, err)


def estimate_offsets(
    geom: CellGeometry,
    meas: list[FaceMeasurement],
    prior: np.ndarray,
    corner_prior: np.ndarray,
    x0: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Regularised fit of offsets (deg) and block corner (mm) to the measurements so far.

    Used to predict postures. With fewer than the full set the problem is under-determined;
    weak priors (5° on the offsets, 50 mm on the corner) keep the unseen directions in place.
    """

    def fun(x: np.ndarray) -> np.ndarray:
        r = residuals(geom, meas, x[:6], x[6:])
        return np.concatenate([r, (x[:6] - prior) / 5.0, (x[6:] - corner_prior) / 50.0])

    start = np.concatenate([prior, corner_prior]) if x0 is None else x0
    sol = least_squares(fun, start, method="trf", xtol=1e-12, ftol=1e-12, max_nfev=400)
    return sol.x[:6], sol.x[6:]
