"""The text of a new profile: the packaged ``template.toml`` filled in for a shipped model.

``template.toml`` is the commented profile ``ucal profile init`` writes. Its values that depend
on the model or on ucal's defaults stand there as placeholders (``""``, ``nan``, ``0``; none
would validate) and are set through tomlkit, which keeps the comments and the layout around
them: the model's DH table and joint ranges, the tool, the block and the reflector plate placed
for paper 000's calibration pose, and the ``Procedure`` and ``ControllerTimeouts`` defaults.
The comments that explain the placement name its figures as ``{field}`` (``str.format``
fields, filled from the same numbers).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import asdict
from importlib import resources
from typing import Any

import numpy as np
import tomlkit
from tomlkit.container import Container
from tomlkit.items import Array, Comment, Table

from ucal.cell import PAPER_CALIBRATION_POSE_DEG, ControllerTimeouts, Procedure
from ucal.errors import InputError
from ucal.kinematics.dh import RobotModel, wrist_centre
from ucal.profile.models import KNOWN_MODELS, load_model
from ucal.profile.read import DEFAULT_FACE_MM
from ucal.profile.validation import DH_KEYS

#: The new-profile template, package data of ``ucal.profile``.
TEMPLATE = "template.toml"
#: Where the template names the shipped model the DH table was copied from.
SHIPPED_DH_COMMENT = "(copied from the shipped\n# {model} model;"
#: Flange length of the shipped models (mm): wrist centre to flange along z6.
FLANGE_MM = 100.0
#: Tool frame of a new profile: transducer 80 mm beyond the flange, beam along flange z.
DEFAULT_TOOL_MM = (0.0, 0.0, 80.0)
#: Distance of the nominal reflector plate's centre behind the block's XZ face plane (mm).
REFLECTOR_BEHIND_MM = 200.0


def nominal_layout(
    model: RobotModel,
    water_path_mm: float | None = None,
    tool_z_mm: float = DEFAULT_TOOL_MM[2],
    face_mm: float | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Block corner and reflector points (mm, base frame) consistent with paper 000's pose.

    At the calibration pose the flange z axis points straight down from the wrist centre W.
    With ``s = flange 100 + tool z + water path`` the block corner is ``W − (s, s, s)``: the
    TCP then stands ``water_path_mm`` above the block's XY face, and the same distance
    separates it from the YZ/XZ faces when the tool points at them from W.

    The reflector plate is horizontal at the XY face's height, centred at
    ``(W_x, W_y − s − 200, W_z − s)``: 200 mm behind the plane of the block's XZ face, on the
    side of the robot base, so the arm reaches it with the beam down (wrist centre at W's
    height) without passing over the block's walls. Defaults: ``Procedure`` water path and
    ``CellProfile`` face size.
    """
    if water_path_mm is None:
        water_path_mm = Procedure().water_path_mm
    w = wrist_centre(model, PAPER_CALIBRATION_POSE_DEG)
    s = FLANGE_MM + tool_z_mm + water_path_mm
    corner = w - s
    centre = np.array([w[0], w[1] - s - REFLECTOR_BEHIND_MM, w[2] - s])
    # Centroid = plate centre; a 120 mm x 120 mm triangle defines the plane well.
    points = centre + np.array([[-60.0, -40.0, 0.0], [60.0, -40.0, 0.0], [0.0, 80.0, 0.0]])
    return corner, points


def _num(x: float) -> float:
    """A number for the template: 3 decimals (µm), no negative zero."""
    return round(float(x), 3) + 0.0


def _vec(values: Iterable[float]) -> list[float]:
    return [_num(v) for v in values]


