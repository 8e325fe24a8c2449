"""Measuring one face at normal incidence, shared by ``calibrate`` and ``verify``.

A face measurement starts from a predicted posture (the kinematics with the offsets estimated
so far), finds the echo and its peak posture with ``ucal.calibration.search`` and reads the water
path there. How hard it searches depends on how good the prediction is expected to be:

* ``SearchMode.DIRECT``: the prediction is trusted to a few hundredths of a degree; fit at once;
* ``SearchMode.QUICK``: within about half a degree; centre on the main lobe first;
* ``SearchMode.ACQUIRE``: acquire from scratch within ``radius_deg``.

A fit that comes out imprecise is redone after centring (the quality gate). A centred peak far
weaker than the main lobe the faces measured so far give at its water path is a side lobe
(``ucal.calibration.search``, "Side lobes"): the search goes on to the main lobe with a raster
where only the main lobe shows, and names the face if it finds none. What a run's faces share
(the profile, k·a, the acquisition gain, the main lobe's heights found so far) is a
``FaceSetup``; what one face needs (the face, where to start, the kinematics to predict with)
a ``FaceRequest``.

The noise floor (``acquisition_gain``) and the acquisition raster (``acquire_and_centre``)
serve every procedure that searches an echo: the block's faces and the tool-frame plate.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, field
from enum import StrEnum

import numpy as np
from scipy.optimize import least_squares

from ucal.acoustics import water_absorption_np_per_mm
from ucal.calibration.exact import residuals
from ucal.calibration.model import (
    CellGeometry,
    Face,
    FaceMeasurement,
    beam_and_tcp,
    face_basis,
)
from ucal.calibration.search import MainLobe, PeakSearch, read_distance
from ucal.calibration.wrist import aim_wrist, beam_jacobian, search_joints
from ucal.cell import CellProfile
from ucal.errors import HardwareError
from ucal.rig import FinalApproachRig, Rig

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
#: Raster line spacings of the block's faces (deg of beam tilt): 2.5° at acquisition gain,
#: 0.5° where a long water path leaves little more than the main lobe above the noise.
FACE_LINE_SPACINGS_DEG = (2.5, 0.5)
#: First radius (deg of beam tilt) of the main-lobe raster (``PeakSearch.seek_main_lobe``),
#: doubled up to ``ACQUIRE_MAX_DEG``: its lines are 0.5° apart.
MAIN_LOBE_RADIUS_DEG = 4.0
#: Noise floor the acquisition gain puts the empty gate at (fraction of full screen height).
ACQUISITION_FLOOR_FSH = 0.025


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


def acquisition_gain(
    rig: Rig, q_away: np.ndarray, floor_fsh: float = ACQUISITION_FLOOR_FSH
) -> float:
    """Measure the noise floor with the beam in open water at ``q_away``; return the gain (dB)
    that puts the floor at ``floor_fsh`` of full screen (2.5 %: threshold 10 %), where the side
    lobes of a normal echo show a degree or more around normal."""
    rig.configure(gain_db=20.0, averages=1)
    rig.move(rig.clip(q_away))
    rig.measure_floor()
    assert rig.floor_per_gain is not None
    return float(np.clip(20 * np.log10(floor_fsh / rig.floor_per_gain), 20.0, 80.0))


def _no_face_echo(rig: Rig, label: str, reached_deg: float, moves: int) -> HardwareError:
    config, _, face = label.rpartition("/")  # "j3/XY", or the full level's "face XY (p7)"
    where = face if face.startswith("face ") else f"face {face}"
    where += f" ({config})" if config else ""
    return HardwareError(
        f"pulser at {rig.pulser.endpoint}: no echo from {where} within "
        f"±{reached_deg:g}° of the predicted posture ({moves} moves): is the block "
        "where [sample] says?"
    )


def side_lobe_error(
    rig: Rig, label: str, below_db: float, moves: int, reached_deg: float | None = None
) -> HardwareError:
    """The search found only a side lobe (``PeakSearch.side_lobe_db``) on the face of ``label``."""
    within = "" if reached_deg is None else f" within ±{reached_deg:g}° of the predicted posture"
    return HardwareError(
        f"pulser at {rig.pulser.endpoint}: {label}: the peak found{within} is {below_db:.0f} dB "
        f"below the main lobe that the faces measured so far give at its water path: a side "
        f"lobe, and no main lobe found ({moves} moves)"
    )


def acquire_and_centre(
    search: PeakSearch,
    rig: Rig,
    q_pred: np.ndarray,
    label: str,
    radius_deg: float,
    gain_db: float,
    max_moves: int | None = MAX_ACQUISITION_MOVES,
    spacings_deg: tuple[float, ...] = FACE_LINE_SPACINGS_DEG,
    max_radius_deg: float = ACQUIRE_MAX_DEG,
    no_echo: Callable[[Rig, str, float, int], HardwareError] = _no_face_echo,
) -> np.ndarray:
    """Raster outward from the prediction, then centre on the main lobe.

    Once the search has a main-lobe height to expect (``PeakSearch.main_lobe``), a raster
    where only the main lobe shows comes first (``PeakSearch.seek_main_lobe``, radius from
    ``MAIN_LOBE_RADIUS_DEG`` doubling to ``max_radius_deg``, half of ``max_moves``). Otherwise,
    or if it finds nothing,
    for each line spacing in turn (for a face: 2.5° first — at acquisition gain the side lobes
    show several degrees around normal at the nominal water path — then 0.5°), the radius
    widens from ``radius_deg`` up to ``max_radius_deg``. After ``max_moves`` moves (None: no
    bound) without an echo it gives up with the ``HardwareError`` (exit 3) of ``no_echo(rig,
    label, radius reached, moves)``: for a face it names the pulser and the face — the block is
    not where ``[sample]`` says, or the beam does not reach it (water, transducer, gate). A
    centred peak that is a side lobe, with no main lobe found, is a ``HardwareError`` naming the
    face too.
    """
    first_move = rig.counters.moves
    reached = 0.0
    if search.main_lobe is not None and search.main_lobe.peaks:
        r = min(MAIN_LOBE_RADIUS_DEG, max_radius_deg)
        budget = None if max_moves is None else max_moves // 2  # the rest: the usual raster
        while True:
            left = None if budget is None else budget - (rig.counters.moves - first_move)
            if left is not None and left <= 0:
                break
            q = search.seek_main_lobe(q_pred, r, left)
            if q is not None:
                below = search.side_lobe_db()
                if below is None:
                    return q
                raise side_lobe_error(rig, label, below, rig.counters.moves - first_move, r)
            reached = max(reached, r)
            if r >= max_radius_deg:
                break
            r = min(2 * r, max_radius_deg)
    for spacing in spacings_deg:
        r = min(radius_deg, max_radius_deg)
        while True:
            left = None if max_moves is None else max_moves - (rig.counters.moves - first_move)
            if left is not None and left <= 0:
                break
            found = search.acquire(q_pred, r, gain_db, spacing_tilt_deg=spacing, max_moves=left)
            if found is not None:
                q = search.centre(found[0], 3.0, gain_db)
                below = search.side_lobe_db()
                if below is not None:
                    raise side_lobe_error(rig, label, below, rig.counters.moves - first_move, r)
                return q
            reached = max(reached, r)
            if r >= max_radius_deg:
                break
            r = min(2 * r, max_radius_deg)
    raise no_echo(rig, label, reached, rig.counters.moves - first_move)


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

    read_at_s: list[float] = []  # the middle of each distance reading on the rig's clock

    def tof() -> tuple[float, float]:
        start = rig.controller.clock.now()
        path = read_distance(rig, profile.water_temperature_c, averages)
        read_at_s.append(0.5 * (start + rig.controller.clock.now()))
        return path

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
        raise side_lobe_error(rig, label, below, rig.counters.moves - first_move)
    if peak.tilt_std_deg <= FIT_GATE_DEG:
        setup.main_lobe.add(height, path)
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
        time_min=read_at_s[-1] / 60.0 if read_at_s else None,
        approach=np.ones(6) if isinstance(rig, FinalApproachRig) else None,  # ends from below
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
