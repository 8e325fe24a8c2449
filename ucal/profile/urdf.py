"""A robot model from a URDF: ``ucal profile init --from-urdf FILE.urdf PATH``.

The URDF must hold a serial chain of six revolute joints (fixed joints between them are
allowed) of the wrist structure the closed-form inverse kinematics needs
(``ucal.kinematics.ik.check_structure``); anything else is refused (``InputError``, exit 2)
naming the file and the joint.

Frames. The model's base frame is the URDF's link ``base`` where one hangs off the tree by
fixed joints (ROS-Industrial's "controller's world frame", at shoulder height on a Staubli
arm), else the link joint 1 is mounted on; its flange frame is the link ``tool0`` where one
hangs off joint 6's child by fixed joints (ROS-Industrial's all-zeros tool frame), else joint
6's child.

Derivation of the standard DH table (``A_i = Rz(θ_i)·Tz(d_i)·Tx(a_i)·Rx(α_i)``, SPEC.md). At
zero joint positions, chaining the joints' ``<origin>`` gives every joint's axis as a line in
the base frame: a point ``p_i`` (the joint frame's origin) and a unit direction ``u_i`` (its
``<axis>`` turned into the base frame). DH frame ``i − 1`` has its z axis on joint ``i``'s
line, pointing along ``u_i`` (so a positive joint position turns the same way in both), and
each row is read off two consecutive lines:

* frame 0 is the base frame itself (ucal's model has no base transform), so joint 1's line
  must be the base z axis, pointing up;
* axes ``i`` and ``i + 1`` skew: ``x_i`` is their common normal from axis ``i`` to axis
  ``i + 1``, ``o_i`` its foot on axis ``i + 1``; ``a_i`` the normal's length;
* intersecting: ``o_i`` is the intersection, ``x_i = ±(z_{i−1} × z_i)``, the sign that keeps
  ``x_i`` nearest ``x_{i−1}`` (so the θ offsets stay small; on a tie the cross product);
* parallel: ``x_i`` is the perpendicular from axis ``i`` to axis ``i + 1`` (``x_{i−1}`` if the
  axes coincide), and ``o_i`` is where the common normal of axes ``i + 1`` and ``i + 2`` meets
  axis ``i + 1`` when those two are not parallel (so that ``d_{i+1} = 0``: on the TX90 family
  the 50 mm lateral offset then stands as ``d_2``, as in the shipped tables), else the foot of
  ``o_{i−1}`` on axis ``i + 1``;

then ``d_i = (o_i − o_{i−1})·z_{i−1}``, ``a_i = (o_i − o_{i−1})·x_i``, ``θ_i`` the angle from
``x_{i−1}`` to ``x_i`` about ``z_{i−1}`` (the θ offset: the DH angle at zero position) and
``α_i`` the angle from ``z_{i−1}`` to ``z_i`` about ``x_i``. Row 6 ends on the flange frame,
which must itself be a DH frame of joint 6: its x axis normal to axis 6 and its origin
``o_5 + d_6·z_5 + a_6·x_6``; else the URDF is refused.

Joint ranges and speeds: each joint's ``<limit lower upper velocity>`` (rad, rad/s → deg,
deg/s), the speeds written as the profile's ``[robot] speed_deg_s`` (a plan then assumes the
arm's maximum speeds). Before anything is written the table's forward kinematics is compared
with the URDF's own (the joints' origins chained with their rotations) at ``CHECK_POSTURES``
random joint vectors inside the ranges: flange positions within ``FK_TOLERANCE_MM`` and
orientations within ``FK_TOLERANCE_RAD``, else the URDF is refused.
"""

from __future__ import annotations

import itertools
import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ucal.errors import InputError
from ucal.kinematics.dh import N_JOINTS, RobotModel, fk
from ucal.kinematics.ik import check_structure

