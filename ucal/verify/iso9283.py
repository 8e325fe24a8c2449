"""ISO 9283 pose accuracy and repeatability (``ucal verify --iso9283``).

ISO 9283:1998 (§6.2, §7.2) judges a robot at five poses in a cube of its workspace: P1 at
the cube's centre, P2–P5 on the diagonals of its plane C1–C2–C7–C8 (through two opposite
edges), at 10 % of a diagonal's length from its ends; the robot starts at P1 and visits P5,
P4, P3, P2, P1, each reached from the same direction, ``cycles`` times (30 in the standard).
Here the cube stands in the tank, its edges along the block's axes: as wide as the area over
the XY face from which every wall can be measured (``ucal.verify.plan.verify_region``), no
taller than ``MAX_SIDE_MM``, its lowest face ``VERIFY_HEIGHT_MM`` above the XY face, the tool
straight down at every pose; each attained pose is measured as verify measures a point (the
three walls' water paths give the wrist centre, the three normal-incidence postures the
flange's orientation, the tool check the tool across the beam), in the block's frame.

The standard's figures, pose by pose, of the ``n`` attained positions ``x_j`` and
orientations ``(a_j, b_j, c_j)`` (small rotations about block X, Y, Z) against the commanded
``x_c`` (§7.2.1, §7.2.2)::

    AP_x = x̄ − x_c, …        AP_P = |x̄ − x_c|        AP_a = ā − a_c, …
    l_j = |x_j − x̄|          S_l = sqrt(Σ (l_j − l̄)² / (n − 1))
    RP_l = l̄ + 3·S_l         RP_a = 3·S_a, …

Their uncertainty is that of the robot's own figures given what ucal measured: a parametric
bootstrap (``BOOTSTRAP_DRAWS``) draws the robot's scatter about the measured mean (the
measured scatter less the measurement's own noise), each attained pose's measurement noise
and the run's common errors (the sound speed, the tool check's edges), and computes the
figures again; the std of a figure is the rms of its draws about the robot's value. So a
figure's std holds the sampling of ``n`` cycles, the noise that inflates RP and the errors
common to every pose that AP carries and RP does not.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from ucal.cell import CellProfile
from ucal.errors import SafetyError
from ucal.iso9283 import POSE_NAMES, orientation_figures, standard_figures
from ucal.kinematics.dh import jacobian
from ucal.verify.measure import PointResult, VerifyResult
from ucal.verify.plan import (
    PLAN_TURNS_DEG,
    PLAN_WALL_PATHS_MM,
    VERIFY_HEIGHT_MM,
    IsoCube,
    Layout,
    PointGroup,
    VerifyPlan,
    down_rotation_local,
    plan_choice,
    verify_region,
)
from ucal.verify.uncertainty import point_noise, table_share

#: The standard's cycles (ISO 9283 §7.2.1).
ISO_CYCLES = 30
#: P2–P5 at 10 % of a diagonal from its ends: 80 % of the way from the centre to a corner.
POSE_FRACTION = 0.8
#: The order of a cycle: P1, P5, P4, P3, P2 (0-based pose numbers).
CYCLE_ORDER = (0, 4, 3, 2, 1)
#: The cube's largest side (mm): its top face 150 mm above the XY face at most, the longest
#: water path a wall's echo takes at 25 MHz (``ucal.verify.plan.WALL_PATH_MM``).
MAX_SIDE_MM = 120.0
#: The cube's sides tried, as shares of the largest that fits, where a pose fails a check.
SIDE_SHARES = (1.0, 0.8, 0.6, 0.4)
#: Draws of the parametric bootstrap (seeded: the figures of a run are reproducible).
BOOTSTRAP_DRAWS = 4000
#: The wrist's joints, whose scatter at a pose no echo here sees, are taken to scatter by up to
#: this many times the angle the arm's measured scatter gives joints 1-3 (uniform from zero):
#: a wrist's gears are smaller and nearer the tool, its angular repeatability no better.
WRIST_SCATTER_MAX = 2.0


def cube_poses(centre_mm: np.ndarray, side_mm: float) -> np.ndarray:
    """P1–P5 (5, 3) in block coordinates (mm) of a cube of ``side_mm`` about ``centre_mm``,
    edges along the block's axes: P1 the centre, P2–P5 towards C1 (−,−,−), C2 (+,−,−),
    C7 (+,+,+) and C8 (−,+,+), the corners of the diagonal plane through the cube's lower
    edge along −Y and its upper edge along +Y."""
    c = np.asarray(centre_mm, float)
    corners = 0.5 * side_mm * np.array([[-1, -1, -1], [1, -1, -1], [1, 1, 1], [-1, 1, 1]], float)
    return np.vstack([c, c + POSE_FRACTION * corners])


def plan_iso9283(profile: CellProfile, cycles: int = ISO_CYCLES) -> VerifyPlan:
    """The five poses of the largest cube that passes every check of verify's plan (the tool
    turned about the beam and the walls' water paths tried as verify tries them, then smaller
    cubes), visited ``cycles`` times in the standard's order; ``SafetyError`` naming the first
    failure where none passes."""
    if cycles < 2:
        raise ValueError(f"ISO 9283 needs at least 2 cycles, got {cycles}")
    first: SafetyError | None = None
    for share in SIDE_SHARES:
        for walls in PLAN_WALL_PATHS_MM:
            for turn in PLAN_TURNS_DEG:
                rot = (
                    down_rotation_local() @ Rotation.from_euler("z", turn, degrees=True).as_matrix()
                )
                try:
                    lo, hi = verify_region(profile, VERIFY_HEIGHT_MM, rot, Layout(walls))
                except SafetyError as e:
                    first = first or e
                    continue
                side = share * min(float(np.min(hi - lo)), MAX_SIDE_MM)
                centre = np.array([*(0.5 * (lo + hi)), VERIFY_HEIGHT_MM + 0.5 * side])
                poses = cube_poses(centre, side)
                about = f", the tool turned {turn:g}° about it" if turn else ""
                group = PointGroup("iso", "beam straight down" + about, rot, float(centre[2]))
                try:
                    plan = plan_choice(
                        profile,
                        5,
                        VERIFY_HEIGHT_MM,
                        turn,
                        Layout(walls),
                        None,
                        None,
                        (group, poses),
                    )
                except SafetyError as e:
                    first = first or e
                    continue
                once = {t.index: t for t in plan.targets}
                targets = tuple(once[i] for _ in range(cycles) for i in CYCLE_ORDER)
                return replace(plan, targets=targets, iso=IsoCube(centre, side, cycles))
    raise SafetyError(f"no ISO 9283 cube fits over the block's XY face: {first}")


def orientation_deviation_deg(
    profile: CellProfile, point: PointResult, commanded: np.ndarray
) -> np.ndarray:
    """The attained tool orientation's small rotation from the commanded one, about block X,
    Y, Z (deg): ``a``, ``b``, ``c`` of ISO 9283."""
    attained = point.flange_local @ profile.tool_matrix[:3, :3]
    return np.asarray(Rotation.from_matrix(attained @ commanded.T).as_rotvec(degrees=True))


def _finite(values: np.ndarray) -> list[float | None]:
    """``values`` for JSON: ``None`` where not determined (NaN)."""
    return [float(v) if np.isfinite(v) else None for v in values]


@dataclass(frozen=True)
class IsoPose:
    """One pose's figures (mm, deg) with their one-sigma uncertainties."""

    name: str
    commanded_mm: np.ndarray
    attained_mm: np.ndarray  # (n, 3), by cycle
    mean_mm: np.ndarray
    ap_xyz_mm: np.ndarray
    ap_xyz_std_mm: np.ndarray
    ap_mm: float
    ap_std_mm: float
    l_mean_mm: float
    s_l_mm: float
    rp_mm: float
    rp_std_mm: float
    ap_abc_deg: np.ndarray
    ap_abc_std_deg: np.ndarray
    rp_abc_deg: np.ndarray
    rp_abc_std_deg: np.ndarray

    def to_json(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "commanded_mm": self.commanded_mm.tolist(),
            "mean_mm": self.mean_mm.tolist(),
            "ap_mm": self.ap_mm,
            "ap_std_mm": self.ap_std_mm,
            "ap_xyz_mm": self.ap_xyz_mm.tolist(),
            "ap_xyz_std_mm": self.ap_xyz_std_mm.tolist(),
            "rp_mm": self.rp_mm,
            "rp_std_mm": self.rp_std_mm,
            "l_mean_mm": self.l_mean_mm,
            "s_l_mm": self.s_l_mm,
            "ap_abc_deg": _finite(self.ap_abc_deg),
            "ap_abc_std_deg": _finite(self.ap_abc_std_deg),
            "rp_abc_deg": _finite(self.rp_abc_deg),
            "rp_abc_std_deg": _finite(self.rp_abc_std_deg),
            "attained_mm": self.attained_mm.tolist(),
        }


