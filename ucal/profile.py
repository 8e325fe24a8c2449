"""Cell profiles: load and validate, create from a shipped model, write results, undo.

A profile (SPEC.md, "Profile file") is a commented TOML file the technician owns. ucal reads it
with tomlkit and writes results back into it with tomlkit, so comments and key order survive.

Writes are atomic and reversible:

* the new text is validated as a profile before anything touches the disk;
* the previous bytes are copied into the history directory ``<profile>.history/``
  (``cell.toml`` → ``cell.toml.history/``) as ``NNNN-before.toml`` and an entry is added to
  ``history.json`` there (id, UTC time, reason, SHA-256 of the bytes before and after);
* the new bytes go to a temporary file in the profile's directory, are fsync'ed and replace
  the profile with ``os.replace``. If any step fails the profile is byte-for-byte unchanged and
  the history entry is withdrawn.

:func:`undo_profile` restores the bytes of the newest entry not yet undone (again atomically),
after saving the bytes it replaces as ``NNNN-after.toml``: an undo loses nothing.
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import json
import logging
import os
import shutil
import socket
import sys
from collections.abc import Iterator, Mapping
from dataclasses import MISSING, asdict, dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any, Literal, overload

import numpy as np
import tomlkit
from tomlkit.items import Array, InlineTable, Table

from ucal import files
from ucal.cell import (
    MAX_CONTROLLER_TIMEOUT_S,
    PAPER_CALIBRATION_POSE_DEG,
    CellProfile,
    ControllerTimeouts,
    Procedure,
    PulserConfig,
    Step,
)
from ucal.errors import InputError, ProfileError
from ucal.kinematics.dh import RobotModel, wrist_centre
from ucal.models import KNOWN_MODELS, load_model
from ucal.validation import (
    DH_KEYS,
    Reader,
    describe_unknown,
    parse_toml_bytes,
    read_toml,
    refuse_misspelt_keys,
    unknown_keys,
)

log = logging.getLogger(__name__)

#: The profile schema this version reads and writes.
SCHEMA = 1

#: Keys ucal knows in each table (others are allowed and reported as warnings; one that is a
#: misspelling of a known key the table lacks is refused).
KNOWN_KEYS: dict[str, frozenset[str] | None] = {
    "": frozenset({"schema"}),
    "robot": frozenset(
        {
            "model",
            "dh",
            "joint_min_deg",
            "joint_max_deg",
            "upper_arm_mm",
            "forearm_mm",
            "dh_length_std_mm",
            "dh_angle_std_deg",
        }
    ),
    "tool": frozenset({"position_mm", "rotation_deg", "position_std_mm", "rotation_std_deg"}),
    "sample": frozenset(
        {"position_mm", "rotation_deg", "face_size_mm", "position_std_mm", "rotation_std_deg"}
    ),
    "reflector": frozenset({"points_mm", "points_std_mm"}),
    "step": frozenset({"height_mm", "height_std_mm", "centre_mm", "size_mm"}),
    "water": frozenset({"temperature_c", "temperature_std_c"}),
    "transducer": frozenset({"frequency_mhz", "element_diameter_mm"}),
    "calibration": None,  # ucal writes run metadata next to the results
    "procedure": frozenset(
        {
            "calibration_pose_deg",
            "water_path_mm",
            "step_deg",
            "speed",
            "singularity_margin_deg",
            "tof_averages",
            "verify_tolerance_mm",
        }
    ),
    "controller": frozenset(MAX_CONTROLLER_TIMEOUT_S),
    "pulser": frozenset({"register_map"}),
}

#: Flange length of the shipped models (mm): wrist centre to flange along z6.
FLANGE_MM = 100.0
#: Tool frame of a new profile: transducer 80 mm beyond the flange, beam along flange z.
DEFAULT_TOOL_MM = (0.0, 0.0, 80.0)
#: Largest Hayati twist (deg) a calibrated table may hold: a calibration finds hundredths.
MAX_CALIBRATED_BETA_DEG = 1.0


def _profile_default(name: str) -> Any:
    """``CellProfile``'s default for the field ``name`` (built anew where a factory makes it)."""
    f = CellProfile.__dataclass_fields__[name]
    return f.default if f.default_factory is MISSING else f.default_factory()


#: Edge length of the calibration block's faces (mm): the ``CellProfile`` default.
DEFAULT_FACE_MM = float(_profile_default("sample_face_size_mm"))
#: Distance of the nominal reflector plate's centre behind the block's XZ face plane (mm).
REFLECTOR_BEHIND_MM = 200.0

HISTORY_SUFFIX = ".history"
HISTORY_INDEX = "history.json"


# ---------------------------------------------------------------------------------------------
# loading


def load_profile(path: str | Path, base_dir: Path | None = None) -> CellProfile:
    """Read and validate the profile at ``path`` (SPEC.md keys; mm, deg, °C, MHz).

    Files the profile names (``[pulser] register_map``) are relative to ``base_dir`` (default:
    the profile's directory; a copy in the history names its profile's). Raises
    :class:`ProfileError` (exit 2) naming the file and the dotted key of the first problem:
    unreadable file, bad TOML, a misspelt key (``did you mean``), missing key, wrong type or
    length, NaN/inf, value out of range, unknown robot model without a ``dh`` table, a register
    map that does not validate (naming the map file and its key).
    """
    p = Path(path)
    return profile_from_data(read_toml(p), p, base_dir)


def profile_warnings(path: str | Path) -> list[str]:
    """Non-fatal remarks on a valid profile: keys ucal does not know (usually typos)."""
    data = read_toml(path).unwrap()
    return [describe_unknown(k, KNOWN_KEYS) for k in unknown_keys(data, KNOWN_KEYS)]


