"""Simulation only: the arm as it bends under gravity and grows as it warms (``ArmTruth``).

The solvers' arm is a rigid chain of DH links. The simulated one (``SimulatedCell``) is not,
where a world says so (``[robot] stiffness_nm_per_rad``, ``[arm]``):

* **Heat.** At ``t_s`` seconds of the cell's clock (the clock of the water's drift) the arm is
  ``ΔT = offset_k + warmup_k·(1 − exp(−t_s/τ))`` warmer than when its DH table held, and every
  link's d and a are ``(1 + α·ΔT)`` times the table's (the twists and the tool are not scaled:
  the tool is its own part; the centres of mass are not moved, a ppm of the torques).
* **Gravity compliance (elastostatics).** Each joint is a torsional spring of stiffness
  ``k_i`` (N·m/rad; 0 = rigid). At a posture, the gravity torque about joint i's axis of
  everything outboard of it (links i..6 and the tool) is ``τ_i = z_{i−1}·Σ_j (c_j − o_{i−1})
  × m_j·g`` (``z_{i−1}``, ``o_{i−1}``: the axis and origin of DH frame i−1; ``c_j``: body j's
  centre of mass), and the link stands at ``θ_i + τ_i/k_i``: a torque turns it the way it
  pulls, so an outstretched arm sags. The encoder does not see it.

The torque is taken on the deflected posture by fixed-point iteration from the rigid one,
twice: ``θ¹ = θ⁰ + τ(θ⁰)/k``, ``θ² = θ⁰ + τ(θ¹)/k``. The map contracts by ρ = |∂τ/∂θ|/k, at
most about 600 N·m/rad (45 kg of arm and a tool 1.2 m out) over the stiffness: ρ ≤ 0.006 at
1e5 N·m/rad, where the sag is ≤ 6 mrad, so ``θ²`` is within ρ²·6 mrad = 0.2 µrad (0.2 µm at a
metre) of the fixed point; at the smallest stiffness a world may state (1e4), where the arm
sags by centimetres, the error is ρ² = 0.4 % of the sag.
"""

from __future__ import annotations

import numpy as np

from ucal.cell import ArmTruth
from ucal.kinematics.gravity import BodyWeights, gravity_torques_nm

#: Fixed-point passes on the deflected posture (module docstring).
SAG_ITERATIONS = 2


class ArmLoad:
    """The bending and growing of one world's arm (``arm``): its DH table's lengths
    (``d_mm``, ``a_mm``, as the table holds them cold) and the DH frames T_1..T_6 of its zero
    pose (``zero_frames``, (6, 4, 4): every angle at its θ offset), where the centres of mass
    are given."""

    def __init__(
        self,
        arm: ArmTruth,
        d_mm: np.ndarray,
        a_mm: np.ndarray,
        zero_frames: np.ndarray,
    ):
        self.arm = arm
        self._d_mm = np.asarray(d_mm, float)
        self._a_mm = np.asarray(a_mm, float)
        self.bends = arm.bends
        k = np.asarray(arm.stiffness_nm_per_rad, float)
        self._compliance = np.divide(1.0, k, out=np.zeros(6), where=k > 0.0)
        self._bodies = BodyWeights.of(
            zero_frames,
            arm.link_mass_kg,
            arm.link_centre_of_mass_mm,
            arm.tool_mass_kg,
            arm.tool_centre_of_mass_mm,
            arm.gravity_m_s2,
        )

    def lengths_mm(self, t_s: float) -> tuple[np.ndarray, np.ndarray]:
        """The links' d and a (mm, (6,) each) at ``t_s`` seconds of the cell's clock."""
        if not self.arm.warms:
            return self._d_mm, self._a_mm
        grow = 1.0 + self.arm.expansion_per_k * self.arm.temperature_k(t_s)
        return self._d_mm * grow, self._a_mm * grow

    def gravity_torque_nm(self, frames: np.ndarray) -> np.ndarray:
        """The gravity torque about each joint's axis (N·m, (6,)) of everything outboard of
        it, at the posture whose DH frames T_1..T_6 are ``frames`` (6, 4, 4)
        (``ucal.kinematics.gravity``)."""
        return gravity_torques_nm(self._bodies, frames)

    def sag_rad(self, frames: np.ndarray) -> np.ndarray:
        """Each joint's deflection τ_i/k_i (rad, (6,)) at ``frames`` (0 on a rigid joint)."""
        return np.asarray(self.gravity_torque_nm(frames) * self._compliance)
