"""What the full level found of each joint's stiffness (``ucal.model.load``'s compliances).

The readings see a joint's compliance only through the sag ``c_i·Δτ_i`` it adds between
postures whose gravity torques differ by ``Δτ_i``: a product. Its std is the fit's on ``c_i``
(every other unknown marginalised) and, as a stiffness of the joint, the uncertainty of the
torque it is a fraction of: the model table's link masses (``LINK_MASS_STD_PCT``) and the
weighed tool (``TOOL_MASS_STD_PCT``), each body's share of ``Δτ_i`` over the readings
(``torque_scale_pct``). A mass 10 % heavier than the table's makes the torque 10 % larger and
the joint seem as much softer, with the sag, and so the tool centre, as it was.

A joint's stiffness is *identified* where three of its stds lie within the issue's ±20 %
(``STIFFNESS_TOLERANCE_PCT``): it is then reported and written (``[calibration]
stiffness_nm_per_rad``, ``stiffness_std_nm_per_rad``) for the next calibration to take as its
prior; else it is *not determined* and the profile's prior stands. On the full level's
postures J2's compliance is identified (its torque changes by tens of N·m with the arm's
reach: 11 of 12 random bent worlds, median std 3.5 %, ``benchmarks/compliance.py``); J3's
mostly is not (1 of 12; stds of 20–80 %): the torque about axis 3 (the forearm's, the wrist's
and the tool's) is part of the torque about axis 2 and changes with it, and a turn of the
forearm about axis 3 differs from one about axis 2 by a shift of the elbow that the links'
lengths and the offsets take up. A known mass added to the holder separates them: read again
at the same postures, nothing changes but each joint's torque, by the mass times its lever,
and the difference of the readings is each joint's compliance times that alone
(``SEPARATE_NOTE``).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, replace

import numpy as np

from ucal.model.least_squares import CellFit
from ucal.model.load import COMPLIANCE, PostureLoad

#: A stiffness is identified where three of its stds lie within this (per cent).
STIFFNESS_TOLERANCE_PCT = 20.0
#: One sigma of a link's mass against the model table's (per cent): castings, cables and
#: paint; the published masses are rounded to a tenth of the link's.
LINK_MASS_STD_PCT = 6.0
#: One sigma of the tool's stated mass and the lever of its centre (per cent): a holder weighed
#: on a kitchen scale, its centre of mass drawn.
TOOL_MASS_STD_PCT = 3.0
#: A compliance whose std is above this share of its prior's was not measured.
UNSEEN_SHARE = 0.95
#: What would separate the compliances the postures alone leave not determined.
SEPARATE_NOTE = (
    "the postures alone do not separate it: the gravity torque that bends it changes with the "
    "arm's reach as its lengths and the other joints' sag do; the same postures read again "
    "with a known mass added to the holder would (the mass changes each joint's torque and "
    "nothing else)"
)


@dataclass(frozen=True)
class JointStiffness:
    """One joint's compliance as the full level found it (µrad per N·m) and its stiffness."""

    joint: int  # 1-based
    compliance_urad_per_nm: float
    compliance_std_urad_per_nm: float | None  # None: held at its prior (its torque unseen)
    prior_urad_per_nm: float
    prior_std_urad_per_nm: float
    #: One sigma of the joint's stiffness (per cent): the fit's and the torque's; None: held,
    #: or its compliance fitted at or below zero.
    std_pct: float | None
    status: str  # "identified" or "not determined"
    reason: str = ""  # why not determined

    @property
    def identified(self) -> bool:
        return self.status == "identified"

    @property
    def stiffness_nm_per_rad(self) -> float | None:
        """1/c (N·m/rad) where identified, else None."""
        return 1e6 / self.compliance_urad_per_nm if self.identified else None

    @property
    def std_nm_per_rad(self) -> float | None:
        k = self.stiffness_nm_per_rad
        return None if k is None or self.std_pct is None else k * self.std_pct / 100.0

    def to_json(self) -> dict[str, object]:
        return {
            **asdict(self),
            "stiffness_nm_per_rad": self.stiffness_nm_per_rad,
            "stiffness_std_nm_per_rad": self.std_nm_per_rad,
        }


