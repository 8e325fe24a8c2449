"""Standard Denavit–Hartenberg forward kinematics for 6R arms, wrist centre and Jacobian.

Convention (SPEC.md): one row per joint ``theta_offset_deg, d_mm, a_mm, alpha_deg``;
the angle entering row *i* is ``reading_i + theta_offset_i + joint_offset_i`` and

    A_i = Rot(z, θ_i) · Trans(0, 0, d_i) · Trans(a_i, 0, 0) · Rot(x, α_i) · Rot(y, β_i).

``β_i`` is Hayati's twist about the link's y axis (``RobotModel.beta_deg``, zero in the shipped
tables): for the nearly parallel axes 2 and 3 a small tilt of axis 3 about the common normal is
``α_2``, a tilt in the plane of the two axes is ``β_2``, which standard DH could only express
with an enormous ``d`` (``calibrate --level full`` identifies it).

The TX90-family table shipped in ``profiles/`` (upper arm L2, forearm L3)::

    row  θ offset   d      a     α
     1      0       0     50   -90     shoulder: axis 2 is 50 mm in front of axis 1
     2    -90      50     L2     0     +50 mm lateral offset along axis 2 (+Y at θ1 = 0)
     3    +90       0      0   +90
     4      0      L3      0   -90     forearm along z3
     5      0       0      0   +90     spherical wrist: axes 4, 5, 6 meet in W
     6      0     100      0     0     flange 100 mm beyond W

Source: the public ROS-Industrial URDF of the TX90 family (``staubli_tx90_support``):
joint 1 at the Staubli world origin 478 mm above the floor (so ``d1 = 0``: the controller's
base frame is at shoulder height), joint 2 at x = 50 mm, the 50 mm lateral offset along +Y,
joints 2, 3, 5 turning about +Y, zero pose = arm straight up. The ±90° offsets on rows 2
and 3 put the model's zero on the controller's. At zero the flange of a TX90XL is at
(50, 50, 650 + 650 + 100) mm with its z axis up and its x axis along base +X.

Paper 002's Table 1 (TX90XL) has the same lengths but its signs (``d4 = −650``,
``θ5 − 90°``) place frames 3–5 differently: its zero pose is not the controller's, so it is
not shipped. With this table paper 000's calibration pose (30.53, 31.15, 109.49, 0, 39.36,
30.54)° points the flange z axis straight down (θ2 + θ3 + θ5 = 180°), as the paper's
figure 5 shows.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field

import numpy as np

from ucal.kinematics.rotations import cross3

#: Joint order of every 6-vector in this package.
N_JOINTS = 6


@dataclass(frozen=True)
class RobotModel:
    """A 6R arm: DH table (6, 4) as ``theta_offset_deg, d_mm, a_mm, alpha_deg``, joint ranges and
    Hayati twists ``beta_deg`` (6,; zeros by default)."""

    name: str
    dh: np.ndarray
    joint_min_deg: np.ndarray
    joint_max_deg: np.ndarray
    beta_deg: np.ndarray = field(default_factory=lambda: np.zeros(N_JOINTS))
    #: where the DH table comes from: "shipped" (the model's data sheet), a file's ``[robot]
    #: dh``, a profile's ``[calibration] dh``, or ``calibrate --level full``
    dh_source: str = field(default="shipped", compare=False)
    #: the joints' speeds (deg/s, (6,)) at speed 1.0 as a plan, its estimate and the simulated
    #: controller take them (``ucal.profile.models.joint_speeds_deg_s``); None: not stated
    speed_deg_s: np.ndarray | None = field(default=None, compare=False)
    #: the joints' maximum accelerations (deg/s², (6,)) where a source states them; None: not
    #: stated (the motion model is joint-interpolated at constant speed and takes none)
    acceleration_deg_s2: np.ndarray | None = field(default=None, compare=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "dh", np.asarray(self.dh, dtype=float).reshape(N_JOINTS, 4))
        object.__setattr__(
            self, "beta_deg", np.asarray(self.beta_deg, dtype=float).reshape(N_JOINTS)
        )
        object.__setattr__(self, "joint_min_deg", np.asarray(self.joint_min_deg, dtype=float))
        object.__setattr__(self, "joint_max_deg", np.asarray(self.joint_max_deg, dtype=float))
        for name in ("speed_deg_s", "acceleration_deg_s2"):
            v = getattr(self, name)
            if v is not None:
                object.__setattr__(self, name, np.asarray(v, dtype=float).reshape(N_JOINTS))

    @property
    def theta_offset_deg(self) -> np.ndarray:
        return self.dh[:, 0]

    @property
    def d_mm(self) -> np.ndarray:
        return self.dh[:, 1]

    @property
    def a_mm(self) -> np.ndarray:
        return self.dh[:, 2]

    @property
    def alpha_deg(self) -> np.ndarray:
        return self.dh[:, 3]

    def within_limits(self, joints_deg: np.ndarray, tol_deg: float = 1e-9) -> np.ndarray:
        """True where every joint reading of (…, 6) lies inside the joint ranges."""
        j = np.asarray(joints_deg, dtype=float)
        return np.all((j >= self.joint_min_deg - tol_deg) & (j <= self.joint_max_deg + tol_deg), -1)

    def with_dh(
        self, dh: np.ndarray, beta_deg: np.ndarray | None = None, source: str | None = None
    ) -> RobotModel:
        """Copy of this model with another DH table (e.g. a perturbed 'true' robot) from
        ``source`` (default: this model's); the Hayati twists are kept unless ``beta_deg`` is
        given."""
        beta = self.beta_deg if beta_deg is None else beta_deg
        return RobotModel(
            self.name,
            np.array(dh, float),
            self.joint_min_deg,
            self.joint_max_deg,
            np.array(beta, float),
            self.dh_source if source is None else source,
            self.speed_deg_s,
            self.acceleration_deg_s2,
        )

    @property
    def has_twists(self) -> bool:
        """True if any Hayati twist is non-zero."""
        return bool(np.any(self.beta_deg != 0.0))


def dh_matrix(theta_rad: np.ndarray, d_mm: float, a_mm: float, alpha_rad: float) -> np.ndarray:
    """One DH link transform ``Rot(z,θ)·Trans(0,0,d)·Trans(a,0,0)·Rot(x,α)`` (…,) → (…, 4, 4)."""
    th = np.asarray(theta_rad, dtype=float)
    ct, st = np.cos(th), np.sin(th)
    ca, sa = np.cos(alpha_rad), np.sin(alpha_rad)
    t = np.zeros(th.shape + (4, 4))
    t[..., 0, 0] = ct
    t[..., 0, 1] = -st * ca
    t[..., 0, 2] = st * sa
    t[..., 0, 3] = a_mm * ct
    t[..., 1, 0] = st
    t[..., 1, 1] = ct * ca
    t[..., 1, 2] = -ct * sa
    t[..., 1, 3] = a_mm * st
    t[..., 2, 1] = sa
    t[..., 2, 2] = ca
    t[..., 2, 3] = d_mm
    t[..., 3, 3] = 1.0
    return t


def _rot_y4(beta_rad: float) -> np.ndarray:
    """Hayati's twist ``Rot(y, β)`` as a 4×4 transform."""
    c, s = np.cos(beta_rad), np.sin(beta_rad)
    return np.array(
        [[c, 0.0, s, 0.0], [0.0, 1.0, 0.0, 0.0], [-s, 0.0, c, 0.0], [0.0, 0.0, 0.0, 1.0]]
    )


def model_angles_rad(
    model: RobotModel, joints_deg: np.ndarray, offsets_deg: np.ndarray | None = None
) -> np.ndarray:
    """Joint readings (…, 6) → DH angles in radians: reading + θ offset + joint offset."""
    q = np.asarray(joints_deg, dtype=float) + model.theta_offset_deg
    if offsets_deg is not None:
        q = q + np.asarray(offsets_deg, dtype=float)
    return np.asarray(np.radians(q))


_EYE4 = np.eye(4)
_EYE4.flags.writeable = False


@functools.lru_cache(maxsize=64)
def _table_constants(
    dh_bytes: bytes, beta_bytes: bytes
) -> tuple[np.ndarray, np.ndarray, tuple[tuple[int, np.ndarray], ...]]:
    """What ``fk_frames`` takes of a DH table and its twists (their bytes: a table changed in
    place is another table): cos α, sin α and each twisted link's ``Rot(y, β)``, read-only."""
    alpha = np.radians(np.frombuffer(dh_bytes).reshape(N_JOINTS, 4)[:, 3])
    beta = np.frombuffer(beta_bytes)
    ca, sa = np.cos(alpha), np.sin(alpha)
    twists = tuple((int(k), _rot_y4(np.radians(beta[k]))) for k in np.flatnonzero(beta))
    for m in (ca, sa, *(t for _, t in twists)):
        m.flags.writeable = False
    return ca, sa, twists


def fk_frames(
    model: RobotModel, joints_deg: np.ndarray, offsets_deg: np.ndarray | None = None
) -> np.ndarray:
    """Frames 0…6 in the base frame for joint readings (…, 6) → (…, 7, 4, 4).

    The six link transforms (``dh_matrix``) are built at once and chained: the solvers call
    this in their inner loops with a dozen postures at a time, where per-link array set-up
    would cost more than the arithmetic.
    """
    th = model_angles_rad(model, joints_deg, offsets_deg)
    shape = th.shape[:-1]
    ct, st = np.cos(th), np.sin(th)
    ca, sa, twists = _table_constants(model.dh.tobytes(), model.beta_deg.tobytes())
    a, d = model.a_mm, model.d_mm
    links = np.zeros(shape + (N_JOINTS, 4, 4))
    links[..., 0, 0] = ct
    links[..., 0, 1] = -st * ca
    links[..., 0, 2] = st * sa
    links[..., 0, 3] = a * ct
    links[..., 1, 0] = st
    links[..., 1, 1] = ct * ca
    links[..., 1, 2] = -ct * sa
    links[..., 1, 3] = a * st
    links[..., 2, 1] = sa
    links[..., 2, 2] = ca
    links[..., 2, 3] = d
    links[..., 3, 3] = 1.0
    frames = np.empty(shape + (N_JOINTS + 1, 4, 4))
    frames[..., 0, :, :] = _EYE4
    for k, twist in twists:  # the twisted links
        links[..., k, :, :] = links[..., k, :, :] @ twist
    frames[..., 1, :, :] = links[..., 0, :, :]
    for i in range(1, N_JOINTS):
        np.matmul(frames[..., i, :, :], links[..., i, :, :], out=frames[..., i + 1, :, :])
    return frames


def fk(
    model: RobotModel,
    joints_deg: np.ndarray,
    tool: np.ndarray | None = None,
    offsets_deg: np.ndarray | None = None,
) -> np.ndarray:
    """Flange (or tool, if a 4×4 ``tool`` transform is given) in the base frame → (…, 4, 4)."""
    t = fk_frames(model, joints_deg, offsets_deg)[..., N_JOINTS, :, :]
    if tool is not None:
        t = t @ np.asarray(tool, dtype=float)
    return t


def wrist_centre(
    model: RobotModel, joints_deg: np.ndarray, offsets_deg: np.ndarray | None = None
) -> np.ndarray:
    """Wrist centre W (origin of frame 4, = frame 5 for a spherical wrist) (…, 3) in mm.

    W depends on joints 1–3 only (paper 000 §4.2, paper 004 §2): the basis of arm–wrist
    separation.
    """
    return fk_frames(model, joints_deg, offsets_deg)[..., 4, :3, 3]


def jacobian(
    model: RobotModel,
    joints_deg: np.ndarray,
    tool: np.ndarray | None = None,
    offsets_deg: np.ndarray | None = None,
) -> np.ndarray:
    """Geometric Jacobian (…, 6, 6) of the flange/tool point: rows vx, vy, vz (mm/rad), wx, wy, wz.

    Column i is ``[z_{i-1} × (p - o_{i-1}); z_{i-1}]`` in the base frame.
    """
    frames = fk_frames(model, joints_deg, offsets_deg)
    end = frames[..., N_JOINTS, :, :]
    if tool is not None:
        end = end @ np.asarray(tool, dtype=float)
    p = end[..., :3, 3]
    z = frames[..., :N_JOINTS, :3, 2]
    o = frames[..., :N_JOINTS, :3, 3]
    lin = cross3(z, p[..., None, :] - o)
    jac = np.concatenate([lin, z], -1)  # (…, 6 joints, 6)
    return np.swapaxes(jac, -1, -2)


def transform(position_mm: np.ndarray, rotation: np.ndarray) -> np.ndarray:
    """Homogeneous transform from a position (3,) and a rotation matrix (3, 3)."""
    t = np.eye(4)
    t[:3, :3] = rotation
    t[:3, 3] = position_mm
    return t
