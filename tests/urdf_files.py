"""A TX90L URDF for the tests, written from the published layout of the ROS-Industrial
description (``staubli_tx90_support`` / ``staubli_tx2-90_support``, ``tx90l_macro.xacro``):
joint 1 0.478 m above ``base_link``, joint 2 0.05 m in front, joint 3 0.05 m across and
0.5 m up, joint 5 0.55 m up, joint 6 0.1 m up, axes z y y z y z, the ``base`` frame at
shoulder height and ``tool0`` on ``link_6``. It is not derived from ucal's DH tables.
"""

from __future__ import annotations

import math

import numpy as np

#: (name, origin xyz (m), origin rpy (rad), axis, lower, upper (deg), velocity (deg/s))
TX90L_JOINTS = (
    ("joint_1", (0, 0, 0.478), (0, 0, 0), (0, 0, 1), -180, 180, 400),
    ("joint_2", (0.05, 0, 0), (0, 0, 0), (0, 1, 0), -130, 147.5, 390),
    ("joint_3", (0, 0.05, 0.5), (0, 0, 0), (0, 1, 0), -145, 145, 420),
    ("joint_4", (0, 0, 0), (0, 0, 0), (0, 0, 1), -270, 270, 540),
    ("joint_5", (0, 0, 0.55), (0, 0, 0), (0, 1, 0), -115, 140, 475),
    ("joint_6", (0, 0, 0.1), (0, 0, 0), (0, 0, 1), -270, 270, 760),
)


def urdf_text(
    joints=TX90L_JOINTS, kinds=None, turned: bool = True, name="staubli_tx90l", tool="0 0 0"
) -> str:
    """The URDF of ``joints``; ``turned``: joint 2's and joint 5's frames turned half a turn
    about z (their axes then −y, their children's origins mirrored), so that the origins are
    not the plain layout above; ``tool``: ``tool0``'s origin on ``link_6`` (m)."""
    kinds = kinds or {}
    links = ["base_link"] + [f"link_{i}" for i in range(1, 7)] + ["base", "tool0"]
    out = [f'<?xml version="1.0"?>\n<robot name="{name}">']
    out += [f'  <link name="{n}"/>' for n in links]
    flip = {"joint_2", "joint_5"} if turned else set()
    parent = "base_link"
    prev_flipped = False
    for i, (jn, xyz, rpy, axis, lo, hi, vel) in enumerate(joints, start=1):
        xyz = np.array(xyz, float)
        if prev_flipped:  # the parent's frame is turned by pi about z
            xyz = xyz * np.array([-1.0, -1.0, 1.0])
        rpy = np.array(rpy, float)
        axis = np.array(axis, float)
        if jn in flip:
            rpy = rpy + np.array([0.0, 0.0, math.pi])
            axis = axis * np.array([-1.0, -1.0, 1.0])
        if prev_flipped and jn not in flip:
            rpy = rpy + np.array([0.0, 0.0, -math.pi])  # back to the plain orientation
        kind = kinds.get(jn, "revolute")
        out.append(
            f'  <joint name="{jn}" type="{kind}"><parent link="{parent}"/>'
            f'<child link="link_{i}"/><origin xyz="{_nums(xyz)}" '
            f'rpy="{_nums(rpy)}"/><axis xyz="{_nums(axis)}"/>'
            f'<limit lower="{math.radians(lo)!r}" upper="{math.radians(hi)!r}" effort="10" '
            f'velocity="{math.radians(vel)!r}"/></joint>'
        )
        parent = f"link_{i}"
        prev_flipped = jn in flip
    tool_rpy = "0 0 0" if not prev_flipped else f"0 0 {-math.pi!r}"
    out.append(
        '  <joint name="joint_6-tool0" type="fixed"><parent link="link_6"/>'
        f'<child link="tool0"/><origin xyz="{tool}" rpy="{tool_rpy}"/></joint>'
    )
    out.append(
        '  <joint name="base_link-base" type="fixed"><parent link="base_link"/>'
        '<child link="base"/><origin xyz="0 0 0.478" rpy="0 0 0"/></joint>'
    )
    out.append("</robot>\n")
    return "\n".join(out)


def _nums(values) -> str:
    return " ".join(format(float(v), ".17g") for v in values)
