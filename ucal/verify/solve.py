"""Verify's reconstruction (pure functions): the wrist centre from three water paths, the
flange's true orientation from three normal-incidence postures, the reached TCP, the tool's
error from the edge scans, the map that carries W and the flange's turn from the points to the
edges, and the statistics of paper 000, Table 5.

At normal incidence ``d_k = n_k·(W − c) − a_T·v`` (``ucal.model.geometry``, eq. 2), so the
three water paths give ``W_k = d_k + a_T·v`` in block coordinates; the flange rotation is
``R(q) = Exp(ω)·R06(q, δ + (0, 0, 0, 0, ε5, 0))``, the reached TCP ``T̂ = W + R(q_cmd)·v``, and
the real one ``T̂ + κ·(1, 1, 1) + R·(Δ⊥ + κ·a_T)`` (``ToolOffset.bias``). The derivation:
docs/method/commissioning.md.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from ucal.cell import CellProfile
from ucal.kinematics.dh import RobotModel, fk_frames
from ucal.kinematics.rotations import tangent_basis
from ucal.model.geometry import (
    CellGeometry,
    beam_and_tcp,
)
from ucal.model.safety import TOLERANCE_SIGMAS, beam_on_flange_axis, offsets_std_deg
from ucal.model.targets import geometry, tool_lever
from ucal.model.wrist import aim_wrist
from ucal.verify.plan import VerifyPlan, VerifyTarget


def wrist_centre_from_distances(distances_mm: np.ndarray, lever_mm: float) -> np.ndarray:
    """W in block coordinates (mm) from the normal-incidence water paths to faces 0, 1, 2.

    ``d_k = n_k·(W − c) − a_T·v`` (``ucal.model.geometry``, eq. 2) → ``W_k = d_k + a_T·v``.
    """
    return np.asarray(distances_mm, float) + float(lever_mm)


@dataclass(frozen=True)
class WristOrientation:
    """True flange orientation at a fixed arm: ``R(q) = Exp(ω)·R06(q, offsets_deg)``."""

    correction: np.ndarray  # (3, 3) Exp(ω), base frame
    offsets_deg: np.ndarray  # (6,) model offsets incl. the fitted wrist residuals
    rms_deg: float  # residual beam misfit (deg)

    def rotation(self, geom: CellGeometry, joints_deg: np.ndarray) -> np.ndarray:
        """True flange rotation (3, 3) at readings with this arm."""
        r06 = fk_frames(geom.model, joints_deg, self.offsets_deg)[6, :3, :3]
        return np.asarray(self.correction @ r06)


def estimate_orientation(
    geom: CellGeometry, peak_joints_deg: np.ndarray, offsets_deg: np.ndarray
) -> WristOrientation:
    """Fit ω (rad) and the joint-5 residual (deg) to three normal-incidence postures.

    ``peak_joints_deg`` (3, 6): the postures at which the true beam is −n_k, k = 0, 1, 2 (same
    arm joints). Joint 6 is held at ``offsets_deg``: the profile's J6 offset is the frame its
    tool was measured in (J6 and the tool's azimuth are one rotation with the beam near the J6
    axis). Fitted at every point from a beam 1–2° off that axis, it picked up the peaks' noise
    (±0.6°, 0.05 mm at the TCP with a tool 1.7 mm off the flange axis).
    """
    q = np.asarray(peak_joints_deg, float)
    base = np.asarray(offsets_deg, float)
    a_t = geom.beam_flange
    normals = np.array([geom.normal(k) for k in range(3)])

    def model(x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        off = base.copy()
        off[4] += x[3]
        corr = Rotation.from_rotvec(x[:3]).as_matrix()
        r06 = fk_frames(geom.model, q, off)[:, 6, :3, :3]
        return corr, off, (corr @ r06 @ a_t)

    def fun(x: np.ndarray) -> np.ndarray:
        _, _, beams = model(x)
        return np.asarray((beams + normals).ravel())

    sol = least_squares(
        fun, np.zeros(4), method="lm", xtol=1e-15, ftol=1e-15, gtol=1e-15, max_nfev=2000
    )
    corr, off, beams = model(sol.x)
    rms = float(np.degrees(np.sqrt(np.mean(np.sum((beams + normals) ** 2, axis=1)))))
    return WristOrientation(corr, off, rms)


def reached_tcp_local(
    geom: CellGeometry,
    w_local_mm: np.ndarray,
    orientation: WristOrientation,
    commanded_deg: np.ndarray,
    v_flange_mm: np.ndarray,
) -> np.ndarray:
    """Reached TCP at the commanded posture in block coordinates (mm): W + R(q_cmd)·v."""
    r = orientation.rotation(geom, commanded_deg)
    return np.asarray(np.asarray(w_local_mm, float) + geom.block_rotation.T @ (r @ v_flange_mm))


def reached_from_peaks(
    profile: CellProfile,
    geom: CellGeometry,
    peak_joints_deg: np.ndarray,
    distances_mm: np.ndarray,
    commanded_deg: np.ndarray,
) -> tuple[np.ndarray, WristOrientation, np.ndarray]:
    """W, the true flange orientation and the reached TCP (block coordinates, mm) of one point
    from its three normal-incidence postures (3, 6) and water paths (3,), with the profile's tool.

    The orientation is fitted about the profile's own offsets: its J6 offset is the frame the
    tool was measured in (``tool-frame``), so the tool's lever across the beam turns with the
    flange as the profile says. A running estimate of J6 (unobservable with the beam near its
    axis: it wanders by tens of degrees) would turn that lever with it — 1.5 mm at the TCP for
    a tool 1.7 mm off the flange axis turned 140°.
    """
    v, lever = tool_lever(profile)
    w_local = wrist_centre_from_distances(distances_mm, lever)
    orient = estimate_orientation(geom, peak_joints_deg, profile.joint_offsets_deg)
    return w_local, orient, reached_tcp_local(geom, w_local, orient, commanded_deg, v)


def exact_reconstruction(
    profile: CellProfile,
    geom: CellGeometry,
    true: CellGeometry,
    target: VerifyTarget,
    offsets_deg: np.ndarray,
) -> tuple[WristOrientation, np.ndarray, np.ndarray]:
    """What verify reconstructs of one planned point on the robot ``true`` (its geometry:
    another table where the profile says its own): exact echoes at that robot's three
    normal-incidence postures and water paths, reconstructed with the profile's ``geom``
    (``reached_from_peaks``). Returns the flange orientation found, the reconstructed TCP and
    the robot's real one (block coordinates, mm), before the tool check."""
    s_mat = profile.sample_matrix
    peaks = np.array(
        [aim_wrist(true, target.face_joints_deg[k], -true.normal(k), offsets_deg) for k in range(3)]
    )
    paths = np.array(
        [
            true.normal(k) @ (beam_and_tcp(true, peaks[k], offsets_deg)[1] - s_mat[:3, 3])
            for k in range(3)
        ]
    )
    _, orient, got = reached_from_peaks(profile, geom, peaks, paths, target.joints_deg)
    tcp = beam_and_tcp(true, target.joints_deg, offsets_deg)[1]
    return orient, got, s_mat[:3, :3].T @ (tcp - s_mat[:3, 3])


