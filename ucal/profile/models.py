"""Shipped robot models: one data file each, ``profiles/<model>.toml`` (package data
``ucal.profiles``), the one place a model is defined (docs/decisions/0015).

A model file's ``[robot]`` holds the DH table and joint ranges (SPEC.md), ``upper_arm_mm`` and
``forearm_mm`` (what the table's lengths are on the data sheet), ``speed_deg_s`` (the joints'
speeds at speed 1.0 as a plan, its real-cell estimate and the simulated controller take
them), ``max_speed_deg_s`` and ``max_effort_nm`` (the arm's limits, a URDF's ``<limit>``),
``base_height_mm`` (the mounting face to the base frame), ``link_mass_kg`` and
``link_centre_of_mass_mm`` (each link's mass, and its centre of mass at the zero pose in the
base frame: what the simulated arm bends under, ``ucal.sim.arm``) and, where a source states
them, ``max_acceleration_deg_s2``. Every ``profiles/*.toml`` but the example cell profile is a
model, named by its file: adding a model is adding its file.
"""

from __future__ import annotations

import functools
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass
from importlib import resources
from typing import Any

import numpy as np

from drivers.controller.motion import DEFAULT_MAX_ACCEL_DEG_S2
from ucal.errors import InputError
from ucal.kinematics.dh import N_JOINTS, RobotModel

#: The example cell profile beside the model files (``ucal.profile.template``), not a model.
EXAMPLE_PROFILE = "example_cell.toml"
#: Model names that ``ucal profile init`` knows: the model files' names.
KNOWN_MODELS = tuple(
    sorted(
        f.name.removesuffix(".toml")
        for f in resources.files("ucal.profiles").iterdir()
        if f.name.endswith(".toml") and f.name != EXAMPLE_PROFILE
    )
)
DEFAULT_MODEL = "tx90l"


@dataclass(frozen=True)
class ModelSheet:
    """What a model file states beyond the kinematics (``robot``): data-sheet lengths (mm),
    the arm's maximum speeds (deg/s) and torques (N·m), the base frame's height above the
    mounting face (mm), the links' masses (kg, (6,)) and centres of mass at the zero pose
    (mm, base frame, (6, 3))."""

    robot: RobotModel
    upper_arm_mm: float
    forearm_mm: float
    max_speed_deg_s: np.ndarray
    max_effort_nm: np.ndarray
    base_height_mm: float
    link_mass_kg: np.ndarray
    link_centre_of_mass_mm: np.ndarray
    #: Each joint's nominal torsional stiffness (N·m/rad, (6,)), the solvers' prior; None:
    #: the table states none.
    stiffness_nm_per_rad: np.ndarray | None = None


def model_table_text(name: str) -> str:
    """TOML text of a shipped model table."""
    if name not in KNOWN_MODELS:
        raise InputError(f"unknown robot model {name!r} (known: {', '.join(KNOWN_MODELS)})")
    return resources.files("ucal.profiles").joinpath(f"{name}.toml").read_text(encoding="utf-8")


@functools.cache
def _robot_table(name: str) -> Mapping[str, Any]:
    """The parsed ``[robot]`` of a model file (read once; every caller builds its own arrays)."""
    table: Mapping[str, Any] = tomllib.loads(model_table_text(name))["robot"]
    return table


def model_sheet(name: str) -> ModelSheet:
    """The model file of a shipped name, read and checked (``InputError`` naming the file and
    the key of a bad value)."""
    where = f"profiles/{name}.toml"
    data = _robot_table(name)
    if data.get("model") != name:
        raise InputError(f"{where}: robot.model: must be {name!r}, the file's name")
    dh = np.array(
        [[r["theta_offset_deg"], r["d_mm"], r["a_mm"], r["alpha_deg"]] for r in data["dh"]]
    )
    accel = data.get("max_acceleration_deg_s2")
    robot = RobotModel(
        name,
        dh,
        _six(data, "joint_min_deg", where, positive=False),
        _six(data, "joint_max_deg", where, positive=False),
        speed_deg_s=_six(data, "speed_deg_s", where),
        acceleration_deg_s2=None if accel is None else _six(data, "max_acceleration_deg_s2", where),
    )
    return ModelSheet(
        robot,
        float(data["upper_arm_mm"]),
        float(data["forearm_mm"]),
        _six(data, "max_speed_deg_s", where),
        _six(data, "max_effort_nm", where),
        float(data["base_height_mm"]),
        _six(data, "link_mass_kg", where),
        _centres(data, "link_centre_of_mass_mm", where),
        None if "stiffness_nm_per_rad" not in data else _six(data, "stiffness_nm_per_rad", where),
    )


