"""Verify's measurement: every planned point of both passes, then the tool check.

At each commanded point the arm (joints 1–3) stays still and the wrist turns the beam onto each
of the three faces in turn (arm–wrist separation, paper 000 §4.2); each face's normal-incidence
posture is searched (``ucal.measure.face.measure``) and its water path read. Every face
measurement enters the running estimate of ``ucal.measure.running`` (calibrate's, with its
trust policy), so the correction found at one point predicts the next: only the first faces
need a wide search. Every posture, the face searches' and the tool check's probes, is reached
from below on every joint (``FinalApproachRig``), as in the calibration. The tool check then
moves the profile's TCP across the XY face's two far edges with the beam normal to it
(``scan_edge``): where the echo falls to half, the real TCP is on the edge.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from ucal.cell import CellProfile
from ucal.devices.rig import Rig
from ucal.errors import HardwareError, SafetyError
from ucal.kinematics.dh import fk_frames
from ucal.measure.edges import EDGES, coarse_edge_fall, fine_edge_scan
from ucal.measure.running import RunningEstimate, read_path_at
from ucal.model.geometry import (
    FACE_NAMES,
    FACE_ORDER,
    CellGeometry,
    Face,
    FaceMeasurement,
    face_basis,
)
from ucal.model.safety import (
    MIN_WATER_PATH_MM,
)
from ucal.model.targets import geometry, tool_lever
from ucal.model.wrist import search_joints
from ucal.progress import MeasureStep, Report
from ucal.verify.plan import (
    EDGE_OVERSHOOT_MM,
    PASSES,
    VerifyPlan,
    edge_label,
    joints_for,
    target_matrix,
    tool_clearance_mm,
    wrist_centre_local,
)
from ucal.verify.solve import (
    EdgeCheck,
    ToolOffset,
    WristMap,
    WristOrientation,
    deviation_stats,
    passed,
    reached_from_peaks,
    solve_tool_offset,
    tool_offset,
)
from ucal.verify.tank import TankEstimate, start_speed

log = logging.getLogger(__name__)

#: Tool check: the coarse search starts this far before the edge the profile predicts (mm).
EDGE_APPROACH_MM = 12.0


@dataclass(frozen=True)
class PointResult:
    """What one commanded point of one pass measured."""

    pass_name: str
    index: int
    nominal_mm: np.ndarray  # (3,) block coordinates
    commanded_deg: np.ndarray  # (6,)
    faces: tuple[FaceMeasurement, ...]  # by face 0, 1, 2
    wrist_centre_mm: np.ndarray  # (3,) block coordinates
    reached_mm: np.ndarray  # (3,) reached TCP, block coordinates
    orientation_rms_deg: float
    #: the flange's measured orientation at the commanded posture (flange → block coordinates)
    flange_local: np.ndarray = field(default_factory=lambda: np.eye(3))

    @property
    def deviation_mm(self) -> np.ndarray:
        return np.asarray(self.reached_mm - self.nominal_mm)


@dataclass(frozen=True)
class SkippedPoint:
    """A "before" point not moved to: the profile's current offsets, or the measured points of
    its pass, put the tool closer to a face there than ``MIN_WATER_PATH_MM`` (the offsets before
    calibration are that far off)."""

    pass_name: str
    index: int
    clearance_mm: float  # the tool's predicted least water path to a face there
    said_by: str = "the points measured before it"

    def reason(self) -> str:
        return (
            f"{self.pass_name} point {self.index + 1} not measured: the tool would come "
            f"{self.clearance_mm:.1f} mm from a face there ({self.said_by} say), less than "
            f"the {MIN_WATER_PATH_MM:g} mm kept"
        )


def predicted_clearance_mm(
    profile: CellProfile, previous: PointResult, joints_deg: np.ndarray, offsets_deg: np.ndarray
) -> float:
    """The tool's least water path to a face at readings ``joints_deg`` (mm): the previous
    point's measured W moved by the profile's displacement of W between the two postures (a
    few mm of arm motion: what the offsets still have wrong changes it by hundredths)."""
    w = previous.wrist_centre_mm + (
        wrist_centre_local(profile, joints_deg, offsets_deg)
        - wrist_centre_local(profile, previous.commanded_deg, offsets_deg)
    )
    return tool_clearance_mm(profile, w)


@dataclass
class VerifyResult:
    """Both passes: per-point results, statistics, counters."""

    plan: VerifyPlan
    points: list[PointResult]
    moves: int
    reads: int
    offsets_estimate_deg: np.ndarray = field(default_factory=lambda: np.zeros(6))
    edge_checks: tuple[EdgeCheck, ...] = ()
    skipped: tuple[SkippedPoint, ...] = ()
    tool: ToolOffset | None = None
    #: ``plan.tank_faces`` read again at the start, then at the end (``ucal.verify.tank``)
    tank_readings: tuple[FaceMeasurement, ...] = ()
    #: the sound speed the points' water paths were converted at (m/s): the tank's at the
    #: start (``ucal.verify.tank.start_speed``); None: the profile's (calibrate's)
    points_speed_m_s: float | None = None

    def indices(self, pass_name: str) -> list[int]:
        """0-based indices of the points measured in one pass, in order."""
        return [p.index for p in self.measured(pass_name)]

    def measured(self, pass_name: str, group: int | None = None) -> list[PointResult]:
        """The measured points of one pass (and one group, if given), by point index."""
        return sorted(
            (
                p
                for p in self.points
                if p.pass_name == pass_name
                and (group is None or self.plan.group_of[p.index] == group)
            ),
            key=lambda p: p.index,
        )

    def deviations(self, pass_name: str, group: int | None = None) -> np.ndarray:
        """Deviations (n, 3) mm of the measured points of one pass (and group), by index."""
        return np.array([p.deviation_mm for p in self.measured(pass_name, group)]).reshape(-1, 3)

    def reached(self, pass_name: str) -> np.ndarray:
        return np.array([p.reached_mm for p in self.measured(pass_name)]).reshape(-1, 3)

    def stats(self, pass_name: str) -> dict[str, list[float]]:
        return deviation_stats(self.deviations(pass_name))

    def group_after_max_mm(self, group: int) -> list[float] | None:
        """The largest "after" deviation per axis of one group's points (None: none measured)."""
        dev = self.deviations("after", group)
        return deviation_stats(dev)["max"] if len(dev) else None

    def to_json(self, tolerance_mm: float | None = None) -> dict[str, Any]:
        """The ``verify --json`` object of SPEC.md plus per-point detail (mm, deg)."""
        # a pass without a measured point (every "before" point skipped): null statistics
        out: dict[str, Any] = {
            f"{p}_mm": {k: [v if np.isfinite(v) else None for v in vs] for k, vs in st.items()}
            for p in PASSES
            for st in (self.stats(p),)
        }
        out["points"] = self.plan.points
        if tolerance_mm is not None:
            out["tolerance_mm"] = float(tolerance_mm)
            out["passed"] = passed(self.stats("after"), tolerance_mm)
        out["frame"] = "block"
        out["height_mm"] = self.plan.height_mm
        out["nominal_mm"] = self.plan.nominal_mm.tolist()
        out["measured_points"] = {p: [i + 1 for i in self.indices(p)] for p in PASSES}
        out["skipped"] = [s.reason() for s in self.skipped]
        out["deviations_mm"] = {p: self.deviations(p).tolist() for p in PASSES}
        out["reached_mm"] = {p: self.reached(p).tolist() for p in PASSES}
        out["offsets_deg"] = {p: self.plan.offsets_deg[p].tolist() for p in PASSES}
        out["groups"] = [
            {
                "name": g.name,
                "orientation": g.description,
                "height_mm": g.height_mm,
                "points": [i + 1 for i, k in enumerate(self.plan.group_of) if k == n],
                "after_max_mm": self.group_after_max_mm(n),
            }
            for n, g in enumerate(self.plan.groups)
        ]
        tool = self.tool
        out["tool_check"] = {
            "offset_mm": tool_offset(self.edge_checks).tolist(),
            "along_beam_mm": None if tool is None else tool.along_mm,
            "across_beam_flange_mm": None if tool is None else tool.across_mm.tolist(),
            "separated": None if tool is None else tool.separated,
            "misfit_mm": None if tool is None else tool.misfit_mm,
            "edges": [
                {
                    "axis": "XY"[c.axis],
                    "tool": self.plan.groups[self.plan.group_of[c.point]].name,
                    "point": c.point + 1,
                    "edge_mm": c.edge_mm,
                    "crossing_mm": c.crossing_mm,
                    "crossing_std_mm": c.crossing_std_mm,
                    "offset_mm": c.offset_mm,
                    "probes": c.probes,
                }
                for c in self.edge_checks
            ],
        }
        out["moves"] = self.moves
        out["pulser_reads"] = self.reads
        return out


