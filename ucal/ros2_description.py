"""The TX90-family arm as a ROS robot description: URDF and xacro text, frames and origins.

The description ``ucal export ros2`` writes (``ucal.ros2`` fills it from a profile): the
links and joints of ROS-Industrial's TX90 description (``base_link``, ``base``, ``link_1`` …
``link_6``, ``joint_1`` … ``joint_6``, ``flange``, ``tool0``) and the tool frame ``ucal_tcp``
on ``tool0``, every joint turning about its own z axis, each origin read from the kinematics
YAML (``NAME_macro.xacro``, in the layout of Universal Robots' ``ur_description``: the macro
reads ``kinematics`` or ``kinematics_offsets_in_urdf``, ``joint_limits`` and ``base`` from it,
``joint_offsets`` from the offsets YAML), or written out (``urdf_xml``: what the xacro renders
with its default arguments). Units m, rad; numbers in full (``number``).
"""

from __future__ import annotations

import warnings
import xml.etree.ElementTree as ET
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from ucal.kinematics.dh import N_JOINTS, transform

#: The URDF's joints, as the ROS-Industrial TX90 description and the VAL3 driver name them.
JOINTS = tuple(f"joint_{i}" for i in range(1, N_JOINTS + 1))
#: The other origins of the kinematics YAML: ``link_6 → flange`` and ``tool0 → ucal_tcp``.
FLANGE = "flange"
TCP = "tcp"
#: The link of the tool frame (``[tool]``), child of ``tool0``.
TCP_LINK = "ucal_tcp"

#: ``link_6 → flange`` after ucal's joint-6 frame, and ``flange → tool0`` (rpy): ROS-Industrial's
#: flange frame has its x axis out of the flange, ``tool0`` the axes of the joint-6 frame.
FLANGE_TURN = transform(np.zeros(3), Rotation.from_euler("y", -np.pi / 2).as_matrix())
TOOL0_RPY = np.array([0.0, np.pi / 2, 0.0])


def number(value: float) -> str:
    """A float as YAML 1.1 and URDF read it back exactly: ``repr``, with a point before an
    exponent (PyYAML takes ``1e-05`` for a string)."""
    text = repr(float(value))
    if "e" in text and "." not in text.split("e")[0]:
        text = text.replace("e", ".0e")
    return text


@dataclass(frozen=True)
class Origin:
    """A URDF ``<origin>``: ``xyz_m`` (3,) and ``rpy_rad`` (3,), ``R = Rz(yaw)·Ry(pitch)·
    Rx(roll)`` (URDF's roll, pitch, yaw about the fixed axes)."""

    xyz_m: np.ndarray
    rpy_rad: np.ndarray

    @classmethod
    def from_matrix(cls, t_mm: np.ndarray) -> Origin:
        """The origin of a transform (4, 4; mm)."""
        t = np.asarray(t_mm, dtype=float)
        with warnings.catch_warnings():
            # pitch = ±90°: scipy sets yaw to 0 and says so; the angles still give the rotation
            warnings.simplefilter("ignore", UserWarning)
            rpy = Rotation.from_matrix(t[:3, :3]).as_euler("xyz")
        return cls(t[:3, 3] / 1000.0, rpy)

    def to_yaml(self) -> dict[str, float]:
        """``x, y, z, roll, pitch, yaw`` as the kinematics YAML holds them (m, rad)."""
        keys = ("x", "y", "z", "roll", "pitch", "yaw")
        return dict(zip(keys, map(float, [*self.xyz_m, *self.rpy_rad]), strict=True))

    def attributes(self) -> dict[str, str]:
        """``xyz`` and ``rpy`` as the attributes of a URDF ``<origin>``."""
        return {
            "xyz": " ".join(number(v) for v in self.xyz_m),
            "rpy": " ".join(number(v) for v in self.rpy_rad),
        }