def reconstruction_error_mm(
    profile: CellProfile, true_model: RobotModel, plan: VerifyPlan
) -> np.ndarray:
    """How far verify's reconstruction puts each "after" point of ``plan`` from where the robot
    really is (n, 3; block coordinates, mm) when its kinematics are ``true_model`` where the
    profile says its own (``exact_reconstruction``), before the tool check."""
    geom = geometry(profile)
    true = replace(geom, model=true_model)
    offsets = plan.offsets_deg["after"]
    errors = []
    for target in (t for t in plan.targets if t.pass_name == "after"):
        _, got, real = exact_reconstruction(profile, geom, true, target, offsets)
        errors.append(got - real)
    return np.array(errors).reshape(-1, 3)


def unidentified_at_points_mm(
    profile: CellProfile, plan: VerifyPlan, names: tuple[str, ...]
) -> float:
    """One sigma (mm) of what the table's lengths ``names`` ("d5", "a5": ``d`` or ``a`` and the
    row), left at [robot] ``dh_length_std_mm`` by the full level, move verify's reconstructed
    points off the real ones: each moved by one sigma (``reconstruction_error_mm``), their
    shares added in quadrature per axis, the largest over the plan's "after" points and the
    axes. Where the region's figure (``unidentified_tcp_mm``, the largest over 100 postures
    about the calibration pose) is what the robot's tool centre may be off anywhere it scans,
    this is what verify's own points are off by."""
    sigma = float(profile.dh_length_std_mm)
    variance = np.zeros(1)
    for name in names:
        dh = profile.model.dh.copy()
        dh[int(name[1:]) - 1, 1 + "da".index(name[0])] += sigma
        moved = replace(profile.model, dh=dh)
        variance = variance + reconstruction_error_mm(profile, moved, plan) ** 2
    return float(np.sqrt(np.max(variance)))


