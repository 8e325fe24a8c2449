"""Rotation matrices and the Staubli orientation convention.

Orientation triples ``[rx, ry, rz]`` (degrees) follow the Staubli convention of SPEC.md:
``R = Rot(x, rx) · Rot(y, ry) · Rot(z, rz)`` (moving axes, x first).
All functions broadcast over leading dimensions.
"""

from __future__ import annotations

import numpy as np


def _rotation(angle_rad: np.ndarray | float, axis: int) -> np.ndarray:
    """Rotation about ``axis`` (0, 1, 2: x, y, z) by ``angle_rad`` (…,) → (…, 3, 3): the
    identity with the plane's cosines and sines written in (the solvers build thousands of
    single rotations, where stacking rows costs far more than the two trigonometric calls)."""
    a = np.asarray(angle_rad, dtype=float)
    c, s = np.cos(a), np.sin(a)
    i, j = [(1, 2), (2, 0), (0, 1)][axis]  # the plane turned, in the right-handed order
    r = np.zeros(a.shape + (3, 3))
    r[..., axis, axis] = 1.0
    r[..., i, i] = c
    r[..., i, j] = -s
    r[..., j, i] = s
    r[..., j, j] = c
    return r


def rot_x(angle_rad: np.ndarray | float) -> np.ndarray:
    """Rotation about x by ``angle_rad`` (…,) → (…, 3, 3)."""
    return _rotation(angle_rad, 0)


def rot_y(angle_rad: np.ndarray | float) -> np.ndarray:
    """Rotation about y by ``angle_rad`` (…,) → (…, 3, 3)."""
    return _rotation(angle_rad, 1)


def rot_z(angle_rad: np.ndarray | float) -> np.ndarray:
    """Rotation about z by ``angle_rad`` (…,) → (…, 3, 3)."""
    return _rotation(angle_rad, 2)


def rpy_to_matrix(rxyz_deg: np.ndarray) -> np.ndarray:
    """Staubli ``[rx, ry, rz]`` in degrees (…, 3) → rotation matrix (…, 3, 3)."""
    r = np.radians(np.asarray(rxyz_deg, dtype=float))
    return np.asarray(rot_x(r[..., 0]) @ rot_y(r[..., 1]) @ rot_z(r[..., 2]))


def matrix_to_rpy(rot: np.ndarray) -> np.ndarray:
    """Rotation matrix (…, 3, 3) → Staubli ``[rx, ry, rz]`` in degrees (…, 3).

    ``R = Rx·Ry·Rz`` gives ``R[0,2] = sin ry``, ``R[1,2] = -sin rx cos ry``,
    ``R[2,2] = cos rx cos ry``, ``R[0,1] = -cos ry sin rz``, ``R[0,0] = cos ry cos rz``.
    At ``ry = ±90°`` (gimbal lock) ``rz`` is set to 0 and ``rx`` absorbs the rotation.
    """
    rot = np.asarray(rot, dtype=float)
    sy = np.clip(rot[..., 0, 2], -1.0, 1.0)
    cy = np.hypot(rot[..., 0, 0], rot[..., 0, 1])
    ry = np.arctan2(sy, cy)
    locked = cy < 1e-12
    rx = np.where(
        locked,
        np.arctan2(rot[..., 2, 1], rot[..., 1, 1]),
        np.arctan2(-rot[..., 1, 2], rot[..., 2, 2]),
    )
    rz = np.where(locked, 0.0, np.arctan2(-rot[..., 0, 1], rot[..., 0, 0]))
    return np.asarray(np.degrees(np.stack([rx, ry, rz], -1)))


def pose_to_matrix(pose: np.ndarray) -> np.ndarray:
    """Pose ``[X, Y, Z, RX, RY, RZ]`` (mm, deg) (…, 6) → homogeneous transform (…, 4, 4)."""
    pose = np.asarray(pose, dtype=float)
    t = np.zeros(pose.shape[:-1] + (4, 4))
    t[..., :3, :3] = rpy_to_matrix(pose[..., 3:6])
    t[..., :3, 3] = pose[..., :3]
    t[..., 3, 3] = 1.0
    return t


def matrix_to_pose(t: np.ndarray) -> np.ndarray:
    """Homogeneous transform (…, 4, 4) → pose ``[X, Y, Z, RX, RY, RZ]`` (mm, deg) (…, 6)."""
    t = np.asarray(t, dtype=float)
    return np.concatenate([t[..., :3, 3], matrix_to_rpy(t[..., :3, :3])], -1)


def rotation_angle_deg(r_a: np.ndarray, r_b: np.ndarray) -> np.ndarray:
    """Angle (deg) of the rotation taking ``r_a`` to ``r_b`` (…, 3, 3) → (…,)."""
    r = np.swapaxes(r_a, -1, -2) @ r_b
    c = (np.trace(r, axis1=-2, axis2=-1) - 1.0) / 2.0
    # acos loses precision near 0; use the skew part too.
    skew = np.stack(
        [r[..., 2, 1] - r[..., 1, 2], r[..., 0, 2] - r[..., 2, 0], r[..., 1, 0] - r[..., 0, 1]], -1
    )
    s = np.linalg.norm(skew, axis=-1) / 2.0
    return np.degrees(np.arctan2(s, c))


def angle_between_deg(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Angle (deg) between vectors ``u`` and ``v`` (…, 3), accurate for tiny angles."""
    u = np.asarray(u, dtype=float)
    v = np.asarray(v, dtype=float)
    cross = np.linalg.norm(cross3(u, v), axis=-1)
    dot = np.sum(u * v, axis=-1)
    return np.degrees(np.arctan2(cross, dot))


def cross3(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``np.cross`` of 3-vectors (…, 3), broadcast, component by component as it computes
    them (the same numbers) without its general set-up."""
    u = np.asarray(u, dtype=float)
    v = np.asarray(v, dtype=float)
    out = np.empty(np.broadcast_shapes(u.shape, v.shape))
    out[..., 0] = u[..., 1] * v[..., 2] - u[..., 2] * v[..., 1]
    out[..., 1] = u[..., 2] * v[..., 0] - u[..., 0] * v[..., 2]
    out[..., 2] = u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0]
    return out


def tangent_basis(a: np.ndarray) -> np.ndarray:
    """Two unit vectors (2, 3) orthogonal to the unit ``a`` and to each other."""
    a = np.asarray(a, float)
    helper = np.array([1.0, 0.0, 0.0]) if abs(a[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    t1 = np.cross(a, helper)
    t1 /= np.linalg.norm(t1)
    return np.array([t1, np.cross(a, t1)])
