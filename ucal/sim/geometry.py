"""Beam–reflector geometry: the beam ray, the calibration block's faces, the reflector plate.

The beam is a ray from the tool centre point along the tool frame's +Z axis (SPEC.md). A
reflector face is a finite rectangle ``origin + u·e1 + v·e2`` with ``u_min ≤ u ≤ u_max``,
``v_min ≤ v ≤ v_max`` and a unit normal pointing to the side that reflects (the water side).
A face reflects only when the beam arrives from that side. Lengths in mm, angles in degrees.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from ucal.cell import Reflector, Step

#: Beam–normal cosine below which a face is treated as seen edge-on (no intersection).
_MIN_COS = 1e-9


@dataclass(frozen=True)
class Face:
    """A finite plane reflector: origin, in-plane unit axes, reflecting normal, extent (mm)."""

    name: str
    origin_mm: np.ndarray
    e1: np.ndarray
    e2: np.ndarray
    normal: np.ndarray
    u_range_mm: tuple[float, float]
    v_range_mm: tuple[float, float]

    @cached_property
    def floats(self) -> tuple[list[float], list[float], list[float], list[float]]:
        """Normal, origin, e1 and e2 as Python floats, for ``intersect``."""
        return (
            _floats(self.normal),
            _floats(self.origin_mm),
            _floats(self.e1),
            _floats(self.e2),
        )


@dataclass(frozen=True)
class FaceHit:
    """Where the beam axis meets a face's plane.

    ``distance_mm``: along the beam from the TCP (the one-way water path); ``point_mm``: the
    hit point (base frame); ``uv_mm``: the hit point in the face's (u, v); ``tilt_deg``: angle
    between the beam and the reversed face normal (0 = normal incidence); ``edge_distances_mm``:
    signed distances to the edges ``u_min, u_max, v_min, v_max`` (positive inside the face);
    ``facing``: the beam arrives from the reflecting side.
    """

    face: Face
    distance_mm: float
    point_mm: np.ndarray
    uv_mm: np.ndarray
    tilt_deg: float
    edge_distances_mm: np.ndarray
    facing: bool

    @property
    def inside(self) -> bool:
        """True when the beam axis hits the face itself (not only its plane)."""
        return bool(np.all(self.edge_distances_mm >= 0.0))


def beam_ray(tcp: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Beam origin (mm, (3,)) and unit direction ((3,)) of a TCP frame (4, 4): its origin and +Z."""
    tcp = np.asarray(tcp, dtype=float)
    return tcp[:3, 3].copy(), tcp[:3, 2].copy()


def block_faces(sample_matrix: np.ndarray, face_size_mm: float) -> tuple[Face, Face, Face]:
    """The calibration block's three faces, named by their normal: ``"x"``, ``"y"``, ``"z"``.

    The block frame (4, 4, in the base frame) has its origin at the corner; each face is the
    square [0, S]² of a coordinate plane and reflects towards the positive octant, e.g. face
    ``"z"`` is the plane z = 0 with u along x, v along y and normal +z.
    """
    m = np.asarray(sample_matrix, dtype=float)
    corner = m[:3, 3].copy()
    ax = [m[:3, i].copy() for i in range(3)]
    span = (0.0, float(face_size_mm))
    return (
        Face("x", corner, ax[1], ax[2], ax[0], span, span),
        Face("y", corner, ax[2], ax[0], ax[1], span, span),
        Face("z", corner, ax[0], ax[1], ax[2], span, span),
    )


def step_face(sample_matrix: np.ndarray, step: Step) -> Face:
    """The top of the step on the block's XY face (``ucal.cell.Step``): a square of side
    ``size_mm`` centred ``height_mm`` above the face at ``centre_mm``, tilted by ``tilt_deg``
    about the block's x and y axes, reflecting upwards (+z of the block)."""
    from scipy.spatial.transform import Rotation  # only a block with a step needs it

    m = np.asarray(sample_matrix, dtype=float)
    tilt = Rotation.from_euler("xy", step.tilt_deg, degrees=True).as_matrix()
    axes = m[:3, :3] @ tilt
    cx, cy = (float(v) for v in step.centre_mm)
    centre = m[:3, :3] @ np.array([cx, cy, step.height_mm]) + m[:3, 3]
    half = 0.5 * float(step.size_mm)
    return Face(
        "step",
        centre,
        axes[:, 0].copy(),
        axes[:, 1].copy(),
        axes[:, 2].copy(),
        (-half, half),
        (-half, half),
    )