def default_profile_text(model: str | RobotModel, dh_source: str = "") -> str:
    """Commented TOML of a new profile for the shipped ``model`` (``KNOWN_MODELS``), or for
    another arm's ``RobotModel`` (its table from ``dh_source``, e.g. a URDF; its joints'
    speeds written as ``[robot] speed_deg_s``): the DH table and joint ranges, a 80 mm tool
    along the flange axis, a block and a reflector plate placed for paper 000's calibration
    pose, water at 20 °C, a 25 MHz 6 mm transducer, zero calibration."""
    if isinstance(model, RobotModel):
        m, shipped = model, False
    elif model in KNOWN_MODELS:
        m, shipped = load_model(model), True
    else:
        raise InputError(f"unknown robot model {model!r} (known: {', '.join(KNOWN_MODELS)})")
    name = m.name
    if shipped:
        dh_source = f"the shipped {name} model"
    proc = Procedure()
    corner, points = nominal_layout(m, proc.water_path_mm)
    w = wrist_centre(m, PAPER_CALIBRATION_POSE_DEG)
    s = FLANGE_MM + DEFAULT_TOOL_MM[2] + proc.water_path_mm

    doc = tomlkit.parse(
        resources.files("ucal.profile").joinpath(TEMPLATE).read_text(encoding="utf-8")
    )
    robot = _table(doc, "robot")
    _set(robot, "model", name)
    # a shipped table's numbers are round; another arm's keep what its source states
    dh_num = _num if shipped else (lambda v: round(float(v), 9) + 0.0)
    for row, values in zip(robot["dh"], m.dh, strict=True):
        for key, v in zip(DH_KEYS, values, strict=True):
            row[key] = dh_num(v)
    _set_vector(robot, "joint_min_deg", m.joint_min_deg)
    _set_vector(robot, "joint_max_deg", m.joint_max_deg)
    if not shipped and m.speed_deg_s is not None:
        # a shipped model's speeds come from its model file, another arm's stand here
        robot["speed_deg_s"] = _vec(m.speed_deg_s)
        robot["speed_deg_s"].comment("the joints' speeds at speed 1.0 (deg/s), " + dh_source)
    _set_vector(_table(doc, "tool"), "position_mm", DEFAULT_TOOL_MM)
    sample = _table(doc, "sample")
    _set_vector(sample, "position_mm", corner)
    _set(sample, "face_size_mm", _num(DEFAULT_FACE_MM))
    for row, point in zip(_table(doc, "reflector")["points_mm"], points, strict=True):
        _fill(row, point)
    procedure = _table(doc, "procedure")
    _set_vector(procedure, "calibration_pose_deg", PAPER_CALIBRATION_POSE_DEG)
    for key in ("water_path_mm", "step_deg", "speed", "singularity_margin_deg"):
        _set(procedure, key, _num(getattr(proc, key)))
    _set(procedure, "tof_averages", proc.tof_averages)
    _set(procedure, "verify_tolerance_mm", _num(proc.verify_tolerance_mm))
    controller = _table(doc, "controller")
    for key, value in asdict(ControllerTimeouts()).items():
        _set(controller, key, _num(value))

    _fill_comments(
        doc,
        {
            "model": name,
            "w": tomlkit.item(_vec(w)).as_string(),
            "s": s,
            "flange_mm": FLANGE_MM,
            "tool_z_mm": DEFAULT_TOOL_MM[2],
            "water_path_mm": proc.water_path_mm,
            "reflector_y_mm": s + REFLECTOR_BEHIND_MM,
            "behind_mm": REFLECTOR_BEHIND_MM,
        },
    )
    text = tomlkit.dumps(doc)
    if not shipped:
        text = text.replace(SHIPPED_DH_COMMENT.format(model=name), f"(copied from\n# {dh_source};")
    return text


def _table(doc: Container, name: str) -> Table:
    table = doc[name]
    assert isinstance(table, Table), f"{TEMPLATE}: [{name}] is not a table"
    return table


def _set(table: Table, key: str, value: Any) -> None:
    """Replace the placeholder ``key`` holds (its trailing comment and spacing kept)."""
    assert key in table, f"{TEMPLATE}: no key {key} to fill"
    table[key] = value


def _set_vector(table: Table, key: str, values: Iterable[float]) -> None:
    _fill(table[key], values)


def _fill(array: Any, values: Iterable[float]) -> None:
    """Set the elements of a placeholder array in place (as many as it holds; layout kept)."""
    numbers = _vec(values)
    assert isinstance(array, Array) and len(array) == len(numbers), (
        f"{TEMPLATE}: {array.as_string()} for {len(numbers)} values"
    )
    for i, v in enumerate(numbers):
        array[i] = v


def _fill_comments(container: Container, fields: Mapping[str, Any]) -> None:
    """Fill the ``{field}`` names of the comment lines in ``container`` and its tables."""
    for _key, item in container.body:
        if isinstance(item, Comment) and "{" in item.trivia.comment:
            item.trivia.comment = item.trivia.comment.format_map(fields)
        elif isinstance(item, Table):
            _fill_comments(item.value, fields)


#: Model of the shipped example cell and the lines written above its template.
EXAMPLE_MODEL = "tx90l"
EXAMPLE_HEADER = f"""\
# Example cell profile: a Staubli TX90L carrying a 25 MHz immersion transducer, water tank
# with the calibration block and a reflector plate, as written by
# `ucal profile init {EXAMPLE_MODEL}`.
# Copy it (or run `ucal profile init MODEL cell.toml`), then enter the measured block pose and
# the touched reflector points before calibrating.
#
"""


def example_profile_text() -> str:
    """``profiles/example_cell.toml``: the ``profile init`` template of ``EXAMPLE_MODEL`` under
    ``EXAMPLE_HEADER`` (one source, so the example never drifts from what ``init`` writes)."""
    return EXAMPLE_HEADER + default_profile_text(EXAMPLE_MODEL)