def urdf_xml(
    name: str,
    prefix: str,
    origins: Mapping[str, Origin],
    limits: Mapping[str, Mapping[str, float]],
    shift_rad: np.ndarray,
    base_height_m: float,
    comments: Sequence[str] = (),
) -> str:
    """The URDF of the arm ``name`` with tf prefix ``prefix``: the joints' ``origins`` (and
    ``FLANGE``'s, ``TCP``'s), their ``limits`` (``min_position``, ``max_position`` of the
    readings, rad; ``max_velocity``, ``max_effort``) moved by ``shift_rad`` (6,: the offsets
    where the joint positions are reading + offset), ``base`` ``base_height_m`` above
    ``base_link``, ``comments`` at the top: what the xacro renders (no ``ros2_control``)."""
    p = prefix
    robot = ET.Element("robot", {"name": name})
    for text in comments:
        robot.append(ET.Comment(f" {text.replace('--', '- -')} "))

    def link(link_name: str) -> None:
        ET.SubElement(robot, "link", {"name": f"{p}{link_name}"})

    def fixed(joint_name: str, parent: str, child: str, origin: Origin) -> None:
        joint = ET.SubElement(robot, "joint", {"name": f"{p}{joint_name}", "type": "fixed"})
        ET.SubElement(joint, "origin", origin.attributes())
        ET.SubElement(joint, "parent", {"link": f"{p}{parent}" if parent != "world" else parent})
        ET.SubElement(joint, "child", {"link": f"{p}{child}"})

    ET.SubElement(robot, "link", {"name": "world"})
    link("base_link")
    fixed("base_joint", "world", "base_link", Origin(np.zeros(3), np.zeros(3)))
    link("base")
    base = Origin(np.array([0.0, 0.0, base_height_m]), np.zeros(3))
    fixed("base_link-base", "base_link", "base", base)
    parent = "base"
    for i, joint_name in enumerate(JOINTS):
        child = f"link_{i + 1}"
        link(child)
        joint = ET.SubElement(robot, "joint", {"name": f"{p}{joint_name}", "type": "revolute"})
        ET.SubElement(joint, "origin", origins[joint_name].attributes())
        ET.SubElement(joint, "parent", {"link": f"{p}{parent}"})
        ET.SubElement(joint, "child", {"link": f"{p}{child}"})
        ET.SubElement(joint, "axis", {"xyz": "0 0 1"})
        lim = limits[joint_name]
        ET.SubElement(
            joint,
            "limit",
            {
                "lower": number(lim["min_position"] + shift_rad[i]),
                "upper": number(lim["max_position"] + shift_rad[i]),
                "effort": number(lim["max_effort"]),
                "velocity": number(lim["max_velocity"]),
            },
        )
        parent = child
    link(FLANGE)
    fixed("joint_6-flange", "link_6", FLANGE, origins[FLANGE])
    link("tool0")
    fixed("flange-tool0", FLANGE, "tool0", Origin(np.zeros(3), TOOL0_RPY))
    link(TCP_LINK)
    fixed(f"tool0-{TCP_LINK}", "tool0", TCP_LINK, origins[TCP])
    ET.indent(robot, space="  ")
    return '<?xml version="1.0"?>\n' + ET.tostring(robot, encoding="unicode") + "\n"


def macro_xacro(name: str, model: str) -> str:
    """``NAME_macro.xacro``: the macro ``ucal_NAME`` (its parameters in the file's comment)."""
    joints, controls = [], []
    for i, joint in enumerate(JOINTS):
        parent = "base" if i == 0 else f"link_{i}"
        call = _JOINT_CALL.replace("@PARENT@", parent).replace("@CHILD@", f"link_{i + 1}")
        joints.append(call.replace("@JOINT@", joint))
        controls.append(_CONTROL_CALL.replace("@JOINT@", joint))
    text = _MACRO.replace("@JOINTS@", "".join(joints)).replace(
        "@CONTROL_JOINTS@", "".join(controls)
    )
    return text.replace("@NAME@", name).replace("@MODEL@", model)


def top_xacro(name: str, prefix: str) -> str:
    """``NAME.urdf.xacro``: the macro's arguments and one arm fixed to ``world``."""
    return _TOP.replace("@NAME@", name).replace("@PREFIX@", prefix)


