"""Measuring one face at normal incidence: every face of the block any command measures.

A face measurement starts from a predicted posture (the kinematics with the offsets estimated
so far), finds the echo and its peak posture with ``ucal.measure.search`` and reads the water
path there. How hard it searches depends on how good the prediction is expected to be:

* ``SearchMode.DIRECT``: the prediction is trusted to a few hundredths of a degree; fit at once;
* ``SearchMode.QUICK``: within about half a degree; centre on the main lobe first;
* ``SearchMode.ACQUIRE``: acquire from scratch within ``radius_deg``.

A fit that comes out imprecise is redone after centring (the quality gate). A centred peak far
weaker than the main lobe the faces measured so far give at its water path is a side lobe
(``ucal.measure.search``, "Side lobes"): the search goes on to the main lobe with a raster
where only the main lobe shows, and names the face if it finds none. What a run's faces share
(the profile, k·a, the acquisition gain, the main lobe's heights found so far) is a
``FaceSetup``; what one face needs (the face, where to start, the kinematics to predict with)
a ``FaceRequest``. Which mode a face gets is the running estimate's policy
(``ucal.measure.running``); the noise floor and the raster are ``ucal.measure.acquire``'s.

Every static posture is reached the way the rig given reaches it: the procedures give a
``FinalApproachRig`` (every joint ends its move in its positive direction). The measurement
records that sign per joint (``approach``) and the minutes since the run's first reading
(``time_min``) at the water path's reading, so that a solver can model lost motion and the
tank's drift.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from enum import StrEnum

import numpy as np

from ucal.acoustics import water_absorption_np_per_mm
from ucal.cell import CellProfile
from ucal.devices.rig import Rig
from ucal.errors import HardwareError
from ucal.measure.acquire import acquire_and_centre, side_lobe_error
from ucal.measure.lobe import MainLobe
from ucal.measure.search import PeakSearch, read_distance
from ucal.model.geometry import (
    CellGeometry,
    Face,
    FaceMeasurement,
    beam_and_tcp,
    face_basis,
)
from ucal.model.wrist import aim_wrist, beam_jacobian, search_joints

log = logging.getLogger(__name__)

#: A fit whose peak posture is less certain than this (deg of tilt) is redone after centring.
FIT_GATE_DEG = 0.02


class SearchMode(StrEnum):
    """How far a face's predicted posture is trusted (module docstring)."""

    DIRECT = "direct"
    QUICK = "quick"
    ACQUIRE = "acquire"


@dataclass(frozen=True)
class FaceSetup:
    """What every face measurement of a run shares."""

    profile: CellProfile
    ka: float  # k·a of the transducer in the profile's water
    acquisition_gain_db: float  # from ``acquisition_gain``
    main_lobe: MainLobe = field(default_factory=MainLobe)  # heights found on the faces so far


@dataclass(frozen=True)
class FaceRequest:
    """One face to measure: where to start and the kinematics that predict its posture."""

    face: Face
    start_deg: np.ndarray  # (6,) arm as planned, wrist where the last search of this face ended
    geometry: CellGeometry  # tool and block orientation as estimated so far
    offsets_deg: np.ndarray  # (6,) joint offsets as estimated so far
    label: str  # for log lines and errors, e.g. "face XY (j3/XY)"
    config: str  # the measurement's configuration or posture label
    mode: SearchMode = SearchMode.ACQUIRE
    radius_deg: float = 16.0  # acquisition radius (deg of beam tilt)


def make_search(
    rig: Rig,
    geom: CellGeometry,
    profile: CellProfile,
    q: np.ndarray,
    face: int,
    est: np.ndarray,
    ka: float,
    joints: tuple[int, int] | None = None,
    main_lobe: MainLobe | None = None,
) -> PeakSearch:
    """A peak search across ``face`` whose fit uses the kinematics with offsets ``est``, and
    that judges its peaks against ``main_lobe`` if given."""
    basis = face_basis(geom, face)
    normal = geom.normal(face)
    js, tilt_map = search_joints(geom, q, est, basis)
    if joints is not None and tuple(joints) != js:
        cols = [(3, 4, 5).index(j) for j in joints]
        tilt_map = (basis @ beam_jacobian(geom, q, est))[:, cols]
        js = (joints[0], joints[1])

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
        main_lobe,
    )


