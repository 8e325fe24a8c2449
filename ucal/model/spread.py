"""What the quantities a plan does not know can turn a planned posture's joints by (3σ).

A plan is made on the profile's nominal cell, but the run aims the wrist at the cell as it
is: the joint offsets within their std (``ucal.model.spread.offsets_std_deg``), the
tool's orientation within ``[tool] rotation_std_deg``, the block's within ``[sample]
rotation_std_deg``. A posture the run re-aims (a face's normal incidence, a scan with the
true beam held on the face's normal) then has other wrist readings than planned, by as much
as those quantities turn it there. ``aim_spread`` and ``pose_spread`` measure that posture by
posture: each quantity moved by one sigma, the posture solved again, the joints' changes
added in variance per quantity and over them (``TOLERANCE_SIGMAS`` of it), so that a plan
keeps that much room beyond the searches' and a run within the declared tolerances never
meets a joint limit it was not planned for. Each quantity's share is kept: a refusal names
the one that takes the room (``Spread.words``) and the tolerance that would lift it.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ucal.cell import CellProfile
from ucal.errors import SafetyError, UnreachableError
from ucal.kinematics.ik import ik
from ucal.kinematics.rotations import rot_x, rot_y, rot_z
from ucal.model.geometry import CellGeometry
from ucal.model.wrist import aim_wrist

#: The margins cover this many sigma of the declared tolerances.
TOLERANCE_SIGMAS = 3.0
#: One sigma of a joint's zero offset that ``calibrate`` has not determined (deg): a fresh
#: cell's zeros are within 1-3° of the controller's (encoders set at the factory, a motor
#: replaced); three sigma cover that.
FRESH_OFFSET_STD_DEG = 1.0


def offsets_std_deg(profile: CellProfile) -> np.ndarray:
    """How well a profile knows each joint's zero offset, for planning (deg, one sigma):
    ``[calibration] std_deg`` where ``calibrate`` determined it, ``FRESH_OFFSET_STD_DEG`` for a
    joint it did not (or a profile never calibrated)."""
    std = profile.joint_offsets_std_deg
    if std is None:
        return np.full(6, FRESH_OFFSET_STD_DEG)
    std = np.asarray(std, float)
    return np.where(np.isfinite(std) & (std > 0), std, FRESH_OFFSET_STD_DEG)


#: The unknown quantities by name: what a refusal calls each, and the key that declares it.
OFFSETS, TOOL, BLOCK = "offsets", "tool", "block"
_AXES = (rot_x, rot_y, rot_z)


@dataclass(frozen=True)
class Spread:
    """``TOLERANCE_SIGMAS`` of what the unknown quantities can turn each joint reading of one
    posture by (deg, (6,)), and each quantity's share (deg, (6,)) with its one-sigma
    tolerance as the profile declares it (deg; the largest of its axes)."""

    deg: np.ndarray
    parts: dict[str, np.ndarray]
    std_deg: dict[str, float]
    #: what would lift a refusal, by quantity, where it is not ``_CURE``'s (a tool-frame
    #: refusal does not send the reader to tool-frame)
    cures: dict[str, str] = field(default_factory=dict)

    @classmethod
    def none(cls) -> Spread:
        return cls(np.zeros(6), {}, {})

    def cause(self, joint: int) -> str | None:
        """The quantity whose share on ``joint`` (0-based) is the largest; None without any."""
        if not self.parts:
            return None
        name = max(self.parts, key=lambda n: self.parts[n][joint])
        return name if self.parts[name][joint] > 0 else None

    def words(self, joint: int, room_deg: float) -> str:
        """What takes the room on ``joint`` (0-based) in words, and the tolerance that would
        lift a refusal given ``room_deg`` (deg) that this spread may take there at most."""
        name = self.cause(joint)
        if name is None:
            return ""
        part = float(self.parts[name][joint])
        std = self.std_deg[name]
        what = _QUANTITY[name](std)
        said = (
            f"{self.deg[joint]:.3g} deg of it for what the cell's tolerances can turn it by "
            f"({TOLERANCE_SIGMAS:g} sigma), {part:.3g} deg of that from {what}"
        )
        rest = float(np.sqrt(max(self.deg[joint] ** 2 - part**2, 0.0)))
        if not np.isfinite(part) or room_deg <= rest:
            return (
                f"{said}; no tolerance of it would lift this (the posture itself leaves too "
                "little room): another posture or block placement"
            )
        lifted = std * np.sqrt(room_deg**2 - rest**2) / part
        cure = self.cures.get(name, _CURE[name])
        return f"{said}; {cure} to ±{_floor(lifted)} deg or less would lift it"


def _floor(x: float) -> str:
    """``x`` rounded down to two significant figures, in words."""
    if x <= 0:
        return "0"
    scale = 10.0 ** (np.floor(np.log10(x)) - 1)
    return f"{np.floor(x / scale) * scale:.3g}"


_QUANTITY = {
    OFFSETS: lambda std: (
        f"the joint offsets (each known to ±{std:.3g} deg one sigma, [calibration] std_deg or a "
        "fresh cell's)"
    ),
    TOOL: lambda std: f"the tool's declared orientation tolerance (±{std:.3g} deg one sigma)",
    BLOCK: lambda std: f"the block's declared orientation tolerance (±{std:.3g} deg one sigma)",
}
_CURE = {
    OFFSETS: "the offsets known better (`ucal calibrate` writes [calibration] std_deg)",
    TOOL: "the tool's orientation known better (`ucal tool-frame`, [tool] rotation_std_deg)",
    BLOCK: "the block's orientation known better (a fixture, [sample] rotation_std_deg)",
}


def declared_spread(
    profile: CellProfile, tolerance_deg: float, block: bool = True, tool_cure: str | None = None
) -> Spread:
    """``tolerance_deg`` (deg) kept on joints 4–6 for the declared orientation tolerances, as a
    ``Spread`` whose shares are the tool's and (``block``) the block's, in proportion to
    their tolerances (``[tool]`` and ``[sample] rotation_std_deg``, their axes' resultant, as
    ``ucal.model.safety.tolerance_margins`` adds them): a refusal then names the one
    that takes the room and the tolerance that would lift it. ``tool_cure``: what would lift
    it for the tool, in place of ``_CURE``'s."""
    norms = {TOOL: float(np.linalg.norm(profile.tool_rotation_std_deg))}
    stds = {TOOL: float(np.max(profile.tool_rotation_std_deg))}
    if block:
        norms[BLOCK] = float(np.linalg.norm(profile.sample_rotation_std_deg))
        stds[BLOCK] = float(np.max(profile.sample_rotation_std_deg))
    total = float(np.linalg.norm(list(norms.values())))
    if not total > 0:
        return Spread.none()
    deg = np.zeros(6)
    deg[3:] = tolerance_deg
    parts = {}
    for name, norm in norms.items():
        part = np.zeros(6)
        part[3:] = tolerance_deg * norm / total
        parts[name] = part
    return Spread(deg, parts, stds, {TOOL: tool_cure} if tool_cure else {})


