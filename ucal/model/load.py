"""The arm under gravity in the cell model: each joint's compliance as an unknown, each
posture's torque from the model table's masses and the profile's tool.

A real arm is not a rigid chain: joint i gives by ``c_i·τ_i`` under the gravity torque ``τ_i``
of everything outboard of it (``ucal.kinematics.gravity``), ``c_i = 1/k_i`` its compliance.
For a TX90-class arm (1e5…1e6 N·m/rad on the shoulder and elbow, about 75 N·m on J2 at the
calibration pose) that is 0.004–0.04° of J2, 0.07–0.7 mm at the flange: more than the
offsets' std. The offset a joint-offset calibration measures is the encoder's error *plus*
the sag at the postures it read, so the solvers model each joint's link at

    θ_i = q_i + δ_i + lag·b_i + c_i·(τ_i(q) − τ_i(q_L))

with ``q_L`` the *load posture* (``[calibration] load_posture_deg``: the first posture of the
calibration that wrote the offsets, the calibration pose): the offsets ``δ`` are those of
that posture's load, as the controller needs them near the block, and only the differences
of torque between postures see the compliance. Those differences are small at the offsets
level (J2 ±5 N·m over its steps, J5 ~2 N·m between faces), so ``c`` keeps its prior there
and carries into the offsets' std what its uncertainty moves them by; the full level's
postures load J2 and J3 differently by tens of N·m and measure their compliance.

The unknowns ``COMPLIANCE`` are in µrad per N·m, each with the prior ``1e6/k̄`` ± ``[robot]
stiffness_std_fraction`` of it (``[robot] stiffness_nm_per_rad``, default the model table's).
A joint whose torque differs by less than ``UNSEEN_SAG_RAD`` over the readings at its prior's
one sigma is held (J1 about a vertical axis sees no torque at all): its compliance moves
nothing the data see.

The torques are those of the nominal table at the readings plus the profile's offsets (the full
level's fitted ones where they stand far from the profile's: ``CellPrior.load_offsets_deg``),
with the model table's masses and the profile's tool (``[tool] mass_kg``,
``centre_of_mass_mm``); the sag's own effect on them, ~1 %, and the DH errors', ppm, are left
out.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ucal.kinematics.dh import RobotModel, fk_frames
from ucal.kinematics.gravity import BodyWeights, gravity_torques_nm

#: Each joint's compliance (µrad per N·m): how far its link turns per unit of gravity torque.
COMPLIANCE = tuple(f"compliance_J{j}_urad_per_nm" for j in range(1, 7))
#: µrad per N·m → degrees per N·m.
URAD_DEG = 1e-6 * 180.0 / np.pi
#: A compliance whose one sigma turns its link by less than this over the readings' torques
#: is held at its prior (rad; 0.1 µrad is 0.1 µm at a metre).
UNSEEN_SAG_RAD = 1e-7


@dataclass(frozen=True)
class PostureLoad:
    """The gravity torques of a cell's postures (``bodies`` on ``model`` with ``offsets_deg``)
    relative to those of its load posture (``reference_nm``, at ``load_posture_deg``)."""

    model: RobotModel
    bodies: BodyWeights
    offsets_deg: np.ndarray
    load_posture_deg: np.ndarray
    reference_nm: np.ndarray

    @classmethod
    def of(
        cls, model: RobotModel, bodies: BodyWeights, offsets_deg: np.ndarray, posture: np.ndarray
    ) -> PostureLoad:
        offsets = np.asarray(offsets_deg, float)
        posture = np.asarray(posture, float)
        ref = torques_nm(model, bodies, posture[None, :], offsets)[0]
        return cls(model, bodies, offsets, posture, ref)

    def relative_nm(self, joints_deg: np.ndarray) -> np.ndarray:
        """τ(q) − τ(q_L) (N·m, (n, 6)) at readings ``joints_deg`` (n, 6)."""
        q = np.asarray(joints_deg, float).reshape(-1, 6)
        return torques_nm(self.model, self.bodies, q, self.offsets_deg) - self.reference_nm


@dataclass(frozen=True)
class Deflection:
    """How far each joint of a calibrated arm gives at a posture beyond what its offsets hold:
    ``c_i·(τ_i − τ_i(q_L))`` of ``load``'s torques with compliances ``compliance_urad_per_nm``
    (µrad per N·m, (6,)), the arm's own model of its sag."""

    load: PostureLoad
    compliance_urad_per_nm: np.ndarray

    @classmethod
    def of(
        cls,
        model: RobotModel,
        bodies: BodyWeights | None,
        offsets_deg: np.ndarray,
        load_posture_deg: np.ndarray | None,
        compliance_urad_per_nm: np.ndarray,
    ) -> Deflection | None:
        """The deflection of an arm whose offsets hold at ``load_posture_deg``; None where
        nothing weighs, no joint gives, or no load posture is known (offsets never calibrated
        with one: what they hold is not stated)."""
        c = np.asarray(compliance_urad_per_nm, float)
        if bodies is None or load_posture_deg is None or not np.any(c > 0.0):
            return None
        return cls(PostureLoad.of(model, bodies, offsets_deg, load_posture_deg), c)

    def sag_deg(self, joints_deg: np.ndarray) -> np.ndarray:
        """Each link's turn (deg, (n, 6)) beyond reading + offset at the links' angles
        reading + offset of ``joints_deg`` (n, 6), relative to the load posture's."""
        return self.load.relative_nm(joints_deg) * (URAD_DEG * self.compliance_urad_per_nm)


def torques_nm(
    model: RobotModel, bodies: BodyWeights, joints_deg: np.ndarray, offsets_deg: np.ndarray
) -> np.ndarray:
    """The gravity torque about each joint (N·m, (n, 6)) at readings ``joints_deg`` (n, 6)."""
    frames = fk_frames(model, np.asarray(joints_deg, float), offsets_deg)[..., 1:, :, :]
    return gravity_torques_nm(bodies, frames)


def model_bodies(
    model: RobotModel,
    link_mass_kg: np.ndarray | None,
    link_centre_of_mass_mm: np.ndarray | None,
    tool_mass_kg: float,
    tool_centre_of_mass_mm: np.ndarray,
    gravity_m_s2: np.ndarray,
) -> BodyWeights | None:
    """The bodies of a profile's arm (its links at the zero pose of ``model``'s nominal table)
    and tool, or None where nothing weighs."""
    if link_mass_kg is None or link_centre_of_mass_mm is None:
        if tool_mass_kg <= 0.0:
            return None
        link_mass_kg, link_centre_of_mass_mm = np.zeros(6), np.zeros((6, 3))
    zero = fk_frames(model, np.zeros(6), np.zeros(6))[1:]
    bodies = BodyWeights.of(
        zero,
        link_mass_kg,
        link_centre_of_mass_mm,
        tool_mass_kg,
        tool_centre_of_mass_mm,
        gravity_m_s2,
    )
    return bodies if bodies.loaded else None


def unseen_compliance(
    relative_nm: np.ndarray, compliance_std_urad_per_nm: np.ndarray
) -> np.ndarray:
    """(6,) bool: the joints whose compliance, at its prior's one sigma, turns the link by
    less than ``UNSEEN_SAG_RAD`` over torque differences ``relative_nm`` (n, 6)."""
    if not len(relative_nm):
        return np.ones(6, bool)
    spread = np.ptp(np.vstack([relative_nm, np.zeros((1, 6))]), axis=0)
    return np.asarray(spread * 1e-6 * np.asarray(compliance_std_urad_per_nm) < UNSEEN_SAG_RAD)
