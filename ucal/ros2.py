"""The calibrated arm for ROS 2: a URDF of the identified kinematics, its offsets, its covariance.

``ucal export ros2 PROFILE -o DIR`` writes, for a profile of model NAME (``tx90l``):

* ``NAME_kinematics.yaml``: the origin of each joint in its parent link (``x, y, z`` in m,
  ``roll, pitch, yaw`` in rad), in the layout of Universal Robots' ``ur_description``
  (``default_kinematics.yaml``: a ``kinematics`` mapping of ``x, y, z, roll, pitch, yaw``
  per joint, and its ``hash``), derived from the identified DH table; the joint limits; the
  profile it came from (SHA-256 of its bytes), ucal's version and the date;
* ``NAME_macro.xacro`` (the macro ``ucal_NAME``, which reads the two YAML files) and
  ``NAME.urdf.xacro`` (its arguments and one arm on ``world``);
* ``NAME.urdf`` and ``NAME_offsets_in_urdf.urdf``: the same rendered with the default
  arguments, for a reader without xacro;
* ``NAME_joint_offsets.yaml``: the joint offsets (rad) and their sign;
* ``NAME_covariance.yaml``: one sigma of each parameter the profile states and the
  covariance of every exported origin.

Frames (ROS-Industrial's names, each with the prefix): ``base_link`` (the mounting face),
``base`` (the controller's world frame at shoulder height, in which ucal states the model and
every pose; the model file's ``base_height_mm`` above ``base_link``, as the ROS-Industrial
TX90 description has it: a nominal value ucal does not measure), ``link_1`` … ``link_6``
(moved by ``joint_1`` … ``joint_6``), ``flange`` (x out of the flange), ``tool0`` (ucal's
flange frame: the joint-6 frame of its model, the controller's ``flange``,
docs/decisions/0001) and ``ucal_tcp`` (the profile's ``[tool]``: the transducer's frame, beam
along +z).

Kinematics. With the DH rows ``A_i = Rz(θ_i)·Tz(d_i)·Tx(a_i)·Rx(α_i)·Ry(β_i)`` and
``θ_i = q_i + θoff_i`` (``ucal.kinematics.dh``; ``q_i`` = reading + offset, the arm's true joint
angle), ``Rz(θ_i) = Rz(θoff_i)·Rz(q_i)``, so a chain of revolute joints about their z axes
with the origins ``O_1 = Rz(θoff_1)``, ``O_i = M_{i-1}·Rz(θoff_i)`` (``M = Tz(d)·Tx(a)·Rx(α)
·Ry(β)``) and the fixed ``link_6 → tool0 = M_6`` is ucal's forward kinematics for the joint
positions ``q``: the zero-offset convention. The θ offsets (the controller's zero, arm
straight up) are folded into the origins; the joint offsets are not: a joint position of
``NAME.urdf`` is ``reading + offset`` (SPEC.md's sign), which the hardware interface computes
(``NAME_joint_offsets.yaml``; ``ros2_control``'s ``SimpleTransmission`` with its ``offset``
does, where the hardware interface applies transmissions). The second variant,
``kinematics_offsets_in_urdf`` (xacro argument ``offsets_in_urdf:=true``,
``NAME_offsets_in_urdf.urdf``), folds the offsets in as well, ``O_i·Rz(offset_i)``: its joint
positions are the controller's readings unchanged, and its limits the controller's ranges.

Units are ROS's (REP 103: m, rad, rad/s, N·m) in every file written here, the one place
outside the controller protocol where ucal leaves mm and degrees; numbers are written in full
(``repr``), so nothing is lost to rounding.
"""

from __future__ import annotations

import hashlib
import json
import logging
import re
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from ucal import __version__
from ucal.cell import CellProfile
from ucal.errors import InputError, ProfileError
from ucal.kinematics.dh import N_JOINTS, RobotModel, dh_matrix, transform
from ucal.kinematics.rotations import rpy_to_matrix
from ucal.output import writable_directory, write_file
from ucal.profile import real_path
from ucal.profile.models import KNOWN_MODELS, model_sheet
from ucal.profile.read import profile_from_data
from ucal.profile.validation import parse_toml_bytes
from ucal.ros2_description import (
    FLANGE,
    FLANGE_TURN,
    JOINTS,
    TCP,
    TCP_LINK,
    Origin,
    macro_xacro,
    number,
    top_xacro,
    urdf_xml,
)