#: The statistics of ``deviation_stats``, in its order.
STATISTICS = ("mean", "max", "std", "signed_mean", "signed_std")


def deviation_stats(deviations_mm: np.ndarray) -> dict[str, list[float]]:
    """Per-axis statistics (paper 000, Table 5) of deviations (n, 3) mm.

    ``mean``, ``max``, ``std``: of the absolute deviations (std with ddof = 0); ``signed_mean``
    and ``signed_std``: of the signed deviations (bias and scatter). NaN for a pass with no
    point measured (every "before" point skipped: offsets before calibration far off).
    """
    d = np.asarray(deviations_mm, float).reshape(-1, 3)
    if not len(d):
        return {k: [float("nan")] * 3 for k in STATISTICS}
    a = np.abs(d)
    return {
        "mean": a.mean(0).tolist(),
        "max": a.max(0).tolist(),
        "std": a.std(0).tolist(),
        "signed_mean": d.mean(0).tolist(),
        "signed_std": d.std(0).tolist(),
    }


def passed(after_stats: dict[str, list[float]], tolerance_mm: float) -> bool:
    """True when no point of the "after" pass deviates more than ``tolerance_mm`` on any axis."""
    return bool(np.max(after_stats["max"]) <= tolerance_mm)


@dataclass(frozen=True)
class EdgeCheck:
    """One edge scan of the tool check (``ucal.verify.measure``): where the real TCP crosses
    x = S (y = S)."""

    axis: int  # 0: block X, 1: block Y
    point: int  # 0-based "after" point the scan started from
    edge_mm: float  # S: the far edge's coordinate
    crossing_mm: float  # t_e: the wrist-centre estimate of the TCP there
    crossing_std_mm: float  # one sigma of t_e from the edge-profile fit
    probes: int  # probes of the scan (coarse and fine)

    @property
    def offset_mm(self) -> float:
        """b: real minus estimated TCP coordinate on this axis (mm)."""
        return self.edge_mm - self.crossing_mm


def tool_offset(checks: tuple[EdgeCheck, ...]) -> np.ndarray:
    """The bias b (3,) of the down points' scans (block axes, mm): what the tool check adds
    to every wrist-centre estimate of a point commanded straight down."""
    b = np.zeros(3)
    for c in checks[:2]:
        b[c.axis] = c.offset_mm
    return b