def profile_from_data(
    data: Mapping[str, Any], path: str | Path, base_dir: Path | None = None
) -> CellProfile:
    """Validate parsed profile data (a tomlkit document or plain dict) → :class:`CellProfile`;
    files it names are relative to ``base_dir`` (default: the directory of ``path``)."""
    if hasattr(data, "unwrap"):
        data = data.unwrap()
    r = Reader(path, data)
    refuse_misspelt_keys(r, KNOWN_KEYS)  # before a misspelt key is reported as a missing one
    schema = r.get(data, "schema", required=True)
    if isinstance(schema, bool) or schema != SCHEMA:
        raise r.error(
            "schema",
            f"must be {SCHEMA} (this version of ucal reads schema {SCHEMA}), got {schema!r}",
        )

    model = read_robot(r, r.table("robot", required=True), "robot")

    tool = r.table("tool", required=True)
    tool_pos = r.vector("tool.position_mm", r.get(tool, "tool.position_mm", True), 3, unit="mm")
    tool_rot = r.vector("tool.rotation_deg", r.get(tool, "tool.rotation_deg", True), 3, unit="deg")

    sample = r.table("sample", required=True)
    sample_pos = r.vector(
        "sample.position_mm", r.get(sample, "sample.position_mm", True), 3, unit="mm"
    )
    sample_rot = r.vector(
        "sample.rotation_deg", r.get(sample, "sample.rotation_deg", True), 3, unit="deg"
    )
    tolerances = read_tolerances(
        r, tool, sample, r.table("water", required=True), r.table("robot", required=True)
    )
    face = r.get(sample, "sample.face_size_mm")
    face_mm = (
        DEFAULT_FACE_MM
        if face is None
        else r.number("sample.face_size_mm", face, lo=0.0, lo_open=True, unit="mm")
    )

    reflector = r.table("reflector")
    points = None
    points_std = _profile_default("reflector_points_std_mm")
    if reflector is not None:
        points = r.plane_points(
            "reflector.points_mm", r.get(reflector, "reflector.points_mm", True)
        )
        v = r.get(reflector, "reflector.points_std_mm")
        if v is not None:
            points_std = r.number("reflector.points_std_mm", v, lo=0.0, hi=100.0, unit="mm")

    step_table = r.table("step")
    step = None if step_table is None else read_step(r, step_table, face_mm, None, profile=True)

    water_c = read_water(r, r.table("water", required=True), "water", required=True)
    freq, diam = read_transducer(r, r.table("transducer", required=True), "transducer", True)

    cal = r.table("calibration")
    offsets = np.zeros(6)
    unobservable: tuple[int, ...] = ()
    offsets_std = None
    if cal is not None:
        v = r.get(cal, "calibration.joint_offsets_deg")
        if v is not None:
            offsets = r.joint_offsets("calibration.joint_offsets_deg", v)
        v = r.get(cal, "calibration.std_deg")
        if v is not None:  # written by calibrate; a negative entry: not determined
            offsets_std = r.vector("calibration.std_deg", v, 6, hi=360.0, unit="deg")
            offsets_std = np.where(offsets_std < 0.0, np.nan, offsets_std)
        v = r.get(cal, "calibration.unobservable_joints")
        if v is not None:
            unobservable = r.joint_numbers("calibration.unobservable_joints", v)
        v = r.get(cal, "calibration.dh")
        if v is not None:
            # the table identified by `calibrate --level full` replaces [robot] dh everywhere
            rows, beta = r.split_beta("calibration.dh", v, MAX_CALIBRATED_BETA_DEG)
            model = model.with_dh(r.dh_table("calibration.dh", rows), beta, "[calibration] dh")

    procedure = read_procedure(r, r.table("procedure"), model)
    controller = read_controller(r, r.table("controller"))
    pulser = read_pulser(r, r.table("pulser"), base_dir)

    return CellProfile(
        model=model,
        tool_position_mm=tool_pos,
        tool_rotation_deg=tool_rot,
        sample_position_mm=sample_pos,
        sample_rotation_deg=sample_rot,
        sample_face_size_mm=face_mm,
        reflector_points_mm=points,
        reflector_points_std_mm=points_std,
        step=step,
        joint_offsets_std_deg=offsets_std,
        water_temperature_c=water_c,
        frequency_mhz=freq,
        element_diameter_mm=diam,
        joint_offsets_deg=offsets,
        unobservable_joints=unobservable,
        procedure=procedure,
        controller=controller,
        pulser=pulser,
        path=Path(path),
        **tolerances,
    )


def read_tolerances(
    r: Reader,
    tool: Mapping[str, Any] | None,
    sample: Mapping[str, Any] | None,
    water: Mapping[str, Any] | None,
    robot: Mapping[str, Any] | None,
) -> dict[str, Any]:
    """One-sigma tolerances: ``[tool]`` / ``[sample]`` ``position_std_mm`` and
    ``rotation_std_deg`` (a number or three, >= 0, mm / deg), ``[water] temperature_std_c``
    (0–20 °C) and ``[robot] dh_length_std_mm`` (0–10 mm), ``dh_angle_std_deg`` (0–1 deg);
    missing keys keep ``CellProfile``'s defaults (SPEC.md)."""
    out: dict[str, Any] = {}
    for table, tname, key, attr, hi, unit in (
        (tool, "tool", "position_std_mm", "tool_position_std_mm", 100.0, "mm"),
        (tool, "tool", "rotation_std_deg", "tool_rotation_std_deg", 10.0, "deg"),
        (sample, "sample", "position_std_mm", "sample_position_std_mm", 100.0, "mm"),
        (sample, "sample", "rotation_std_deg", "sample_rotation_std_deg", 10.0, "deg"),
    ):
        v = r.get(table, f"{tname}.{key}")
        if v is None:
            out[attr] = _profile_default(attr)
        elif isinstance(v, (int, float)) and not isinstance(v, bool):
            out[attr] = np.full(3, r.number(f"{tname}.{key}", v, lo=0.0, hi=hi, unit=unit))
        else:
            out[attr] = r.vector(f"{tname}.{key}", v, 3, lo=0.0, hi=hi, unit=unit)
    for table, key, attr, hi, unit in (
        (water, "water.temperature_std_c", "water_temperature_std_c", 20.0, "degC"),
        (robot, "robot.dh_length_std_mm", "dh_length_std_mm", 10.0, "mm"),
        (robot, "robot.dh_angle_std_deg", "dh_angle_std_deg", 1.0, "deg"),
    ):
        v = r.get(table, key)
        out[attr] = (
            _profile_default(attr) if v is None else r.number(key, v, lo=0.0, hi=hi, unit=unit)
        )
    return out


#: Highest step a ``[step]`` table may state (mm), and the largest tilt a world may give its top.
MAX_STEP_MM = 200.0
MAX_STEP_TILT_DEG = 1.0