#: How closely the table must reproduce the URDF's flange: position (mm), orientation (rad).
FK_TOLERANCE_MM = 1e-3
FK_TOLERANCE_RAD = 1e-9
#: Random joint vectors (inside the ranges, seeded) at which the two are compared.
CHECK_POSTURES = 500
#: Below these, directions are parallel / lines meet / a length is zero (unit vectors; m).
_PARALLEL = 1e-9
_MEET_M = 1e-9
#: The link names of ROS-Industrial's base frame and flange frame.
BASE_LINK = "base"
FLANGE_LINK = "tool0"


@dataclass(frozen=True)
class UrdfJoint:
    """A URDF ``<joint>``: its type, links, origin (4×4, m), axis (unit, in the joint frame) and
    ``<limit>`` (rad, rad/s; None where absent)."""

    name: str
    kind: str
    parent: str
    child: str
    origin: np.ndarray
    axis: np.ndarray
    lower: float | None
    upper: float | None
    velocity: float | None


@dataclass(frozen=True)
class UrdfArm:
    """A URDF's six-revolute chain: its joints from the base (``chain``), the fixed transforms
    of the base and flange frames (4×4, m, at zero positions in the root link) and the links
    named as the base and flange frames."""

    path: Path
    name: str
    joints: dict[str, UrdfJoint]
    chain: tuple[UrdfJoint, ...]
    base_link: str
    flange_link: str

    def frames_m(self, q_rad: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The base and flange frames in the root link (4×4, m) at joint positions ``q_rad``
        (6,): the joints' origins chained with their rotations (the URDF's own kinematics)."""
        angles = {j.name: float(q) for j, q in zip(self.chain, q_rad, strict=True)}
        return self._link_m(self.base_link, angles), self._link_m(self.flange_link, angles)

    def flange_mm(self, q_rad: np.ndarray) -> np.ndarray:
        """The flange frame in the base frame (4×4, mm) at joint positions ``q_rad`` (6,)."""
        base, flange = self.frames_m(q_rad)
        t = np.linalg.inv(base) @ flange
        t[:3, 3] *= 1000.0
        return np.asarray(t)

    def _link_m(self, link: str, angles: dict[str, float]) -> np.ndarray:
        t = np.eye(4)
        for j in reversed(_path_to_root(self.joints, link)):
            t = t @ j.origin
            if j.name in angles:
                t = t @ _rotation4(j.axis, angles[j.name])
        return t


def read_urdf(path: str | Path) -> UrdfArm:
    """Read ``path``'s joints and find its six-revolute chain; ``InputError`` (exit 2) naming the
    file and the joint for what is not one."""
    p = Path(path)
    try:
        root = ET.parse(p).getroot()
    except OSError as e:
        raise InputError(f"{p}: cannot read the URDF: {e.strerror or e}") from None
    except ET.ParseError as e:
        raise InputError(f"{p}: not XML: {e}") from None
    if root.tag != "robot":
        raise InputError(f"{p}: not a URDF (its root element is <{root.tag}>, not <robot>)")
    joints: dict[str, UrdfJoint] = {}
    for el in root.iter("joint"):
        j = _joint(p, el)
        if j.name in joints:
            raise InputError(f"{p}: joint {j.name}: defined twice")
        joints[j.name] = j
    movable = [j for j in joints.values() if j.kind != "fixed"]
    for j in movable:
        if j.kind != "revolute":
            raise InputError(
                f"{p}: joint {j.name}: a {j.kind} joint (a six-revolute serial chain is needed)"
            )
    if len(movable) != N_JOINTS:
        raise InputError(
            f"{p}: {len(movable)} revolute joints (a six-revolute serial chain is needed)"
        )
    # the chain: each joint below the one before it, the deepest last
    paths = {j.name: [k.name for k in _path_to_root(joints, j.child)] for j in movable}
    chain = sorted(movable, key=lambda j: len(paths[j.name]))
    for before, after in itertools.pairwise(chain):
        if before.name not in paths[after.name]:
            raise InputError(
                f"{p}: joint {after.name}: not on one serial chain with joint {before.name}"
            )
    for j in chain:
        if j.lower is None or j.upper is None or not j.lower < j.upper:
            raise InputError(f"{p}: joint {j.name}: no <limit lower upper> range")
        if j.velocity is None or not j.velocity > 0:
            raise InputError(f"{p}: joint {j.name}: no positive <limit velocity>")
    # above joint 1 every joint is fixed (it is the shallowest of the six): the base link
    # hangs off the same tree by fixed joints, or joint 1's parent is the base frame
    mounted = chain[0].parent
    base_path = _path_to_root(joints, BASE_LINK)
    fixed_base = bool(base_path) and all(j.kind == "fixed" for j in base_path)
    base = BASE_LINK if fixed_base else mounted
    flange = FLANGE_LINK if _fixed_below(joints, FLANGE_LINK, chain[-1].child) else chain[-1].child
    name = root.get("name") or p.stem
    return UrdfArm(p, name, joints, tuple(chain), base, flange)


def model_from_urdf(arm: UrdfArm, name: str | None = None) -> RobotModel:
    """The standard DH model of ``arm`` (module docstring), named ``name`` (default: the
    URDF's robot name), its ranges and speeds from the joints' ``<limit>``; checked against the
    URDF's own kinematics (``check_against_urdf``)."""
    dh = _dh_table_mm_deg(arm)
    model = RobotModel(
        name or arm.name,
        dh,
        np.array([_clean(math.degrees(j.lower or 0.0)) for j in arm.chain]),
        np.array([_clean(math.degrees(j.upper or 0.0)) for j in arm.chain]),
        dh_source=f"{arm.path}",
        speed_deg_s=np.array([_clean(math.degrees(j.velocity or 0.0)) for j in arm.chain]),
    )
    try:
        check_structure(model)
    except InputError as e:
        raise InputError(f"{arm.path}: not the wrist structure ucal solves: {e}") from None
    check_against_urdf(arm, model)
    return model


def check_against_urdf(arm: UrdfArm, model: RobotModel) -> tuple[float, float]:
    """The largest flange position (mm) and orientation (rad) differences between ``model`` and
    the URDF over ``CHECK_POSTURES`` seeded random joint vectors inside the ranges;
    ``InputError`` naming the file where they exceed ``FK_TOLERANCE_MM`` / ``_RAD``."""
    rng = np.random.default_rng(0x0D0F)
    q_deg = rng.uniform(model.joint_min_deg, model.joint_max_deg, (CHECK_POSTURES, N_JOINTS))
    q_deg[0] = 0.0
    ours = fk(model, q_deg)
    worst_mm = worst_rad = 0.0
    for q, t in zip(q_deg, ours, strict=True):
        ref = arm.flange_mm(np.radians(q))
        worst_mm = max(worst_mm, float(np.linalg.norm(t[:3, 3] - ref[:3, 3])))
        # ‖R − R_ref‖_F = 2√2·sin(φ/2) ≈ √2·φ for the angle φ between the two
        worst_rad = max(worst_rad, float(np.linalg.norm(ref[:3, :3] - t[:3, :3])) / math.sqrt(2))
    if worst_mm > FK_TOLERANCE_MM or worst_rad > FK_TOLERANCE_RAD:
        raise InputError(
            f"{arm.path}: the DH table does not reproduce the URDF's forward kinematics "
            f"(flange {worst_mm * 1000:.3g} µm, {worst_rad:.3g} rad apart at worst over "
            f"{CHECK_POSTURES} joint vectors)"
        )
    return worst_mm, worst_rad


def _dh_table_mm_deg(arm: UrdfArm) -> np.ndarray:
    """Rows ``theta_offset_deg, d_mm, a_mm, alpha_deg`` of ``arm`` (module docstring)."""
    base, flange = arm.frames_m(np.zeros(N_JOINTS))
    inv = np.linalg.inv(base)
    points, dirs = [], []
    for j in arm.chain:
        t = inv @ _link_at_zero(arm, j.parent) @ j.origin
        points.append(t[:3, 3])
        dirs.append(_unit(t[:3, :3] @ j.axis))
    first = arm.chain[0]
    if (
        np.linalg.norm(dirs[0] - [0.0, 0.0, 1.0]) > _PARALLEL
        or np.linalg.norm(points[0][:2]) > _MEET_M
    ):
        raise InputError(
            f"{arm.path}: joint {first.name}: its axis is not the z axis of the base frame "
            f"({arm.base_link}), pointing up (the model has no base transform)"
        )
    z, o, x = dirs[0], np.zeros(3), np.array([1.0, 0.0, 0.0])
    rows = []
    for i in range(1, N_JOINTS):
        zn, pn = dirs[i], points[i]
        cross = np.cross(z, zn)
        if np.linalg.norm(cross) > _PARALLEL:
            c1, c2 = _closest_points(o, z, pn, zn)
            normal = c2 - c1
            if np.linalg.norm(normal) > _MEET_M:
                xn = _unit(normal)
            else:
                xn = _unit(cross)
                if float(xn @ x) < -_PARALLEL:
                    xn = -xn
            on = c2
        else:
            v = (pn - o) - float((pn - o) @ z) * z
            xn = _unit(v) if np.linalg.norm(v) > _MEET_M else x
            on = pn + float((o - pn) @ zn) * zn
            if i + 1 < N_JOINTS and np.linalg.norm(np.cross(zn, dirs[i + 1])) > _PARALLEL:
                on = _closest_points(pn, zn, points[i + 1], dirs[i + 1])[0]
        rows.append(_row(z, o, x, zn, on, xn))
        z, o, x = zn, on, xn
    tf = inv @ flange
    xe, ze, oe = tf[:3, 0], tf[:3, 2], tf[:3, 3]
    d6 = float((oe - o) @ z)
    a6 = float((oe - o) @ xe)
    last = arm.chain[-1]
    if abs(float(xe @ z)) > _PARALLEL or np.linalg.norm(oe - o - d6 * z - a6 * xe) > _MEET_M:
        raise InputError(
            f"{arm.path}: joint {last.name}: the flange frame ({arm.flange_link}) is not a DH "
            f"frame of the joint's axis (its x axis normal to the axis, its origin on the "
            f"common normal)"
        )
    rows.append(_row(z, o, x, ze, oe, xe))
    return np.array(rows)


def _row(
    z: np.ndarray, o: np.ndarray, x: np.ndarray, zn: np.ndarray, on: np.ndarray, xn: np.ndarray
) -> list[float]:
    """``theta_offset_deg, d_mm, a_mm, alpha_deg`` from frame (z, o, x) to frame (zn, on, xn)."""
    theta = math.atan2(float(np.cross(x, xn) @ z), float(x @ xn))
    alpha = math.atan2(float(np.cross(z, zn) @ xn), float(z @ zn))
    d = float((on - o) @ z)
    a = float((on - o) @ xn)
    return [
        _clean(math.degrees(theta)),
        _clean(d * 1000.0),
        _clean(a * 1000.0),
        _clean(math.degrees(alpha)),
    ]


def _clean(v: float) -> float:
    """``v`` rounded to 1e-9 (its unit's nano part): 0.1 m read from a URDF is 100.0 mm."""
    return round(v, 9) + 0.0


def _closest_points(
    p1: np.ndarray, u1: np.ndarray, p2: np.ndarray, u2: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The points of two non-parallel lines ``p + s·u`` (unit ``u``) closest to each other."""
    w = p1 - p2
    b, d, e = float(u1 @ u2), float(u1 @ w), float(u2 @ w)
    den = 1.0 - b * b
    s = (b * e - d) / den
    t = (e - b * d) / den
    return p1 + s * u1, p2 + t * u2


def _link_at_zero(arm: UrdfArm, link: str) -> np.ndarray:
    return arm._link_m(link, {})


def _path_to_root(joints: dict[str, UrdfJoint], link: str) -> list[UrdfJoint]:
    """The joints from ``link`` up to the root, nearest first."""
    parent_of = {j.child: j for j in joints.values()}
    path: list[UrdfJoint] = []
    while link in parent_of:
        j = parent_of[link]
        if j in path:
            break  # a loop: not a tree; the chain checks refuse it
        path.append(j)
        link = j.parent
    return path


def _fixed_below(joints: dict[str, UrdfJoint], link: str, above: str) -> bool:
    """Whether ``link`` hangs off ``above`` by fixed joints alone."""
    for j in _path_to_root(joints, link):
        if j.kind != "fixed":
            return False
        if j.parent == above:
            return True
    return False


def _joint(path: Path, el: ET.Element) -> UrdfJoint:
    name = el.get("name") or "?"
    parent, child = el.find("parent"), el.find("child")
    if parent is None or child is None or not parent.get("link") or not child.get("link"):
        raise InputError(f"{path}: joint {name}: needs <parent link> and <child link>")
    origin = el.find("origin")
    xyz = _floats(path, name, "origin xyz", None if origin is None else origin.get("xyz"))
    rpy = _floats(path, name, "origin rpy", None if origin is None else origin.get("rpy"))
    axis_el = el.find("axis")
    axis = _floats(path, name, "axis xyz", None if axis_el is None else axis_el.get("xyz"))
    if axis_el is None:
        axis = np.array([1.0, 0.0, 0.0])  # the URDF default
    if np.linalg.norm(axis) == 0.0:
        raise InputError(f"{path}: joint {name}: a zero <axis>")
    t = np.eye(4)
    t[:3, :3] = _rpy(rpy)
    t[:3, 3] = xyz
    limit = el.find("limit")

    def lim(key: str) -> float | None:
        v = None if limit is None else limit.get(key)
        if v is None:
            return None
        try:
            return float(v)
        except ValueError:
            raise InputError(f"{path}: joint {name}: <limit {key}> is not a number") from None

    return UrdfJoint(
        name,
        el.get("type") or "?",
        str(parent.get("link")),
        str(child.get("link")),
        t,
        _unit(axis),
        lim("lower"),
        lim("upper"),
        lim("velocity"),
    )


def _floats(path: Path, joint: str, what: str, text: str | None) -> np.ndarray:
    if text is None:
        return np.zeros(3)
    try:
        v = np.array([float(s) for s in text.split()])
    except ValueError:
        raise InputError(f"{path}: joint {joint}: <{what}> is not three numbers") from None
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        raise InputError(f"{path}: joint {joint}: <{what}> is not three numbers")
    return v


def _rpy(rpy: np.ndarray) -> np.ndarray:
    """URDF ``rpy``: fixed-axis roll about x, pitch about y, yaw about z: Rz·Ry·Rx."""
    r, p, y = rpy
    return np.asarray(
        _rot(np.array([0.0, 0.0, 1.0]), y)
        @ _rot(np.array([0.0, 1.0, 0.0]), p)
        @ _rot(np.array([1.0, 0.0, 0.0]), r)
    )


def _rot(u: np.ndarray, angle: float) -> np.ndarray:
    """Rotation by ``angle`` (rad) about the unit vector ``u`` (Rodrigues)."""
    k = np.array([[0.0, -u[2], u[1]], [u[2], 0.0, -u[0]], [-u[1], u[0], 0.0]])
    return np.asarray(np.eye(3) + math.sin(angle) * k + (1.0 - math.cos(angle)) * (k @ k))


def _rotation4(u: np.ndarray, angle: float) -> np.ndarray:
    t = np.eye(4)
    t[:3, :3] = _rot(u, angle)
    return t


def _unit(v: np.ndarray) -> np.ndarray:
    return np.asarray(v, float) / float(np.linalg.norm(v))
