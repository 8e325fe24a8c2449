"""The residual model of the calibration solvers: the face measurements' normalised residuals
for a vector of named unknowns (``ucal.model.priors``), as ``ucal.model.fit``'s
docstring writes them, with the sound speed drifting over the run, the lost motion of
each joint against each reading's approach and each joint giving under its gravity load
(``ucal.model.load``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from ucal.kinematics.dh import RobotModel, transform
from ucal.model.geometry import (
    FACE_NAMES,
    CellGeometry,
    FaceMeasurement,
    beam_and_tcp,
    distance_joints,
)
from ucal.model.load import COMPLIANCE, URAD_DEG, PostureLoad
from ucal.model.priors import (
    BACKLASH,
    BETA,
    BLOCK,
    DH,
    DRIFT,
    OFFSETS,
    SOUND,
    TOOL,
    ParameterTable,
)


def measurement_label(m: FaceMeasurement) -> str:
    return f"{m.config}/{FACE_NAMES[m.face]}"


def rpy_matrix(rxyz_deg: np.ndarray) -> np.ndarray:
    """``rpy_to_matrix`` for one triple, written out (it runs in the solver's inner loop)."""
    cx, cy, cz = np.cos(np.radians(rxyz_deg))
    sx, sy, sz = np.sin(np.radians(rxyz_deg))
    # Rx·Ry·Rz (Staubli convention)
    return np.array(
        [
            [cy * cz, -cy * sz, sy],
            [sx * sy * cz + cx * sz, -sx * sy * sz + cx * cz, -sx * cy],
            [-cx * sy * cz + sx * sz, cx * sy * sz + sx * cz, cx * cy],
        ]
    )


def cell_geometry(table: ParameterTable, values: np.ndarray, model: RobotModel) -> CellGeometry:
    """The geometry (tool, block orientation) that a parameter vector describes."""
    tool = transform(table.get(TOOL[:3], values), rpy_matrix(table.get(TOOL[3:], values)))
    return CellGeometry(model, tool, rpy_matrix(table.get(BLOCK[3:], values)))


class Reading(Protocol):
    """What the drift and the lost motion read of a measurement (a face's, the plate's): the
    minutes since the run's first reading and each joint's approach sign, where it says."""

    @property
    def time_min(self) -> float | None: ...

    @property
    def approach(self) -> np.ndarray | None: ...


def approach_signs(meas: Sequence[Reading]) -> np.ndarray:
    """Each reading's approach (n, 6): +1 where the joint last moved in its positive direction,
    −1 in its negative one; a reading that does not say is +1, the approach of every posture
    ``ucal.devices.rig.FinalApproachRig`` reaches."""
    out = np.ones((len(meas), 6))
    for i, m in enumerate(meas):
        if m.approach is not None:
            out[i] = np.where(np.asarray(m.approach, float) < 0, -1.0, 1.0)
    return out


def readings_approach(meas: Sequence[Reading]) -> str:
    """The approach ``meas`` were read from, in SPEC.md's words: ``"positive"`` when every
    joint of every reading ended its move in its positive direction (the approach the offsets
    of ``[calibration]`` belong to), ``"negative"`` when every one ended it in its negative
    one, else ``"both"`` (some joints read from either side: their lost motion is seen)."""
    signs = approach_signs(meas)
    if np.all(signs > 0):
        return "positive"
    return "negative" if np.all(signs < 0) else "both"


def reference_time_min(meas: Sequence[Reading]) -> float:
    """The time the fitted sound speed is given at (min): the mean of the readings' times
    (0 when none has one), where the speed and its drift are least correlated."""
    times = [m.time_min for m in meas if m.time_min is not None]
    return float(np.mean(times)) if times else 0.0


def two_sided_joints(meas: Sequence[Reading]) -> np.ndarray:
    """(6,) bool: the joints that ``meas`` approach from both sides (their lost motion is
    seen)."""
    signs = approach_signs(meas)
    if not len(signs):
        return np.zeros(6, bool)
    return np.asarray(np.any(signs > 0, axis=0) & np.any(signs < 0, axis=0))


@dataclass(frozen=True)
class MeasurementArrays:
    """Face measurements as arrays, built once per fit (its residuals run hundreds of times)."""

    postures: np.ndarray  # (2n, 6): the peak postures, then where each water path was read
    faces: np.ndarray  # (n,)
    in_plane: np.ndarray  # (n, 2): each face's two in-plane block axes
    tilt_std_rad: np.ndarray  # (n,)
    distance_mm: np.ndarray  # (n,)
    distance_std_mm: np.ndarray
    #: (n,) minutes from the reference time (``reference_time_min``); 0 for a reading without
    #: time, which then sees the sound speed at the reference time.
    minutes: np.ndarray
    #: (2n, 6) how much of the lost motion each posture's link lags behind the positive
    #: approach: (1 − approach)/2, so 0 approaching from below and 1 from above.
    lag: np.ndarray
    #: (2n, 6) each posture's gravity torque less the load posture's (N·m,
    #: ``ucal.model.load``); zeros where nothing weighs.
    load_nm: np.ndarray

    @classmethod
    def of(
        cls,
        meas: list[FaceMeasurement],
        time_ref_min: float | None = None,
        load: PostureLoad | None = None,
    ) -> MeasurementArrays:
        """The arrays of ``meas``, their times from ``time_ref_min`` (default: their
        ``reference_time_min``), their torques relative to ``load``'s posture (None: none)."""
        faces = np.array([m.face for m in meas], int)
        t_ref = reference_time_min(meas) if time_ref_min is None else time_ref_min
        lag = 0.5 * (1.0 - approach_signs(meas))
        postures = np.array(
            [m.joints_deg for m in meas] + [distance_joints(m) for m in meas], float
        ).reshape(-1, 6)
        return cls(
            postures,
            faces,
            np.array([[i for i in range(3) if i != f] for f in faces], int),
            np.radians([m.tilt_std_deg for m in meas]),
            np.array([m.distance_mm for m in meas], float),
            np.array([m.distance_std_mm for m in meas], float),
            np.array([0.0 if m.time_min is None else m.time_min - t_ref for m in meas], float),
            np.concatenate([lag, lag]).reshape(-1, 6),
            np.zeros_like(postures) if load is None else load.relative_nm(postures),
        )


def table_geometry(table: ParameterTable, values: np.ndarray, model: RobotModel) -> CellGeometry:
    """``cell_geometry`` with the DH lengths and twists of ``values`` (and Hayati's β₂ when the
    table has it) in ``model``."""
    dh = model.dh.copy()
    dh[:, 1:4] = table.get(DH, values).reshape(6, 3)
    beta = None
    if BETA[0] in table.names:
        beta = np.zeros(6) if model.beta_deg is None else model.beta_deg.copy()
        beta[1] = table.get(BETA, values)[0]
    return cell_geometry(table, values, model.with_dh(dh, beta))


def data_residuals(
    table: ParameterTable,
    values: np.ndarray,
    model: RobotModel,
    meas: list[FaceMeasurement] | MeasurementArrays,
    c0_m_s: float,
    time_ref_min: float | None = None,
    load: PostureLoad | None = None,
) -> np.ndarray:
    """Normalised measurement residuals (n, 3): two tilt rows, one distance row each.

    The joints enter at ``reading + offset + lag·backlash`` (the offsets are the positive
    approach's, ``MeasurementArrays.lag``) and each water path at the sound speed of its time,
    ``c + ċ·(t − t_ref)``, where the table has those unknowns; ``time_ref_min`` is ``t_ref``
    (default: ``reference_time_min`` of ``meas``); each joint gives by its compliance times
    the posture's torque less the load posture's (``ucal.model.load``; ``load``, where
    ``meas`` is a list: the torques' reference)."""
    arr = (
        meas
        if isinstance(meas, MeasurementArrays)
        else MeasurementArrays.of(meas, time_ref_min, load)
    )
    n = len(arr.faces)
    geom = table_geometry(table, values, model)
    offsets = table.get(OFFSETS, values)
    corner = table.get(BLOCK[:3], values)
    speed = table.get(SOUND, values)[0] + (
        table.get(DRIFT, values)[0] * arr.minutes if DRIFT[0] in table.names else 0.0
    )
    postures = arr.postures
    if BACKLASH[0] in table.names:
        postures = postures + arr.lag * table.get(BACKLASH, values)
    if COMPLIANCE[0] in table.names:
        postures = postures + arr.load_nm * (URAD_DEG * table.get(COMPLIANCE, values))
    both, tcp_both = beam_and_tcp(geom, postures, offsets)  # one FK call
    beam, beam_d, tcp = both[:n], both[n:], tcp_both[n:]
    rot = geom.block_rotation
    normal = rot[:, arr.faces].T  # (n, 3)
    basis = rot.T[arr.in_plane]  # (n, 2, 3)
    out = np.empty((n, 3))
    out[:, :2] = np.einsum("nkj,nj->nk", basis, beam) / arr.tilt_std_rad[:, None]  # tilts
    # Along the beam to the face: the TOF may be read a few tenths of a degree off normal,
    # where the path is n·(p − c)/cos θ (2 µm longer at 0.36° and 100 mm).
    cos_t = np.maximum(-np.einsum("nj,nj->n", normal, beam_d), 0.5)
    path = np.einsum("nj,nj->n", normal, tcp - corner) / cos_t
    out[:, 2] = (path - speed / c0_m_s * arr.distance_mm) / arr.distance_std_mm
    return out