def read_step(
    r: Reader, table: Mapping[str, Any], face_mm: float, base: Step | None, profile: bool
) -> Step:
    """``[step]``: ``height_mm`` (0–200), ``centre_mm`` = [x, y] on the block's XY face (block
    frame) and ``size_mm`` (side of its square top), the top inside the face; a profile also
    states ``height_std_mm`` (> 0: the height's one sigma), a world may state ``tilt_deg`` =
    [about x, about y] (up to 1 deg). Keys a world leaves out are ``base``'s (the profile's)."""
    required = base is None

    def number(key: str, lo: float, hi: float, default: float | None, lo_open: bool) -> float:
        v = r.get(table, f"step.{key}", required or default is None)
        if v is None:
            assert default is not None
            return default
        return r.number(f"step.{key}", v, lo=lo, hi=hi, lo_open=lo_open, unit="mm")

    height = number("height_mm", 0.0, MAX_STEP_MM, None if base is None else base.height_mm, True)
    size = number("size_mm", 0.0, face_mm, None if base is None else base.size_mm, True)
    v = r.get(table, "step.centre_mm", required)
    if v is not None:
        lo, hi = 0.5 * size, face_mm - 0.5 * size
        centre = r.vector("step.centre_mm", v, 2, lo=lo, hi=hi, unit="mm")
    else:
        assert base is not None  # required without a base
        centre = base.centre_mm
    std = 0.0 if base is None else base.height_std_mm
    tilt = np.zeros(2)
    if profile:
        std = number("height_std_mm", 0.0, 10.0, None, True)
    else:
        v = r.get(table, "step.tilt_deg")
        if v is not None:
            tilt = r.vector(
                "step.tilt_deg", v, 2, lo=-MAX_STEP_TILT_DEG, hi=MAX_STEP_TILT_DEG, unit="deg"
            )
    return Step(height, np.asarray(centre, float), size, std, tilt)


def read_robot(
    r: Reader, robot: Mapping[str, Any] | None, prefix: str, ranges_from: RobotModel | None = None
) -> RobotModel:
    """``[robot]``: a shipped ``model`` name, or a full ``dh`` table (then ``model`` is just a
    name), plus joint ranges (deg). Ranges default to ``ranges_from``'s if given (a world
    file keeps the profile's), else to the shipped model's."""
    name_raw = r.get(robot, f"{prefix}.model")
    dh_raw = r.get(robot, f"{prefix}.dh")
    name = None if name_raw is None else r.string(f"{prefix}.model", name_raw)
    if dh_raw is None:
        if name is None:
            raise r.error(
                f"{prefix}.model",
                "missing key (a shipped model name or a full dh table is required)",
            )
        if name not in KNOWN_MODELS:
            raise r.error(
                f"{prefix}.model",
                f"unknown robot model {name!r} (known: "
                f"{', '.join(KNOWN_MODELS)}; or give a full dh table)",
            )
    shipped = load_model(name) if name in KNOWN_MODELS else None
    base = ranges_from if ranges_from is not None else shipped
    if dh_raw is None:
        assert shipped is not None  # a shipped model name, checked above
        dh = shipped.dh
    else:
        dh = r.dh_table(f"{prefix}.dh", dh_raw)

    lo, hi = r.get(robot, f"{prefix}.joint_min_deg"), r.get(robot, f"{prefix}.joint_max_deg")
    if lo is None and hi is None and base is not None:
        jmin, jmax = base.joint_min_deg, base.joint_max_deg
    else:
        if lo is None:
            raise r.error(f"{prefix}.joint_min_deg", "missing key")
        if hi is None:
            raise r.error(f"{prefix}.joint_max_deg", "missing key")
        jmin, jmax = r.joint_ranges(f"{prefix}.joint_min_deg", lo, f"{prefix}.joint_max_deg", hi)
    source = "shipped" if dh_raw is None else f"{r.path} [{prefix}] dh"
    return RobotModel(name or "custom", dh, jmin, jmax, dh_source=source)


@overload
def read_water(
    r: Reader, water: Mapping[str, Any] | None, prefix: str, required: Literal[True]
) -> float: ...
@overload
def read_water(
    r: Reader, water: Mapping[str, Any] | None, prefix: str, required: bool
) -> float | None: ...
def read_water(
    r: Reader, water: Mapping[str, Any] | None, prefix: str, required: bool
) -> float | None:
    """``[water] temperature_c`` in 0–60 °C (the range of the sound-speed formula)."""
    v = r.get(water, f"{prefix}.temperature_c", required)
    return (
        None if v is None else r.number(f"{prefix}.temperature_c", v, lo=0.0, hi=60.0, unit="degC")
    )


@overload
def read_transducer(
    r: Reader, table: Mapping[str, Any] | None, prefix: str, required: Literal[True]
) -> tuple[float, float]: ...
@overload
def read_transducer(
    r: Reader, table: Mapping[str, Any] | None, prefix: str, required: bool
) -> tuple[float | None, float | None]: ...
def read_transducer(
    r: Reader, table: Mapping[str, Any] | None, prefix: str, required: bool
) -> tuple[float | None, float | None]:
    """``[transducer] frequency_mhz`` (> 0, <= 500 MHz), ``element_diameter_mm`` (> 0, <= 100)."""
    f = r.get(table, f"{prefix}.frequency_mhz", required)
    d = r.get(table, f"{prefix}.element_diameter_mm", required)
    freq = (
        None
        if f is None
        else r.number(f"{prefix}.frequency_mhz", f, lo=0.0, lo_open=True, hi=500.0, unit="MHz")
    )
    diam = (
        None
        if d is None
        else r.number(f"{prefix}.element_diameter_mm", d, lo=0.0, lo_open=True, hi=100.0, unit="mm")
    )
    return freq, diam


