"""The profile's arm under its load: what gravity puts on each joint and how far it gives.

Keys (SPEC.md's additions; none given: the shipped model table's masses and stiffnesses, a
weightless tool):

* ``[robot] stiffness_nm_per_rad = [6]`` — each joint's nominal torsional stiffness (0: rigid,
  else 1e4…1e10 N·m/rad); default: the model table's. ``[robot] stiffness_std_fraction`` —
  one sigma of each joint's stiffness relative to it (0…2, default 0.5, SPEC.md), taken as
  the same fraction of its compliance (1/k): the solvers carry each joint's compliance as an
  unknown with this prior (``ucal.model.load``);
* ``[robot] link_mass_kg = [6]``, ``link_centre_of_mass_mm = [[x, y, z] × 6]`` — each link's
  mass and its centre of mass at the zero pose (base frame), for a model ucal does not ship
  (default: the model table's; none for a model without one: nothing weighs);
* ``[tool] mass_kg`` (0…50 kg, default 0) and ``centre_of_mass_mm`` (flange frame, default the
  flange's centre): what the transducer and its holder weigh and where;
* ``[calibration] load_posture_deg = [6]`` (written by ``calibrate``) — the joint readings at
  whose gravity load the written offsets hold: the link of joint i stands at ``reading +
  offset + c_i·(τ_i(q) − τ_i(load posture))``, so a posture loaded as the calibration's was
  needs no correction and every other one is corrected by its own torque's difference;
* ``[calibration] stiffness_nm_per_rad = [6]`` and ``stiffness_std_nm_per_rad = [6]`` (written
  by ``calibrate --level full``, −1 where not determined: ``ucal.model.stiffness``) — each
  joint's stiffness the full level identified and its one sigma: where given they take the
  place of ``[robot] stiffness_nm_per_rad`` and ``stiffness_std_fraction`` for that joint, so the
  next calibration starts from what this one measured (its prior the narrower std).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from ucal.kinematics.dh import RobotModel
from ucal.profile.models import KNOWN_MODELS, model_sheet
from ucal.profile.validation import Reader

#: One sigma of a joint's compliance when the profile states none (per cent of the nominal):
#: SPEC.md's default ``stiffness_std_fraction`` of 0.5. The stiffness published for arms of
#: this class spans 1e5…1e6 N·m/rad on the shoulder and elbow (no TX90 figure is public): a
#: compliance log-uniform over that decade has a one sigma of 64 % of its mean, so a cell
#: whose arm may lie anywhere in it states 0.64.
STIFFNESS_STD_PCT = 50.0
MAX_STIFFNESS_STD_PCT = 200.0
MIN_STIFFNESS_NM_PER_RAD = 1e4
MAX_STIFFNESS_NM_PER_RAD = 1e10
MAX_TOOL_MASS_KG = 50.0
MAX_LINK_MASS_KG = 500.0
#: The keys of the arm's load a profile's ``[robot]`` and ``[tool]`` may hold.
ROBOT_LOAD_KEYS = frozenset(
    {"stiffness_nm_per_rad", "stiffness_std_fraction", "link_mass_kg", "link_centre_of_mass_mm"}
)
TOOL_LOAD_KEYS = frozenset({"mass_kg", "centre_of_mass_mm"})


def read_arm_load(
    r: Reader,
    robot: Mapping[str, Any] | None,
    tool: Mapping[str, Any] | None,
    cal: Mapping[str, Any] | None,
    model: RobotModel,
) -> dict[str, Any]:
    """``CellProfile``'s fields of the arm's load (module docstring), every key checked."""
    sheet = model_sheet(model.name) if model.name in KNOWN_MODELS else None
    out: dict[str, Any] = {}
    v = r.get(robot, "robot.stiffness_nm_per_rad")
    if v is not None:
        out["stiffness_nm_per_rad"] = read_stiffness(r, "robot.stiffness_nm_per_rad", v)
    elif sheet is not None and sheet.stiffness_nm_per_rad is not None:
        out["stiffness_nm_per_rad"] = sheet.stiffness_nm_per_rad
    std_pct = STIFFNESS_STD_PCT
    v = r.get(robot, "robot.stiffness_std_fraction")
    if v is not None:
        hi = MAX_STIFFNESS_STD_PCT / 100.0
        std_pct = 100.0 * r.number("robot.stiffness_std_fraction", v, lo=0.0, hi=hi, unit="")
    out["stiffness_std_pct"] = np.full(6, std_pct)
    calibrated = read_calibrated_stiffness(r, cal)
    if calibrated is not None:
        k, std = calibrated
        given = k > 0.0
        nominal = np.asarray(out.get("stiffness_nm_per_rad", np.zeros(6)), float)
        out["stiffness_nm_per_rad"] = np.where(given, k, nominal)
        out["stiffness_std_pct"] = np.where(
            given, 100.0 * std / np.where(given, k, 1.0), out["stiffness_std_pct"]
        )
    v = r.get(robot, "robot.link_mass_kg")
    if v is not None:
        out["link_mass_kg"] = r.vector(
            "robot.link_mass_kg", v, 6, lo=0.0, hi=MAX_LINK_MASS_KG, unit="kg"
        )
    elif sheet is not None:
        out["link_mass_kg"] = sheet.link_mass_kg
    v = r.get(robot, "robot.link_centre_of_mass_mm")
    if v is not None:
        out["link_centre_of_mass_mm"] = read_centres(r, "robot.link_centre_of_mass_mm", v)
    elif sheet is not None:
        out["link_centre_of_mass_mm"] = sheet.link_centre_of_mass_mm
    if ("link_mass_kg" in out) != ("link_centre_of_mass_mm" in out):
        missing = "link_centre_of_mass_mm" if "link_mass_kg" in out else "link_mass_kg"
        raise r.error(
            f"robot.{missing}",
            f"needed with the other: {model.name!r} is not a shipped model, so no table gives "
            "its links' masses and centres",
        )
    v = r.get(tool, "tool.mass_kg")
    if v is not None:
        out["tool_mass_kg"] = r.number("tool.mass_kg", v, lo=0.0, hi=MAX_TOOL_MASS_KG, unit="kg")
    v = r.get(tool, "tool.centre_of_mass_mm")
    if v is not None:
        out["tool_centre_of_mass_mm"] = r.vector("tool.centre_of_mass_mm", v, 3, unit="mm")
    v = None if cal is None else r.get(cal, "calibration.load_posture_deg")
    if v is not None:
        out["load_posture_deg"] = r.vector(
            "calibration.load_posture_deg", v, 6, lo=-720.0, hi=720.0, unit="deg"
        )
    return out


def read_calibrated_stiffness(
    r: Reader, cal: Mapping[str, Any] | None
) -> tuple[np.ndarray, np.ndarray] | None:
    """``[calibration] stiffness_nm_per_rad`` and ``stiffness_std_nm_per_rad`` (module
    docstring): (6,) each, −1 where not determined; None where not written."""
    key, std_key = "calibration.stiffness_nm_per_rad", "calibration.stiffness_std_nm_per_rad"
    v = None if cal is None else r.get(cal, key)
    w = None if cal is None else r.get(cal, std_key)
    if v is None and w is None:
        return None
    if v is None or w is None:
        missing = key if v is None else std_key
        raise r.error(
            missing,
            "written with the other by calibrate --level full: a stiffness without its std "
            "(or a std without its stiffness) is no prior (write both, or remove both)",
        )
    k = r.vector(key, v, 6, lo=-1.0, hi=MAX_STIFFNESS_NM_PER_RAD, unit="N m/rad")
    std = r.vector(std_key, w, 6, lo=-1.0, hi=MAX_STIFFNESS_NM_PER_RAD, unit="N m/rad")
    for i in range(6):
        if k[i] == -1.0 and std[i] == -1.0:
            continue
        if k[i] < MIN_STIFFNESS_NM_PER_RAD:
            raise r.error(
                f"{key}[{i}]",
                f"must be -1 (not determined) or >= {MIN_STIFFNESS_NM_PER_RAD:g} N m/rad, "
                f"got {k[i]:g}",
            )
        if not 0.0 < std[i] <= k[i] * MAX_STIFFNESS_STD_PCT / 100.0:
            raise r.error(
                f"{std_key}[{i}]",
                f"must be above 0 and at most {MAX_STIFFNESS_STD_PCT:g} % of the stiffness "
                f"({k[i]:g} N m/rad) where the stiffness is determined, got {std[i]:g}",
            )
    return k, std


def read_centres(r: Reader, key: str, value: Any) -> np.ndarray:
    """Six centres of mass (mm, (6, 3)), ``[x, y, z]`` each."""
    return np.array(
        [r.vector(f"{key}[{i}]", row, 3, unit="mm") for i, row in enumerate(r.array(key, value, 6))]
    )


def read_stiffness(r: Reader, key: str, value: Any) -> np.ndarray:
    """Six stiffnesses: 0 (rigid) or within 1e4…1e10 N·m/rad."""
    k = r.vector(key, value, 6, lo=0.0, hi=MAX_STIFFNESS_NM_PER_RAD, unit="N m/rad")
    for i, x in enumerate(k):
        if 0.0 < x < MIN_STIFFNESS_NM_PER_RAD:
            raise r.error(
                f"{key}[{i}]",
                f"must be 0 (rigid) or >= {MIN_STIFFNESS_NM_PER_RAD:g} N m/rad, got {x:g}: "
                "a softer joint sags by more than the small deflections ucal models",
            )
    return k