log = logging.getLogger(__name__)

#: A tf prefix: empty, or a ROS name's characters (``arm_``, ``left/``).
_PREFIX = re.compile(r"[A-Za-z_][A-Za-z0-9_/]*")


def _link_matrix(model: RobotModel, row: int) -> np.ndarray:
    """``M = Tz(d)·Tx(a)·Rx(α)·Ry(β)`` of DH row ``row`` (0-based; mm): ``A`` at θ = 0."""
    m = dh_matrix(np.array(0.0), model.d_mm[row], model.a_mm[row], np.radians(model.alpha_deg[row]))
    twist = Rotation.from_euler("y", model.beta_deg[row], degrees=True).as_matrix()
    return np.asarray(m @ transform(np.zeros(3), twist))


def _rot_z(angle_deg: float) -> np.ndarray:
    return transform(np.zeros(3), Rotation.from_euler("z", angle_deg, degrees=True).as_matrix())


def chain_matrices(
    model: RobotModel, tool_mm: np.ndarray, offsets_deg: np.ndarray | None = None
) -> dict[str, np.ndarray]:
    """The origins (4, 4; mm) of ``joint_1`` … ``joint_6`` in their parent links, of
    ``link_6 → flange`` and of ``tool0 → ucal_tcp`` (module docstring): with ``offsets_deg``
    (6,) folded in, the joint positions are the readings; without, reading + offset."""
    shift = np.zeros(N_JOINTS) if offsets_deg is None else np.asarray(offsets_deg, dtype=float)
    out: dict[str, np.ndarray] = {}
    parent = np.eye(4)
    for i, name in enumerate(JOINTS):
        out[name] = parent @ _rot_z(model.theta_offset_deg[i] + shift[i])
        parent = _link_matrix(model, i)
    out[FLANGE] = parent @ FLANGE_TURN
    out[TCP] = np.asarray(tool_mm, dtype=float)
    return out


@dataclass(frozen=True)
class Ros2Arm:
    """What ``ucal export ros2`` writes, read from one profile.

    ``name``: the files' stem and the robot's name (the model's, as a ROS name); ``prefix``:
    the tf prefix of the rendered URDFs (and the xacro's default); ``cell``: the profile as
    read; ``profile``: its file; ``sha256``: of its bytes; ``written``: the export's time
    (UTC, ISO 8601).
    """

    name: str
    prefix: str
    cell: CellProfile
    profile: Path
    sha256: str
    written: str

    @property
    def model(self) -> RobotModel:
        return self.cell.model

    @property
    def offsets_deg(self) -> np.ndarray:
        return np.asarray(self.cell.joint_offsets_deg, dtype=float)

    @property
    def hash(self) -> str:
        """The ``hash`` the YAML files carry: the profile's SHA-256."""
        return f"sha256:{self.sha256}"

    def origins(self, offsets_in_urdf: bool = False) -> dict[str, Origin]:
        """The exported origins (``chain_matrices``), offsets folded in or not."""
        offsets = self.offsets_deg if offsets_in_urdf else None
        mats = chain_matrices(self.model, self.cell.tool_matrix, offsets)
        return {k: Origin.from_matrix(t) for k, t in mats.items()}

    def limits(self) -> dict[str, dict[str, float]]:
        """Per joint ``min_position``, ``max_position`` (rad, of the controller's readings),
        ``max_velocity`` (rad/s), ``max_effort`` (N·m), as ``ur_description`` names them."""
        speeds, efforts = _speeds_and_efforts(self.model.name)
        return {
            name: {
                "min_position": float(np.radians(self.model.joint_min_deg[i])),
                "max_position": float(np.radians(self.model.joint_max_deg[i])),
                "max_velocity": float(np.radians(speeds[i])),
                "max_effort": float(efforts[i]),
            }
            for i, name in enumerate(JOINTS)
        }

    @property
    def base_height_mm(self) -> float:
        """``base_link → base`` (mm): the model file's ``base_height_mm`` (nominal, not
        measured), 0 for an arm that is not a shipped model."""
        name = self.model.name
        return model_sheet(name).base_height_mm if name in KNOWN_MODELS else 0.0