def read_procedure(r: Reader, table: Mapping[str, Any] | None, model: RobotModel) -> Procedure:
    """Optional ``[procedure]`` → :class:`Procedure` (missing keys keep its defaults)."""
    if table is None:
        return Procedure()
    d = Procedure()
    pose = None
    v = r.get(table, "procedure.calibration_pose_deg")
    if v is not None:
        pose = r.joints_within(
            "procedure.calibration_pose_deg", v, model.joint_min_deg, model.joint_max_deg
        )

    def num(key: str, default: float, **kw: Any) -> float:
        raw = r.get(table, f"procedure.{key}")
        return default if raw is None else r.number(f"procedure.{key}", raw, **kw)

    averages = r.get(table, "procedure.tof_averages")
    return Procedure(
        calibration_pose_deg=pose,
        water_path_mm=num(
            "water_path_mm", d.water_path_mm, lo=0.0, lo_open=True, hi=1000.0, unit="mm"
        ),
        step_deg=num("step_deg", d.step_deg, lo=0.0, lo_open=True, hi=30.0, unit="deg"),
        speed=num("speed", d.speed, lo=0.0, lo_open=True, hi=1.0),
        singularity_margin_deg=num(
            "singularity_margin_deg",
            d.singularity_margin_deg,
            lo=0.0,
            hi=90.0,
            hi_open=True,
            unit="deg",
        ),
        tof_averages=(
            d.tof_averages
            if averages is None
            else r.integer("procedure.tof_averages", averages, lo=1, hi=65535)
        ),
        verify_tolerance_mm=num(
            "verify_tolerance_mm", d.verify_tolerance_mm, lo=0.0, lo_open=True, hi=100.0, unit="mm"
        ),
    )


def read_controller(r: Reader, table: Mapping[str, Any] | None) -> ControllerTimeouts:
    """Optional ``[controller]`` timeouts (s, > 0, at most ``MAX_CONTROLLER_TIMEOUT_S``)."""
    if table is None:
        return ControllerTimeouts()
    values = {}
    for key, hi in MAX_CONTROLLER_TIMEOUT_S.items():
        raw = r.get(table, f"controller.{key}")
        if raw is not None:
            values[key] = r.number(f"controller.{key}", raw, lo=0.0, lo_open=True, hi=hi, unit="s")
    return ControllerTimeouts(**values)


def read_pulser(
    r: Reader, table: Mapping[str, Any] | None, base_dir: Path | None = None
) -> PulserConfig:
    """Optional ``[pulser]``: ``register_map``, a map file relative to ``base_dir`` (default:
    the profile's directory), read and validated."""
    raw = r.get(table, "pulser.register_map")
    if raw is None:
        return PulserConfig()
    path, register_map = r.register_map("pulser.register_map", raw, base_dir)
    return PulserConfig(register_map_path=path, register_map=register_map)


def profile_to_dict(profile: CellProfile) -> dict[str, Any]:
    """A profile as plain JSON-able data in the profile's own table/key layout."""
    m = profile.model
    proc = profile.procedure
    return {
        "schema": SCHEMA,
        "path": None if profile.path is None else str(profile.path),
        "robot": {
            "model": m.name,
            "dh": [dict(zip(DH_KEYS, map(float, row), strict=True)) for row in m.dh],
            "joint_min_deg": m.joint_min_deg.tolist(),
            "joint_max_deg": m.joint_max_deg.tolist(),
        },
        "tool": {
            "position_mm": profile.tool_position_mm.tolist(),
            "rotation_deg": profile.tool_rotation_deg.tolist(),
        },
        "sample": {
            "position_mm": profile.sample_position_mm.tolist(),
            "rotation_deg": profile.sample_rotation_deg.tolist(),
            "face_size_mm": profile.sample_face_size_mm,
        },
        "reflector": (
            None
            if profile.reflector_points_mm is None
            else {"points_mm": np.asarray(profile.reflector_points_mm).tolist()}
        ),
        "water": {"temperature_c": profile.water_temperature_c},
        "transducer": {
            "frequency_mhz": profile.frequency_mhz,
            "element_diameter_mm": profile.element_diameter_mm,
        },
        "calibration": {
            "joint_offsets_deg": profile.joint_offsets_deg.tolist(),
            "unobservable_joints": list(profile.unobservable_joints),
        },
        "procedure": {
            "calibration_pose_deg": (
                None
                if proc.calibration_pose_deg is None
                else np.asarray(proc.calibration_pose_deg).tolist()
            ),
            "water_path_mm": proc.water_path_mm,
            "step_deg": proc.step_deg,
            "speed": proc.speed,
            "singularity_margin_deg": proc.singularity_margin_deg,
            "tof_averages": proc.tof_averages,
        },
        "controller": asdict(profile.controller),
        "pulser": {
            "register_map": (
                None
                if profile.pulser.register_map_path is None
                else str(profile.pulser.register_map_path)
            )
        },
    }


# ---------------------------------------------------------------------------------------------
# new profiles


def _num(x: float) -> str:
    """A number for the template: 3 decimals (µm), no negative zero."""
    v = round(float(x), 3)
    return repr(v + 0.0)


def _vec(values: Any) -> str:
    return "[" + ", ".join(_num(v) for v in values) + "]"


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