def torque_scale_pct(load: PostureLoad, joints_deg: np.ndarray) -> np.ndarray:
    """One sigma (per cent, (6,)) of the scale of each joint's torque differences over the
    readings ``joints_deg`` (n, 6) that the bodies' masses leave: each body's mass off by
    ``e`` scales the joint's fitted compliance by ``e`` times its share of the differences."""
    total = load.relative_nm(joints_deg)
    norm = np.sum(total * total, axis=0)
    sigma = np.append(np.full(6, LINK_MASS_STD_PCT), TOOL_MASS_STD_PCT)
    var = np.zeros(6)
    for b in range(7):
        weights = np.zeros_like(load.bodies.weights_n)
        weights[b] = load.bodies.weights_n[b]
        one = PostureLoad.of(
            load.model,
            replace(load.bodies, weights_n=weights),
            load.offsets_deg,
            load.load_posture_deg,
        )
        share = np.divide(
            np.sum(one.relative_nm(joints_deg) * total, axis=0),
            norm,
            out=np.zeros(6),
            where=norm > 0.0,
        )
        var += (sigma[b] * share) ** 2
    return np.sqrt(var)


def identified_stiffness(
    cell: CellFit, load: PostureLoad | None, joints_deg: np.ndarray
) -> tuple[JointStiffness, ...]:
    """Each joint's compliance in ``cell`` (a fit carrying ``COMPLIANCE``) at readings
    ``joints_deg`` (n, 6) whose torques ``load`` gives (None: nothing weighs), judged against
    ``STIFFNESS_TOLERANCE_PCT`` (module docstring); () where the fit has no compliances."""
    table = cell.table
    if COMPLIANCE[0] not in table.names:
        return ()
    scale = np.zeros(6) if load is None else torque_scale_pct(load, joints_deg)
    out = []
    for j, name in enumerate(COMPLIANCE):
        i = table.index(name)
        c, prior, prior_std = cell.value(name), float(table.prior[i]), float(table.prior_stds[i])
        if not table.free[i] or not np.isfinite(cell.std[i]):
            reason = (
                "rigid, as the profile states"
                if prior == 0.0
                else "its torque does not change over the postures (or nothing weighs)"
            )
            out.append(
                JointStiffness(j + 1, c, None, prior, prior_std, None, "not determined", reason)
            )
            continue
        sigma = float(cell.std[i])
        pct = float(np.hypot(100.0 * sigma / c, scale[j])) if c > 0.0 else None
        ok = pct is not None and 3.0 * pct <= STIFFNESS_TOLERANCE_PCT
        reason = "" if ok else _not_determined(c, sigma, prior_std, pct)
        out.append(
            JointStiffness(
                j + 1,
                c,
                sigma,
                prior,
                prior_std,
                pct,
                "identified" if ok else "not determined",
                reason,
            )
        )
    return tuple(out)


def _not_determined(c: float, sigma: float, prior_std: float, pct: float | None) -> str:
    """Why a compliance the readings see is not determined."""
    if sigma >= UNSEEN_SHARE * prior_std:
        return "the readings add nothing to its prior (its torque hardly changes)"
    if pct is None:
        return f"its compliance is {c:.3g} ± {sigma:.3g} µrad per N·m: no stiffness"
    return f"its std ({pct:.0f} %) leaves it beyond ±{STIFFNESS_TOLERANCE_PCT:g} % at 3σ"


def stiffness_note(found: tuple[JointStiffness, ...]) -> str:
    """The result's words on the compliances the readings measured but did not determine
    (what would separate them); "" where every one they see is identified."""
    weak = [
        s.joint
        for s in found
        if not s.identified
        and s.compliance_std_urad_per_nm is not None
        and s.compliance_std_urad_per_nm < UNSEEN_SHARE * s.prior_std_urad_per_nm
    ]
    if not weak:
        return ""
    joints = ", ".join(f"J{j}" for j in weak)
    return f"stiffness of {joints} not determined: {SEPARATE_NOTE}"


def written_stiffness(
    found: tuple[JointStiffness, ...],
) -> tuple[list[float], list[float]] | None:
    """``[calibration] stiffness_nm_per_rad`` and ``stiffness_std_nm_per_rad`` of ``found``:
    the stiffness (rounded to a unit) and its std (rounded up: a std written is a promise),
    −1 where not determined (the ``[robot]`` prior then stands); None where the fit had no
    compliances."""
    if not found:
        return None
    k, std = [], []
    for s in found:
        value, sigma = s.stiffness_nm_per_rad, s.std_nm_per_rad
        k.append(-1.0 if value is None else float(round(value)))
        std.append(-1.0 if sigma is None else float(np.ceil(sigma)))
    return k, std