def _speeds_and_efforts(model: str) -> tuple[Sequence[float], Sequence[float]]:
    """The joints' maximum speeds (deg/s) and torques (N·m) of the URDF's ``<limit>``: the
    model file's (``max_speed_deg_s``, ``max_effort_nm``), or for another model the shipped
    models' lowest of each (a URDF must state them)."""
    if model in KNOWN_MODELS:
        sheet = model_sheet(model)
        return sheet.max_speed_deg_s.tolist(), sheet.max_effort_nm.tolist()
    sheets = [model_sheet(n) for n in KNOWN_MODELS]
    speeds = np.min([s.max_speed_deg_s for s in sheets], axis=0)
    efforts = np.min([s.max_effort_nm for s in sheets], axis=0)
    return speeds.tolist(), efforts.tolist()


def ros_name(model: str) -> str:
    """A model's name as a ROS name and file stem (``tx2-90`` → ``tx2_90``)."""
    name = re.sub(r"[^A-Za-z0-9_]", "_", model)
    return name if re.match(r"[A-Za-z_]", name) else f"arm_{name}"


def check_prefix(prefix: str) -> str:
    """``prefix`` if it is a tf prefix (empty, or letters, digits, ``_`` and ``/``, not
    starting with a digit); else ``InputError`` (exit 2) naming ``--prefix``."""
    if prefix and not _PREFIX.fullmatch(prefix):
        raise InputError(
            f"--prefix {prefix!r}: a tf prefix is letters, digits, '_' and '/', "
            "not starting with a digit (e.g. 'arm_')"
        )
    return prefix


def ros2_arm(profile_path: Path, prefix: str = "") -> Ros2Arm:
    """Read the profile at ``profile_path`` (its bytes hashed as they are parsed) for export.

    Raises ``InputError`` (exit 2) naming the file and key of a profile that cannot be read
    or does not validate, or ``--prefix`` if it is not a tf prefix.
    """
    check_prefix(prefix)
    path = Path(profile_path)
    try:
        raw = path.read_bytes()
    except OSError as e:
        raise ProfileError(path, None, f"cannot read: {e.strerror or e}") from None
    cell = profile_from_data(parse_toml_bytes(raw, path), path)
    return Ros2Arm(
        name=ros_name(cell.model.name),
        prefix=prefix,
        cell=cell,
        profile=real_path(path),
        sha256=hashlib.sha256(raw).hexdigest(),
        written=datetime.now(UTC).isoformat(timespec="seconds"),
    )


# -- YAML ------------------------------------------------------------------------------------


def _scalar(value: Any) -> str:
    if value is None:
        return "null"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    if isinstance(value, (float, np.floating)):
        return number(float(value)) if np.isfinite(value) else "null"
    if isinstance(value, str):
        return json.dumps(value)  # a double-quoted YAML scalar
    if isinstance(value, (list, tuple, np.ndarray)):
        return "[" + ", ".join(_scalar(v) for v in value) + "]"
    raise TypeError(f"no YAML for {type(value).__name__}")


def yaml_text(data: Mapping[str, Any], header: Sequence[str] = ()) -> str:
    """``data`` (nested mappings of numbers, strings, None and lists of them) as block YAML,
    below ``header`` as comment lines."""
    lines = [f"# {h}".rstrip() for h in header]

    def emit(mapping: Mapping[str, Any], indent: int) -> None:
        for key, value in mapping.items():
            pad = "  " * indent
            if isinstance(value, Mapping):
                lines.append(f"{pad}{key}:")
                emit(value, indent + 1)
            else:
                lines.append(f"{pad}{key}: {_scalar(value)}")

    emit(data, 0)
    return "\n".join(lines) + "\n"


