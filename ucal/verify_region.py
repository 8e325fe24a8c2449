"""Region check (``ucal verify --region N``): the kinematic model against the block's faces over
postures spread like a full calibration's.

``ucal verify`` checks twenty points above one face; a model fitted near one configuration can
pass it and still be wrong across the workspace. Here the model under test (the profile's
table, ``[calibration] dh`` where present, with its joint offsets and tool) is held fixed and
the block is measured from N postures spread over what the block allows (the candidates of
``ucal.calibration.full_plan``, chosen farthest apart in J1-J3 and face, not the calibration's
own). Each measurement gives a normal-incidence posture and a water path; only the block's pose,
the sound speed and the tool's orientation are fitted to them (the cell's, not the robot's
kinematics), so what remains
is the model's error in the directions ultrasound sees: the beam's tilt (deg) and the distance
along each face's normal (mm). A χ² test against the measurements' own noise gives the verdict;
the largest residuals must stay within ``--tolerance-mm`` (distances) as well.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ucal.calibration.fit import DH, OFFSETS, TOOL, prior_from_profile, solve_cell
from ucal.calibration.full_plan import FullPlan, Posture, candidate_postures, order_postures
from ucal.calibration.full_run import run_full
from ucal.calibration.model import FaceMeasurement
from ucal.calibration.search import Rig
from ucal.cell import CellProfile

#: Joint-space weights of the farthest-point spread (deg of J1, J2, J3; a face change = 30°).
_SPREAD_FACE_DEG = 30.0


def plan_region(
    profile: CellProfile, n: int, seed: int = 0, exclude: tuple[Posture, ...] = ()
) -> FullPlan:
    """``n`` checked postures spread farthest apart (J1-J3 and face) over the candidates,
    starting from a seeded random one, none within 1° of an ``exclude`` posture."""
    cands = [
        c
        for c in candidate_postures(profile)
        if not c.step  # the faces only: the model is judged, not the step
        and all(np.max(np.abs(c.joints_deg - e.joints_deg)) > 1.0 for e in exclude)
    ]
    key = np.array([np.append(c.joints_deg[:3], _SPREAD_FACE_DEG * c.face) for c in cands])
    rng = np.random.default_rng(seed)
    chosen = [int(rng.integers(len(cands)))]
    dist = np.linalg.norm(key - key[chosen[0]], axis=1)
    while len(chosen) < min(n, len(cands)):
        i = int(np.argmax(dist))
        chosen.append(i)
        dist = np.minimum(dist, np.linalg.norm(key - key[i], axis=1))
    postures = order_postures([cands[i] for i in chosen])
    postures = [
        Posture(f"r{i + 1:02d}", p.face, p.joints_deg, p.water_path_mm)
        for i, p in enumerate(postures)
    ]
    j1 = [p.joints_deg[0] for p in postures]
    return FullPlan(
        tuple(postures), len(cands), float("nan"), float("nan"), (float(min(j1)), float(max(j1)))
    )


@dataclass(frozen=True)
class RegionResult:
    """The model's residuals over the region (block pose and sound speed fitted)."""

    postures: int
    rms_distance_mm: float
    max_distance_mm: float
    rms_tilt_deg: float
    max_tilt_deg: float
    chi2_reduced: float
    verdict: str
    worst: str
    tolerance_mm: float

    @property
    def passed(self) -> bool:
        return self.verdict == "ok" and self.max_distance_mm <= self.tolerance_mm

    def to_json(self) -> dict:
        return {
            "region": {
                "postures": self.postures,
                "rms_distance_mm": self.rms_distance_mm,
                "max_distance_mm": self.max_distance_mm,
                "rms_tilt_deg": self.rms_tilt_deg,
                "max_tilt_deg": self.max_tilt_deg,
                "chi2_reduced": self.chi2_reduced,
                "verdict": self.verdict,
                "worst": self.worst,
            },
            "tolerance_mm": self.tolerance_mm,
            "passed": self.passed,
        }


def judge_region(
    profile: CellProfile, meas: list[FaceMeasurement], tolerance_mm: float
) -> RegionResult:
    """Fit only the block pose and the sound speed to ``meas`` with the profile's model held;
    the residuals are the model's (module docstring)."""
    prior = prior_from_profile(profile)
    # the robot's model is what is checked; the block, the water and the tool's orientation
    # (tool-frame's, and invisible to the kinematics of the TCP) are the cell's
    cell = solve_cell(prior, meas, fixed=OFFSETS + DH + TOOL[:3])
    q = cell.quality
    dist = np.array(
        [r.distance * m.distance_std_mm for r, m in zip(q.residuals, meas, strict=True)]
    )
    tilt = np.array(
        [np.hypot(*r.tilt) * m.tilt_std_deg for r, m in zip(q.residuals, meas, strict=True)]
    )
    return RegionResult(
        len(meas),
        float(np.sqrt(np.mean(dist**2))),
        float(np.max(np.abs(dist))),
        float(np.sqrt(np.mean(tilt**2))),
        float(np.max(tilt)),
        q.chi2_reduced,
        q.verdict,
        q.worst,
        tolerance_mm,
    )


def run_region(
    profile: CellProfile, plan: FullPlan, rig: Rig, tolerance_mm: float, progress=None
) -> RegionResult:
    """Measure the region's postures (as ``calibrate --level full`` does) and judge them."""
    run = run_full(profile, plan, rig, progress)
    return judge_region(profile, run.measurements, tolerance_mm)