def _six(data: Mapping[str, Any], key: str, where: str, positive: bool = True) -> np.ndarray:
    """Six finite numbers (positive ones where ``positive``) of ``data[key]``."""
    v = np.array(data.get(key, ()), dtype=float)
    if v.shape != (N_JOINTS,) or not np.all(np.isfinite(v)) or (positive and np.any(v <= 0)):
        kind = "positive numbers" if positive else "numbers"
        raise InputError(f"{where}: robot.{key}: must be {N_JOINTS} finite {kind}")
    return v


def _centres(data: Mapping[str, Any], key: str, where: str) -> np.ndarray:
    """Six finite points (mm, (6, 3)) of ``data[key]``."""
    try:
        v = np.array(data.get(key, ()), dtype=float)
    except ValueError:  # ragged rows
        v = np.zeros(0)
    if v.shape != (N_JOINTS, 3) or not np.all(np.isfinite(v)):
        raise InputError(f"{where}: robot.{key}: must be {N_JOINTS} points [x, y, z] (mm)")
    return v


def load_model(name: str) -> RobotModel:
    """Robot model of a shipped name (``KNOWN_MODELS``): its DH table, ranges and speeds."""
    return model_sheet(name).robot


def joint_speeds_deg_s(model: RobotModel | None) -> np.ndarray:
    """The joints' speeds at speed 1.0 (deg/s) that a plan, its estimate and the simulated
    controller take for ``model``: its own (a profile's ``[robot] speed_deg_s``, a model
    file's), else its shipped model's, else (no model, or another arm) the lowest of the
    shipped models' for each joint."""
    if model is not None and model.speed_deg_s is not None:
        return model.speed_deg_s
    if model is not None and model.name in KNOWN_MODELS:
        return joint_speeds_deg_s(load_model(model.name))
    return np.asarray(np.min([joint_speeds_deg_s(load_model(n)) for n in KNOWN_MODELS], axis=0))


def joint_accelerations_deg_s2(model: RobotModel | None) -> np.ndarray:
    """The joints' accelerations (deg/s²) that the motion model (``drivers.controller.motion``)
    takes for ``model`` in a plan's estimate and the simulated controller: its own, else its
    shipped model's, else (no model, or another arm) a TX90-class arm's."""
    if model is not None and model.acceleration_deg_s2 is not None:
        return model.acceleration_deg_s2
    if model is not None and model.name in KNOWN_MODELS:
        shipped = load_model(model.name).acceleration_deg_s2
        if shipped is not None:
            return shipped
    return np.asarray(DEFAULT_MAX_ACCEL_DEG_S2, float)


def controller_model(model: RobotModel, source: object = "profile") -> RobotModel:
    """The arm as its controller models it: the shipped DH table of ``model``'s name (no
    Hayati twists; joint offsets are the caller's to leave out), ``model``'s joint ranges.

    Raises ``InputError`` (exit 2) naming ``source`` (the profile) and ``robot.model`` when the
    name is not a shipped model: the controller's own table is then unknown to ucal.
    """
    if model.name not in KNOWN_MODELS:
        raise InputError(
            f"{source}: robot.model: {model.name!r} is not a shipped model "
            f"({', '.join(KNOWN_MODELS)}): the controller's nominal DH table is not known"
        )
    shipped = load_model(model.name)
    return RobotModel(
        shipped.name,
        shipped.dh,
        model.joint_min_deg,
        model.joint_max_deg,
        speed_deg_s=model.speed_deg_s,
        acceleration_deg_s2=model.acceleration_deg_s2,
    )