def run_verify(
    profile: CellProfile,
    plan: VerifyPlan,
    rig: Rig,
    progress: Report | None = None,
) -> VerifyResult:
    """Move to every planned point of both passes and measure where the robot really is,
    reporting each point and each edge of the tool check as it starts.

    The caller owns the connection, STOP and preflight. Never writes the profile.
    """
    geom = geometry(profile)
    v, _ = tool_lever(profile)
    # the noise floor off the first point's XY face, turning a joint that tilts the beam
    first = plan.targets[0]
    js0, _ = search_joints(
        geom, first.face_joints_deg[2], plan.offsets_deg["before"], face_basis(geom, 2)
    )
    # the arm stays still while the wrist measures a point: its links where they settled
    running = RunningEstimate.start(profile, rig, geom, first.joints_deg, js0[1], keep_still=True)
    approach = running.rig
    total = len(plan.targets) + len(plan.edge_points) + (2 if plan.tank_faces else 0)

    def read_tank(moment: str, done: int) -> list[FaceMeasurement]:
        """calibrate's water paths of ``plan.tank_faces`` read again where it read them."""
        if not plan.tank_faces:
            return []
        if progress:
            progress(MeasureStep(f"tank at the {moment}", done, total))
        return [read_path_at(rig, profile, m, f"tank {moment}") for m in plan.tank_faces]

    tank = read_tank("start", 0)
    first_point = 1 if tank else 0
    # the points' water paths at the tank's speed as the start read it: the wrist map and the
    # tool check's edges are carried from the points' W (ucal.verify.tank)
    speed = None if plan.tank is None or not tank else start_speed(plan.tank, tank, profile)
    if speed is not None:
        running.converting_at(speed[1])
    last_wrist: dict[int, np.ndarray] = {}
    results: list[PointResult] = []
    skipped: list[SkippedPoint] = []
    orientations: dict[int, WristOrientation] = {}  # of the "after" points
    for n_done, target in enumerate(plan.targets, start=first_point):
        if progress:
            what = f"{target.pass_name} point {target.index + 1}"
            progress(MeasureStep(what, n_done, total, target.pass_name))
        # the tool's clearance there from the pass's points measured so far: offsets before
        # calibration 2° off put the TCP tens of mm from the nominal point, into the block
        done = [p for p in results if p.pass_name == target.pass_name]
        skip = None
        if target.clearance_mm < MIN_WATER_PATH_MM:
            skip = SkippedPoint(
                target.pass_name, target.index, target.clearance_mm, "the profile's offsets"
            )
        elif done:
            clear = predicted_clearance_mm(
                profile, done[-1], target.joints_deg, plan.offsets_deg[target.pass_name]
            )
            if clear < MIN_WATER_PATH_MM:
                skip = SkippedPoint(target.pass_name, target.index, clear)
        if skip is not None:
            if target.pass_name != "before":
                raise SafetyError(
                    f"{skip.reason()}: the profile's offsets put the robot that far from "
                    "its nominal points; calibrate first"
                )
            log.warning("%s", skip.reason())
            skipped.append(skip)
            continue
        # the commanded point (TCP on the nominal point), reached from below on every joint
        # as in the calibration: a joint with backlash lags the same way as when calibrated
        approach.move(target.joints_deg)
        faces: dict[int, FaceMeasurement] = {}
        for k in FACE_ORDER:
            label = f"{target.label}/{FACE_NAMES[k]}"
            start = target.joints_deg.copy()
            start[3:] = last_wrist.get(k, target.face_joints_deg[k])[3:]
            found = running.measure(Face(k), start, label, f"{target.pass_name}/{target.index}")
            m = found.measurement
            faces[k] = m
            last_wrist[k] = m.joints_deg
        ordered = tuple(faces[k] for k in range(3))
        w_local, orient, tcp = reached_from_peaks(
            profile,
            geom,
            np.array([m.joints_deg for m in ordered]),
            np.array([m.distance_mm for m in ordered]),
            target.joints_deg,
        )
        if target.pass_name == "after":
            orientations[target.index] = orient
        res = PointResult(
            target.pass_name,
            target.index,
            plan.nominal_mm[target.index],
            target.joints_deg,
            ordered,
            w_local,
            tcp,
            orient.rms_deg,
            geom.block_rotation.T @ orient.rotation(geom, target.joints_deg),
        )
        results.append(res)
        log.info("%s: deviation %s mm", target.label, np.round(res.deviation_mm, 4).tolist())
    # tool check: the real TCP against the estimate at the XY face's far edges
    after = {p.index: p for p in results if p.pass_name == "after"}
    wrist = WristMap.fit(
        profile,
        np.array([p.commanded_deg for p in after.values()]),
        np.array([p.wrist_centre_mm for p in after.values()]),
        plan.offsets_deg["after"],
        np.array([orientations[i].rotation(geom, p.commanded_deg) for i, p in after.items()]),
    )
    scans = []
    for n_scan, (axis, i) in enumerate(plan.edge_points):
        if progress:
            what = edge_label(axis, plan.groups[plan.group_of[i]])
            progress(
                MeasureStep(what, first_point + len(plan.targets) + n_scan, total, "after", "XY")
            )
        scans.append(
            scan_edge(
                rig, approach.move, geom, profile, plan, after[i], orientations[i], wrist, axis, v
            )
        )
    checks = tuple(scans)
    tool = solve_tool_offset(
        checks, [after[c.point].flange_local for c in checks], geom.beam_flange
    )
    log.info(
        "tool check: κ %.4f mm along the beam, Δ⊥ %s mm (flange)%s",
        tool.along_mm,
        np.round(tool.across_mm, 4).tolist(),
        "" if tool.separated else " (one sense about the beam: one quantity)",
    )
    results = [replace(p, reached_mm=p.reached_mm + tool.bias(p.flange_local)) for p in results]
    tank += read_tank("end", total - 1)
    # Leave the robot at the last commanded point (beam down, clear of the block).
    approach.move(plan.targets[-1].joints_deg)
    if progress:
        progress(MeasureStep("solving", total, total))
    return VerifyResult(
        plan,
        results,
        rig.counters.moves,
        rig.counters.reads,
        running.offsets_deg.copy(),
        checks,
        tuple(skipped),
        tool,
        tuple(tank),
        None if speed is None else speed[0],
    )