@dataclass(frozen=True)
class FaceResult:
    measurement: FaceMeasurement
    prediction_error_deg: float  # beam tilt between the predicted and the found posture


def measure(rig: Rig, setup: FaceSetup, request: FaceRequest) -> FaceResult:
    """Find normal incidence on the requested face near the posture predicted from its start
    and read the water path there (module docstring)."""
    profile, ka, acq_gain = setup.profile, setup.ka, setup.acquisition_gain_db
    geom, face, est = request.geometry, request.face, request.offsets_deg
    label, mode, radius_deg = request.label, request.mode, request.radius_deg
    q_pred = aim_wrist(geom, request.start_deg, -geom.normal(face), est)
    search = make_search(rig, geom, profile, q_pred, face, est, ka, main_lobe=setup.main_lobe)
    first_move = rig.counters.moves
    averages = max(profile.procedure.tof_averages, 1)

    def tof() -> tuple[float, float]:
        return read_distance(rig, profile.water_temperature_c, averages)

    peak = None
    acquired = False  # whether the raster search has run (else the prediction was trusted)
    if mode == SearchMode.DIRECT:
        try:
            peak = search.fit(q_pred, averages=8, distance=tof)
        except HardwareError as e:
            log.info("%s: direct fit failed (%s)", label, e)
    if peak is None or peak.tilt_std_deg > FIT_GATE_DEG:
        q_c = search.quick_centre(q_pred) if mode != SearchMode.ACQUIRE else None
        if q_c is None:
            q_c = acquire_and_centre(search, rig, q_pred, label, radius_deg, acq_gain)
            acquired = True
        peak = search.fit(q_c, averages=8, distance=tof)
    if peak.tilt_std_deg > FIT_GATE_DEG:
        log.info("%s: poor fit (σ %.3f°), centring again", label, peak.tilt_std_deg)
        q_c = search.quick_centre(peak.joints_deg)
        if q_c is None:
            q_c = acquire_and_centre(search, rig, q_pred, label, 8.0, acq_gain)
            acquired = True
        peak = search.fit(q_c, averages=8, distance=tof)
    assert peak.distance is not None
    path, path_std = peak.distance
    height = peak.amplitude / 10 ** (rig.settings.gain_db / 20)
    below = search.side_lobe_db((height, path))
    if below is not None and not acquired:
        # A fit where the prediction put it can settle on a side lobe, or on the noise of a
        # beam far from normal (a flat patch fits a broad "peak"): that is a prediction to
        # distrust, not yet a face without a main lobe. Search as for an unknown posture.
        log.info("%s: the fit is %.0f dB below the main lobe: searching", label, below)
        q_c = acquire_and_centre(search, rig, q_pred, label, radius_deg, acq_gain)
        peak = search.fit(q_c, averages=8, distance=tof)
        assert peak.distance is not None
        path, path_std = peak.distance
        height = peak.amplitude / 10 ** (rig.settings.gain_db / 20)
        below = search.side_lobe_db((height, path))
    if below is not None:
        raise side_lobe_error(search, label, below, rig.counters.moves - first_move)
    if peak.tilt_std_deg <= FIT_GATE_DEG:
        setup.main_lobe.add(height, path)
        note = search.transducer_note()
        if note is not None and not setup.main_lobe.noted:
            log.warning("%s: %s", label, note)
            setup.main_lobe.noted = True
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
        request.config,
        face,
        peak.joints_deg,
        path,
        distance_std_mm=max(path_std, 1e-4),
        tilt_std_deg=max(peak.tilt_std_deg, 1e-4),
        amplitude=peak.amplitude,
        distance_joints_deg=peak.distance_joints_deg,
        gain_db=rig.settings.gain_db,
        probes=peak.probes,
        search_joints=(search.ja, search.jb),
        time_min=peak.time_min,
        approach=peak.approach,
    )
    return FaceResult(m, err)