@dataclass(frozen=True)
class ToolOffset:
    """The real tool against the profile's, as the edge scans see it
    (docs/method/commissioning.md): κ, what the water paths took for the TCP's reach along the
    beam too little, and Δ⊥, the tool's error across the beam (flange frame, mm)."""

    along_mm: float  # κ = a_T'·v' − a_T·v
    across_mm: np.ndarray  # (3,) Δ⊥, flange frame, orthogonal to the profile's beam
    beam_flange: np.ndarray  # (3,) the profile's beam a_T, flange frame
    separated: bool  # scans in both senses about the beam: κ and Δ⊥ apart
    #: the largest misfit of a scan to κ and Δ⊥ (mm; 0 with three scans or fewer): four
    #: scans hold one check. The model takes the profile's beam direction as the real one;
    #: a beam a few tenths of a degree off it (a tool not yet measured) turns the flange
    #: orientation the postures give by as much, differently in each sense about the beam,
    #: and shows here as the misfit (docs/method/commissioning.md).
    misfit_mm: float = 0.0

    def bias(self, flange_local: np.ndarray) -> np.ndarray:
        """Real minus estimated TCP (block coordinates, mm) of a point whose flange is turned
        ``flange_local`` (flange → block): ``κ·(1, 1, 1) + R·(Δ⊥ + κ·a_T)``."""
        delta = self.across_mm + self.along_mm * self.beam_flange
        return self.along_mm * np.ones(3) + np.asarray(flange_local, float) @ delta


def solve_tool_offset(
    checks: tuple[EdgeCheck, ...], flange_local: list[np.ndarray], beam_flange: np.ndarray
) -> ToolOffset:
    """κ and Δ⊥ from the edge scans (each b = S − t_e on its axis) and the flange's turn at
    each scan's point: least squares over ``b = [κ·(1, 1, 1) + R·(Δ⊥ + κ·a_T)]_axis``. With the
    down scans alone (one sense about the beam) κ and Δ⊥ are one quantity: the least-norm
    split, exact for the down points, is kept and said (``separated`` False)."""
    a_t = np.asarray(beam_flange, float)
    basis = tangent_basis(a_t)
    rows = np.array(
        [
            [1.0 + (r @ a_t)[c.axis], (r @ basis[0])[c.axis], (r @ basis[1])[c.axis]]
            for c, r in zip(checks, flange_local, strict=True)
        ]
    )
    b = np.array([c.offset_mm for c in checks])
    x, _, rank, _ = np.linalg.lstsq(rows, b, rcond=None)
    misfit = float(np.max(np.abs(rows @ x - b)))
    return ToolOffset(float(x[0]), x[1] * basis[0] + x[2] * basis[1], a_t, bool(rank == 3), misfit)


#: ``WristMap.fit``: the misfit (mm) a degree of an offset correction beyond its bound costs.
BOUND_WEIGHT = 10.0


