"""The calibrated cell as VAL3 data: the tool and the calibration block's frame.

``ucal export val3`` writes a small VAL3 application (a library: data, empty ``start`` and
``stop``) in the XML of VAL3 projects, as the open-source staubli_val3_driver sources hold
them: ``NAME.pjx`` (the project: programs, its data file), ``NAME.dtx`` (the data),
``start.pgx``, ``stop.pgx``. Each datum is a ``Data`` element (name, access, ``xsi:type=
"array"``, VAL3 type, size) with one ``Value`` per element (``key`` and, for the
geometric types, ``x, y, z`` in mm and ``rx, ry, rz`` in degrees):

* ``tUcalTool`` (``tool``, father ``flange[0]``): the profile's ``[tool]``, the transducer's
  frame (beam along +z) relative to the flange;
* ``fUcalBlock`` (``frame``, father ``world[0]``): the profile's ``[sample]``, the block's
  corner and faces in the robot's base frame;
* ``trUcalTool``, ``trUcalBlock`` (``trsf``): the same two transformations as plain values.

Conventions. VAL3 lengths are mm (the project says ``millimeterUnit="true"``) and a trsf's
orientation is ``Rot(x, rx)·Rot(y, ry)·Rot(z, rz)`` about the moving axes: SPEC.md's Staubli
convention, in which the profile stores ``rotation_deg``, so no axis or sign changes. The
angles are rewritten from the rotation (scipy's intrinsic ``"XYZ"`` Euler angles) so that
``rx, rz`` lie in [−180°, 180°] and ``ry`` in [−90°, 90°], as the controller shows a trsf,
and are written with ``DECIMALS`` decimals (1e-6 mm, 1e-6°).

Frames. The flange of ucal's models (the joint-6 frame of the shipped DH tables) is the
controller's ``flange``: at zero readings it sits on the joint-6 axis, 100 mm beyond the
wrist centre, with its axes parallel to the base frame's (z up), as the ROS-Industrial URDF
places its all-zeros tool frame ``tool0`` (docs/decisions/0001); both turn with joint 6. So
``[tool]`` goes to the controller unchanged. The base frame of the models is the
controller's ``world`` (the Staubli world frame at shoulder height), the frame in which the
calibrated model and ``[sample]`` are stated. (``[sample]`` is the block pose the profile
states; ``calibrate`` fits the block within its tolerance but does not write it back.)

What the data does not carry: the joint offsets and an identified DH table stay in the
profile (the controller keeps its zeros in its arm configuration, which ucal does not edit).
A program that wants the calibrated accuracy moves to targets from ``ucal path
--for-controller`` (``ucal.kinematics.filtering``).
"""

from __future__ import annotations

import json
import logging
import warnings
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from ucal.cell import CellProfile
from ucal.kinematics.dh import transform
from ucal.output import writable_directory, write_file
from ucal.profile import HistoryEntry, last_measurement, real_path

log = logging.getLogger(__name__)

#: The application's name (its folder and project file); a VAL3 identifier.
APPLICATION = "ucalCell"
#: Names of the data in the application.
TOOL_NAME = "tUcalTool"
BLOCK_NAME = "fUcalBlock"
TOOL_TRSF_NAME = "trUcalTool"
BLOCK_TRSF_NAME = "trUcalBlock"
#: The JSON file written beside the application.
JSON_NAME = "ucal_cell.json"
#: Decimals of every written length (mm) and angle (deg).
DECIMALS = 6

DATA_NS = "http://www.staubli.com/robotics/VAL3/Data/2"
PROJECT_NS = "http://www.staubli.com/robotics/VAL3/Project/3"
PROGRAM_NS = "http://www.staubli.com/robotics/VAL3/Program/2"
XSI_NS = "http://www.w3.org/2001/XMLSchema-instance"
#: The VAL3 version the project declares (a CS8 from 7.7 on, and every CS9, loads it).
VAL3_VERSION = "s7.7.2"

#: VAL3 files begin with a byte-order mark and this declaration.
_BOM = "\ufeff"
_DECLARATION = '<?xml version="1.0" encoding="utf-8"?>\n'


