"""Measurement model of the joint-offset calibration.

A *face measurement* is taken with the arm joints (1–3) held in one configuration and the wrist
joints (4–6) searched until the beam is normal to one face of the calibration block (peak echo
amplitude). It records

* the joint readings ``q`` (deg) at normal incidence,
* the water path ``d`` (mm) from the time of flight, ``d = c(T)·tof/2``.

With the block frame ``S`` (rotation ``R_S``, corner ``c``), face ``k`` is the plane through
``c`` with unit normal ``n_k = R_S e_k`` (k = 0: YZ face, normal +X_S; 1: XZ face, +Y_S;
2: XY face, +Z_S). With the true offsets ``δ`` (SPEC sign: actual = reading + δ), the beam
direction ``b(q+δ) = R_06(q+δ)·a_T`` (``a_T`` = tool z axis in the flange frame) and the tool
centre ``p(q+δ)``, an ideal measurement satisfies

    (1)  b(q+δ) = −n_k                          (normal incidence; two independent equations)
    (2)  d = n_k · (p(q+δ) − c)                  (water path along the normal)

Equation (2) is exact at normal incidence, whatever the tool geometry. Subtracting (2) between
two arm configurations at the same face removes ``c`` and the tool offset along the beam:
``Δd_k = n_k · Δp``; and because the beam direction is the same in both, ``p − W`` has the same
component along ``n_k`` (``n_k·R_06 v = −a_T·v`` for the fixed vector ``v`` from W to the TCP in
the flange frame), so ``Δd_k = n_k · ΔW``: the change of the measured distance to a face equals
the displacement of the wrist centre W along that face's normal (paper 000, §4.3).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import IntEnum, StrEnum

import numpy as np

from ucal.kinematics.dh import RobotModel, fk_frames
from ucal.kinematics.rotations import angle_between_deg


class Face(IntEnum):
    """A face of the calibration block, by the block axis of its normal (0: +X, 1: +Y, 2: +Z).

    An ``int``: it indexes block coordinates and serialises as the number it always was."""

    YZ = 0
    XZ = 1
    XY = 2


FACE_NAMES = tuple(f.name for f in Face)  # ("YZ", "XZ", "XY"): face k has normal +axis k
#: Faces in the order a posture measures them: XY (the beam straight down at the calibration
#: pose), YZ, XZ.
FACE_ORDER = (Face.XY, Face.YZ, Face.XZ)


class Configuration(StrEnum):
    """An arm configuration of the joint-offset calibration (paper 000): the calibration pose,
    joint 3 stepped, joint 2 stepped, and joint 1 stepped (the second azimuth)."""

    BASE = "base"
    J3 = "j3"
    J2 = "j2"
    J1 = "j1"


#: The recorded probes of a peak fit: joint pairs (n, 2), amplitudes (n,), the grid's centre (6,).
Probes = tuple[np.ndarray, np.ndarray, np.ndarray]


@dataclass(frozen=True)
class FaceMeasurement:
    """One normal-incidence measurement (see module docstring)."""

    config: str  # arm configuration (``Configuration``) or another procedure's posture label
    face: int  # a ``Face`` (an int given here is made one): normal along block x, y, z
    joints_deg: np.ndarray  # (6,) readings at normal incidence
    distance_mm: float  # water path from TOF
    distance_std_mm: float = 0.01  # one-sigma of distance_mm (from repeated TOF readings)
    tilt_std_deg: float = 0.002  # one-sigma of the normal-incidence posture, as beam tilt
    amplitude: float = float("nan")
    #: Readings where the TOF was read, if not ``joints_deg`` (the last probe at the peak).
    distance_joints_deg: np.ndarray | None = None
    #: The pulser gain of the fit (dB), its probes and the two wrist joints it searched: a fit
    #: with better kinematics later re-uses them without motion (``refit_peaks``).
    gain_db: float | None = field(default=None, compare=False)
    probes: Probes | None = field(default=None, compare=False)
    search_joints: tuple[int, int] | None = field(default=None, compare=False)
    #: When the water path was read (minutes since the run's first reading; the solvers use
    #: differences only): the sound speed drifts with the tank's temperature. None: not known.
    time_min: float | None = field(default=None, compare=False)
    #: The sign of each joint's last motion before the reading ((6,), +1 or −1): the link lags
    #: its encoder by half the lost motion against it. None: not known (taken as +1).
    approach: np.ndarray | None = field(default=None, compare=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "face", Face(self.face))


@dataclass(frozen=True)
class CellGeometry:
    """What the solvers assume known: the kinematic model, the tool, the block orientation."""

    model: RobotModel
    tool_matrix: np.ndarray  # (4, 4) tool frame in the flange frame
    block_rotation: np.ndarray  # (3, 3) R_S: block axes in the base frame

    @property
    def beam_flange(self) -> np.ndarray:
        """Beam direction ``a_T`` in the flange frame (tool +z)."""
        return self.tool_matrix[:3, 2]

    def normal(self, face: int) -> np.ndarray:
        """Unit normal of face ``face`` in the base frame (pointing into the water)."""
        return self.block_rotation[:, face]


def beam_and_tcp(
    geom: CellGeometry,
    joints_deg: np.ndarray,
    offsets_deg: np.ndarray,
    beam_flange: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Beam direction (…, 3) and tool centre (…, 3, mm) in the base frame."""
    frames = fk_frames(geom.model, joints_deg, offsets_deg)
    flange = frames[..., 6, :, :]
    a_t = geom.beam_flange if beam_flange is None else beam_flange
    beam = flange[..., :3, :3] @ a_t
    tcp = flange[..., :3, :3] @ geom.tool_matrix[:3, 3] + flange[..., :3, 3]
    return beam, tcp


def distance_joints(m: FaceMeasurement) -> np.ndarray:
    """Readings at which the water path of ``m`` was read."""
    return m.joints_deg if m.distance_joints_deg is None else m.distance_joints_deg


def face_basis(geom: CellGeometry, face: int) -> np.ndarray:
    """The two in-plane unit axes (2, 3) of a face: the other two block axes."""
    others = [i for i in range(3) if i != face]
    return geom.block_rotation[:, others].T


def tilt_components(geom: CellGeometry, beam: np.ndarray, face: int) -> np.ndarray:
    """Beam tilt from the face's inward normal as two small-angle components (rad) (…, 2).

    Zero at normal incidence (beam = −n). The components are the beam's projections on the
    face's in-plane axes, i.e. sines of the tilt in two perpendicular planes.
    """
    return np.asarray(beam @ face_basis(geom, face).T)


def beam_on_axis(geom: CellGeometry, tol_deg: float = 1.0) -> bool:
    """True if the nominal beam lies within ``tol_deg`` of the joint-6 axis (flange z)."""
    return bool(angle_between_deg(geom.beam_flange, np.array([0.0, 0.0, 1.0])) < tol_deg)