@dataclass(frozen=True)
class WristMap:
    """Where the wrist centre really is at given readings (block coordinates, mm), and how the
    flange is really turned (base frame): the profile's kinematics with corrections to the
    offsets of joints 1–3, a small turn and shift of the block, and a constant turn of the
    flange (what the block's turn does to the faces' normals, and joint 1), fitted to the W and
    the flange rotations measured at the "after" points. It carries both from the points to
    the edge scans 100–200 mm away: what the profile still has wrong in the arm (joint 1
    unobservable with a hand-placed block, a joint left uncalibrated: degrees, tens of mm at
    the TCP) changes along the way, which moving W with the profile alone, or with one rigid
    motion, misses by tenths of a mm. W alone hardly separates a joint-2 error from a turn of
    the block (a rigid motion at each joint 1); the rotations do, as the axis of joints 2 and 3
    turns with joint 1: on a profile with J1 and J2 left 1.8° and 1.6° off, the flange's turn
    carried with W alone missed the real TCP at the edge by 0.16 mm, 0.06 mm with both."""

    model: RobotModel
    offsets_deg: np.ndarray  # (6,) the profile's offsets with the fitted corrections on J1–J3
    to_block: np.ndarray  # (3, 3) base frame → block coordinates
    origin_mm: np.ndarray  # (3,) block coordinates of the base origin
    turn: np.ndarray = field(default_factory=lambda: np.eye(3))  # (3, 3) true = turn · model

    @classmethod
    def fit(
        cls,
        profile: CellProfile,
        joints_deg: np.ndarray,
        measured_mm: np.ndarray,
        offsets_deg: np.ndarray,
        rotations: np.ndarray | None = None,
    ) -> WristMap:
        """Least squares over the points (readings (n, 6), measured W (n, 3), true flange
        rotations (n, 3, 3) in the base frame, if given; their misfit weighed as the TCP
        moves, times the tool's reach). Where the points do not separate an offset correction
        from a turn of the block (one or two points, or joint 1 against the block's yaw), a
        weak prior prefers the offsets: both carry W the same way where they are one
        motion. No correction goes beyond ``TOLERANCE_SIGMAS`` of what the profile knows of
        that offset (``offsets_std_deg``): a few points nearly in line along joint 2's axis
        leave a turn about it free, and a wrist offset the map does not model (one calibrate
        left undetermined) then drove joint 2's correction to tens of degrees, the scans' ends
        beyond the arm's reach."""
        s_mat = profile.sample_matrix
        q = np.asarray(joints_deg, float).reshape(-1, 6)
        measured = np.asarray(measured_mm, float).reshape(-1, 3)
        base = np.asarray(offsets_deg, float)
        reach = float(np.linalg.norm(tool_lever(profile)[0]))
        bound = TOLERANCE_SIGMAS * offsets_std_deg(profile)
        std = profile.joint_offsets_std_deg
        # the wrist offsets the last calibration left undetermined turn the flange: fitted
        # too where the rotations are measured (else the arm's corrections absorb them);
        # joint 6 not with the beam on its axis (where it turns the beam's footprint alone)
        free = np.zeros(3)
        if std is not None and rotations is not None:
            free = (~(np.asarray(std, float)[3:] > 0)).astype(float)
            if beam_on_flange_axis(profile):
                free[2] = 0.0

        def build(x: np.ndarray) -> WristMap:
            off = base.copy()
            off[:3] += x[:3]
            off[3:] += free * x[12:] if len(x) > 12 else 0.0
            rot = Rotation.from_rotvec(x[3:6]).as_matrix() @ s_mat[:3, :3].T
            turn = Rotation.from_rotvec(x[9:12]).as_matrix()
            return cls(profile.model, off, rot, x[6:9] - rot @ s_mat[:3, 3], turn)

        def fun(x: np.ndarray) -> np.ndarray:
            m = build(x)
            corrections = np.concatenate([x[:3], free * x[12:]]) if len(x) > 12 else x[:3]
            beyond = np.maximum(np.abs(corrections) - bound[: len(corrections)], 0.0)
            res = [
                (m(q) - measured).ravel(),
                1e-4 * corrections,
                BOUND_WEIGHT * beyond,
                (1 - free) * x[12:] if len(x) > 12 else np.zeros(0),
                0.1 * x[3:6],
            ]
            if rotations is not None:
                miss = np.swapaxes(m.rotation(q), -1, -2) @ rotations
                res.append(reach * Rotation.from_matrix(miss).as_rotvec().ravel())
            else:
                res.append(x[9:12])
            return np.concatenate(res)

        x0 = np.zeros(15 if free.any() else 12)
        x0[6:9] = (measured - build(x0)(q)).mean(0)
        sol = least_squares(fun, x0, method="lm", xtol=1e-15, ftol=1e-15, gtol=1e-15)
        return build(sol.x)

    def __call__(self, joints_deg: np.ndarray) -> np.ndarray:
        """W (block coordinates, mm) at readings (6,) or (n, 6)."""
        w = fk_frames(self.model, np.asarray(joints_deg, float), self.offsets_deg)[..., 4, :3, 3]
        return np.asarray(w @ self.to_block.T + self.origin_mm)

    def rotation(self, joints_deg: np.ndarray) -> np.ndarray:
        """The true flange rotation (base frame) at readings (6,) or (n, 6)."""
        frames = fk_frames(self.model, np.asarray(joints_deg, float), self.offsets_deg)
        return np.asarray(self.turn @ frames[..., 6, :3, :3])