_MACRO = """\
<?xml version="1.0"?>
<!--
  ucal_@NAME@: the Staubli @MODEL@ as ucal calibrated it (ucal export ros2).

  The joint origins, the flange and the tool frame come from @NAME@_kinematics.yaml (the
  layout of ur_description's default_kinematics.yaml), the joint offsets from
  @NAME@_joint_offsets.yaml; both carry the hash of the profile they came from, and must
  carry the same. Units m, rad.

  Parameters:
    prefix                      tf prefix of every link and joint ("" or e.g. "arm_")
    parent, <origin>            where base_link (the mounting face) is fixed
    kinematics_parameters_file  @NAME@_kinematics.yaml (absolute, or relative to this file)
    joint_offsets_file          @NAME@_joint_offsets.yaml
    offsets_in_urdf             false: joint position = reading + offset (the hardware
                                interface adds the offsets); true: the offsets are folded
                                into the origins, joint position = the controller's reading
    ros2_control_plugin         "" (no ros2_control tag) or a hardware plugin: then a system
                                with position command and state interfaces per joint and a
                                SimpleTransmission per joint whose <offset> is the joint's
                                offset (0 with offsets_in_urdf)
    name                        the ros2_control system's name

  Frames: base_link -> base (the controller's world frame, shoulder height) -> link_1 ...
  link_6 -> flange (x out of the flange) -> tool0 (ucal's flange frame) -> ucal_tcp (the
  profile's [tool]: the transducer, beam along +z).
-->
<robot xmlns:xacro="http://wiki.ros.org/xacro">

  <xacro:macro name="ucal_@NAME@_origin" params="o">
    <origin xyz="${o['x']} ${o['y']} ${o['z']}" rpy="${o['roll']} ${o['pitch']} ${o['yaw']}"/>
  </xacro:macro>

  <!-- A link and the joint that carries it: fixed, or revolute about z within limits -->
  <xacro:macro name="ucal_@NAME@_link" params="prefix joint parent child o limits:='' shift:=0">
    <link name="${prefix}${child}"/>
    <joint name="${prefix}${joint}" type="${'fixed' if limits == '' else 'revolute'}">
      <xacro:ucal_@NAME@_origin o="${o}"/>
      <parent link="${prefix}${parent}"/>
      <child link="${prefix}${child}"/>
      <xacro:if value="${limits != ''}">
        <axis xyz="0 0 1"/>
        <limit lower="${limits['min_position'] + shift}" upper="${limits['max_position'] + shift}"
               effort="${limits['max_effort']}" velocity="${limits['max_velocity']}"/>
      </xacro:if>
    </joint>
  </xacro:macro>

  <xacro:macro name="ucal_@NAME@_control_joint" params="prefix joint offset">
    <joint name="${prefix}${joint}">
      <command_interface name="position"/>
      <state_interface name="position"/>
      <state_interface name="velocity"/>
    </joint>
    <transmission name="${prefix}${joint}_transmission">
      <plugin>transmission_interface/SimpleTransmission</plugin>
      <actuator name="${prefix}${joint}_motor" role="actuator1"/>
      <joint name="${prefix}${joint}" role="joint1">
        <mechanical_reduction>1.0</mechanical_reduction>
        <offset>${offset}</offset>
      </joint>
    </transmission>
  </xacro:macro>

  <xacro:macro name="ucal_@NAME@" params="
      prefix
      parent
      *origin
      kinematics_parameters_file
      joint_offsets_file
      offsets_in_urdf:=false
      ros2_control_plugin:=''
      name:=@NAME@">

    <xacro:property name="ucal_doc" value="${xacro.load_yaml(kinematics_parameters_file)}"/>
    <xacro:property name="ucal_offsets_doc" value="${xacro.load_yaml(joint_offsets_file)}"/>
    <xacro:property name="ucal_kin" value="${ucal_doc['kinematics_offsets_in_urdf']
        if offsets_in_urdf else ucal_doc['kinematics']}"/>
    <xacro:property name="ucal_offsets" value="${ucal_offsets_doc['joint_offsets']}"/>
    <xacro:property name="ucal_limits" value="${ucal_doc['joint_limits']}"/>
    <xacro:if value="${ucal_kin['hash'] != ucal_offsets_doc['hash'] and xacro.fatal(
        'ucal_@NAME@: ' + kinematics_parameters_file + ' and ' + joint_offsets_file +
        ' come from different profiles (hash ' + ucal_kin['hash'] + ', ' +
        ucal_offsets_doc['hash'] + '): export them together')}"/>

    <link name="${prefix}base_link"/>
    <joint name="${prefix}base_joint" type="fixed">
      <xacro:insert_block name="origin"/>
      <parent link="${parent}"/>
      <child link="${prefix}base_link"/>
    </joint>
    <xacro:ucal_@NAME@_link prefix="${prefix}" joint="base_link-base" parent="base_link"
        child="base" o="${dict(x=0.0, y=0.0, z=ucal_doc['base']['height'], roll=0.0, pitch=0.0,
        yaw=0.0)}"/>

@JOINTS@
    <xacro:ucal_@NAME@_link prefix="${prefix}" joint="joint_6-flange" parent="link_6"
        child="flange" o="${ucal_kin['flange']}"/>
    <xacro:ucal_@NAME@_link prefix="${prefix}" joint="flange-tool0" parent="flange"
        child="tool0" o="${dict(x=0.0, y=0.0, z=0.0, roll=0.0, pitch=pi / 2, yaw=0.0)}"/>
    <xacro:ucal_@NAME@_link prefix="${prefix}" joint="tool0-ucal_tcp" parent="tool0"
        child="ucal_tcp" o="${ucal_kin['tcp']}"/>

    <xacro:if value="${ros2_control_plugin != ''}">
      <ros2_control name="${name}" type="system">
        <hardware>
          <plugin>${ros2_control_plugin}</plugin>
        </hardware>
@CONTROL_JOINTS@      </ros2_control>
    </xacro:if>
  </xacro:macro>
</robot>
"""