def _source(arm: Ros2Arm) -> dict[str, Any]:
    return {
        "profile": str(arm.profile),
        "sha256": arm.sha256,
        "model": arm.model.name,
        "dh": arm.model.dh_source,
        "ucal_version": __version__,
        "date": arm.written,
    }


def _written_by(arm: Ros2Arm) -> list[str]:
    return [
        f"Written by ucal {__version__} (ucal export ros2) on {arm.written}",
        f"from {arm.profile} (sha256 {arm.sha256}).",
    ]


def kinematics_yaml(arm: Ros2Arm) -> str:
    """``NAME_kinematics.yaml`` (module docstring)."""
    header = [
        f"The {arm.model.name} as ucal knows it, for {arm.name}.urdf.xacro: the layout of",
        "ur_description's default_kinematics.yaml. Units m, rad (REP 103).",
        *_written_by(arm),
        f"DH table: {arm.model.dh_source} (standard DH, Hayati beta), turned into the",
        "origin of each joint in its parent link: x, y, z; roll, pitch, yaw (URDF:",
        "Rz(yaw)*Ry(pitch)*Rx(roll)); every joint turns about its own z axis.",
        "flange: link_6 -> flange; tcp: tool0 -> ucal_tcp (the profile's [tool]).",
        "kinematics: joint position = reading + offset (the true joint angle; the offsets are in",
        f"  {arm.name}_joint_offsets.yaml). The DH theta offsets (the controller's zero) are in",
        "  the origins: all readings 0 is the arm straight up.",
        "kinematics_offsets_in_urdf: the joint offsets folded in too: joint position = the",
        "  controller's reading (xacro offsets_in_urdf:=true).",
        "joint_limits: of the controller's readings (rad), speeds (rad/s), torques (N m).",
    ]
    data: dict[str, Any] = {}
    for key, baked in (("kinematics", False), ("kinematics_offsets_in_urdf", True)):
        section: dict[str, Any] = {k: o.to_yaml() for k, o in arm.origins(baked).items()}
        section["hash"] = arm.hash
        data[key] = section
    data["base"] = {"height": arm.base_height_mm / 1000.0}
    data["joint_limits"] = arm.limits()
    data["source"] = _source(arm)
    return yaml_text(data, header)


def joint_offsets_yaml(arm: Ros2Arm) -> str:
    """``NAME_joint_offsets.yaml``: the offsets (rad, and deg), their one sigma, their sign."""
    cell = arm.cell
    std = cell.joint_offsets_std_deg
    header = [
        f"Joint zero offsets of the {arm.model.name}, as calibrated.",
        *_written_by(arm),
        "Sign: position = reading + offset. Add the offset to the controller's joint reading",
        f"to get the joint position of {arm.name}.urdf; command the controller target - offset.",
        "ros2_control: a transmission_interface/SimpleTransmission with mechanical_reduction 1",
        "and <offset> = the value does exactly this (x_joint = x_actuator + offset), where the",
        f"hardware interface applies its transmissions ({arm.name}.urdf.xacro writes them with",
        "ros2_control_plugin:=...). Not with offsets_in_urdf:=true: that URDF has them already.",
        "std: one sigma (rad); null: not determined (unobservable_joints) or never calibrated.",
    ]
    data: dict[str, Any] = {
        "hash": arm.hash,
        "sign": "position = reading + offset",
        "joint_offsets": dict(zip(JOINTS, np.radians(arm.offsets_deg).tolist(), strict=True)),
        "joint_offsets_deg": dict(zip(JOINTS, arm.offsets_deg.tolist(), strict=True)),
        "std": dict(
            zip(JOINTS, [None] * N_JOINTS if std is None else np.radians(std).tolist(), strict=True)
        ),
        "unobservable_joints": [JOINTS[j - 1] for j in cell.unobservable_joints],
        "source": _source(arm),
    }
    return yaml_text(data, header)


# -- covariance ------------------------------------------------------------------------------

