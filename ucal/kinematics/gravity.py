"""The gravity torque about each joint of a 6R arm: what bends it where its joints give.

At a posture whose DH frames are ``T_1..T_6``, the torque about joint i's axis of everything
outboard of it (links i..6 and the tool) is

    τ_i = z_{i−1} · Σ_{j ≥ i} (c_j − o_{i−1}) × m_j·g

(``z_{i−1}``, ``o_{i−1}``: the axis and origin of DH frame i−1, the base frame for joint 1;
``c_j``: body j's centre of mass; ``g`` gravity in the base frame). A joint of stiffness k
then turns by τ/k the way the torque pulls: an outstretched arm sags. Both the simulated arm
(``ucal.sim.arm``, on its true table and its deflected posture, with the world's masses) and
the solvers (``ucal.model.load``, on the profile's table at the readings, with the model
table's masses and the profile's tool) take their torques from here.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class BodyWeights:
    """The arm's bodies as gravity sees them: each link's weight and the tool's (N, (7, 3):
    links 1..6, then the tool), each link's centre of mass in its own DH frame (mm, (6, 3))
    and the tool's in the flange frame (mm, (3,))."""

    weights_n: np.ndarray
    link_local_mm: np.ndarray
    tool_mm: np.ndarray

    @classmethod
    def of(
        cls,
        zero_frames: np.ndarray,
        link_mass_kg: np.ndarray,
        link_centre_of_mass_mm: np.ndarray,
        tool_mass_kg: float,
        tool_centre_of_mass_mm: np.ndarray,
        gravity_m_s2: np.ndarray,
    ) -> BodyWeights:
        """The bodies of links whose centres of mass are given at the zero pose (every DH
        angle at its θ offset, base frame, (6, 3)), where their DH frames are
        ``zero_frames`` (6, 4, 4)."""
        c0 = np.asarray(link_centre_of_mass_mm, float)
        local = np.array(
            [f[:3, :3].T @ (c - f[:3, 3]) for f, c in zip(zero_frames, c0, strict=True)]
        )
        masses = np.append(np.asarray(link_mass_kg, float), float(tool_mass_kg))
        weights = masses[:, None] * np.asarray(gravity_m_s2, float)[None, :]
        return cls(weights, local, np.asarray(tool_centre_of_mass_mm, float))

    @property
    def loaded(self) -> bool:
        """Whether anything weighs."""
        return bool(np.any(self.weights_n != 0.0))


def gravity_torques_nm(bodies: BodyWeights, frames: np.ndarray) -> np.ndarray:
    """The gravity torque about each joint's axis (N·m, (…, 6)) of everything outboard of it,
    at the postures whose DH frames T_1..T_6 are ``frames`` (…, 6, 4, 4) (module docstring)."""
    rot, org = frames[..., :3, :3], frames[..., :3, 3]
    centres = np.einsum("...jab,jb->...ja", rot, bodies.link_local_mm) + org
    tool = np.einsum("...ab,b->...a", rot[..., 5, :, :], bodies.tool_mm) + org[..., 5, :]
    centres_m = 1e-3 * np.concatenate([centres, tool[..., None, :]], axis=-2)
    moments = np.cross(centres_m, bodies.weights_n)  # about the base origin, (…, 7, 3)
    outboard_nm = np.flip(np.cumsum(np.flip(moments, -2), axis=-2), -2)[..., :6, :]
    outboard_n = np.cumsum(bodies.weights_n[::-1], axis=0)[::-1][:6]
    # joint i turns about z of frame i−1 (the base frame for joint 1) through its origin
    base_z = np.broadcast_to([0.0, 0.0, 1.0], rot.shape[:-3] + (1, 3))
    axes = np.concatenate([base_z, rot[..., :5, :, 2]], axis=-2)
    origins_m = 1e-3 * np.concatenate([np.zeros(rot.shape[:-3] + (1, 3)), org[..., :5, :]], -2)
    about = outboard_nm - np.cross(origins_m, outboard_n)
    return np.asarray(np.einsum("...ia,...ia->...i", axes, about))