@dataclass(frozen=True)
class Trsf:
    """A VAL3 ``trsf``: ``position_mm`` (3,) and ``rotation_deg`` (3,) as ``rx, ry, rz``
    (``R = Rot(x, rx)·Rot(y, ry)·Rot(z, rz)``)."""

    position_mm: np.ndarray
    rotation_deg: np.ndarray

    @classmethod
    def from_matrix(cls, t: np.ndarray) -> Trsf:
        """The trsf of a transform (4, 4), angles as the controller shows them (module
        docstring), rounded to ``DECIMALS``."""
        t = np.asarray(t, dtype=float)
        with warnings.catch_warnings():
            # ry = ±90°: scipy sets rz to 0 and says so; the angles still give the rotation
            warnings.simplefilter("ignore", UserWarning)
            angles = Rotation.from_matrix(t[:3, :3]).as_euler("XYZ", degrees=True)
        return cls(_rounded(t[:3, 3]), _rounded(angles))

    @property
    def matrix(self) -> np.ndarray:
        """The transform (4, 4)."""
        rot = Rotation.from_euler("XYZ", self.rotation_deg, degrees=True).as_matrix()
        return transform(self.position_mm, rot)

    def attributes(self) -> dict[str, str]:
        """``x, y, z, rx, ry, rz`` as the attributes of a VAL3 ``Value``."""
        values = [*self.position_mm, *self.rotation_deg]
        return {
            k: _number(v) for k, v in zip(("x", "y", "z", "rx", "ry", "rz"), values, strict=True)
        }

    def to_json(self) -> dict[str, list[float]]:
        return {
            "position_mm": self.position_mm.tolist(),
            "rotation_deg": self.rotation_deg.tolist(),
        }


def _rounded(values: np.ndarray) -> np.ndarray:
    """``values`` rounded to ``DECIMALS``, without negative zeros."""
    return np.round(np.asarray(values, dtype=float), DECIMALS) + 0.0


def _number(value: float) -> str:
    """A number as VAL3 files write it: plain decimals, no trailing zeros, no negative zero."""
    text = f"{value:.{DECIMALS}f}".rstrip("0").rstrip(".")
    return "0" if text in ("", "-0") else text


@dataclass(frozen=True)
class Val3Cell:
    """What ``ucal export val3`` hands to the controller, read from one profile.

    ``tool`` relative to the flange, ``block`` in the base (world) frame; ``profile`` the
    profile's file; ``calibration`` the history entry of the last ``tool-frame`` or
    ``calibrate`` write that is still in the profile (None: there is none);
    ``model``, ``kinematics`` (where the DH table comes from) and ``joint_offsets_deg``
    describe what the data leaves in the profile.
    """

    tool: Trsf
    block: Trsf
    profile: Path
    calibration: HistoryEntry | None
    model: str
    kinematics: str
    joint_offsets_deg: np.ndarray


def val3_cell(profile: CellProfile, profile_path: Path) -> Val3Cell:
    """The tool and block of ``profile`` (read from ``profile_path``) as VAL3 trsf values."""
    return Val3Cell(
        tool=Trsf.from_matrix(profile.tool_matrix),
        block=Trsf.from_matrix(profile.sample_matrix),
        profile=real_path(profile_path),
        calibration=last_measurement(profile_path),
        model=profile.model.name,
        kinematics=profile.model.dh_source,
        joint_offsets_deg=np.asarray(profile.joint_offsets_deg, dtype=float),
    )


def calibration_text(cell: Val3Cell) -> str:
    """When and by what the profile was last calibrated, in words."""
    c = cell.calibration
    if c is None:
        return "none (no tool-frame or calibrate write in the profile's history)"
    return f"{c.time} (history entry {c.id}: {c.reason})"


def _comment(text: str) -> ET.Element[Any]:
    """An XML comment holding ``text`` ("--" may not appear in one)."""
    while "--" in text:
        text = text.replace("--", "- -")
    return ET.Comment(f" {text.rstrip('-')} ")


