"""Read and validate a cell profile (SPEC.md, "Profile file"), and the tables a world file shares.

:func:`load_profile` turns a profile into a :class:`CellProfile` or raises a
:class:`ProfileError` naming the file and the dotted key of the first problem; the ``read_*``
functions read one table each, so that ``ucal.world`` reads its tables by the same rules.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import MISSING, asdict, replace
from pathlib import Path
from typing import Any, Literal, overload

import numpy as np

from ucal.cell import (
    MAX_CONTROLLER_TIMEOUT_S,
    MAX_PULSER_TIMEOUT_S,
    PULSER_TIMINGS,
    CellProfile,
    ControllerTimeouts,
    Procedure,
    PulserConfig,
    Step,
)
from ucal.errors import InputError
from ucal.kinematics.dh import RobotModel
from ucal.profile.arm_load import ROBOT_LOAD_KEYS, TOOL_LOAD_KEYS, read_arm_load
from ucal.profile.by_hand import KEYS as BY_HAND_KEYS
from ucal.profile.by_hand import by_hand_to_dict, read_by_hand
from ucal.profile.calibration import read_calibration
from ucal.profile.cell import CELL_KEYS, read_cell
from ucal.profile.described import DESCRIPTION_KEYS, read_description
from ucal.profile.models import KNOWN_MODELS, load_model
from ucal.profile.validation import (
    DH_KEYS,
    Reader,
    describe_unknown,
    parse_toml_bytes,
    read_toml,
    refuse_misspelt_keys,
    unknown_keys,
)

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
            "speed_deg_s",
            "dh_length_std_mm",
            "dh_angle_std_deg",
            "backlash_std_deg",
            *ROBOT_LOAD_KEYS,
        }
    ),
    "tool": frozenset(
        {"position_mm", "rotation_deg", "position_std_mm", "rotation_std_deg", *TOOL_LOAD_KEYS}
    )
    | DESCRIPTION_KEYS["tool"],
    "sample": frozenset(
        {"position_mm", "rotation_deg", "face_size_mm", "position_std_mm", "rotation_std_deg"}
    )
    | DESCRIPTION_KEYS["sample"],
    "reflector": frozenset({"points_mm", "points_std_mm"}),
    "step": frozenset({"height_mm", "height_std_mm", "centre_mm", "size_mm"}),
    "water": frozenset(
        {"temperature_c", "temperature_std_c", "drift_std_c_per_min", "thermometer_std_c"}
    ),
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
    "pulser": frozenset(
        {"register_map", "timeout_s", "retries", "timing", "reference_echo", *BY_HAND_KEYS}
    ),
    "cell": CELL_KEYS,  # the cell's name and validation interval for published results
}

#: Fastest joint speed (deg/s) a profile may state: a few times an industrial arm's wrist.
MAX_JOINT_SPEED_DEG_S = 2000.0
#: Largest Hayati twist (deg) a calibrated table may hold: a calibration finds hundredths.
MAX_CALIBRATED_BETA_DEG = 1.0


def _profile_default(name: str) -> Any:
    """``CellProfile``'s default for the field ``name`` (built anew where a factory makes it)."""
    f = CellProfile.__dataclass_fields__[name]
    return f.default if f.default_factory is MISSING else f.default_factory()


#: Edge length of the calibration block's faces (mm): the ``CellProfile`` default.
DEFAULT_FACE_MM = float(_profile_default("sample_face_size_mm"))


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


