"""Shipped robot models (``profiles/<model>.toml``, installed as package data ``ucal.profiles``)."""

from __future__ import annotations

import tomllib
from importlib import resources

import numpy as np

from ucal.errors import InputError
from ucal.kinematics.dh import RobotModel

#: Model names that ``ucal profile init`` knows.
KNOWN_MODELS = ("tx90", "tx90l", "tx90xl")
DEFAULT_MODEL = "tx90l"


def model_table_text(name: str) -> str:
    """TOML text of a shipped model table."""
    if name not in KNOWN_MODELS:
        raise InputError(f"unknown robot model {name!r} (known: {', '.join(KNOWN_MODELS)})")
    return resources.files("ucal.profiles").joinpath(f"{name}.toml").read_text(encoding="utf-8")


def load_model(name: str) -> RobotModel:
    """Robot model of a shipped name (``tx90``, ``tx90l``, ``tx90xl``)."""
    data = tomllib.loads(model_table_text(name))["robot"]
    dh = np.array(
        [[r["theta_offset_deg"], r["d_mm"], r["a_mm"], r["alpha_deg"]] for r in data["dh"]]
    )
    return RobotModel(name, dh, data["joint_min_deg"], data["joint_max_deg"])


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
    return RobotModel(shipped.name, shipped.dh, model.joint_min_deg, model.joint_max_deg)