def reflector_face(reflector: Reflector) -> Face:
    """The reflector plate as a ``Face``: centred on its point, ``e1`` = edge direction in-plane."""
    n = np.asarray(reflector.normal, dtype=float)
    n = n / np.linalg.norm(n)
    e1 = np.asarray(reflector.edge_direction, dtype=float)
    e1 = e1 - np.dot(e1, n) * n
    if np.linalg.norm(e1) < 1e-9:  # edge direction along the normal: pick any in-plane axis
        e1 = np.cross(n, [1.0, 0.0, 0.0] if abs(n[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 = e1 / np.linalg.norm(e1)
    e2 = np.cross(n, e1)
    # the flat part: the rounded band of the edges reflects away from the transducer
    w, h = (
        float(s) - 2.0 * float(reflector.edge_radius_mm)
        for s in np.asarray(reflector.size_mm, dtype=float)
    )
    return Face(
        "reflector",
        np.asarray(reflector.point_mm, dtype=float),
        e1,
        e2,
        n,
        (-w / 2.0, w / 2.0),
        (-h / 2.0, h / 2.0),
    )


def bowed_hit(
    hit: FaceHit, direction: np.ndarray, flatness_mm: float, size_mm: np.ndarray
) -> FaceHit:
    """``hit`` on a plate bowed by ``flatness_mm`` peak to valley (``ucal.cell.Reflector``):
    the surface lies ``s(u, v)`` along the normal, so the path is ``s/cos θ`` shorter, and the
    beam's tilt is taken from the local normal ``n − s_u·e1 − s_v·e2`` (first order in the
    slope, which is at most 2f/w)."""
    face = hit.face
    w, h = (float(x) for x in size_mm)
    u, v = (float(x) for x in hit.uv_mm)
    f = float(flatness_mm)
    s = f * ((2 * u / w) ** 2 + (2 * v / h) ** 2) / 2.0 - f / 2.0
    normal = face.normal - (4 * f * u / w**2) * face.e1 - (4 * f * v / h**2) * face.e2
    normal = normal / np.linalg.norm(normal)
    d = np.asarray(direction, float)
    cos_n = float(d @ normal)
    tilt = math.degrees(math.atan2(float(np.linalg.norm(np.cross(d, normal))), -cos_n))
    path = hit.distance_mm - s / max(-float(d @ face.normal), 1e-9)
    return FaceHit(
        face,
        path,
        hit.point_mm + (path - hit.distance_mm) * d,
        hit.uv_mm,
        tilt,
        hit.edge_distances_mm,
        hit.facing,
    )


def intersect(origin_mm: np.ndarray, direction: np.ndarray, face: Face) -> FaceHit | None:
    """Intersect the beam ray with a face's plane; None if parallel or behind the transducer."""
    return intersect_all(origin_mm, direction, (face,))[0]


def intersect_all(
    origin_mm: np.ndarray, direction: np.ndarray, faces: tuple[Face, ...]
) -> list[FaceHit | None]:
    """``intersect`` of one beam ray with each of ``faces``, in their order."""
    # scalar arithmetic on Python floats: called for every face at every reading, where numpy's
    # per-call overhead on 3-vectors dominates
    ray = (_floats(origin_mm), _floats(direction))
    return [_intersect(*ray, face) for face in faces]


def _floats(v: np.ndarray) -> list[float]:
    values: list[float] = np.asarray(v, dtype=float).tolist()
    return values


def _intersect(origin: list[float], direction: list[float], face: Face) -> FaceHit | None:
    dx, dy, dz = direction
    (nx, ny, nz), (fx, fy, fz), (e1x, e1y, e1z), (e2x, e2y, e2z) = face.floats
    cos_n = dx * nx + dy * ny + dz * nz
    if abs(cos_n) < _MIN_COS:
        return None
    ox, oy, oz = origin
    t = ((fx - ox) * nx + (fy - oy) * ny + (fz - oz) * nz) / cos_n
    if t <= 0.0:
        return None
    px, py, pz = ox + t * dx, oy + t * dy, oz + t * dz
    qx, qy, qz = px - fx, py - fy, pz - fz
    u = qx * e1x + qy * e1y + qz * e1z
    v = qx * e2x + qy * e2y + qz * e2z
    edges = np.array(
        [
            u - face.u_range_mm[0],
            face.u_range_mm[1] - u,
            v - face.v_range_mm[0],
            face.v_range_mm[1] - v,
        ]
    )
    # tilt between beam and −n, via atan2 of |d × n| and −d·n (accurate near 0)
    sin_t = math.sqrt(
        (dy * nz - dz * ny) ** 2 + (dz * nx - dx * nz) ** 2 + (dx * ny - dy * nx) ** 2
    )
    tilt = math.degrees(math.atan2(sin_t, -cos_n))
    return FaceHit(
        face, t, np.array([px, py, pz]), np.array([u, v]), tilt, edges, facing=cos_n < 0.0
    )