def profile_from_text(text: str, path: str | Path, base_dir: Path | None = None) -> CellProfile:
    """The profile whose TOML is ``text`` (a record's copy, a shipped template), errors naming
    ``path`` as :func:`load_profile`'s name the file."""
    return profile_from_data(parse_toml_bytes(text.encode("utf-8"), path), path, base_dir)


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
    robot_model = model  # the [robot] table's, whose shipped sheet gives the masses

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
    drawn = read_description(r, tool, "tool", tool_pos, tool_rot)
    placed = read_description(r, sample, "sample", sample_pos, sample_rot)
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

    described_model = None
    cal = r.table("calibration")
    offsets = np.zeros(6)
    unobservable: tuple[int, ...] = ()
    offsets_std = None
    dh_std = None
    read_calibration(r, cal)  # what later commands take over, checked before anything moves
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
            described_model = model
            model = model.with_dh(r.dh_table("calibration.dh", rows), beta, "[calibration] dh")
        v = r.get(cal, "calibration.dh_std")
        if v is not None:
            if r.get(cal, "calibration.dh") is None:
                raise r.error(
                    "calibration.dh_std",
                    "written with [calibration] dh by calibrate --level full: without dh it "
                    "describes no table (remove it, or restore dh)",
                )
            dh_std = read_dh_std(r, "calibration.dh_std", v)

    load = read_arm_load(r, r.table("robot", required=True), tool, cal, robot_model)
    procedure = read_procedure(r, r.table("procedure"), model)
    controller = read_controller(r, r.table("controller"))
    pulser = read_pulser(r, r.table("pulser"), base_dir)
    read_cell(r, r.table("cell"), Path(path).stem)  # checked here; ``ucal.fleet`` reads it

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
        dh_std=dh_std,
        water_temperature_c=water_c,
        frequency_mhz=freq,
        element_diameter_mm=diam,
        joint_offsets_deg=offsets,
        unobservable_joints=unobservable,
        procedure=procedure,
        controller=controller,
        pulser=pulser,
        path=Path(path),
        described_model=described_model,
        described_tool=drawn,
        described_sample=placed,
        **tolerances,
        **load,
    )


#: The columns of ``[calibration] dh_std``: one sigma of each row's lengths (mm) and twists (deg).
DH_STD_KEYS = ("d_mm", "a_mm", "alpha_deg", "beta_deg")


def read_dh_std(r: Reader, key: str, raw: Any) -> np.ndarray:
    """``[calibration] dh_std``: six rows, each a table of some of ``DH_STD_KEYS`` (one sigma,
    up to 10 mm / 1 deg, as the [robot] tolerances; negative: not determined) → (6, 4), NaN
    where not determined or left out (the [robot] tolerance then stands)."""
    out = np.full((6, 4), np.nan)
    for i, row in enumerate(r.array(key, raw, 6)):
        rkey = f"{key}[{i}]"
        if not isinstance(row, Mapping):
            raise r.error(rkey, f"must be a table of {', '.join(DH_STD_KEYS)}")
        r.refuse_misspelt(rkey, row, DH_STD_KEYS, "column")
        extra = sorted(set(row) - set(DH_STD_KEYS))
        if extra:
            raise r.error(f"{rkey}.{extra[0]}", f"unknown column (known: {', '.join(DH_STD_KEYS)})")
        for j, name in enumerate(DH_STD_KEYS):
            if name in row:
                hi, unit = (10.0, "mm") if name.endswith("_mm") else (1.0, "deg")
                v = r.number(f"{rkey}.{name}", row[name], hi=hi, unit=unit)
                out[i, j] = v if v >= 0.0 else np.nan
    return out