def default_profile_text(model: str) -> str:
    """Commented TOML of a new profile for the shipped ``model`` (``tx90``, ``tx90l``,
    ``tx90xl``): its DH table and joint ranges, a 80 mm tool along the flange axis, a block
    and a reflector plate placed for paper 000's calibration pose, water at 20 °C, a 25 MHz
    6 mm transducer, zero calibration."""
    if model not in KNOWN_MODELS:
        raise InputError(f"unknown robot model {model!r} (known: {', '.join(KNOWN_MODELS)})")
    m = load_model(model)
    proc = Procedure()
    ctl = ControllerTimeouts()
    corner, points = nominal_layout(m, proc.water_path_mm)
    w = wrist_centre(m, PAPER_CALIBRATION_POSE_DEG)
    s = FLANGE_MM + DEFAULT_TOOL_MM[2] + proc.water_path_mm
    rows = "\n".join(
        f"    {{ theta_offset_deg = {_num(t)}, d_mm = {_num(d)}, a_mm = {_num(a)}, "
        f"alpha_deg = {_num(al)} }},"
        for t, d, a, al in m.dh
    )
    pts = "\n".join(f"    {_vec(p)}," for p in points)
    return f"""\
# ucal cell profile: one robot cell, nominal geometry and calibration results.
# Units: mm, degrees, degrees Celsius, MHz. Orientations [rx, ry, rz] follow the Staubli
# convention R = Rot(x, rx) * Rot(y, ry) * Rot(z, rz). Check every value against your cell.
# ucal rewrites only the keys it computes; comments and key order are kept. Each write keeps
# the version it replaced in the folder <this file name>.history next to this file
# (see `ucal profile history PATH` and `ucal profile undo PATH`).
schema = 1

[robot]
model = "{model}"
# Standard DH rows: theta_offset_deg, d_mm, a_mm, alpha_deg (copied from the shipped
# {model} model; zero pose = arm straight up, as on the controller).
dh = [
{rows}
]
joint_min_deg = {_vec(m.joint_min_deg)}
joint_max_deg = {_vec(m.joint_max_deg)}

[tool]
# Tool centre point (transducer face) relative to the flange; the beam leaves it along +Z.
position_mm = {_vec(DEFAULT_TOOL_MM)}
rotation_deg = [0.0, 0.0, 0.0]
# How well the tool frame is known (one sigma): from the drawing until `tool-frame` measures it.
position_std_mm = [1.0, 1.0, 1.0]
rotation_std_deg = [0.5, 0.5, 0.5]

[sample]
# Calibration block: the corner where its three reflecting faces meet (base frame).
# Nominal placement for the calibration pose below: corner = W - ({s:g}, {s:g}, {s:g}) mm,
# W = {_vec(w)} being the wrist centre at that pose and {s:g} = flange {FLANGE_MM:g}
# + tool {DEFAULT_TOOL_MM[2]:g} + water path {proc.water_path_mm:g}: the beam (straight down)
# meets the XY face {proc.water_path_mm:g} mm below the TCP. Replace with the measured pose.
position_mm = {_vec(corner)}
rotation_deg = [0.0, 0.0, 0.0]
face_size_mm = {_num(DEFAULT_FACE_MM)}
# How well that pose is known (one sigma): a hand-placed block. Its yaw and joint 1 are one
# rotation about the base axis, so joint 1 is calibrated only as well as the yaw is known: a
# doweled, levelled fixture states its own (e.g. 0.5 mm, [0.01, 0.01, 0.01] deg).
position_std_mm = 5.0
rotation_std_deg = [0.5, 0.5, 0.5]

[reflector]
# Three or more points touched on a flat plate (tool-frame calibration). Nominal plate:
# horizontal, centred at W + (0, -{s + REFLECTOR_BEHIND_MM:g}, -{s:g}) mm, i.e. at the
# height of the block's XY face and {REFLECTOR_BEHIND_MM:g} mm behind its XZ face on the
# robot's side: reachable with the beam down, {proc.water_path_mm:g} mm of water below the TCP,
# without reaching over the block. Replace with the touched points.
points_mm = [
{pts}
]
points_std_mm = 1.0   # one sigma of a touched point (a robot not yet calibrated touches mm off)

[water]
temperature_c = 20.0
temperature_std_c = 2.0   # thermometer tolerance; the sound speed is fitted within it

[transducer]
frequency_mhz = 25.0
element_diameter_mm = 6.0

[procedure]
# Paper 000, section 5.1: calibration pose (deg); theta2 + theta3 + theta5 = 180 points
# the flange axis straight down.
calibration_pose_deg = {_vec(PAPER_CALIBRATION_POSE_DEG)}
water_path_mm = {_num(proc.water_path_mm)}   # TCP to face at each measurement
step_deg = {_num(proc.step_deg)}         # joint step between measurements
speed = {_num(proc.speed)}            # fraction of the controller's maximum speed
singularity_margin_deg = {_num(proc.singularity_margin_deg)}   # |theta5| stays above this
tof_averages = {proc.tof_averages}       # pulser averages per distance reading
verify_tolerance_mm = {_num(proc.verify_tolerance_mm)}   # `verify` exits 1 beyond this (mm)

[controller]
# How long the controller link may take (s). The VAL3 server sends nothing for 1 s after a
# client connects, so the first state message needs well over that.
connect_timeout_s = {_num(ctl.connect_timeout_s)}       # each TCP connection
first_state_timeout_s = {_num(ctl.first_state_timeout_s)}   # first state message after connecting
state_timeout_s = {_num(ctl.state_timeout_s)}         # longest silence of the running state stream
reply_timeout_s = {_num(ctl.reply_timeout_s)}         # reply to a trajectory point
halt_timeout_s = {_num(ctl.halt_timeout_s)}          # arm short of its target this long = halted
settle_timeout_s = {_num(ctl.settle_timeout_s)}       # a move to finish and settle

[calibration]
# Written by `ucal calibrate`: actual joint angle = encoder reading + offset (deg).
joint_offsets_deg = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0]
# 1-based joints whose offset the data could not determine (their offset is kept).
unobservable_joints = []
"""


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


def create_profile(path: str | Path, model: str, force: bool = False) -> Path:
    """Write a new profile for ``model`` at ``path``; refuse (exit 2) if it exists unless
    ``force`` (the replaced file then goes to the history, so it can be undone)."""
    p = Path(path)
    text = default_profile_text(model)
    profile_from_data(tomlkit.parse(text), p)  # the template must always validate
    if p.is_symlink():  # write through the link: it stays a link
        p = real_path(p)
    if p.exists():
        if not force:
            raise ProfileError(
                p,
                None,
                "already exists (use --force to replace it; the old file is kept in the history)",
            )
        # A run that holds the profile (calibrate, tool-frame) writes into it at its end: a
        # new profile under it would receive results measured on another cell description.
        with profile_lock(p, f"ucal profile init {model} {p} --force"):
            _replace_with_history(p, text.encode("utf-8"), f"init {model} --force")
    else:
        try:
            p.parent.mkdir(parents=True, exist_ok=True)
        except OSError as e:
            raise ProfileError(p, None, f"cannot create directory: {e.strerror or e}") from None
        _atomic_write(p, text.encode("utf-8"))
    return p


# ---------------------------------------------------------------------------------------------
# writing


def to_plain(value: Any) -> Any:
    """numpy arrays/scalars and tuples → plain lists, floats, ints (recursively)."""
    if isinstance(value, np.ndarray):
        return [to_plain(v) for v in value.tolist()]
    if isinstance(value, np.bool_):
        return bool(value)
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, np.floating):
        return float(value)
    if isinstance(value, (list, tuple)):
        return [to_plain(v) for v in value]
    if isinstance(value, Mapping):
        return {str(k): to_plain(v) for k, v in value.items()}
    return value


def _is_multiline(item: Any) -> bool:
    return isinstance(item, Array) and "\n" in item.as_string()