#: Columns of ``CellProfile.dh_std`` and the names the covariance file gives them.
_DH_PARAMETERS = ("d", "a", "alpha", "beta")
#: The one DH row whose Hayati twist is a parameter of the model: joints 2 and 3 are parallel.
_TWISTED_ROW = 1


@dataclass(frozen=True)
class Parameter:
    """One parameter of the exported model: ``value`` and ``std`` in SI (m, rad; ``std``
    None: not known), ``status`` how the profile knows it."""

    value: float
    std: float | None
    status: str

    def to_yaml(self) -> dict[str, Any]:
        variance = None if self.std is None else self.std**2
        return {"value": self.value, "std": self.std, "variance": variance, "status": self.status}


def offset_parameters(cell: CellProfile) -> dict[str, Parameter]:
    """The joint offsets (rad) with their one sigma and status."""
    out = {}
    for i, name in enumerate(JOINTS):
        value = float(np.radians(cell.joint_offsets_deg[i]))
        if cell.joint_offsets_std_deg is None:
            out[name] = Parameter(value, None, "not calibrated (no [calibration] std_deg)")
        elif i + 1 in cell.unobservable_joints or not np.isfinite(cell.joint_offsets_std_deg[i]):
            out[name] = Parameter(value, None, "not determined (kept from the profile)")
        else:
            std = float(np.radians(cell.joint_offsets_std_deg[i]))
            out[name] = Parameter(value, std, "calibrated")
    return out


def dh_parameters(cell: CellProfile) -> list[dict[str, Parameter]]:
    """Each DH row's ``d, a`` (m), ``alpha, beta`` (rad): identified (``[calibration]
    dh_std``) or known to the ``[robot]`` tolerance. ``beta`` only where it is a parameter
    (row 2, or a row whose twist is not zero)."""
    m = cell.model
    values = np.column_stack([m.d_mm / 1000.0, m.a_mm / 1000.0, np.radians(m.alpha_deg)])
    values = np.column_stack([values, np.radians(m.beta_deg)])
    tolerance = [
        cell.dh_length_std_mm / 1000.0,
        cell.dh_length_std_mm / 1000.0,
        float(np.radians(cell.dh_angle_std_deg)),
        float(np.radians(cell.dh_angle_std_deg)),
    ]
    rows = []
    for i in range(N_JOINTS):
        row = {}
        for j, name in enumerate(_DH_PARAMETERS):
            identified = cell.dh_std is not None and np.isfinite(cell.dh_std[i, j])
            if name == "beta" and not (identified or i == _TWISTED_ROW or m.beta_deg[i] != 0.0):
                continue
            if identified:
                assert cell.dh_std is not None
                scale = 1e-3 if j < 2 else np.pi / 180.0
                row[name] = Parameter(
                    float(values[i, j]), float(cell.dh_std[i, j] * scale), "identified"
                )
            else:
                status = "tolerance ([robot] dh_*_std: not identified)"
                row[name] = Parameter(float(values[i, j]), tolerance[j], status)
        rows.append(row)
    return rows


def tool_parameters(cell: CellProfile) -> dict[str, Parameter]:
    """The ``[tool]`` frame (m; its Stäubli angles in rad) with its one sigmas."""
    status = "as drawn" if cell.described_tool is None else "measured (tool-frame)"
    values = [*(cell.tool_position_mm / 1000.0), *np.radians(cell.tool_rotation_deg)]
    stds = [*(cell.tool_position_std_mm / 1000.0), *np.radians(cell.tool_rotation_std_deg)]
    keys = ("x", "y", "z", "rx", "ry", "rz")
    return {
        k: Parameter(float(v), float(s), status) for k, v, s in zip(keys, values, stds, strict=True)
    }


