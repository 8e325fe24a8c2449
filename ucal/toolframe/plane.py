"""The reflector plate's plane from points touched on it (``[reflector] points_mm``).

Three points define the plane exactly (paper 002, eqs. 9–10: ``n = (B − A) × (C − A)``,
``n·(x − A) = 0``); with more, the plane is the total-least-squares fit: it passes through the
centroid ``c`` of the points and its normal is the right singular vector of the centred points
``P − c`` with the smallest singular value (the direction of least spread). Written as
``n·x = h`` with ``h = n·c`` (mm).

The normal is oriented towards the water side, i.e. the side the transducer comes from. The
touched points do not tell that side; the robot stands on it, so the normal is turned towards
the robot base origin (for a plate lying in the tank below the arm: upwards, as the simulated
cell's plate). The in-plane axes ``e1`` (the projection of the base X axis, or of base Y if X is
nearly normal to the plate) and ``e2 = n × e1`` are the nominal scan directions of the edge
search; the plate's real edges need not be parallel to them.

Lengths in mm.
"""

from __future__ import annotations

from dataclasses import dataclass
from itertools import combinations
from pathlib import Path

import numpy as np

from ucal.errors import InputError, ProfileError

#: The profile key holding the touched points.
POINTS_KEY = "reflector.points_mm"
#: Points closer than this are duplicates (mm).
DUPLICATE_MM = 0.01
#: Spread across the best-fit line below this fraction of the spread along it: collinear.
COLLINEAR_RATIO = 1e-3


@dataclass(frozen=True)
class Plane:
    """A plane ``n·x = offset_mm`` with in-plane axes; see the module docstring."""

    normal: np.ndarray  # (3,) unit, towards the water side
    offset_mm: float  # h in n·x = h
    centroid_mm: np.ndarray  # (3,) centroid of the touched points (on the plane)
    e1: np.ndarray  # (3,) unit, in the plane
    e2: np.ndarray  # (3,) unit, n × e1
    rms_mm: float  # rms distance of the points from the fitted plane
    n_points: int

    def distance_mm(self, x_mm: np.ndarray) -> np.ndarray:
        """Signed distance (mm) of points (…, 3) from the plane, positive on the water side."""
        return np.asarray(x_mm, float) @ self.normal - self.offset_mm

    def project(self, x_mm: np.ndarray) -> np.ndarray:
        """Orthogonal projection (…, 3) of points onto the plane."""
        x = np.asarray(x_mm, float)
        return np.asarray(x - self.distance_mm(x)[..., None] * self.normal)

    def to_plane(self, x_mm: np.ndarray) -> np.ndarray:
        """In-plane coordinates (…, 2) = (e1, e2) components of ``x − centroid`` (mm)."""
        d = np.asarray(x_mm, float) - self.centroid_mm
        return np.stack([d @ self.e1, d @ self.e2], -1)

    @property
    def rotation(self) -> np.ndarray:
        """(3, 3) with columns ``e1, e2, n``: the plate frame in the base frame."""
        return np.column_stack([self.e1, self.e2, self.normal])


def _error(path: str | Path | None, message: str) -> InputError:
    if path is not None:
        return ProfileError(path, POINTS_KEY, message)
    return InputError(f"{POINTS_KEY}: {message}")


def fit_plane(
    points_mm: np.ndarray | None,
    path: str | Path | None = None,
    towards_mm: np.ndarray | None = None,
) -> Plane:
    """Fit the plate's plane to three or more touched points (n, 3) in mm.

    ``towards_mm`` is a point on the water side (default: the robot base origin) used to
    orient the normal. Raises :class:`ProfileError` (with ``path``) or :class:`InputError`,
    both exit 2 and naming ``reflector.points_mm``, for a missing key, fewer than three points,
    non-finite values, duplicate points or collinear points.
    """
    if points_mm is None:
        raise _error(
            path,
            "missing: touch three or more points on the reflector plate and "
            "enter them (mm, base frame)",
        )
    try:
        pts = np.asarray(points_mm, float)
    except (TypeError, ValueError):
        raise _error(path, "must be a list of [x, y, z] points (mm)") from None
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise _error(path, f"must be a list of [x, y, z] points (mm), got shape {pts.shape}")
    if len(pts) < 3:
        raise _error(
            path, f"needs at least three points to define the plate's plane, got {len(pts)}"
        )
    if not np.all(np.isfinite(pts)):
        raise _error(path, "points must be finite numbers (mm)")
    for i in range(len(pts)):
        for j in range(i + 1, len(pts)):
            if np.linalg.norm(pts[i] - pts[j]) < DUPLICATE_MM:
                raise _error(
                    path, f"point {j} duplicates point {i}: the points do not define a plane"
                )
    centroid = pts.mean(0)
    _, sv, vt = np.linalg.svd(pts - centroid)
    if sv[1] < COLLINEAR_RATIO * sv[0]:
        raise _error(
            path,
            "points are collinear: they do not define a plane (touch a third "
            "point away from the line through the others)",
        )
    n = vt[2] / np.linalg.norm(vt[2])
    towards = np.zeros(3) if towards_mm is None else np.asarray(towards_mm, float)
    side = float(n @ (towards - centroid))
    if abs(side) < 1e-9:  # the reference lies in the plane: fall back to "up"
        side = float(n[2]) if abs(n[2]) > 1e-12 else 1.0
    if side < 0:
        n = -n
    h = float(n @ centroid)
    rms = float(np.sqrt(np.mean((pts @ n - h) ** 2)))
    e1 = np.array([1.0, 0.0, 0.0]) - n[0] * n
    if np.linalg.norm(e1) < 0.3:
        e1 = np.array([0.0, 1.0, 0.0]) - n[1] * n
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(n, e1)
    return Plane(n, h, centroid, e1, e2, rms, len(pts))


def hull_reach_mm(
    plane: Plane, points_mm: np.ndarray, direction: np.ndarray, origin_mm: np.ndarray | None = None
) -> float:
    """How far (mm) a ray from ``origin_mm`` (default: the centroid; inside the hull) along the
    in-plane unit ``direction`` stays inside the convex hull of the touched points; 0 if the
    origin is outside. The hull of points touched on a flat convex plate lies on the plate."""
    uv = plane.to_plane(points_mm)
    o = np.zeros(2) if origin_mm is None else plane.to_plane(origin_mm)
    d2 = np.array([direction @ plane.e1, direction @ plane.e2])
    d2 = d2 / np.linalg.norm(d2)
    # Every segment between two points lies in the hull and the hull's boundary edges are
    # among them, so the farthest crossing of the ray with any segment is where it leaves.
    reach, behind = -1.0, False
    for i, j in combinations(range(len(uv)), 2):
        a, b = uv[i] - o, uv[j] - o
        m = np.column_stack([d2, a - b])
        if abs(np.linalg.det(m)) < 1e-12:
            continue
        t, s = np.linalg.solve(m, a)
        if -1e-12 <= s <= 1 + 1e-12:
            if t >= 0:
                reach = max(reach, float(t))
            else:
                behind = True
    return reach if (reach >= 0 and behind) else 0.0