def line_to_edge(
    coordinate_at: Callable[[float], float],
    start_mm: float,
    guess_mm: float,
    edge_mm: float,
    overshoot_mm: float,
) -> tuple[float, float]:
    """Where along a scan line (the profile's TCP moved by t from the point) the estimated
    TCP reaches the edge, and where it is ``overshoot_mm`` beyond: two secant steps from the
    point (t = 0, estimate ``start_mm``) and a first guess, ``coordinate_at(t)`` the estimate
    at the line's posture t."""
    t_a, c_a = 0.0, float(start_mm)
    t_edge = float(guess_mm)
    slope = 1.0
    for _ in range(2):
        if t_edge == t_a:  # the previous step landed on the edge exactly
            break
        c_e = coordinate_at(t_edge)
        secant = (c_e - c_a) / (t_edge - t_a)
        if not abs(secant) > 1e-9:  # the estimate did not move along the line: keep the step
            break
        slope = secant
        t_a, c_a = t_edge, c_e
        t_edge += (edge_mm - c_e) / slope
    return t_edge, t_edge + overshoot_mm / slope


def scan_edge(
    rig: Rig,
    move: Callable[[np.ndarray], np.ndarray],
    geom: CellGeometry,
    profile: CellProfile,
    plan: VerifyPlan,
    point: PointResult,
    orient: WristOrientation,
    wrist: WristMap,
    axis: int,
    v_flange_mm: np.ndarray,
) -> EdgeCheck:
    """Scan the TCP from an "after" point across the XY face's far edge on ``axis``.

    The profile's TCP moves along +``axis``, 30 mm above the face, in the nominal orientation
    tilted by the least rotation that brings the beam normal to the face (the beam the point's
    three peak postures give, ``orient``; no turn about the beam, which would move a real TCP
    that is off the profile's across the beam); each
    probe's scan coordinate is the wrist-centre estimate of the TCP at its settled readings
    (the point's measured W moved with ``wrist``, plus ``R(q)·v`` with the flange rotation
    ``wrist`` carries from the points). Coarse steps until the echo
    falls below half, then a fine scan across the fall fitted with the edge profile. ``move``
    moves the robot (reaching each probe from below on every joint) and returns the readings.
    """
    off = wrist.offsets_deg  # the arm as the "after" points measured it
    size = float(profile.sample_face_size_mm)
    nominal = plan.nominal_mm[point.index]
    q_i = np.asarray(point.commanded_deg, float)
    b_rot = geom.block_rotation
    # the point's true flange rotation, moved with that arm (not with the running estimate,
    # which has absorbed whatever the profile's tool hides)
    frames_i = fk_frames(geom.model, q_i, off)
    r_true = orient.rotation(geom, q_i)
    r_i = r_true @ frames_i[6, :3, :3].T  # true = r_i · model, base frame
    # the map's displacement from the point's own measured W (its fit is not exact there)
    anchor = point.wrist_centre_mm - wrist(q_i)
    # the least tilt of the true beam onto the face's normal, as a model flange rotation
    beam = r_true @ geom.beam_flange
    cross = np.cross(beam, -geom.normal(2))
    tilt = Rotation.from_rotvec(
        np.arctan2(np.linalg.norm(cross), beam @ -geom.normal(2))
        * cross
        / max(float(np.linalg.norm(cross)), 1e-300)
    ).as_matrix()
    flange_rot = r_i.T @ tilt @ r_true
    tool_rot = flange_rot @ profile.tool_matrix[:3, :3]
    unit = np.eye(3)[axis]
    label = edge_label(axis, plan.groups[plan.group_of[point.index]])
    near = q_i.copy()
    n_probes = 0

    def joints_at(t: float, seed: np.ndarray) -> np.ndarray:
        pose = target_matrix(profile, nominal + t * unit)
        pose[:3, :3] = tool_rot
        return joints_for(profile, pose, off, seed, label)

    def posture(t: float) -> np.ndarray:
        nonlocal near
        near = joints_at(t, near)
        return near

    def coordinate(q: np.ndarray) -> float:
        """The scan coordinate at readings ``q``: W and the flange's turn carried from the
        points by the arm they measured, the TCP's estimate on the scan axis."""
        tcp = wrist(q) + anchor + b_rot.T @ (wrist.rotation(q) @ v_flange_mm)
        return float(tcp[axis])

    def probe(t: float) -> tuple[float, float]:
        """The probe's scan coordinate (its wrist-centre estimate) and amplitude."""
        nonlocal n_probes
        settled = np.asarray(move(posture(t)), float)
        a = rig.normalised_amplitude(EDGES.averages)
        c = coordinate(settled)
        log.debug("%s probe %s: %.5f mm, amplitude %.4f", label, settled.tolist(), c, a)
        n_probes += 1
        return c, a

    def amplitude(t: float) -> float:
        return probe(t)[1]

    # where the edge is along the line: the point's own estimate of its TCP says how far the
    # robot is from where the profile puts it, and the arm the points measured how far it
    # really moves along the line (a joint-1 offset the block's yaw hides turns every motion:
    # 20 mm over 170 mm with the profile's J1 1.8° off); two secant steps on the estimate
    t_edge, t_max = line_to_edge(
        lambda t: coordinate(joints_at(t, q_i)),
        coordinate(q_i),
        size - float(point.reached_mm[axis]),
        size,
        EDGE_OVERSHOOT_MM,
    )
    # the echo's level on the face at the point, then the coarse search from
    # EDGE_APPROACH_MM before that edge (stepping back while the echo
    # there is already below half: a tool or a block further off than that)
    move(posture(0.0))
    rig.level_gain(EDGES.averages)
    level = rig.normalised_amplitude(EDGES.averages)
    t = max(0.0, t_edge - EDGE_APPROACH_MM)
    while (a := amplitude(t)) < 0.5 * level and t > 0.0:
        t = max(0.0, t - EDGE_APPROACH_MM)
    t_c = coarse_edge_fall(amplitude, t, a, t_max, EDGES.coarse_step_mm, EDGES.coarse_memory)
    if t_c is None:
        raise HardwareError(
            f"{rig.pulser.endpoint}: {label}: the echo did not fall at the block's edge "
            f"within {t_max:.0f} mm of point {point.index + 1}: is [sample] face_size_mm "
            "right and the edge clean?"
        )
    try:
        fit = fine_edge_scan(probe, t_c, EDGES.fine_half_mm, EDGES.fine_probes, t_max)
    except ValueError as e:
        raise HardwareError(
            f"{rig.pulser.endpoint}: {label}: the fine scan near point {point.index + 1} "
            f"does not show the echo falling to half at the block's edge ({e})"
        ) from None
    log.info(
        "%s: crossing %.4f ± %.4f mm, edge %.1f mm (σ %.2f mm, rms %.2g)",
        label,
        fit.crossing,
        fit.crossing_std,
        size,
        fit.width_mm,
        fit.rms,
    )
    return EdgeCheck(axis, point.index, size, fit.crossing, fit.crossing_std, n_probes)