def _pose_covariance(
    fn: Callable[[np.ndarray], np.ndarray], p0: np.ndarray, std: np.ndarray
) -> np.ndarray:
    """First-order covariance (6, 6) of the transform ``fn(p)`` (4, 4; mm) for independent
    parameters ``p`` (SI) of one sigma ``std``: rows x, y, z (m), rotations about the parent's
    x, y, z axes (rad), as ``geometry_msgs/PoseWithCovariance`` orders them."""
    jac = np.zeros((6, len(p0)))
    h = 1e-6  # central differences: error ~h² of a smooth function
    for k in range(len(p0)):
        dp = np.zeros(len(p0))
        dp[k] = h
        hi, lo = fn(p0 + dp), fn(p0 - dp)
        jac[:3, k] = (hi[:3, 3] - lo[:3, 3]) / 1000.0 / (2 * h)
        jac[3:, k] = Rotation.from_matrix(hi[:3, :3] @ lo[:3, :3].T).as_rotvec() / (2 * h)
    return jac @ np.diag(np.asarray(std, dtype=float) ** 2) @ jac.T


def origin_covariances(cell: CellProfile) -> dict[str, np.ndarray]:
    """The covariance (6, 6) of each origin of ``kinematics`` (joint positions = reading +
    offset): a joint's from the DH row before it, the flange's from row 6, the tcp's from
    ``[tool]``; the θ offsets are the controller's zero, exact by convention."""
    m = cell.model
    rows = dh_parameters(cell)
    out = {JOINTS[0]: np.zeros((6, 6))}

    def row_fn(i: int, names: list[str]) -> Callable[[np.ndarray], np.ndarray]:
        def fn(p: np.ndarray) -> np.ndarray:
            si = dict(zip(names, p, strict=True))
            dh = m.dh.copy()
            beta = m.beta_deg.copy()
            dh[i, 1], dh[i, 2] = si["d"] * 1000.0, si["a"] * 1000.0
            dh[i, 3] = np.degrees(si["alpha"])
            if "beta" in si:
                beta[i] = np.degrees(si["beta"])
            mats = chain_matrices(m.with_dh(dh, beta), np.eye(4))
            return mats[JOINTS[i + 1]] if i + 1 < N_JOINTS else mats[FLANGE]

        return fn

    for i, row in enumerate(rows):
        names = list(row)
        p0 = np.array([row[n].value for n in names])
        std = np.array([row[n].std for n in names], dtype=float)
        key = JOINTS[i + 1] if i + 1 < N_JOINTS else FLANGE
        out[key] = _pose_covariance(row_fn(i, names), p0, std)
    tool = tool_parameters(cell)

    def tool_fn(p: np.ndarray) -> np.ndarray:
        return transform(p[:3] * 1000.0, rpy_to_matrix(np.degrees(p[3:])))

    p0 = np.array([t.value for t in tool.values()])
    out[TCP] = _pose_covariance(tool_fn, p0, np.array([t.std for t in tool.values()]))
    return out


def covariance_yaml(arm: Ros2Arm) -> str:
    """``NAME_covariance.yaml``: every parameter with its one sigma and status, and the
    covariance of each exported origin."""
    header = [
        f"How well the exported {arm.model.name} is known: one sigma (SI: m, rad) of each",
        "parameter the profile states, and the covariance of each origin of",
        f"{arm.name}_kinematics.yaml (kinematics).",
        *_written_by(arm),
        "The profile keeps one sigma per parameter, not their correlations: the parameters are",
        "taken as independent (calibrate inflates each identified sigma to cover them).",
        "status: calibrated / identified: determined by ucal; tolerance: the profile's [robot]",
        "tolerance of a parameter not identified (a prior, not a measurement); not determined /",
        "not calibrated: std null. The DH theta offsets are the controller's zero, exact by",
        "convention: their error is the joint offset's.",
        "origin_covariance: 6 x 6, row-major (geometry_msgs/PoseWithCovariance): x, y, z (m),",
        "rotation about the parent link's x, y, z (rad), first order in the parameters above.",
        "With offsets_in_urdf:=true, add joint_N's offset variance to the rotation about its z.",
        "Not exported: the calibration's nuisance quantities (the block's pose, the sound speed,",
        "the plate), which belong to the cell, not to the arm; base_link -> base is nominal.",
    ]
    cell = arm.cell
    covs = origin_covariances(cell)
    data: dict[str, Any] = {
        "hash": arm.hash,
        "joint_offsets": {k: p.to_yaml() for k, p in offset_parameters(cell).items()},
        "dh": {
            f"row_{i + 1}": {k: p.to_yaml() for k, p in row.items()}
            for i, row in enumerate(dh_parameters(cell))
        },
        "tool": {k: p.to_yaml() for k, p in tool_parameters(cell).items()},
        "origin_covariance": {k: c.ravel().tolist() for k, c in covs.items()},
        "source": _source(arm),
    }
    return yaml_text(data, header)