def _toml_value(value: Any, old: Any) -> Any:
    """A plain value → tomlkit item; arrays keep the old value's one-line/multiline layout;
    a list of tables becomes a multiline array of inline tables (as the ``dh`` table)."""
    if isinstance(value, list):
        arr = tomlkit.array()
        for v in value:
            if isinstance(v, Mapping):
                it = tomlkit.inline_table()
                it.update(v)
                arr.append(it)
            else:
                arr.append(v)
        if _is_multiline(old) or (
            old is None and any(isinstance(v, (Mapping, list)) for v in value)
        ):
            arr.multiline(True)
        return arr
    if isinstance(value, Mapping) and isinstance(old, InlineTable):
        it = tomlkit.inline_table()
        it.update(value)
        return it
    return tomlkit.item(value)


def _set_key(table: Any, key: str, value: Any) -> None:
    """Set ``key`` in a tomlkit table: in place if present (its comment kept), else after the
    table's last key (not after the comments that introduce the next table)."""
    if value is None:
        if key in table:
            del table[key]
        return
    old = table.get(key) if key in table else None
    item = _toml_value(value, old)
    if old is not None:
        table[key] = item
        return
    keys = list(table)
    # tomlkit appends after the table's trailing comments, i.e. below the comment that
    # introduces the next table; Container._insert_after (no public equivalent) avoids that.
    # If a tomlkit release drops it, the key is appended (still valid TOML).
    if isinstance(table, Table) and keys and hasattr(table.value, "_insert_after"):
        table.value._insert_after(keys[-1], key, item)
    else:
        table[key] = item


def render_update(text: str, updates: Mapping[str, Mapping[str, Any]]) -> str:
    """Apply ``updates`` (table → key → value; ``None`` deletes the key) to TOML ``text``,
    keeping comments and key order; missing tables are appended."""
    doc = tomlkit.parse(text)
    for tname, keys in updates.items():
        if not isinstance(keys, Mapping):
            doc[tname] = tomlkit.item(to_plain(keys))
            continue
        if tname not in doc:
            doc.add(tname, tomlkit.table())
        table = doc[tname]
        for key, value in keys.items():
            _set_key(table, key, to_plain(value))
    return tomlkit.dumps(doc)


def write_profile(path: str | Path, updates: Mapping[str, Mapping[str, Any]], reason: str) -> None:
    """Write ``updates`` (e.g. ``{"calibration": {"joint_offsets_deg": offsets}}``) into the
    profile at ``path``, atomically, keeping comments and key order, and record the replaced
    bytes in the history with ``reason`` (e.g. ``"calibrate"``).

    The result is validated as a profile first. Any failure raises :class:`ProfileError`
    (exit 2) and leaves the profile byte-for-byte unchanged. A symlinked profile is written
    through the link (the link stays a link; the history sits beside the real file).
    """
    p = real_path(path)
    try:
        before = p.read_bytes()
    except OSError as e:
        raise ProfileError(p, None, f"cannot read: {e.strerror or e}") from None
    text = parse_toml_bytes(before, p).as_string()
    after = render_update(text, updates).encode("utf-8")
    profile_from_data(parse_toml_bytes(after, p), p)
    if after == before:
        log.info("%s: nothing to change", p)
        return
    _replace_with_history(p, after, reason, before)


def _atomic_write(path: Path, data: bytes, mode: int | None = None) -> None:
    """Replace ``path`` with ``data``: temp file in the same directory, fsync, ``os.replace``.

    The file keeps its mode (a new one: ``mode``, else the umask's). On failure the temp file
    is removed and ``path`` is untouched; raises ProfileError.
    """
    _commit(_stage(path, data, mode), path)


def _stage(path: Path, data: bytes, mode: int | None = None) -> Path:
    """Write ``data`` to a new fsync'ed temporary file beside ``path`` and return it: everything
    that needs disk space, before anything is replaced (mode as ``files.stage``)."""
    try:
        return files.stage(path, data, mode)
    except OSError as e:
        raise ProfileError(
            path, None, f"cannot write: {e.strerror or e} (file unchanged)"
        ) from None


def _commit(tmp: Path, path: Path) -> None:
    """Rename a staged file over ``path`` (atomic; needs no space); remove it on failure."""
    try:
        files.commit(tmp, path)
    except OSError as e:
        raise ProfileError(
            path, None, f"cannot write: {e.strerror or e} (file unchanged)"
        ) from None


# ---------------------------------------------------------------------------------------------
# history and undo


@dataclass
class HistoryEntry:
    """One write of a profile: what it replaced and why.

    ``before`` is the file (in the history directory) holding the replaced bytes; the hashes
    are SHA-256 hex digests of the profile bytes before and after the write. ``after`` names
    the copy of the replaced-by-undo bytes once the entry has been undone.
    """

    id: int
    time: str
    reason: str
    before: str
    before_sha256: str
    after_sha256: str
    undone: bool = False
    undone_time: str | None = None
    after: str | None = None


def real_path(path: str | Path) -> Path:
    """The file a profile path names, symbolic links resolved (the path itself if none)."""
    return Path(os.path.realpath(path))


def history_dir(path: str | Path) -> Path:
    """The history directory of a profile: ``cell.toml`` → ``cell.toml.history``, beside the
    real file when ``path`` is a symbolic link."""
    p = real_path(path)
    return p.with_name(p.name + HISTORY_SUFFIX)