@dataclass(frozen=True)
class Iso9283:
    """``verify --iso9283``'s figures: the cube, the cycles and each pose's."""

    cube: IsoCube
    poses: tuple[IsoPose, ...]
    frame: str = "block"
    notes: tuple[str, ...] = field(default=())

    def facts(self) -> dict[str, Any]:
        """What the verify picture carries of the figures, for ``ucal report`` (mm)."""
        return {
            "cycles": self.cube.cycles,
            "side_mm": self.cube.side_mm,
            "poses": [
                {k: getattr(p, k) for k in ("name", "ap_mm", "ap_std_mm", "rp_mm", "rp_std_mm")}
                for p in self.poses
            ],
        }

    def to_json(self) -> dict[str, Any]:
        return {
            "standard": "ISO 9283:1998, 7.2 (unidirectional pose accuracy and repeatability)",
            "frame": self.frame,
            "cycles": self.cube.cycles,
            "cube": {"centre_mm": self.cube.centre_mm.tolist(), "side_mm": self.cube.side_mm},
            "poses": [p.to_json() for p in self.poses],
            "ap_mm": [p.ap_mm for p in self.poses],
            "ap_std_mm": [p.ap_std_mm for p in self.poses],
            "rp_mm": [p.rp_mm for p in self.poses],
            "rp_std_mm": [p.rp_std_mm for p in self.poses],
            "notes": list(self.notes),
        }


