"""A world file's arm as it bends and warms (``ucal.cell.ArmTruth``, ``ucal.sim.arm``).

Keys (``ucal.world``, SPEC.md's additions; none given: a rigid arm at its table's length):

* ``[robot] stiffness_nm_per_rad = [6]`` — each joint's torsional stiffness (0 = rigid, else
  1e4…1e10 N·m/rad): the link turns by the gravity torque over it;
* ``[robot] link_mass_kg = [6]`` (0…500 kg) and ``link_centre_of_mass_mm = [[x, y, z] × 6]``
  (each link's centre of mass at the zero pose, every DH angle at its θ offset, base frame) —
  default: the shipped model table's (``profiles/<model>.toml``), so a world that gives only
  the stiffness bends under the published masses; a model ucal does not ship must give them;
* ``[robot] gravity_m_s2 = [gx, gy, gz]`` — gravity in the base frame (default
  ``[0, 0, −9.80665]``; each component within ±50);
* ``[tool] mass_kg`` (0…50) and ``centre_of_mass_mm`` (flange frame, as ``position_mm``);
* ``[arm] offset_k`` (−50…50 K: the arm this much warmer than when its DH table held, from
  the start), ``warmup_k`` (−50…50 K more, approached as ``1 − exp(−t/τ)`` over the cell's
  clock), ``warmup_time_constant_min`` (τ, 0.1…10 000 min, default 30) and ``expansion_per_k``
  (0…1e-4 per K, default aluminium's 23e-6): every link's d and a grow by that per K;
* SPEC.md's form of the same in ``[robot]``: ``temperature_rise_k`` (how much warmer the arm
  is than when it was calibrated), ``warm_up_time_constant_min`` (0, the default: the rise
  holds for the whole run; else it grows during the run as ``1 − exp(−t/τ)``) and
  ``expansion_ppm_per_k`` (default 23). A world gives one form or the other.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import replace
from typing import Any

from ucal.cell import ArmTruth
from ucal.kinematics.dh import RobotModel
from ucal.profile.arm_load import (
    MAX_LINK_MASS_KG,
    MAX_TOOL_MASS_KG,
    read_centres,
    read_stiffness,
)
from ucal.profile.models import KNOWN_MODELS, model_sheet
from ucal.profile.validation import Reader

MAX_GRAVITY_M_S2 = 50.0
MAX_ARM_K = 50.0
MAX_EXPANSION_PER_K = 1e-4
#: The shortest warm-up time constant a world may give (min), in either form.
MIN_WARM_UP_MIN = 0.1
#: SPEC.md's ``[robot]`` keys of the warm arm: (key, low, high, unit).
WARM_KEYS = (
    ("temperature_rise_k", -MAX_ARM_K, MAX_ARM_K, "K"),
    ("warm_up_time_constant_min", 0.0, 10000.0, "min"),
    ("expansion_ppm_per_k", 0.0, MAX_EXPANSION_PER_K * 1e6, "ppm/K"),
)
#: The world's keys of the bending, warming arm, by table.
ROBOT_KEYS = frozenset(
    {"stiffness_nm_per_rad", "link_mass_kg", "link_centre_of_mass_mm", "gravity_m_s2"}
    | {key for key, *_ in WARM_KEYS}
)
TOOL_KEYS = frozenset({"mass_kg", "centre_of_mass_mm"})
ARM_KEYS = frozenset({"offset_k", "warmup_k", "warmup_time_constant_min", "expansion_per_k"})

#: The plain values: (table, key, count (0: a number), low, high, unit, ``ArmTruth`` field).
_VALUES: tuple[tuple[str, str, int, float | None, float | None, str, str], ...] = (
    ("robot", "link_mass_kg", 6, 0.0, MAX_LINK_MASS_KG, "kg", "link_mass_kg"),
    ("robot", "gravity_m_s2", 3, -MAX_GRAVITY_M_S2, MAX_GRAVITY_M_S2, "m/s^2", "gravity_m_s2"),
    ("tool", "mass_kg", 0, 0.0, MAX_TOOL_MASS_KG, "kg", "tool_mass_kg"),
    ("tool", "centre_of_mass_mm", 3, None, None, "mm", "tool_centre_of_mass_mm"),
    ("arm", "offset_k", 0, -MAX_ARM_K, MAX_ARM_K, "K", "offset_k"),
    ("arm", "warmup_k", 0, -MAX_ARM_K, MAX_ARM_K, "K", "warmup_k"),
    (
        "arm",
        "warmup_time_constant_min",
        0,
        MIN_WARM_UP_MIN,
        10000.0,
        "min",
        "warmup_time_constant_min",
    ),
    ("arm", "expansion_per_k", 0, 0.0, MAX_EXPANSION_PER_K, "/K", "expansion_per_k"),
)


def read_arm(
    r: Reader,
    robot: Mapping[str, Any] | None,
    tool: Mapping[str, Any] | None,
    arm: Mapping[str, Any] | None,
    model: RobotModel,
) -> ArmTruth | None:
    """The arm of a world's ``[robot]``, ``[tool]`` and ``[arm]`` keys (module docstring), or
    None when it gives none of them. ``model``: the world's true model, whose shipped table
    gives the masses a world leaves out."""
    changes: dict[str, Any] = {}
    tables = {"robot": robot, "tool": tool, "arm": arm}
    v = r.get(robot, "robot.stiffness_nm_per_rad")
    if v is not None:
        changes["stiffness_nm_per_rad"] = read_stiffness(r, "robot.stiffness_nm_per_rad", v)
    v = r.get(robot, "robot.link_centre_of_mass_mm")
    if v is not None:
        changes["link_centre_of_mass_mm"] = read_centres(r, "robot.link_centre_of_mass_mm", v)
    for table, key, n, lo, hi, unit, name in _VALUES:
        dotted = f"{table}.{key}"
        v = r.get(tables[table], dotted)
        if v is None:
            continue
        changes[name] = (
            r.number(dotted, v, lo=lo, hi=hi, unit=unit)
            if n == 0
            else r.vector(dotted, v, n, lo=lo, hi=hi, unit=unit)
        )
    _warm_arm(r, robot, arm, changes)
    if "stiffness_nm_per_rad" in changes:
        _model_masses(r, model, changes)
    return replace(ArmTruth(), **changes) if changes else None


def _warm_arm(
    r: Reader,
    robot: Mapping[str, Any] | None,
    arm: Mapping[str, Any] | None,
    changes: dict[str, Any],
) -> None:
    """SPEC.md's ``[robot]`` keys of the warm arm as ``ArmTruth``'s fields (module docstring)."""
    given = {}
    for key, lo, hi, unit in WARM_KEYS:
        v = r.get(robot, f"robot.{key}")
        if v is not None:
            given[key] = r.number(f"robot.{key}", v, lo=lo, hi=hi, unit=unit)
    if not given:
        return
    if arm:
        raise r.error(
            f"robot.{next(iter(given))}",
            "the arm's warming is given twice: [robot]'s keys or the [arm] table, not both",
        )
    rise = given.get("temperature_rise_k", 0.0)
    tau = given.get("warm_up_time_constant_min", 0.0)
    if 0.0 < tau < MIN_WARM_UP_MIN:
        raise r.error(
            "robot.warm_up_time_constant_min",
            f"must be 0 (the rise holds for the whole run) or >= {MIN_WARM_UP_MIN:g} min, "
            f"got {tau:g}",
        )
    if tau > 0.0:  # grows during the run from the calibration's temperature
        changes.update(warmup_k=rise, warmup_time_constant_min=tau)
    else:
        changes["offset_k"] = rise
    if "expansion_ppm_per_k" in given:
        changes["expansion_per_k"] = given["expansion_ppm_per_k"] * 1e-6


def _model_masses(r: Reader, model: RobotModel, changes: dict[str, Any]) -> None:
    """The shipped model table's link masses and centres where the world leaves them out."""
    missing = [k for k in ("link_mass_kg", "link_centre_of_mass_mm") if k not in changes]
    if not missing:
        return
    if model.name not in KNOWN_MODELS:
        raise r.error(
            f"robot.{missing[0]}",
            f"needed with robot.stiffness_nm_per_rad: {model.name!r} is not a shipped model, "
            "so no table gives its links' masses",
        )
    sheet = model_sheet(model.name)
    changes.setdefault("link_mass_kg", sheet.link_mass_kg)
    changes.setdefault("link_centre_of_mass_mm", sheet.link_centre_of_mass_mm)