#: One joint of the chain, and its ros2_control joint and transmission, in ``_MACRO``.
_JOINT_CALL = """\
    <xacro:ucal_@NAME@_link prefix="${prefix}" joint="@JOINT@" parent="@PARENT@" child="@CHILD@"
        o="${ucal_kin['@JOINT@']}" limits="${ucal_limits['@JOINT@']}"
        shift="${0.0 if offsets_in_urdf else ucal_offsets['@JOINT@']}"/>
"""
_CONTROL_CALL = """\
        <xacro:ucal_@NAME@_control_joint prefix="${prefix}" joint="@JOINT@"
            offset="${0.0 if offsets_in_urdf else ucal_offsets['@JOINT@']}"/>
"""

_TOP = """\
<?xml version="1.0"?>
<!--
  The calibrated @NAME@ fixed to world (ucal export ros2). Render with
    xacro @NAME@.urdf.xacro > @NAME@.urdf
  or in a launch file (robot_description = Command(['xacro ', path, ' prefix:=arm_'])).
  Arguments: prefix, kinematics_params, joint_offsets_params (paths absolute or relative
  to this file), offsets_in_urdf (true: joint positions are the controller's readings),
  ros2_control_plugin (a hardware plugin: adds the ros2_control tag); see @NAME@_macro.xacro.
-->
<robot xmlns:xacro="http://wiki.ros.org/xacro" name="@NAME@">
  <xacro:arg name="prefix" default="@PREFIX@"/>
  <xacro:arg name="kinematics_params" default="@NAME@_kinematics.yaml"/>
  <xacro:arg name="joint_offsets_params" default="@NAME@_joint_offsets.yaml"/>
  <xacro:arg name="offsets_in_urdf" default="false"/>
  <xacro:arg name="ros2_control_plugin" default=""/>

  <xacro:include filename="@NAME@_macro.xacro"/>

  <link name="world"/>
  <xacro:ucal_@NAME@
      prefix="$(arg prefix)"
      parent="world"
      kinematics_parameters_file="$(arg kinematics_params)"
      joint_offsets_file="$(arg joint_offsets_params)"
      offsets_in_urdf="$(arg offsets_in_urdf)"
      ros2_control_plugin="$(arg ros2_control_plugin)">
    <origin xyz="0 0 0" rpy="0 0 0"/>
  </xacro:ucal_@NAME@>
</robot>
"""