def database_xml(cell: Val3Cell) -> str:
    """The ``.dtx`` data file of the application (module docstring)."""
    # names written as VAL3 files spell them (ElementTree's namespace handling would prefix
    # every element): the namespaces are declared on the root, the data's own are unqualified
    root = ET.Element("Database", {"xmlns:xsi": XSI_NS, "xmlns": DATA_NS})
    root.append(_comment(f"written by ucal export val3 from {cell.profile}"))
    root.append(_comment(f"last calibration: {calibration_text(cell)}"))
    datas = ET.SubElement(root, "Datas")

    def datum(name: str, val3_type: str, trsf: Trsf, father: str | None, what: str) -> None:
        datas.append(_comment(what))
        data = ET.SubElement(
            datas,
            "Data",
            {"name": name, "access": "public", "xsi:type": "array", "type": val3_type, "size": "1"},
        )
        attrs = {"key": "0", **trsf.attributes()}
        if father is not None:
            attrs["fatherId"] = father
        ET.SubElement(data, "Value", attrs)

    tool_what = "[tool]: transducer frame relative to the flange, beam along +z (mm, deg)"
    block_what = "[sample]: calibration block corner and faces in the base frame (mm, deg)"
    datum(TOOL_NAME, "tool", cell.tool, "flange[0]", tool_what)
    datum(BLOCK_NAME, "frame", cell.block, "world[0]", block_what)
    datum(TOOL_TRSF_NAME, "trsf", cell.tool, None, tool_what)
    datum(BLOCK_TRSF_NAME, "trsf", cell.block, None, block_what)
    ET.indent(root, space="  ")
    return _DECLARATION + ET.tostring(root, encoding="unicode") + "\n"


def project_xml() -> str:
    """The ``.pjx`` project file: the two programs and the data file."""
    return (
        _DECLARATION
        + f'<Project xmlns="{PROJECT_NS}">\n'
        + f'  <Parameters version="{VAL3_VERSION}" stackSize="5000" millimeterUnit="true" />\n'
        + "  <Programs>\n"
        + '    <Program file="start.pgx" />\n'
        + '    <Program file="stop.pgx" />\n'
        + "  </Programs>\n"
        + "  <Database>\n"
        + f'    <Data file="{APPLICATION}.dtx" />\n'
        + "  </Database>\n"
        + "  <Libraries />\n"
        + "</Project>\n"
    )


def program_xml(name: str) -> str:
    """An empty program ``name`` (``start`` and ``stop``: the library only holds data)."""
    return (
        _DECLARATION
        + f'<Programs xmlns:xsi="{XSI_NS}" xmlns="{PROGRAM_NS}">\n'
        + f'  <Program name="{name}">\n'
        + "    <Code><![CDATA[begin\nend]]></Code>\n"
        + "  </Program>\n"
        + "</Programs>\n"
    )


def cell_json(cell: Val3Cell) -> dict[str, Any]:
    """The same data as JSON (``ucal_cell.json``; mm, deg, Staubli angles)."""
    c = cell.calibration
    return {
        "application": APPLICATION,
        "profile": str(cell.profile),
        "calibration": (
            None if c is None else {"time": c.time, "reason": c.reason, "history_id": c.id}
        ),
        "orientation": "R = Rot(x, rx) * Rot(y, ry) * Rot(z, rz)",
        "tool": {
            "name": TOOL_NAME,
            "trsf": TOOL_TRSF_NAME,
            "father": "flange",
            **cell.tool.to_json(),
        },
        "block": {
            "name": BLOCK_NAME,
            "trsf": BLOCK_TRSF_NAME,
            "father": "world",
            **cell.block.to_json(),
        },
        "model": cell.model,
        "kinematics": cell.kinematics,
        "joint_offsets_deg": cell.joint_offsets_deg.tolist(),
    }


def write_application(cell: Val3Cell, directory: Path) -> list[Path]:
    """Write the application ``directory/APPLICATION/`` and ``directory/ucal_cell.json``.

    Each file is written atomically (a temporary file beside it, renamed; a replaced file
    keeps its mode). Raises ``InputError`` (exit 2) naming the directory that cannot be
    created or written, or the file that could not be. Returns the files written.
    """
    directory = Path(directory)
    app = directory / APPLICATION
    writable_directory(directory)
    writable_directory(app)
    contents = {
        app / f"{APPLICATION}.pjx": project_xml(),
        app / f"{APPLICATION}.dtx": database_xml(cell),
        app / "start.pgx": program_xml("start"),
        app / "stop.pgx": program_xml("stop"),
    }
    written = []
    for path, text in contents.items():
        write_file(path, (_BOM + text).encode("utf-8"))
        written.append(path)
    json_path = directory / JSON_NAME
    write_file(json_path, (json.dumps(cell_json(cell), indent=2) + "\n").encode("utf-8"))
    written.append(json_path)
    log.info("wrote %s and %s", app, json_path)
    return written