def robot_scatter(by_pose: list[np.ndarray], noise_var: np.ndarray) -> np.ndarray:
    """The robot's own scatter's covariance (3, 3), pooled over the poses: the attained
    positions about their pose's mean (``by_pose``: (n, 3) each; the poses lie within one cube,
    where the arm's Jacobian hardly changes, and five poses give the few cycles' spread five
    times the degrees of freedom) less the measurement's noise (``noise_var``, (3,)), kept
    positive semi-definite."""
    dev = np.vstack([x - x.mean(axis=0) for x in by_pose])
    dof = sum(len(x) - 1 for x in by_pose)
    cov = dev.T @ dev / max(dof, 1) - np.diag(noise_var)
    w, vec = np.linalg.eigh(0.5 * (cov + cov.T))
    return np.asarray((vec * np.clip(w, 0.0, None)) @ vec.T)


def joint_jacobian_mm_per_deg(profile: CellProfile, joints_deg: np.ndarray) -> np.ndarray:
    """How the tool centre moves in block coordinates per degree of each joint (3, 6; mm/deg)
    at readings ``joints_deg``, by the profile's kinematics (the geometric Jacobian's linear
    rows, ``ucal.kinematics.dh.jacobian``)."""
    lin = jacobian(profile.model, joints_deg, profile.tool_matrix, profile.joint_offsets_deg)[:3]
    return np.asarray(profile.sample_matrix[:3, :3].T @ lin * np.radians(1.0))