def tank_corrected(result: VerifyResult, tank: TankEstimate, conversion_m_s: float) -> VerifyResult:
    """``result`` with every water path converted at the tank's speed of its time.

    Face k's path gives the wrist centre's block coordinate k (``W_k = d_k + a_T·v``), so a
    path read at c_v, ``d·c(t)/c_v`` truly, moves W and the reached TCP by ``d·(c(t)/c_v − 1)``
    on that axis. The tool check's crossings are wrist-centre estimates carried from their
    point's W: each moves with its point's, and the tool's bias is solved again from them.
    """

    def shift(p: PointResult) -> np.ndarray:
        return np.array(
            [m.distance_mm * (tank.speed_at(m.time_min) / conversion_m_s - 1.0) for m in p.faces]
        )

    shifts = {(p.pass_name, p.index): shift(p) for p in result.points}
    checks = tuple(
        replace(c, crossing_mm=c.crossing_mm + shifts[("after", c.point)][c.axis])
        for c in result.edge_checks
    )
    old, tool = result.tool, result.tool
    if old is not None and checks:
        after = {p.index: p for p in result.points if p.pass_name == "after"}
        tool = solve_tool_offset(
            checks, [after[c.point].flange_local for c in checks], old.beam_flange
        )

    def corrected(p: PointResult) -> PointResult:
        d = shifts[(p.pass_name, p.index)]
        reached = p.reached_mm + d
        if old is not None and tool is not None:
            reached = reached - old.bias(p.flange_local) + tool.bias(p.flange_local)
        faces = tuple(replace(m, distance_mm=m.distance_mm + d[k]) for k, m in enumerate(p.faces))
        return replace(p, faces=faces, wrist_centre_mm=p.wrist_centre_mm + d, reached_mm=reached)

    return replace(
        result, points=[corrected(p) for p in result.points], edge_checks=checks, tool=tool
    )
