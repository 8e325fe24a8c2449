"""How far verify's measurement of a reached point may be from where the robot really is, per
block axis: what verify's ``measurement_std_mm``, its "marginal" and ISO 9283's figures rest on.

Three shares, independent:

* the point's own (``PointNoise.random_mm``): face k's water path gives the wrist centre W
  along block axis k (its normal), so its noise falls on that axis; the orientation its three
  peaks give (their ``tilt_std_deg``) moves the tool centre by the tool's lever across it;
* the run's common ones (``PointNoise.common_mm``): the sound speed on every water path (one
  sigma of a path of its length), the tool check's edge crossings on X and Y (with the beam
  straight down the check sees the tool across the beam, and the lever's length along it
  cancels in Z), and, for points in an orientation the check does not scan (the tilted ones),
  the beam's direction in the flange as the profile knows it (``[tool] rotation_std_deg``):
  the peaks tilt with it and carry W across the beam by the lever (0.3° puts a point 0.4 mm
  off); and the pulser's electronic delay, not measured
  (0 ± 50 ns: c·delay/2 on every path, which the tool check takes out of X and Y, not of Z;
  an ISO run's positions are the tool centre as time of flight sees it, delay included);
* the DH table's (``table_share``): the table within its sigmas makes true robots whose exact
  echoes, reconstructed with the profile's table, put each point and its orientation off by
  so much, less what the tool check's edges take out of X and Y.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np
from scipy.spatial.transform import Rotation

from ucal.acoustics import sound_speed_m_s
from ucal.cell import CellProfile
from ucal.errors import SafetyError
from ucal.kinematics.dh import fk_frames
from ucal.model.geometry import CellGeometry, beam_and_tcp
from ucal.model.priors import DELAY_PRIOR_STD_NS
from ucal.model.targets import geometry, tool_lever
from ucal.verify.measure import PointResult, VerifyResult
from ucal.verify.plan import VerifyPlan, joints_for, target_matrix
from ucal.verify.solve import exact_reconstruction


@dataclass(frozen=True)
class PointNoise:
    """One sigma of one attained pose's measurement (block X, Y, Z): ``random_mm`` its own (the
    water paths' noise, the orientation its peaks give times the tool's lever), ``common_mm``
    what it shares with every pose of the run (the sound speed, the tool check's edges);
    ``orientation_deg`` its orientation's (about each block axis)."""

    random_mm: np.ndarray
    common_mm: np.ndarray
    orientation_deg: float

    @property
    def total_mm(self) -> np.ndarray:
        return np.asarray(np.hypot(self.random_mm, self.common_mm))


def point_noise(
    profile: CellProfile,
    point: PointResult,
    result: VerifyResult,
    path_std_mm: Callable[[float], float],
    delay: bool = True,
) -> PointNoise:
    """How far the measurement of ``point`` may be from the pose the robot attained, one
    sigma per block axis (``PointNoise``). ``path_std_mm(path)``: one sigma of a water path
    of that length from the sound speed (mm).

    Face k's water path gives W along block axis k (its normal), so its noise and the sound
    speed's share of it fall on that axis; the orientation's, from the three peaks' tilt
    (``tilt_std_deg``), moves the tool centre by the lever |v| across it; the tool check's
    edges carry their crossings' std onto X and Y (with the beam straight down they see the
    tool across the beam, and the lever's length along it cancels in Z)."""
    v, _ = tool_lever(profile)
    lever = float(np.linalg.norm(v))
    tilt = np.array([m.tilt_std_deg for m in point.faces], float)
    tilt_deg = float(np.sqrt(np.mean(tilt**2))) if len(tilt) else 0.0
    paths = np.array([m.distance_std_mm for m in point.faces], float)
    random_mm = np.hypot(paths, lever * np.radians(tilt_deg))
    common = np.array([path_std_mm(m.distance_mm) for m in point.faces], float)
    if delay:
        # the pulser's electronic delay, unmeasured (0 ± DELAY_PRIOR_STD_NS): every water
        # path longer by c·delay/2; the tool check takes it out of X and Y, not of Z
        c_mm_per_ns = float(sound_speed_m_s(profile.water_temperature_c)) * 1e-6
        common[2] = np.hypot(common[2], 0.5 * c_mm_per_ns * DELAY_PRIOR_STD_NS)
    # the beam's direction in the flange as the profile has it (tool-frame's std, else the
    # drawing's tolerance): the peaks tilt with it and carry W across the beam by the lever;
    # the tool check's edges, scanned with the tool turned as a group's points have it, see
    # that too: only a group without scans of its own (the tilted points) keeps it
    plan = result.plan
    group_of = plan.group_of or (0,) * plan.points
    scanned = {group_of[i] for _, i in plan.edge_points}
    beam_deg = (
        0.0
        if group_of[point.index] in scanned
        else float(np.sqrt(np.mean(np.square(profile.tool_rotation_std_deg[:2]))))
    )
    for axis in (0, 1):
        stds = [c.crossing_std_mm for c in result.edge_checks if c.axis == axis]
        crossing = float(np.sqrt(np.mean(np.square(stds)))) if stds else 0.0
        common[axis] = np.sqrt(
            common[axis] ** 2 + crossing**2 + (lever * np.radians(beam_deg)) ** 2
        )
    return PointNoise(random_mm, common, tilt_deg)


def measurement_std_mm(stds_mm: np.ndarray) -> list[float] | None:
    """One sigma of an "after" point's measurement per block axis (mm): the rms over the
    points of ``point_stds_mm``; ``measurement_std_mm`` of ``verify --json``."""
    if not len(stds_mm):
        return None
    rms: list[float] = np.sqrt(np.mean(np.asarray(stds_mm) ** 2, axis=0)).tolist()
    return rms


def table_sigmas(profile: CellProfile) -> list[tuple[int, int, float]]:
    """The DH table's quantities a reconstruction leans on and one sigma of each: (row, column
    of the table: 1 d, 2 a, 3 alpha, sigma in mm or deg): ``[calibration] dh_std`` where the full
    level identified it (its undetermined ones at the tolerance), else [robot]
    ``dh_length_std_mm`` on every length the model does not hold at zero and
    ``dh_angle_std_deg`` on every twist."""
    dh = profile.model.dh
    out = []
    for row in range(6):
        for col in (1, 2, 3):
            tol = profile.dh_angle_std_deg if col == 3 else profile.dh_length_std_mm
            if col != 3 and dh[row, col] == 0.0 and profile.dh_std is None:
                continue
            sigma = tol if profile.dh_std is None else float(profile.dh_std[row, col - 1])
            out.append((row, col, float(tol if not np.isfinite(sigma) or sigma < 0 else sigma)))
    return out


def table_share(profile: CellProfile, plan: VerifyPlan) -> tuple[np.ndarray, np.ndarray]:
    """What the DH table within its sigmas (``table_sigmas``) moves each "after" point's
    measurement by, one sigma per block axis: position (n, 3; mm) and orientation (n, 3; deg),
    by point number (an ISO run's five poses).

    Each quantity moved by one sigma makes a true robot: its exact echoes at the pose's three
    normal-incidence postures, reconstructed with the profile's table
    (``ucal.verify.solve.reached_from_peaks``), give the pose and the flange's orientation at
    the commanded readings; against that robot's own, the error, less what the tool check
    takes out (X and Y as its edge scans' start poses have them); the shares add in
    quadrature. The tool check takes out of X and Y the error of the pose its scan starts
    from, and puts in how differently from the profile's table the true one carries the tool
    from there to the edge it crosses: a point takes its own group's scans (the tool turned
    as the point has it), a group without scans (the tilted points) their mean."""
    geom = geometry(profile)
    off = plan.offsets_deg["after"]
    s_mat = profile.sample_matrix
    first = {t.index: t for t in reversed(plan.targets) if t.pass_name == "after"}
    poses = [first[i] for i in sorted(first)]
    group_of = plan.group_of or (0,) * plan.points
    # where each edge scan of the tool check crosses its edge, and the pose it starts from
    scans = []
    for axis, index in plan.edge_points:
        q_start = first[index].joints_deg
        at = plan.nominal_mm[index].copy()
        at[axis] = profile.sample_face_size_mm
        pose = target_matrix(profile, at, plan.rotation_local(index))
        try:
            q_edge = joints_for(profile, pose, off, q_start, "the tool check's edge")
        except SafetyError:  # the plan checked the scan's ends; the edge itself may lie
            q_edge = q_start  # outside a wrist margin: its carrying then left out
        scans.append((axis, index, q_start, q_edge))
    var_p = np.zeros((len(poses), 3))
    var_o = np.zeros((len(poses), 3))

    def tcp_local(g: CellGeometry, q: np.ndarray) -> np.ndarray:
        return np.asarray(s_mat[:3, :3].T @ (beam_and_tcp(g, q, off)[1] - s_mat[:3, 3]))

    for row, col, sigma in table_sigmas(profile):
        dh = profile.model.dh.copy()
        dh[row, col] += sigma
        true = replace(geom, model=replace(profile.model, dh=dh))
        err_p, err_o = [], []
        for t in poses:
            orient, got, real = exact_reconstruction(profile, geom, true, t, off)
            err_p.append(got - real)
            r_true = fk_frames(true.model, t.joints_deg, off)[6, :3, :3]
            turn = orient.rotation(geom, t.joints_deg) @ r_true.T
            err_o.append(s_mat[:3, :3].T @ Rotation.from_matrix(turn).as_rotvec(degrees=True))
        e = np.array(err_p)
        point = {t.index: k for k, t in enumerate(poses)}
        fix: dict[tuple[int, int], list[float]] = {}
        for axis, index, q_start, q_edge in scans:
            # the check's correction: how differently from the profile's table the true one
            # carries the tool from the scan's start point to the edge, less that point's error
            carried = (tcp_local(true, q_edge) - tcp_local(true, q_start)) - (
                tcp_local(geom, q_edge) - tcp_local(geom, q_start)
            )
            fix.setdefault((group_of[index], axis), []).append(
                float(carried[axis] - e[point[index], axis])
            )
        every = {a: [v for (_, b), vs in fix.items() if b == a for v in vs] for a in (0, 1)}
        for k, t in enumerate(poses):
            for axis in (0, 1):
                used = fix.get((group_of[t.index], axis)) or every[axis]
                if used:
                    e[k, axis] += float(np.mean(used))
        var_p += e**2
        var_o += np.array(err_o) ** 2
    return np.sqrt(var_p), np.sqrt(var_o)


def point_stds_mm(
    profile: CellProfile,
    result: VerifyResult,
    path_std_mm: Callable[[float], float],
    share_mm: np.ndarray | None = None,
) -> np.ndarray:
    """One sigma per block axis (n, 3; mm) of each measured "after" point (by point number,
    ``result.measured("after")``'s order): its own and the run's common shares with the DH
    table's (``share_mm``, by point number; computed when None) in quadrature."""
    share = table_share(profile, result.plan)[0] if share_mm is None else share_mm
    points = result.measured("after")
    own = np.array([point_noise(profile, p, result, path_std_mm).total_mm for p in points])
    return np.asarray(np.sqrt(own.reshape(-1, 3) ** 2 + share[[p.index for p in points]] ** 2))