# -- files ---------------------------------------------------------------------------------


def urdf_text(arm: Ros2Arm, offsets_in_urdf: bool = False) -> str:
    """``NAME.urdf`` (joint positions = reading + offset) or ``NAME_offsets_in_urdf.urdf``
    (the readings): what the xacro renders with ``offsets_in_urdf`` and prefix ``arm.prefix``."""
    variant = (
        "joint positions = the controller's readings (offsets folded in)"
        if offsets_in_urdf
        else f"joint positions = reading + offset ({arm.name}_joint_offsets.yaml)"
    )
    comments = [
        f"{arm.model.name} as ucal knows it: {variant}.",
        " ".join(_written_by(arm)),
        f"Rendered from {arm.name}.urdf.xacro (offsets_in_urdf:="
        f"{str(offsets_in_urdf).lower()}); units m, rad.",
    ]
    shift = np.zeros(N_JOINTS) if offsets_in_urdf else np.radians(arm.offsets_deg)
    return urdf_xml(
        arm.name,
        arm.prefix,
        arm.origins(offsets_in_urdf),
        arm.limits(),
        shift,
        arm.base_height_mm / 1000.0,
        comments,
    )


def file_names(name: str) -> dict[str, str]:
    """What each written file is → its name in DIR."""
    return {
        "kinematics": f"{name}_kinematics.yaml",
        "joint_offsets": f"{name}_joint_offsets.yaml",
        "covariance": f"{name}_covariance.yaml",
        "macro": f"{name}_macro.xacro",
        "xacro": f"{name}.urdf.xacro",
        "urdf": f"{name}.urdf",
        "urdf_offsets_in_urdf": f"{name}_offsets_in_urdf.urdf",
    }


def write_ros2(arm: Ros2Arm, directory: Path) -> dict[str, Path]:
    """Write the files of ``arm`` into ``directory`` (created if missing).

    Each file is written atomically (a temporary file beside it, renamed). Raises
    ``InputError`` (exit 2) naming the directory that cannot be created or written, or the
    file that could not be. Returns what each file is → its path.
    """
    directory = Path(directory)
    writable_directory(directory)
    texts = {
        "kinematics": kinematics_yaml(arm),
        "joint_offsets": joint_offsets_yaml(arm),
        "covariance": covariance_yaml(arm),
        "macro": macro_xacro(arm.name, arm.model.name),
        "xacro": top_xacro(arm.name, arm.prefix),
        "urdf": urdf_text(arm, offsets_in_urdf=False),
        "urdf_offsets_in_urdf": urdf_text(arm, offsets_in_urdf=True),
    }
    written = {}
    for kind, name in file_names(arm.name).items():
        path = directory / name
        write_file(path, texts[kind].encode("utf-8"))
        written[kind] = path
    log.info("wrote %s", ", ".join(str(p) for p in written.values()))
    return written


def export_json(arm: Ros2Arm, written: Mapping[str, Path]) -> dict[str, Any]:
    """What ``ucal export ros2 --json`` prints (mm, deg, as every ucal JSON)."""
    return {
        "profile": str(arm.profile),
        "profile_sha256": arm.sha256,
        "model": arm.model.name,
        "kinematics": arm.model.dh_source,
        "name": arm.name,
        "prefix": arm.prefix,
        "joint_offsets_deg": arm.offsets_deg.tolist(),
        "tcp_link": f"{arm.prefix}{TCP_LINK}",
        "files": {kind: str(p) for kind, p in written.items()},
    }
