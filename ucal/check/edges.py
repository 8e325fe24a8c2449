"""The check's edge crossings: the tool across the beam, where no water path sees it.

A face measurement sees the tool along the beam (its water path) and the beam's direction (its
normal incidence), never the tool centre's position across the beam: moving the centre
sideways changes neither. An edge does. With the beam normal to the block's XY face, the TCP
is moved outward across the face's two far edges (block x = S and y = S, S the face's size),
as verify's tool check moves it, and the 50 % point of the echo's fall is where the beam axis
crosses the edge (``ucal.measure.edges``, tool-frame's eq. E4). Each crossing is one row of
the check's fit (``edge_residuals``): the beam's hit on the face plane at the crossing's
readings, its coordinate along the scan's block axis, against S,

    r = (e_k·(h(q + δ) − c) − S) / σ_e,   h = p + s·b,  s = −n·(p − c)/(n·b),

``p`` and ``b`` the tool centre and the beam at the readings (the offsets, the DH table, the
tool, the lost motion of the cell's unknowns), ``c`` the block's corner, ``n`` the XY face's
normal, ``e_k`` the block axis of the edge, σ_e the crossing's one sigma from the fit of the
fall. A crossing holds no sound speed and no time of flight. It moves with the tool across
the beam, with the block in x or y, and with the arm's joints; the faces tell the block and
the joints apart, so the check's suspects are told apart with two crossings (``ucal.check.
observe``). S, the edge's radius and the footprint's width are the same in the reference's
crossings and the check's: their changes do not depend on them.

The lines are planned from the profile (its offsets, tool and block) through the planned
``base/XY`` posture (two lines an edge, ``LATERAL_MM`` either side of its hit point), so the
reference and the check command the same probes; each line's
ends are checked against the joint ranges and the singularity margin before the first motion,
and a line that cannot be planned is left out with the reason (the tool across the beam is
then not determined: ``ucal.check.observe``).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from ucal.cell import CellProfile
from ucal.devices.rig import Rig
from ucal.errors import SafetyError
from ucal.kinematics.dh import RobotModel, fk
from ucal.kinematics.ik import ik
from ucal.measure.approach import FinalApproachRig
from ucal.measure.edges import EdgeScan, coarse_edge_fall, fine_edge_scan
from ucal.model.geometry import Configuration, Face, beam_and_tcp
from ucal.model.priors import BACKLASH, BLOCK, OFFSETS, ParameterTable
from ucal.model.residuals import approach_signs, table_geometry
from ucal.model.safety import EDGE_MARGIN_MM, check_joints
from ucal.model.targets import PlannedTarget

log = logging.getLogger(__name__)

#: The face the edges belong to and the posture the lines start from.
EDGE_FACE = Face.XY
EDGE_CONFIGURATION = Configuration.BASE
#: The block axes of the far edges scanned (0: the edge x = S, 1: y = S), each along two lines
#: this far either side of the base/XY posture's hit point along the edge (mm): two crossings
#: of one straight edge, each line's noise its own.
EDGE_AXES = (0, 1)
LATERAL_MM = (-15.0, 15.0)
#: The coarse search starts this far before the edge the profile predicts (mm) at least, and
#: the line runs this far beyond it at least: a block bumped or a tool remounted by a few mm is
#: found. Both grow with what the profile does not know (``search_margin_mm``).
EDGE_APPROACH_MM = 8.0
EDGE_OVERSHOOT_MM = 10.0
#: Sigmas of the profile's declared tolerances the lines cover, and the least reach either side
#: of the profile's edge where the reference's crossing does not say where the edge is (mm):
#: at the offsets level the profile may put the beam's hit point a centimetre off (a tool
#: tilted beyond its tolerance, taken up by the offsets: ``benchmarks/check_changes.py``).
SEARCH_SIGMAS = 3.0
WIDE_SEARCH_MM = 30.0
#: The scan's settings: verify's (``ucal.measure.edges.EdgeScan``) with a fine scan of 41
#: probes over ±5 mm (the footprint's σ is 1.5 mm at 25 MHz and 6 mm), 16 averages a probe: a
#: crossing repeats to 0.008–0.018 mm on the simulated cell's 8-bit amplitude (21 probes:
#: 0.015–0.025 mm; 64 averages: no better).
SCAN = EdgeScan(fine_probes=41)
#: The smallest one sigma a crossing is given (mm): the fall's fit on a clean edge.
CROSSING_STD_FLOOR_MM = 0.002


@dataclass(frozen=True)
class EdgeLine:
    """One planned scan: the profile's TCP at ``pose`` (4, 4, base frame; the planned
    ``base/XY`` posture's) moved by t along ``direction`` (the block axis ``axis`` in the base
    frame) from ``start_mm`` to ``end_mm``, the profile putting the edge at ``edge_mm``."""

    label: str
    axis: int
    pose: np.ndarray
    direction: np.ndarray
    start_mm: float
    edge_mm: float
    end_mm: float
    start_deg: np.ndarray  # the readings at t = 0 (beside the planned base/XY posture)

    def at(self, t_mm: float) -> np.ndarray:
        """The tool pose at ``t_mm`` along the line."""
        pose = self.pose.copy()
        pose[:3, 3] += t_mm * self.direction
        return pose

    def oriented(self, profile: CellProfile, readings_deg: np.ndarray) -> EdgeLine:
        """The line with the tool turned as at ``readings_deg`` (the base/XY face's measured
        normal incidence, as the profile's kinematics put it), the positions kept, each end
        checked again (``SafetyError``)."""
        model, tool = profile.model, profile.tool_matrix
        offsets = np.asarray(profile.joint_offsets_deg, float)
        pose = self.pose.copy()
        pose[:3, :3] = fk(model, readings_deg, tool, offsets)[:3, :3]
        q0 = ik(model, pose, tool, offsets, near_deg=readings_deg)
        line = replace(self, pose=pose, start_deg=q0)
        for where in (line.start_mm, line.end_mm):
            q = ik(model, line.at(where), tool, offsets, near_deg=q0)
            check_joints(profile, q, self.label)
        return line


@dataclass(frozen=True)
class EdgeReading:
    """Where the beam axis crossed a far edge of the XY face: the readings of the fine scan's
    probe nearest the 50 % point, the shift (mm, base frame) from that probe's TCP to it along
    the line, and its one sigma along the line (mm)."""

    label: str
    axis: int
    joints_deg: np.ndarray
    shift_mm: np.ndarray
    std_mm: float
    edge_mm: float  # the face's size: where the edge is on the block axis
    probes: int = 0
    #: where along its line the beam crossed the edge (mm): a later check's line is centred
    #: there (``plan_edges``)
    t_mm: float | None = None
    time_min: float | None = field(default=None, compare=False)
    approach: np.ndarray | None = field(default=None, compare=False)

    def to_json(self) -> dict[str, Any]:
        """The reading as the history keeps it."""
        return {
            "label": self.label,
            "axis": self.axis,
            "joints_deg": [float(v) for v in self.joints_deg],
            "shift_mm": [float(v) for v in self.shift_mm],
            "std_mm": float(self.std_mm),
            "edge_mm": float(self.edge_mm),
            "probes": int(self.probes),
            "t_mm": self.t_mm,
            "time_min": self.time_min,
            "approach": None if self.approach is None else [float(v) for v in self.approach],
        }

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> EdgeReading:
        approach = data.get("approach")
        return cls(
            str(data["label"]),
            int(data["axis"]),
            np.asarray(data["joints_deg"], float),
            np.asarray(data["shift_mm"], float),
            float(data["std_mm"]),
            float(data["edge_mm"]),
            int(data.get("probes", 0)),
            data.get("t_mm"),
            data.get("time_min"),
            None if approach is None else np.asarray(approach, float),
        )


def search_margin_mm(profile: CellProfile, water_path_mm: float) -> float:
    """How far (mm) the edge may be from where the profile puts it, at ``SEARCH_SIGMAS`` of
    its declared tolerances: the tool across the beam, the tool's tilt over its length and
    the water path (the line is turned to the beam's measured normal incidence, which the
    profile's tool puts elsewhere), the block's position and its turn about its normal over
    the face."""
    tool = np.asarray(profile.tool_position_std_mm, float)
    tilt = np.radians(np.asarray(profile.tool_rotation_std_deg, float)[:2])
    lever = float(np.linalg.norm(profile.tool_position_mm)) + water_path_mm
    block = float(np.max(profile.sample_position_std_mm))
    yaw = np.radians(float(np.asarray(profile.sample_rotation_std_deg, float)[2]))
    spread = np.sqrt(
        np.sum(tool[:2] ** 2)
        + np.sum((lever * tilt) ** 2)
        + block**2
        + (float(profile.sample_face_size_mm) * yaw) ** 2
    )
    return float(SEARCH_SIGMAS * spread)


def edge_label(axis: int) -> str:
    return f"{EDGE_CONFIGURATION}/{EDGE_FACE.name} {'xy'[axis]} edge"


def plan_edges(
    profile: CellProfile,
    targets: tuple[PlannedTarget, ...],
    reference: tuple[EdgeReading, ...] = (),
) -> tuple[tuple[EdgeLine, ...], tuple[str, ...]]:
    """The scans across the XY face's far edges from the planned ``base/XY`` posture, each
    line's ends checked (joint ranges, singularity margin); the lines, and for each one left
    out the reason. A line the ``reference`` crossed is centred on its crossing and reaches
    ``search_margin_mm`` either side; another reaches ``WIDE_SEARCH_MM`` at least."""
    crossed = {r.label: r.t_mm for r in reference if r.t_mm is not None}
    start = next(
        (t for t in targets if t.config == EDGE_CONFIGURATION and t.face == EDGE_FACE), None
    )
    if start is None:
        return (), ("no base/XY posture to start the edge scans from",)
    model, tool = profile.model, profile.tool_matrix
    offsets = np.asarray(profile.joint_offsets_deg, float)
    pose = fk(model, start.joints_deg, tool, offsets)
    block = profile.sample_matrix
    rot, corner = block[:3, :3], block[:3, 3]
    normal, beam, tcp = rot[:, EDGE_FACE], pose[:3, 2], pose[:3, 3]
    hit = tcp - (normal @ (tcp - corner)) / (normal @ beam) * beam
    local = rot.T @ (hit - corner)
    size = float(profile.sample_face_size_mm)
    margin = search_margin_mm(profile, float(start.water_path_mm))
    lines, left_out = [], []
    for axis, lateral in ((a, ell) for a in EDGE_AXES for ell in LATERAL_MM):
        other = 1 - axis
        label = f"{edge_label(axis)} {lateral:+.0f} mm"
        edge = crossed.get(label, size - float(local[axis]))
        reach = max(margin, EDGE_APPROACH_MM) if label in crossed else max(margin, WIDE_SEARCH_MM)
        shifted = pose.copy()
        shifted[:3, 3] += lateral * rot[:, other]
        try:
            if not EDGE_MARGIN_MM <= local[other] + lateral <= size - EDGE_MARGIN_MM:
                raise SafetyError(
                    f"plan {label}: the line would run {local[other] + lateral:.1f} mm from the "
                    f"corner along block {'xy'[other]}, within {EDGE_MARGIN_MM:g} mm of an edge"
                )
            q0 = ik(model, shifted, tool, offsets, near_deg=start.joints_deg)
            line = EdgeLine(
                label,
                axis,
                shifted,
                rot[:, axis].copy(),
                max(0.0, edge - reach),
                edge,
                edge + max(reach, EDGE_OVERSHOOT_MM),
                q0,
            )
            for where in (0.0, line.start_mm, line.end_mm):
                q = ik(model, line.at(where), tool, offsets, near_deg=q0)
                check_joints(profile, q, f"plan {label}")
        except SafetyError as e:
            left_out.append(f"{label} left out: {e}")
            continue
        lines.append(line)
    return tuple(lines), tuple(left_out)


def scan_edge(
    rig: Rig, profile: CellProfile, line: EdgeLine, normal_deg: np.ndarray | None = None
) -> EdgeReading | None:
    """Scan ``line`` (every probe static, reached from below on every joint), the tool turned
    as at ``normal_deg`` (the base/XY face's measured normal incidence: the beam truly normal
    to the face, where the profile's tool may leave it a degree off and the echo a tenth):
    the echo's level on the face at the line's start, coarse steps outward until it falls
    below half, then the fine scan across the fall fitted with the edge profile. None, said in
    the log, when the turned line leaves the joints' room or the echo does not fall within
    the line (the block or the tool moved farther than it reaches: the faces say which)."""
    if normal_deg is not None:
        try:
            line = line.oriented(profile, np.asarray(normal_deg, float))
        except SafetyError as e:
            log.warning("%s: not scanned turned as the face's normal incidence: %s", line.label, e)
            return None
    model, tool = profile.model, profile.tool_matrix
    offsets = np.asarray(profile.joint_offsets_deg, float)
    approach = FinalApproachRig(rig)
    near = line.start_deg.copy()
    fine: list[tuple[float, np.ndarray, float, np.ndarray]] = []
    count = 0

    def probe(t: float) -> tuple[float, float]:
        nonlocal near, count
        near = ik(model, line.at(t), tool, offsets, near_deg=near)
        settled = np.asarray(approach.move(near), float)
        a = rig.normalised_amplitude(SCAN.averages)
        fine.append((t, settled, rig.minutes(), np.asarray(rig.approach, float).copy()))
        log.debug("%s probe at %.2f mm: amplitude %.5f", line.label, t, a)
        count += 1
        return t, a

    def detected() -> float:
        """The detection level at the current gain, as a probe's amplitude (0 dB)."""
        return rig.threshold() / 10 ** (rig.settings.gain_db / 20)

    # the gain levelled at the line's start, then the coarse search from there (stepping back
    # while no echo shows: a tool or a block further off than the line's approach). The level
    # is the start's, not the face posture's: 200 mm away the beam may be a few tenths of a
    # degree off normal (the DH table within its tolerance) and its echo a tenth as high
    t = line.start_mm
    probe(t)
    rig.level_gain(SCAN.averages)
    a = probe(t)[1]
    while a <= detected() and t > 0.0:
        t = max(0.0, t - EDGE_APPROACH_MM)
        if (a := probe(t)[1]) > detected():
            rig.level_gain(SCAN.averages)
            a = probe(t)[1]
    t_c = coarse_edge_fall(
        lambda s: probe(s)[1], t, a, line.end_mm, SCAN.coarse_step_mm, SCAN.coarse_memory
    )
    if t_c is None:
        log.warning("%s: the echo did not fall within %.0f mm", line.label, line.end_mm)
        return None
    fine.clear()
    try:
        fit = fine_edge_scan(probe, t_c, SCAN.fine_half_mm, SCAN.fine_probes, line.end_mm)
    except ValueError as e:
        log.warning("%s: the fine scan shows no fall to half (%s)", line.label, e)
        return None
    i = int(np.argmin([abs(r[0] - fit.crossing) for r in fine]))
    t_i, joints, minutes, signs = fine[i]
    log.info(
        "%s: crossing %.4f ± %.4f mm (edge predicted at %.3f mm; σ %.2f mm, rms %.2g)",
        line.label,
        fit.crossing,
        fit.crossing_std,
        line.edge_mm,
        fit.width_mm,
        fit.rms,
    )
    return EdgeReading(
        line.label,
        line.axis,
        joints,
        (fit.crossing - t_i) * line.direction,
        max(float(fit.crossing_std), CROSSING_STD_FLOOR_MM),
        float(profile.sample_face_size_mm),
        count,
        float(fit.crossing),
        minutes,
        signs,
    )


@dataclass(frozen=True)
class EdgeArrays:
    """Edge readings as arrays, built once per fit."""

    joints: np.ndarray  # (n, 6)
    shift: np.ndarray  # (n, 3)
    axes: np.ndarray  # (n,)
    edge_mm: np.ndarray
    std_mm: np.ndarray
    lag: np.ndarray  # (n, 6): (1 − approach)/2, as the faces'

    @classmethod
    def of(cls, readings: list[EdgeReading]) -> EdgeArrays:
        return cls(
            np.array([r.joints_deg for r in readings], float).reshape(-1, 6),
            np.array([r.shift_mm for r in readings], float).reshape(-1, 3),
            np.array([r.axis for r in readings], int),
            np.array([r.edge_mm for r in readings], float),
            np.array([r.std_mm for r in readings], float),
            0.5 * (1.0 - approach_signs(readings)).reshape(-1, 6),
        )

    def __len__(self) -> int:
        return len(self.axes)


def edge_residuals(
    table: ParameterTable, values: np.ndarray, model: RobotModel, arrays: EdgeArrays
) -> np.ndarray:
    """The crossings' normalised residuals (n,) (module docstring)."""
    if not len(arrays):
        return np.zeros(0)
    geom = table_geometry(table, values, model)
    postures = arrays.joints
    if BACKLASH[0] in table.names:
        postures = postures + arrays.lag * table.get(BACKLASH, values)
    beam, tcp = beam_and_tcp(geom, postures, table.get(OFFSETS, values))
    tcp = tcp + arrays.shift
    corner = table.get(BLOCK[:3], values)
    rot = geom.block_rotation
    normal = rot[:, EDGE_FACE]
    s = -((tcp - corner) @ normal) / (beam @ normal)
    hit = tcp + s[:, None] * beam
    along = np.einsum("nj,nj->n", rot[:, arrays.axes].T, hit - corner)
    return np.asarray((along - arrays.edge_mm) / arrays.std_mm)