def read_tolerances(
    r: Reader,
    tool: Mapping[str, Any] | None,
    sample: Mapping[str, Any] | None,
    water: Mapping[str, Any] | None,
    robot: Mapping[str, Any] | None,
) -> dict[str, Any]:
    """One-sigma tolerances: ``[tool]`` / ``[sample]`` ``position_std_mm`` and
    ``rotation_std_deg`` (a number or three, >= 0, mm / deg), ``[robot] backlash_std_deg`` (a
    number or six, 0–1 deg), ``[water] temperature_std_c`` (0–20 °C), ``drift_std_c_per_min``
    (0–10 °C/min), ``thermometer_std_c`` (0–5 °C) and ``[robot] dh_length_std_mm`` (0–10
    mm), ``dh_angle_std_deg`` (0–1 deg); missing keys keep ``CellProfile``'s defaults (SPEC.md)."""
    out: dict[str, Any] = {}
    for table, tname, key, attr, size, hi, unit in (
        (tool, "tool", "position_std_mm", "tool_position_std_mm", 3, 100.0, "mm"),
        (tool, "tool", "rotation_std_deg", "tool_rotation_std_deg", 3, 10.0, "deg"),
        (sample, "sample", "position_std_mm", "sample_position_std_mm", 3, 100.0, "mm"),
        (sample, "sample", "rotation_std_deg", "sample_rotation_std_deg", 3, 10.0, "deg"),
        (robot, "robot", "backlash_std_deg", "backlash_std_deg", 6, 1.0, "deg"),
    ):
        v = r.get(table, f"{tname}.{key}")
        if v is None:
            out[attr] = _profile_default(attr)
        elif isinstance(v, (int, float)) and not isinstance(v, bool):
            out[attr] = np.full(size, r.number(f"{tname}.{key}", v, lo=0.0, hi=hi, unit=unit))
        else:
            out[attr] = r.vector(f"{tname}.{key}", v, size, lo=0.0, hi=hi, unit=unit)
    for table, key, attr, hi, unit in (
        (water, "water.temperature_std_c", "water_temperature_std_c", 20.0, "degC"),
        (water, "water.drift_std_c_per_min", "drift_std_c_per_min", 10.0, "degC/min"),
        (water, "water.thermometer_std_c", "thermometer_std_c", 5.0, "degC"),
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
    name), plus joint ranges (deg) and the joints' speeds at speed 1.0 (``speed_deg_s``,
    deg/s, 0–2000). Ranges and speeds default to ``ranges_from``'s if given (a world file
    keeps the profile's), else to the shipped model's (``ucal.profile.models``; another arm's then
    are the lowest of the shipped models', ``joint_speeds_deg_s``)."""
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
    v = r.get(robot, f"{prefix}.speed_deg_s")
    speeds: np.ndarray | None
    if v is not None:
        speeds = r.vector(
            f"{prefix}.speed_deg_s",
            v,
            6,
            lo=0.0,
            lo_open=True,
            hi=MAX_JOINT_SPEED_DEG_S,
            unit="deg/s",
        )
    else:
        speeds = None if base is None else base.speed_deg_s
    source = "shipped" if dh_raw is None else f"{r.path} [{prefix}] dh"
    return RobotModel(name or "custom", dh, jmin, jmax, dh_source=source, speed_deg_s=speeds)


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
    the profile's directory), read and validated; ``timeout_s`` and ``retries``, how long a
    request waits for the first byte of its answer beyond the instrument's own time (a
    reading's averaging) and how often one that got none is asked again before the device
    counts as silent; ``timing`` (``"gate"`` or ``"ascan"``) and
    ``reference_echo``, a CSV file of ``ucal echo``'s reference format, relative like the
    map."""
    d = PulserConfig()
    timeout = r.get(table, "pulser.timeout_s")
    retries = r.get(table, "pulser.retries")
    timing = r.get(table, "pulser.timing")
    if timing is not None and timing not in PULSER_TIMINGS:
        raise r.error(
            "pulser.timing",
            f"must be one of {', '.join(map(repr, PULSER_TIMINGS))}, got {timing!r}",
        )
    by_hand = read_by_hand(r, table)
    if by_hand is not None:
        if timing not in (None, "ascan"):
            raise r.error(
                "pulser.timing",
                "a pulser set by hand has no gate ucal reads: its echoes are timed from the "
                'A-scans, "ascan"',
            )
        timing = "ascan"
    config = PulserConfig(
        timeout_s=d.timeout_s
        if timeout is None
        else r.number("pulser.timeout_s", timeout, lo=0.01, hi=MAX_PULSER_TIMEOUT_S, unit="s"),
        retries=d.retries if retries is None else r.integer("pulser.retries", retries, lo=0, hi=10),
        timing=d.timing if timing is None else str(timing),
        by_hand=by_hand,
    )
    raw = r.get(table, "pulser.reference_echo")
    if raw is not None:
        p = Path(r.string("pulser.reference_echo", raw)).expanduser()
        if not p.is_absolute():
            p = (r.path.parent if base_dir is None else base_dir) / p
        try:
            from ucal.echo.files import read_reference  # scipy.signal: only when named

            reference = read_reference(p)
        except InputError as e:
            raise r.error("pulser.reference_echo", str(e)) from None
        config = replace(config, reference_echo_path=p, reference_echo=reference)
    raw = r.get(table, "pulser.register_map")
    if raw is None:
        return config
    path, register_map = r.register_map("pulser.register_map", raw, base_dir)
    return replace(config, register_map_path=path, register_map=register_map)


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
            ),
            "timeout_s": profile.pulser.timeout_s,
            "retries": profile.pulser.retries,
            "timing": profile.pulser.timing,
            "reference_echo": (
                None
                if profile.pulser.reference_echo_path is None
                else str(profile.pulser.reference_echo_path)
            ),
            **by_hand_to_dict(profile.pulser.by_hand),
        },
    }