def _perturbed(
    profile: CellProfile, geom: CellGeometry, offsets_deg: np.ndarray, offsets: bool = True
) -> list[tuple[str, float, CellGeometry, np.ndarray]]:
    """The cell with one unknown moved by one sigma, for each unknown of non-zero std:
    (quantity, its std, geometry, offsets)."""
    out: list[tuple[str, float, CellGeometry, np.ndarray]] = []
    if offsets:
        for j, std in enumerate(offsets_std_deg(profile)):
            moved = np.array(offsets_deg, float)
            moved[j] += std
            out.append((OFFSETS, float(std), geom, moved))
    for j, std in enumerate(np.asarray(profile.tool_rotation_std_deg, float)):
        if std > 0:
            tool = geom.tool_matrix.copy()
            tool[:3, :3] = tool[:3, :3] @ _AXES[j](np.radians(std))
            out.append(
                (TOOL, float(std), CellGeometry(geom.model, tool, geom.block_rotation), offsets_deg)
            )
    for j, std in enumerate(np.asarray(profile.sample_rotation_std_deg, float)):
        if std > 0:
            block = geom.block_rotation @ _AXES[j](np.radians(std))
            out.append(
                (BLOCK, float(std), CellGeometry(geom.model, geom.tool_matrix, block), offsets_deg)
            )
    return out


def _gather(q_deg: np.ndarray, moved: list[tuple[str, float, np.ndarray | None]]) -> Spread:
    """The spread from each one-sigma cell's readings (None: that cell has no posture)."""
    var: dict[str, np.ndarray] = {}
    std: dict[str, float] = {}
    for name, sigma, q in moved:
        d = np.full(6, np.inf) if q is None else (q - q_deg + 180.0) % 360.0 - 180.0
        var[name] = var.get(name, np.zeros(6)) + d**2
        std[name] = max(std.get(name, 0.0), sigma)
    parts = {n: TOLERANCE_SIGMAS * np.sqrt(v) for n, v in var.items()}
    total = TOLERANCE_SIGMAS * np.sqrt(sum(var.values(), np.zeros(6)))
    return Spread(total, parts, std)


def aim_spread(
    profile: CellProfile,
    geom: CellGeometry,
    q_deg: np.ndarray,
    face: int,
    offsets_deg: np.ndarray,
    offsets: bool = True,
) -> Spread:
    """What the unknowns can turn the wrist of ``q_deg`` (the beam aimed normal to ``face``
    with ``offsets_deg``, arm joints as commanded) by when the run aims it at the cell as it
    is (module docstring; ``offsets``: the joint offsets among the unknowns)."""
    moved: list[tuple[str, float, np.ndarray | None]] = []
    for name, sigma, g, off in _perturbed(profile, geom, offsets_deg, offsets):
        try:
            q = aim_wrist(g, q_deg, -g.normal(face), off)
        except SafetyError:
            q = None
        moved.append((name, sigma, q))
    return _gather(np.asarray(q_deg, float), moved)


def pose_spread(
    profile: CellProfile,
    geom: CellGeometry,
    pose: np.ndarray,
    q_deg: np.ndarray,
    offsets_deg: np.ndarray,
    offsets: bool = True,
) -> Spread:
    """What the unknowns can turn the readings ``q_deg`` that put the tool at ``pose`` (4, 4,
    base frame) by when the run puts the true tool there (module docstring; ``offsets``: the
    joint offsets among the unknowns). The block's orientation does not enter."""
    moved: list[tuple[str, float, np.ndarray | None]] = []
    for name, sigma, g, off in _perturbed(profile, geom, offsets_deg, offsets):
        if name == BLOCK:
            continue
        try:
            q = ik(profile.model, pose, g.tool_matrix, off, near_deg=q_deg)
        except UnreachableError:
            q = None
        moved.append((name, sigma, q))
    return _gather(np.asarray(q_deg, float), moved)