def _sha(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def _now() -> str:
    return datetime.now(UTC).isoformat(timespec="seconds")


def profile_history(path: str | Path) -> list[HistoryEntry]:
    """The history entries of a profile, oldest first (empty if it was never rewritten)."""
    index = history_dir(path) / HISTORY_INDEX
    if not index.exists():
        return []
    try:
        raw = json.loads(index.read_text(encoding="utf-8"))
        return [HistoryEntry(**e) for e in raw["entries"]]
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise ProfileError(index, None, f"unreadable history index: {e}") from None


#: History reasons of the writes that put a measurement into a profile.
MEASURED_BY = ("tool-frame", "calibrate")


def last_measurement(path: str | Path) -> HistoryEntry | None:
    """The newest write of ``tool-frame`` or ``calibrate`` in a profile's history that was not
    undone (its ``time`` is when that result went into the profile); None if there is none."""
    for entry in reversed(profile_history(path)):
        if entry.reason.startswith(MEASURED_BY) and not entry.undone:
            return entry
    return None


def placed_block(profile: CellProfile, path: Path) -> tuple[np.ndarray, np.ndarray]:
    """The block's corner and orientation as the technician last described them: ``[sample]``
    of the profile at ``path`` before the ``calibrate`` writes (which write the block they
    measured) since its last other change (a hand edit)."""
    pose = (profile.sample_position_mm, profile.sample_rotation_deg)
    for entry in reversed([e for e in profile_history(path) if not e.undone]):
        before = history_dir(path) / entry.before
        if not before.exists():
            break
        old = load_profile(before, base_dir=path.parent)
        was = (old.sample_position_mm, old.sample_rotation_deg)
        if not entry.reason.startswith("calibrate") and not all(map(np.array_equal, was, pose)):
            break  # this write changed the block by hand: that is the description
        pose = was
    return pose


def before_measurement(profile: CellProfile) -> CellProfile:
    """``profile`` with the tool and the kinematic model it had before ucal first wrote a
    measurement into it (the before-file of its history's oldest ``tool-frame`` or
    ``calibrate`` entry), and the block as placed (``placed_block``); ``profile`` itself if
    ucal never did.

    What the simulator takes as "the cell as the profile says": the technician's description,
    not ucal's estimates of it, so that a simulated cell stays one cell while the commands
    write into its profile.
    """
    if profile.path is None:
        return profile
    for entry in profile_history(profile.path):
        if entry.reason.startswith(MEASURED_BY):
            before = history_dir(profile.path) / entry.before
            if not before.exists():
                break
            old = load_profile(before, base_dir=profile.path.parent)
            position, rotation = placed_block(profile, profile.path)
            return profile.replace(
                model=old.model,
                tool_position_mm=old.tool_position_mm,
                tool_rotation_deg=old.tool_rotation_deg,
                sample_position_mm=position,
                sample_rotation_deg=rotation,
            )
    return profile


def _index_bytes(path: Path, entries: list[HistoryEntry]) -> bytes:
    data = {"profile": path.name, "entries": [asdict(e) for e in entries]}
    return (json.dumps(data, indent=1) + "\n").encode("utf-8")


def _save_history(path: Path, entries: list[HistoryEntry]) -> None:
    _atomic_write(history_dir(path) / HISTORY_INDEX, _index_bytes(path, entries), _index_mode(path))


def _index_mode(path: Path) -> int | None:
    """The history holds copies of the profile: a new index takes the profile's mode (an
    existing one keeps its own)."""
    return None if (history_dir(path) / HISTORY_INDEX).exists() else files.existing_mode(path)


def _replace_both(path: Path, data: bytes, entries: list[HistoryEntry], copy: Path) -> None:
    """Replace the history index (``entries``) and then the profile (``data``).

    Both new files are written and fsync'ed before either is renamed into place, so a full
    disk fails before anything changes: the staged files and the new history ``copy`` are
    removed, and the index and the profile keep their bytes.
    """
    index = history_dir(path) / HISTORY_INDEX
    staged: list[Path] = []
    try:
        staged.append(_stage(index, _index_bytes(path, entries), _index_mode(path)))
        staged.append(_stage(path, data))
        _commit(staged[0], index)
    except ProfileError:
        for tmp in staged:
            with contextlib.suppress(OSError):
                tmp.unlink()
        with contextlib.suppress(OSError):
            copy.unlink()
        raise
    _commit(staged[1], path)


def _write_new(path: Path, data: bytes, mode: int | None) -> None:
    """Write a history copy (fsync'ed, with ``mode``: the profile's); it is new, so no rename
    is needed.

    A copy that cannot be written whole (e.g. the disk is full) is removed again, so that no
    empty or truncated ``NNNN-before.toml`` is left to collide with the next write.
    """
    try:
        files.write_new(path, data, mode)
    except OSError as e:
        raise ProfileError(path, None, f"cannot write history copy: {e.strerror or e}") from None


def _next_history_id(hdir: Path, entries: list[HistoryEntry]) -> int:
    """The next free history id: past every indexed entry and every ``NNNN-*.toml`` present
    (a copy left behind by an interrupted write must not block the next one)."""
    ids = [e.id for e in entries]
    with contextlib.suppress(OSError):
        for f in hdir.iterdir():
            head = f.name.split("-", 1)[0]
            if f.suffix == ".toml" and head.isdigit():
                ids.append(int(head))
    return max(ids, default=0) + 1


def _replace_with_history(
    path: Path, after: bytes, reason: str, before: bytes | None = None
) -> HistoryEntry:
    """Record ``before`` (default: the current bytes) in the history, then replace ``path``
    with ``after`` atomically; withdraw the entry if the replacement fails."""
    path = real_path(path)
    if before is None:
        before = path.read_bytes()
    hdir = history_dir(path)
    try:
        hdir.mkdir(exist_ok=True)
    except OSError as e:
        raise ProfileError(
            hdir, None, f"cannot create history directory: {e.strerror or e}"
        ) from None
    entries = profile_history(path)
    new_id = _next_history_id(hdir, entries)
    copy = hdir / f"{new_id:04d}-before.toml"
    _write_new(copy, before, files.existing_mode(path))
    entry = HistoryEntry(
        id=new_id,
        time=_now(),
        reason=reason,
        before=copy.name,
        before_sha256=_sha(before),
        after_sha256=_sha(after),
    )
    try:
        _replace_both(path, after, entries + [entry], copy)
    except ProfileError:
        _withdraw(path, entries, copy)  # only needed when the final rename failed
        raise
    log.info("%s: written (%s); previous version kept as %s", path, reason, copy)
    return entry


def _withdraw(path: Path, entries: list[HistoryEntry], copy: Path) -> None:
    """Best effort: put the index back as it was (if it lists ``copy``) and remove ``copy``."""
    try:
        if any(e.before == copy.name for e in profile_history(path)):
            _save_history(path, entries)
    except ProfileError:
        log.warning("%s: could not withdraw history entry %s", path, copy.name)
    try:
        copy.unlink()
    except FileNotFoundError:
        pass
    except OSError:
        log.warning("%s: could not remove the unused history copy %s", path, copy.name)


def undo_profile(path: str | Path, force: bool = False) -> HistoryEntry:
    """Restore the profile bytes replaced by the newest write not yet undone, atomically.

    Refuses (exit 2) when there is nothing to undo, or when the profile was changed since that
    write (its SHA-256 differs), unless ``force``. The bytes replaced by the undo are kept as
    ``NNNN-after.toml``. Returns the undone entry.
    """
    p = real_path(path)
    with profile_lock(p, f"ucal profile undo {p}"):
        return _undo_held(p, force)


def _undo_held(p: Path, force: bool) -> HistoryEntry:
    """``undo_profile`` with the profile held."""
    entries = profile_history(p)
    pending = [e for e in entries if not e.undone]
    if not pending:
        raise ProfileError(p, None, "nothing to undo (no recorded write)")
    entry = pending[-1]
    hdir = history_dir(p)
    try:
        current = p.read_bytes()
        previous = (hdir / entry.before).read_bytes()
    except OSError as e:
        raise ProfileError(p, None, f"cannot read for undo: {e.strerror or e}") from None
    if _sha(previous) != entry.before_sha256:
        raise ProfileError(hdir / entry.before, None, "history copy is corrupt (hash mismatch)")
    if _sha(current) != entry.after_sha256 and not force:
        raise ProfileError(
            p,
            None,
            f"changed since write {entry.id} ({entry.reason}, "
            f"{entry.time}); use --force to undo anyway",
        )
    after_copy = hdir / f"{entry.id:04d}-after.toml"
    if after_copy.exists():  # left over by an undo whose rename failed
        stamp = datetime.now(UTC).strftime("%Y%m%dT%H%M%S%f")
        after_copy = hdir / f"{entry.id:04d}-after-{stamp}.toml"
    _write_new(after_copy, current, files.existing_mode(p))
    entry.undone, entry.undone_time, entry.after = True, _now(), after_copy.name
    try:
        _replace_both(p, previous, entries, after_copy)
    except ProfileError:
        entry.undone, entry.undone_time, entry.after = False, None, None
        try:
            if any(e.id == entry.id and e.undone for e in profile_history(p)):
                _save_history(p, entries)  # only when the final rename failed
        except ProfileError:
            log.warning("%s: could not withdraw the undo record", p)
        with contextlib.suppress(OSError):
            after_copy.unlink()
        raise
    return entry


# ---------------------------------------------------------------------------------------------
# one run at a time, and room to write


LOCK_SUFFIX = ".lock"
#: Free space a profile write needs besides the profile's own bytes (temporary file, history
#: copy, index): the profile's size three times over plus this margin.
MIN_FREE_BYTES = 1 << 20


@dataclass(frozen=True)
class LockHolder:
    """Who holds a profile: process id, host, command line and UTC start time."""

    pid: int
    host: str
    command: str
    started: str

    def describe(self) -> str:
        """The holder in words, for the refusal message."""
        return f"pid {self.pid} on {self.host}, started {self.started}: {self.command}"


def lock_path(path: str | Path) -> Path:
    """The lock file of a profile: ``cell.toml`` → ``cell.toml.lock``, beside the real file."""
    p = real_path(path)
    return p.with_name(p.name + LOCK_SUFFIX)


def _read_holder(fd: int) -> LockHolder | None:
    try:
        raw = os.pread(fd, 65536, 0)
        return LockHolder(**json.loads(raw.decode("utf-8")))
    except (OSError, ValueError, TypeError):
        return None  # the holder is still writing it, or it is not ours


@contextlib.contextmanager
def profile_lock(path: str | Path, command: str | None = None) -> Iterator[LockHolder]:
    """Hold the profile for one run: a second run on the same profile refuses at once.

    An advisory ``fcntl.flock`` on ``<profile>.lock`` beside the real file (symbolic links
    resolved, so two links to one profile share the lock). The operating system releases it
    when the process ends, however it ends: a crashed run never leaves a lock that blocks.
    The file records the holder (pid, host, command, start time) for the refusal, which is an
    ``InputError`` (exit 2) naming the profile and the holder. The file is removed on release.
    """
    lock = lock_path(path)
    me = LockHolder(
        pid=os.getpid(),
        host=socket.gethostname(),
        command=command or " ".join(["ucal", *sys.argv[1:]]),
        started=_now(),
    )
    while True:
        try:
            fd = os.open(lock, os.O_RDWR | os.O_CREAT, 0o644)
        except OSError as e:
            raise ProfileError(
                lock.parent,
                None,
                f"cannot create the lock file {lock.name} "
                f"for {real_path(path).name}: "
                f"{e.strerror or e}",
            ) from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            holder = _read_holder(fd)
            os.close(fd)
            who = holder.describe() if holder else "another process"
            raise InputError(
                f"{real_path(path)}: in use by another run ({who}); wait for it "
                f"to finish (the lock is {lock})"
            ) from None
        try:
            same = os.fstat(fd).st_ino == os.stat(lock).st_ino
        except OSError:
            same = False
        if same:
            break
        os.close(fd)  # the holder removed the file between our open and our lock: again
    try:
        data = json.dumps(asdict(me)).encode("utf-8")
        with contextlib.suppress(OSError):  # the holder's name is a courtesy, the lock is not
            os.ftruncate(fd, 0)
            os.pwrite(fd, data, 0)
        log.debug("%s: locked (%s)", lock, me.describe())
        yield me
    finally:
        with contextlib.suppress(OSError):
            os.unlink(lock)  # while still held: a waiting opener then sees another inode
        os.close(fd)


def check_writable(path: str | Path, min_free_bytes: int = MIN_FREE_BYTES) -> None:
    """Preflight before the first motion: the profile's directory and its history directory
    must be writable and hold room for the write; else ``ProfileError`` (exit 2) naming the
    directory. ``min_free_bytes`` is the margin over three times the profile's size."""
    p = real_path(path)
    hdir = history_dir(p)
    try:
        size = p.stat().st_size
    except OSError:
        size = 0
    need = 3 * size + int(min_free_bytes)
    for directory, what in ((p.parent, "profile directory"), (hdir, "history directory")):
        if not directory.exists():
            if directory == hdir:
                continue  # created by the first write, in the profile directory checked above
            raise ProfileError(directory, None, f"{what} of {p.name} does not exist")
        if not directory.is_dir():
            raise ProfileError(directory, None, f"{what} of {p.name} is not a directory")
        if not os.access(directory, os.W_OK | os.X_OK):
            raise ProfileError(
                directory,
                None,
                f"{what} is not writable: the results for "
                f"{p.name} could not be written after the run",
            )
        try:
            free = shutil.disk_usage(directory).free
        except OSError as e:
            raise ProfileError(
                directory, None, f"cannot check free space: {e.strerror or e}"
            ) from None
        if free < need:
            raise ProfileError(
                directory,
                None,
                f"{what} has {free} bytes free, {need} needed to write {p.name} and its history",
            )