def unseen_wrist_scatter(
    profile: CellProfile, joints_deg: np.ndarray, arm: np.ndarray
) -> np.ndarray:
    """The wrist's share of the tool centre's scatter at a pose (3, 3; mm²), which no
    measurement here sees: every posture of a pose's measurement turns the wrist away from
    the commanded one, so its joints' settling at the pose is lost, while the arm's (joints
    1-3, which stay still) is in the wrist centre the water paths give. Here its joints
    scatter by the angle the arm's measured scatter ``arm`` (3, 3; mm²) gives joints 1-3;
    the bootstrap scales it by 0 to ``WRIST_SCATTER_MAX``."""
    jac = joint_jacobian_mm_per_deg(profile, joints_deg)
    arm_jac, wrist_jac = jac[:, :3], jac[:, 3:]
    var_deg2 = float(np.trace(arm)) / max(float(np.trace(arm_jac @ arm_jac.T)), 1e-300)
    return np.asarray(var_deg2 * wrist_jac @ wrist_jac.T)


def iso_figures(
    profile: CellProfile,
    result: VerifyResult,
    path_std_mm: Callable[[float], float],
    seed: int = 0,
    share: tuple[np.ndarray, np.ndarray] | None = None,
) -> Iso9283:
    """The standard's figures of an ISO 9283 run (``plan.iso``) with their uncertainty (the
    module docstring's bootstrap)."""
    plan = result.plan
    assert plan.iso is not None
    rng = np.random.default_rng(seed)
    commanded_rot = plan.rotation_local(0)
    points = result.measured("after")
    # the tool centre as time of flight sees it: the delay is part of its definition
    noises = {id(p): point_noise(profile, p, result, path_std_mm, delay=False) for p in points}
    by_pose = [[p for p in points if p.index == i] for i in range(len(POSE_NAMES))]
    attained_mm = [np.array([p.reached_mm for p in ps]) for ps in by_pose]
    noise_var = np.mean([n.random_mm**2 for n in noises.values()], axis=0)
    scatter = robot_scatter(attained_mm, noise_var)
    chol = np.linalg.cholesky(scatter + 1e-18 * np.eye(3))
    # the run's common errors: the sound speed, the tool check's edges and the one visit of
    # the pose its scans start from, whose scatter the tool check carries to every pose
    common = np.sqrt(
        np.mean([n.common_mm**2 for n in noises.values()], axis=0)
        + np.r_[np.diag(scatter)[:2] + noise_var[:2], 0.0]
    )
    delta = rng.standard_normal((BOOTSTRAP_DRAWS, 3)) * common
    share_mm, share_deg = table_share(profile, plan) if share is None else share
    poses = []
    for i, name in enumerate(POSE_NAMES):
        attained = by_pose[i]
        x = attained_mm[i]
        c = plan.nominal_mm[i]
        n = len(x)
        rnd = np.array([noises[id(p)].random_mm for p in attained])
        tilt = np.array([noises[id(p)].orientation_deg for p in attained])
        abc = np.array([orientation_deviation_deg(profile, p, commanded_rot) for p in attained])
        fig = standard_figures(x, c)
        ori = orientation_figures(abc)
        # the bootstrap: the robot's scatter about its mean, each pose's noise, the common
        # errors; each figure against the robot's own (noise-free, mean as measured)
        r = rng.standard_normal((BOOTSTRAP_DRAWS, n, 3)) @ chol.T
        eps = rng.standard_normal((BOOTSTRAP_DRAWS, n, 3)) * rnd
        wrist = unseen_wrist_scatter(profile, attained[0].commanded_deg, scatter)
        w_vals, w_vec = np.linalg.eigh(wrist)
        # a nuisance carried with its prior: the wrist's joints scatter by 0 to
        # WRIST_SCATTER_MAX times the arm's angle, drawn anew in each draw
        k = rng.uniform(0.0, WRIST_SCATTER_MAX, (BOOTSTRAP_DRAWS, 1, 1))
        unseen = k * (
            rng.standard_normal((BOOTSTRAP_DRAWS, n, 3))
            @ (w_vec * np.sqrt(np.clip(w_vals, 0.0, None))).T
        )
        mean = x.mean(axis=0)
        robot = standard_figures(mean + r + unseen, c)
        table = rng.standard_normal((BOOTSTRAP_DRAWS, 3)) * share_mm[i]
        seen = standard_figures(mean + r + eps + (delta + table)[:, None, :], c)
        ap_true = float(np.linalg.norm(mean - c))
        ap_xyz_std = np.sqrt(np.mean((seen["ap_xyz"] - (mean - c)) ** 2, axis=0))
        ap_std = float(np.sqrt(np.mean((seen["ap"] - ap_true) ** 2)))
        # against the robot's expected RP over n cycles: the sampling of so few is in it
        rp_std = float(np.sqrt(np.mean((seen["rp"] - np.mean(robot["rp"])) ** 2)))
        s_abc = abc.std(axis=0, ddof=1)
        abc_noise = float(np.sqrt(np.mean(tilt**2)))
        # the beam's direction is measured against the block's faces themselves (the gauge):
        # its noise and the arm's scatter, which the cycles average, ...
        # and the model's carrying it from the faces' postures to the commanded one
        ap_abc_std = np.sqrt((s_abc**2 + abc_noise**2) / n + share_deg[i] ** 2)
        rp_abc_std = 3.0 * np.hypot(s_abc / np.sqrt(2.0 * (n - 1)), abc_noise)
        # the beam straight down: c turns the tool about it, which changes no echo (the run
        # holds joint 6 at the profile's offset, the frame the tool was measured in)
        for arr in (ori["ap_abc"], ori["rp_abc"], ap_abc_std, rp_abc_std):
            arr[2] = np.nan
        poses.append(
            IsoPose(
                name,
                c,
                x,
                mean,
                fig["ap_xyz"],
                ap_xyz_std,
                float(fig["ap"]),
                ap_std,
                float(fig["l_mean"]),
                float(fig["s_l"]),
                float(fig["rp"]),
                rp_std,
                ori["ap_abc"],
                ap_abc_std,
                ori["rp_abc"],
                rp_abc_std,
            )
        )
    notes = [
        "APc and RPc not determined: c turns the tool about the beam (straight down), which "
        "changes no echo"
    ]
    if plan.iso.cycles < ISO_CYCLES:
        notes.append(
            f"{plan.iso.cycles} cycles where ISO 9283 asks for {ISO_CYCLES}: RP's std holds the "
            "sampling of so few"
        )
    return Iso9283(plan.iso, tuple(poses), notes=tuple(notes))


def iso_summary(plan: VerifyPlan, profile_path: Path) -> str:
    """The ISO 9283 plan in words for the confirmation (stderr)."""
    assert plan.iso is not None
    cube = plan.iso
    group = plan.groups[0]
    lines = [
        f"verify {profile_path} --iso9283: the five poses of ISO 9283 in a {cube.side_mm:.0f} mm "
        f"cube centred {np.round(cube.centre_mm, 1).tolist()} mm (block), {group.description}, "
        f"visited {cube.cycles} times (P1, P5, P4, P3, P2), 3 face searches per pose "
        f"({3 * len(plan.targets)} in all):"
    ]
    lines += [
        f"  {name}: block {np.round(p, 1).tolist()} mm"
        for name, p in zip(POSE_NAMES, plan.nominal_mm, strict=True)
    ]
    lines.append("then a tool check across the XY face's two far edges, straight down.")
    return "\n".join(lines)
