"""Positioning error before and after calibration (paper 000, §5.2): plan, measure, statistics.

**Nominal points.** ``n`` points in up to three orientations of the tool (``point_groups``),
each group a grid (e.g. 4 × 2 for 8) spread uniformly over a plane parallel to the block's XY
face: the beam straight down onto the face (tool z = −block z, the orientation of the
calibration pose and of paper 000's points), ``height_mm`` (30 mm, as in the paper) above it;
the same beam with the tool turned 180° about it (J6 half a turn away: what the tool's lever
across the beam does there is the opposite); and the beam tilted ``TILT_DEG`` towards block +X
over a patch of its own ``TILTED_RAISE_MM`` higher (W moves 47 mm towards the YZ wall with the
tilt, so the patch moves the other way). One point is commanded straight down, two in the first
two orientations, more a third each in the turned and tilted ones. Each grid stays inside the
XY face with ``EDGE_MARGIN_MM`` and where the wrist centre W is ``WALL_PATH_MM`` (50–150 mm of
water path) from the two walls (the YZ and XZ faces), so that each wall can be measured from
every point. Coordinates are block coordinates (mm): origin at the block corner of the profile,
axes along the block's edges.

**Two passes.** *before*: every point is commanded with joint readings from IK with the
offsets the profile had before its last calibration (``offsets_before_calibration``); *after*:
with its current ones (``ik(..., offsets_deg=profile offsets)``, readings = kinematic angle −
offset).

**What is measured, and how.** At each commanded point the arm (joints 1–3) stays still and the
wrist turns the beam onto each of the three faces in turn; the wrist turns the beam about W
without moving W (arm–wrist separation, paper 000 §4.2). For each face the peak-amplitude
(normal-incidence) posture is searched (``PeakSearch``: a main-lobe cross from a prediction,
a raster acquisition if the prediction misses, then the directivity fit) and the water path
``d_k`` is read by time of flight. At normal incidence (``ucal.calibration.model``, eq. 2)

    d_k = n_k·(W − c) − a_T·v        (v: W → TCP in the flange frame, a_T: beam in that frame)

so the three distances give W in block coordinates, ``W_k = d_k + a_T·v``, against the *true*
block. The three peak postures also fix the true orientation of the flange: they are three
known wrist postures at which the true beam is −n_k. With the arm still, the true flange
rotation is ``R(q) = Exp(ω)·R06(q, δ + (0, 0, 0, 0, ε5, 0))`` for an unknown small rotation ω
(it absorbs the arm offsets and joint 4) and a wrist residual ε5: four unknowns, six equations
(joint 6 is held at the profile's offset, the frame the tool was measured in: with the beam
near the joint-6 axis J6 and the tool's azimuth are one rotation). The wrist-centre estimate
of the tool centre is the TCP of the *commanded* posture, ``T̂ = W + R(q_cmd)·v``, in block
coordinates.

**Why the tool needs a measurement of its own.** Let the real tool be ``v' = v + Δ`` (flange
frame; the real beam a_T' along it). A water path at normal incidence sees only the TCP's
component along the beam: ``d_k = n_k·(W − c) − a_T'·v'``, whatever Δ does across the beam
(a plane moved across itself is the same plane; turning the tool about the profile's TCP only
moves the real TCP across the beam at normal incidence, where no water path sees it). So the
reached TCP ``T = W + R·v'`` and its estimate differ by

    T − T̂ = (a_T'·v' − a_T·v)·(1, 1, 1) + R(q_cmd)·Δ        (block coordinates)

and at the nominal orientation (the profile's beam along −z, so ``R·Δ`` has z component
−a_T·Δ) the z component is ``(a_T' − a_T)·v'``, the beam's direction error times the lever
(a micrometre after ``tool-frame``), while x and y carry the tool's error across the beam
plus its error along it: one bias ``b = (b_x, b_y, 0)`` for all points commanded in that
orientation; it is invisible to water paths and is what a tool error does to every TCP the
profile computes. In general, with ``κ = a_T'·v' − a_T·v`` and ``Δ = Δ⊥ + (a_T·Δ)·a_T``,

    T − T̂ = κ·(1, 1, 1) + R·(Δ⊥ + κ·a_T)        (``ToolOffset.bias``)

taking ``a_T·Δ = κ − (a_T' − a_T)·v'`` as κ: the second term is the beam's direction error
times the tool's lever *across* the beam (v' lies nearly along the beam), 0.03 mm for a tool
1.5° and 3 mm off its drawing, micrometres after ``tool-frame``. Three unknowns, κ and Δ⊥:
the edge scans from a point commanded straight down give ``κ + (R·Δ⊥)_x`` and
``κ + (R·Δ⊥)_y``, those from a point with the tool turned 180° about the beam ``κ − (R·Δ⊥)_x``
and ``κ − (R·Δ⊥)_y``; together (least squares, ``solve_tool_offset``) they give κ and Δ⊥, hence
the bias at any orientation, the tilted points' included. With the down points alone (one
point) the least-norm split is exact for them and is all that is used.

**Tool check: the edges of the XY face.** A knife edge is a reflector whose echo sees the beam
across its axis: with the beam at normal incidence to the XY face, the echo falls to half
where the beam axis — the real TCP's x (or y) — crosses the face's far edge, x = S (y = S; S
the face size). After both passes, from the "after" point nearest each far edge, the robot
moves the profile's TCP along +x (+y), 30 mm above the face, in the nominal orientation tilted
by the least rotation that makes the beam normal to the face (the true beam the point's three
peak postures give; no turn about the beam, which would move a real TCP that is off the
profile's across it): from ``EDGE_APPROACH_MM`` before the edge the point's estimate predicts,
coarse steps until the echo falls below half, then ``EDGE_FINE_PROBES`` static probes across the
fall, fitted with the edge profile ``A0·Φ((t_e − t)/σ)`` (``ucal.toolframe.exact``, eq. E4).
The scan coordinate of each probe is its wrist-centre estimate ``T̂(q)``: the point's measured
W moved by ``WristMap`` — the profile's kinematics with corrections to the offsets of joints
1–3, a small turn and shift of the block and a constant turn of the flange, fitted to the W
and the flange rotations measured at the "after" points (an offset left in joint 1,
unobservable with a hand-placed block, or a joint left uncalibrated turns every displacement
of the arm, and the edges are 100–200 mm from the points) — plus the flange rotation that map
gives at the probe, times v. So the
crossing ``t_e`` is what the estimate says where the real TCP is at x = S, and

    b_x = S − t_e,   b_y = S − t_e(y)

is the tool's error in block axes at the nominal orientation; the same scans from a turned
point give the other sense. Every reached point of both passes is ``T̂ + bias(R)`` at its own
measured flange orientation R (the "before" pass, commanded with other offsets, turns the tool
by up to their difference). That is the "after" figure: the real TCP against the nominal
point, tool and kinematics together; a tool 1 mm off across the beam makes it ~1 mm and the
run fails its tolerance. Two edge scans of about 30 probes each in each sense about the beam.

**What the check does not see: the beam's direction.** All of the above takes the flange
orientation R from the three normal-incidence postures with the profile's beam a_T: if the
real beam a_T' is a few tenths of a degree off it (a tool not yet measured), R comes out
turned by as much, and T̂ = W + R·v moves by up to that angle times |v| (180 mm from W to
the TCP: 0.3° is up to 0.9 mm). The turn is in the flange frame, so it changes sign with the
tool turned 180° about the beam, but the orientation fit (a base-frame correction and a joint-5
residual, ``estimate_orientation``) absorbs it differently at each posture: the bias model no
longer holds, and the four edge scans, one more than its three unknowns, disagree. Their
largest misfit (``ToolOffset.misfit_mm``) is of the size of the error in every "after"
figure (a tool turned 0.3°: misfit 0.42 mm, "after" 0.44 mm off the truth); above
``MEASURED_WITHIN_MM`` verify says so in its notes and widens its marginal band by it. After
``tool-frame`` (beam within 0.001°) it was at most 0.016 mm on the commissioning benchmark.

**Gauge: relative to the block.** W is measured against the true block's faces and the
nominal points are placed from the profile's block, so every figure says where the tool is
relative to the block: an error in the profile's block pose shows in it, a turn of the arm and
the block together about the base axis does not. That is the gauge ``calibrate`` fixes
(``ucal.calibration.gauge``): J1 relative to the block as placed, the block's corner and tilts
as the calibration measured them (written into ``[sample]``). In the robot's base frame the
points are then known only to the block's yaw tolerance times their distance from the base
axis (``VerifyGauge``: ``absolute_std_mm``), which verify states and cannot check. The
"before" pass is commanded with the offsets *and* the block pose the profile had before its
last calibration.

**Predictions.** Every face measurement enters a running regularised fit of the joint offsets
and the block corner (as in the calibration sequence), so the posture correction found at one
point predicts the next: only the first faces of a run need a wide search, and a face whose
last prediction was within ``DIRECT_FIT_TILT_DEG`` goes straight to the directivity fit.

**Statistics** (paper 000, Table 5): per axis, the mean, maximum and standard deviation
(population, ddof = 0) of the absolute deviations; the signed mean and standard deviation are
given as well (the bias and the scatter).
"""

from __future__ import annotations

import logging
import math
import tomllib
from collections.abc import Callable
from contextlib import AbstractContextManager
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
from scipy.optimize import brentq, least_squares
from scipy.spatial.transform import Rotation

from ucal.acoustics import sound_speed_m_s
from ucal.calibration.faces import (
    FaceRequest,
    FaceSetup,
    SearchMode,
    acquisition_gain,
    estimate_offsets,
    measure,
)
from ucal.calibration.model import (
    FACE_NAMES,
    FACE_ORDER,
    CellGeometry,
    Face,
    FaceMeasurement,
    face_basis,
)
from ucal.calibration.safety import (
    EDGE_MARGIN_MM,
    MIN_WATER_PATH_MM,
    check_face,
    check_joints,
)
from ucal.calibration.search import ka_of
from ucal.calibration.sequence import calibration_pose, geometry
from ucal.calibration.wrist import aim_wrist, search_joints
from ucal.cell import CellProfile, WorldTruth
from ucal.edges import coarse_edge_fall, fine_edge_scan
from ucal.errors import HardwareError, SafetyError, UnreachableError
from ucal.kinematics.dh import RobotModel, fk_frames
from ucal.kinematics.ik import ik
from ucal.procedure import CheckingJob, Measured, Outcome, RunOptions
from ucal.profile import history_dir, load_profile, profile_history
from ucal.progress import MeasureStep, Report
from ucal.rig import FinalApproachRig, Rig
from ucal.session import CellSession
from ucal.sim.cell import SimulatedCell
from ucal.timing import EDGE_SCAN, NO_SEARCH, DurationEstimate, estimate_run
from ucal.toolframe.exact import tangent_basis
from ucal.verify_picture import PICTURE_SUFFIX as PICTURE_SUFFIX
from ucal.verify_picture import PictureText, plot_verify
from ucal.verify_picture import verify_picture_path as verify_picture_path

log = logging.getLogger(__name__)

#: Paper 000, §5.2: the plane of the nominal points is 30 mm from the block's XY face.
VERIFY_HEIGHT_MM = 30.0
#: Paper 000, §5.2: twenty nominal points.
DEFAULT_POINTS = 20
#: Water path from the TCP to each wall (YZ, XZ face) when the wrist points at it (mm):
#: short enough for a strong echo at 25 MHz (−0.27 dB per mm), long enough for clearance.
WALL_PATH_MM = (50.0, 150.0)
#: A face whose last prediction missed by less than this (deg of beam tilt) is fitted directly.
DIRECT_FIT_TILT_DEG = 0.12
PASSES = ("before", "after")
#: How far verify's reached TCP may be from the real one (mm): the largest difference on the
#: commissioning benchmark (``benchmarks/commissioning.py``, 80 runs on fresh cells) was 0.043
#: mm. A largest deviation that close to the tolerance gives a marginal verdict.
MEASURED_WITHIN_MM = 0.05
#: Tool check: the edge scans run this far beyond the XY face's far edge at most (mm).
EDGE_OVERSHOOT_MM = 15.0
#: Tool check: the coarse search starts this far before the edge the profile predicts (mm).
EDGE_APPROACH_MM = 12.0
#: Tool check: coarse step of the TCP towards the edge (mm; the footprint's σ is ~1.5 mm) ...
EDGE_COARSE_STEP_MM = 2.0
#: ... the echo falling below half the largest of this many last readings.
EDGE_COARSE_MEMORY = 4
#: Tool check: the fine scan spans ± this about the coarse crossing (mm) ...
EDGE_FINE_HALF_MM = 5.0
#: ... with this many static probes.
EDGE_FINE_PROBES = 21
#: Pulser readings averaged per probe of an edge scan.
EDGE_AVERAGES = 16
#: The tilted group's beam: this far from straight down (deg), towards block +X ...
TILT_DEG = 15.0
#: ... its points this much higher above the XY face than the others (mm): a patch of its own.
TILTED_RAISE_MM = 30.0


# ---------------------------------------------------------------------------------------------
# geometry


def tool_lever(profile: CellProfile) -> tuple[np.ndarray, float]:
    """The vector v from the wrist centre W to the TCP in the flange frame (mm) and a_T·v (mm).

    Constant for a spherical wrist; computed from the model at the zero pose.
    """
    frames = fk_frames(profile.model, np.zeros(6))
    flange = frames[6]
    w = frames[4, :3, 3]
    tcp = (flange @ profile.tool_matrix)[:3, 3]
    v = flange[:3, :3].T @ (tcp - w)
    return v, float(profile.tool_matrix[:3, 2] @ v)


def down_rotation_local() -> np.ndarray:
    """Tool orientation of the nominal points in block coordinates: tool z = −block z."""
    return np.diag([-1.0, 1.0, -1.0])


@dataclass(frozen=True)
class PointGroup:
    """Nominal points commanded in one tool orientation, over a patch of their own."""

    name: str  # "down", "turned", "tilted"
    description: str
    rotation_local: np.ndarray  # (3, 3) the tool's orientation, block coordinates
    height_mm: float  # the points' plane above the XY face


def point_groups(
    n_points: int, height_mm: float = VERIFY_HEIGHT_MM
) -> list[tuple[PointGroup, int]]:
    """The orientations the points are commanded in and how many points each (module doc):
    the beam straight down (paper 000's), the tool turned 180° about that beam, and the beam
    tilted ``TILT_DEG`` towards block +X over a patch ``TILTED_RAISE_MM`` higher; one point
    takes the first, two the first two, more a third of them each for the others."""
    if n_points < 1:
        raise ValueError(f"the number of points must be at least 1, got {n_points}")
    down = PointGroup("down", "beam straight down", down_rotation_local(), height_mm)
    turned = PointGroup(
        "turned",
        "beam straight down, the tool turned 180° about it",
        down_rotation_local() @ np.diag([-1.0, -1.0, 1.0]),
        height_mm,
    )
    tilted = PointGroup(
        "tilted",
        f"beam {TILT_DEG:g}° from straight down towards block +X",
        Rotation.from_euler("y", -TILT_DEG, degrees=True).as_matrix() @ down_rotation_local(),
        height_mm + TILTED_RAISE_MM,
    )
    if n_points <= 2:
        return [(down, 1), (turned, 1)][:n_points]
    k = n_points // 3
    return [(down, n_points - 2 * k), (turned, k), (tilted, k)]


def grid_shape(n: int) -> tuple[int, int]:
    """Columns (along block X) and rows (along block Y) of an ``n``-point grid, most square
    first, more columns than rows (20 → 5 × 4, 4 → 2 × 2, 6 → 3 × 2, 7 → 7 × 1)."""
    if n < 1:
        raise ValueError(f"the number of points must be at least 1, got {n}")
    rows = max(r for r in range(1, math.isqrt(n) + 1) if n % r == 0)
    return n // rows, rows


def verify_region(
    profile: CellProfile,
    height_mm: float = VERIFY_HEIGHT_MM,
    rotation_local: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Lower and upper corner (block X, Y of the TCP, mm) of the area a grid spans with the tool
    turned ``rotation_local`` (block coordinates; default straight down).

    The TCP must lie ``EDGE_MARGIN_MM`` inside the XY face, and W must be ``WALL_PATH_MM`` of
    water path (plus the lever a_T·v) from the YZ and XZ faces.
    """
    v, lever = tool_lever(profile)
    rot = down_rotation_local() if rotation_local is None else rotation_local
    r_flange = rot @ profile.tool_matrix[:3, :3].T
    w_from_tcp = -(r_flange @ v)  # W − TCP in block coordinates
    size = profile.sample_face_size_mm
    lo = np.maximum(EDGE_MARGIN_MM, WALL_PATH_MM[0] + lever - w_from_tcp[:2])
    hi = np.minimum(size - EDGE_MARGIN_MM, WALL_PATH_MM[1] + lever - w_from_tcp[:2])
    if np.any(hi <= lo):
        raise SafetyError(
            f"no room for verification points on the XY face of the block "
            f"({size:g} mm faces, tool lever {lever:.1f} mm, walls "
            f"{WALL_PATH_MM[0]:g}–{WALL_PATH_MM[1]:g} mm away)"
        )
    return lo, hi


def nominal_points(
    profile: CellProfile,
    n: int,
    height_mm: float = VERIFY_HEIGHT_MM,
    rotation_local: np.ndarray | None = None,
) -> np.ndarray:
    """Nominal TCP positions (n, 3) in block coordinates (mm): a grid (``grid_shape``) over
    ``verify_region`` at ``height_mm`` above the XY face, in serpentine order (short moves)."""
    nx, ny = grid_shape(n)
    lo, hi = verify_region(profile, height_mm, rotation_local)
    xs = np.linspace(lo[0], hi[0], nx) if nx > 1 else np.array([0.5 * (lo[0] + hi[0])])
    ys = np.linspace(lo[1], hi[1], ny) if ny > 1 else np.array([0.5 * (lo[1] + hi[1])])
    pts: list[list[float]] = []
    for j, y in enumerate(ys):
        row = xs if j % 2 == 0 else xs[::-1]
        pts.extend([x, y, height_mm] for x in row)
    return np.array(pts, float)


def target_matrix(
    profile: CellProfile, point_local_mm: np.ndarray, rotation_local: np.ndarray | None = None
) -> np.ndarray:
    """Tool pose (4, 4, base frame) of a nominal point given in block coordinates (mm), the
    tool turned ``rotation_local`` (block coordinates; default straight down)."""
    s_mat = profile.sample_matrix
    t = np.eye(4)
    t[:3, :3] = s_mat[:3, :3] @ (
        down_rotation_local() if rotation_local is None else rotation_local
    )
    t[:3, 3] = s_mat[:3, :3] @ np.asarray(point_local_mm, float) + s_mat[:3, 3]
    return t


# ---------------------------------------------------------------------------------------------
# "before": the profile as it was before its last calibration


@dataclass(frozen=True)
class BeforeProfile:
    """The "before" pass: the offsets and the block pose the profile had before its last
    calibration, and where they come from."""

    offsets_deg: np.ndarray
    source: str
    #: the block's corner (mm) and orientation (deg) then, base frame; None: the current ones
    sample_position_mm: np.ndarray | None = None
    sample_rotation_deg: np.ndarray | None = None

    def placed(self, profile: CellProfile) -> CellProfile:
        """``profile`` with the block where it was before the calibration (``calibrate``
        writes the block it measured)."""
        if self.sample_position_mm is None or self.sample_rotation_deg is None:
            return profile
        return profile.replace(
            sample_position_mm=self.sample_position_mm,
            sample_rotation_deg=self.sample_rotation_deg,
        )

    def same_as(self, profile: CellProfile) -> bool:
        """True when "before" is the profile as it is: both passes command the same points."""
        placed = self.placed(profile)
        return bool(
            np.allclose(self.offsets_deg, profile.joint_offsets_deg, rtol=0.0, atol=1e-9)
            and np.allclose(placed.sample_matrix, profile.sample_matrix, rtol=0.0, atol=1e-9)
        )


def offsets_before_calibration(profile_path: str | Path) -> BeforeProfile:
    """The joint offsets and the block pose of the profile as it was before its last
    ``calibrate`` write (its history); zero offsets and the current block when the history
    holds none (a profile calibrated by hand, or never)."""

    for entry in reversed(profile_history(profile_path)):
        if entry.reason.startswith("calibrate") and not entry.undone:
            before = history_dir(profile_path) / entry.before
            if before.exists():
                old = load_profile(before, base_dir=Path(profile_path).parent)
                return BeforeProfile(
                    np.asarray(old.joint_offsets_deg, float),
                    f"history entry {entry.id} ({entry.time}): the profile "
                    "before its last calibration (its offsets and block pose)",
                    np.asarray(old.sample_position_mm, float),
                    np.asarray(old.sample_rotation_deg, float),
                )
    return BeforeProfile(np.zeros(6), "no calibration in the profile's history: zero offsets")


@dataclass(frozen=True)
class SoundSpeed:
    """The sound speed verify converts times of flight with, and where it comes from."""

    m_s: float
    temperature_c: float  # the water temperature Marczak's c(T) gives it at
    source: str


def profile_notes(profile: CellProfile) -> list[str]:
    """What the profile says it does not know that shows in every "after" figure: joints the
    last calibration could not determine (J6 excepted: the tool is measured in its frame) or
    a profile never calibrated. One sentence each, for ``notes`` in ``--json``."""
    if profile.joint_offsets_std_deg is None:
        return [
            "the profile's joint offsets were never calibrated ([calibration] has no std_deg): "
            "'after' is the robot as its controller zeroes it; run `ucal calibrate` first"
        ]
    kept = [j for j in profile.unobservable_joints if j != 6]
    if not kept:
        return []
    names = ", ".join(f"J{j}" for j in kept)
    why = (
        " (with a hand-placed block J1's offset and the block's yaw are one rotation: a "
        "doweled, levelled fixture and its [sample] rotation_std_deg let calibrate measure it)"
        if 1 in kept
        else ""
    )
    return [
        f"{names} not calibrated ([calibration] unobservable_joints, kept at the profile's "
        f"value): its error is in every 'after' figure{why}"
    ]


@dataclass(frozen=True)
class VerifyGauge:
    """What verify's figures are relative to, and what that leaves known in the robot's base
    frame (``ucal.calibration.gauge``).

    Every deviation is measured against the block's faces (the water paths and the edges):
    it says where the tool is relative to the block. ``calibrate`` gives J1 relative to the
    block as placed (``[calibration] gauge = "block"``), so in the base frame the points are
    where the profile puts them only to the block's yaw tolerance times their distance from
    the base axis; with a doweled block (``"base"``) that is small.
    """

    j1: str | None  # [calibration] gauge as calibrate wrote it; None: not written
    yaw_std_deg: float  # [sample] rotation_std_deg[2]
    reach_mm: float = 0.0  # the points' largest distance from the base axis

    @property
    def absolute_std_mm(self) -> float | None:
        """One sigma of the points' position in the base frame from the block's yaw (mm);
        None when the profile does not say how J1 was calibrated."""
        if self.j1 is None:
            return None
        return self.reach_mm * math.radians(self.yaw_std_deg)

    def statement(self) -> str:
        """The gauge in words (``gauge_note`` in ``--json``)."""
        text = (
            "positions relative to the block (gauge: block): every deviation is measured "
            "against the block's faces, which is what a scan of a part located from the block "
            "needs"
        )
        absolute = self.absolute_std_mm
        if self.j1 == "block" and absolute is not None:
            text += (
                f"; J1 is calibrated relative to the block as placed, so in the robot's base "
                f"frame the points are where the profile puts them only to ±{absolute:.1f} mm "
                f"(one sigma: the block's yaw as placed, ±{self.yaw_std_deg:g}°, at "
                f"{self.reach_mm:.0f} mm from the base axis); a doweled, levelled block makes "
                "them absolute"
            )
        elif self.j1 == "base" and absolute is not None:
            text += (
                f"; J1 is absolute (the block's yaw declared to ±{self.yaw_std_deg:g}°): in the "
                f"robot's base frame too, to ±{absolute:.2f} mm"
            )
        return text


def calibration_gauge(profile: CellProfile, profile_path: str | Path) -> VerifyGauge:
    """How the profile's J1 was calibrated (``[calibration] gauge``, written by ``calibrate``)
    and the block's yaw tolerance."""
    try:
        with open(profile_path, "rb") as f:
            j1 = tomllib.load(f).get("calibration", {}).get("gauge")
    except (OSError, tomllib.TOMLDecodeError):
        j1 = None
    yaw = float(np.broadcast_to(profile.sample_rotation_std_deg, 3)[2])
    return VerifyGauge(j1 if j1 in ("block", "base") else None, yaw)


def sound_speed_for_verify(profile: CellProfile, profile_path: str | Path) -> SoundSpeed:
    """The sound speed ``calibrate`` measured with the offsets (``[calibration]
    sound_speed_m_s``), else Marczak's at the profile's ``[water] temperature_c``.

    The thermometer's tolerance (±2 °C, 6 m/s) is 0.4 % of every water path: 0.6 mm at the
    150 mm of a wall, different at every point; the calibration's fitted speed is known to
    tenths of a m/s.
    """

    temp = float(profile.water_temperature_c)
    try:
        with open(profile_path, "rb") as f:
            measured = tomllib.load(f).get("calibration", {}).get("sound_speed_m_s")
    except (OSError, tomllib.TOMLDecodeError):
        measured = None
    if isinstance(measured, int | float) and np.isfinite(measured):
        c = float(measured)
        lo, hi = 0.0, 70.0  # c(T) rises monotonically here
        c_lo, c_hi = (float(sound_speed_m_s(t)) for t in (lo, hi))
        if c_lo < c < c_hi:
            t_eq = float(brentq(lambda t: float(sound_speed_m_s(t)) - c, lo, hi, xtol=1e-9))
            return SoundSpeed(
                c, t_eq, f"[calibration] sound_speed_m_s, measured with the offsets ({c:.2f} m/s)"
            )
    c = float(sound_speed_m_s(temp))
    return SoundSpeed(c, temp, f"[water] temperature_c = {temp:g} °C ({c:.2f} m/s, Marczak)")


def passed(after_stats: dict[str, list[float]], tolerance_mm: float) -> bool:
    """True when no point of the "after" pass deviates more than ``tolerance_mm`` on any axis."""
    return bool(np.max(after_stats["max"]) <= tolerance_mm)


# ---------------------------------------------------------------------------------------------
# plan


@dataclass(frozen=True)
class VerifyTarget:
    """One commanded point of one pass, with the planned face postures."""

    pass_name: str  # "before" or "after"
    index: int  # 0-based point number
    joints_deg: np.ndarray  # (6,) commanded readings (TCP on the nominal point)
    face_joints_deg: np.ndarray  # (3, 6) planned normal-incidence postures, by face 0, 1, 2
    #: the tool's least water path to a face there as the profile's current offsets predict
    #: it (mm): a "before" point commanded with offsets degrees off may be in the block
    clearance_mm: float = np.inf

    @property
    def label(self) -> str:
        return f"{self.pass_name} {self.index + 1}"


@dataclass(frozen=True)
class VerifyPlan:
    """Nominal points and the commanded postures of both passes."""

    nominal_mm: np.ndarray  # (n, 3) block coordinates
    height_mm: float  # of the points commanded straight down
    offsets_deg: dict[str, np.ndarray]  # offsets the IK of each pass used
    targets: tuple[VerifyTarget, ...]  # all "before" targets, then all "after"
    #: tool check: the block axis (0: X, 1: Y) of each edge scan and the point whose "after"
    #: posture it starts from (the down points' first, then the turned points')
    edge_points: tuple[tuple[int, int], ...] = ((0, 0), (1, 0))
    groups: tuple[PointGroup, ...] = ()
    group_of: tuple[int, ...] = ()  # each point's group

    @property
    def points(self) -> int:
        return len(self.nominal_mm)

    def rotation_local(self, index: int) -> np.ndarray:
        """The tool's commanded orientation at point ``index`` (block coordinates)."""
        return (
            self.groups[self.group_of[index]].rotation_local
            if self.groups
            else down_rotation_local()
        )


def wrist_centre_local(
    profile: CellProfile, joints_deg: np.ndarray, offsets_deg: np.ndarray
) -> np.ndarray:
    """The profile's wrist centre W at readings (6,) with ``offsets_deg``, block coordinates."""
    s_mat = profile.sample_matrix
    w = fk_frames(profile.model, np.asarray(joints_deg, float), offsets_deg)[4, :3, 3]
    return s_mat[:3, :3].T @ (w - s_mat[:3, 3])


def tool_clearance_mm(profile: CellProfile, w_local_mm: np.ndarray) -> float:
    """The least water path (mm) the tool can have to a face while the wrist turns it about W
    (block coordinates): W's distance to the nearest face less the tool's reach from W."""
    v, _ = tool_lever(profile)
    return float(np.min(w_local_mm) - np.linalg.norm(v))


def joints_for(
    profile: CellProfile,
    pose: np.ndarray,
    offsets_deg: np.ndarray,
    near_deg: np.ndarray,
    label: str,
) -> np.ndarray:
    """Joint readings (deg) that put the profile's tool at ``pose`` (4, 4, base frame), nearest
    ``near_deg``, checked against the ranges (``SafetyError`` naming ``label`` otherwise)."""
    try:
        q = ik(profile.model, pose, profile.tool_matrix, offsets_deg, near_deg=near_deg)
    except UnreachableError as e:
        raise SafetyError(f"{label}: {e}") from None
    check_joints(profile, q, label)
    return q


def plan_verify(
    profile: CellProfile,
    n_points: int = DEFAULT_POINTS,
    height_mm: float = VERIFY_HEIGHT_MM,
    before_offsets_deg: np.ndarray | None = None,
    before_placed: CellProfile | None = None,
) -> VerifyPlan:
    """Plan and check every posture of both passes before the first motion.

    The "before" points are commanded with ``before_offsets_deg`` (zero if not given) in the
    block frame of ``before_placed`` (the block where the profile had it then; the current one
    if not given), the "after" points with the profile's offsets and block.

    Checks (``SafetyError``, exit 4): IK reaches each point inside the joint ranges; every
    commanded and planned face posture keeps ``SEARCH_MARGIN_DEG`` inside the wrist ranges and
    the θ5 singularity margin of the profile; each beam meets its face inside the edges; the
    wrist centre is far enough from each face that the TCP, turning about W, stays
    ``MIN_WATER_PATH_MM`` away from it.
    """
    geom = geometry(profile)
    groups = point_groups(n_points, height_mm)
    nominal = np.concatenate(
        [nominal_points(profile, n, g.height_mm, g.rotation_local) for g, n in groups]
    )
    group_of = tuple(i for i, (_, n) in enumerate(groups) for _ in range(n))
    rotations = [groups[g][0].rotation_local for g in group_of]
    v, _ = tool_lever(profile)
    reach = float(np.linalg.norm(v))
    before = np.zeros(6) if before_offsets_deg is None else np.asarray(before_offsets_deg, float)
    offsets = {"before": before, "after": np.array(profile.joint_offsets_deg, float)}
    # each pass as its profile saw the cell (the block calibrate measured, or the one before)
    placed = {"before": before_placed or profile, "after": profile}
    geoms = {"before": geometry(placed["before"]), "after": geom}
    near = calibration_pose(profile)
    targets: list[VerifyTarget] = []
    for pass_name in PASSES:
        off = offsets[pass_name]
        seen, seen_geom = placed[pass_name], geoms[pass_name]
        prev = near
        for i, p in enumerate(nominal):
            label = f"{pass_name} point {i + 1}"
            pose = target_matrix(seen, p, rotations[i])
            q = joints_for(profile, pose, off, prev, f"plan {label}")
            w_local = wrist_centre_local(seen, q, off)
            if tool_clearance_mm(profile, w_local) < MIN_WATER_PATH_MM:
                raise SafetyError(
                    f"plan {label}: the wrist centre would be "
                    f"{np.min(w_local):.1f} mm from a face; the tool ({reach:.1f} "
                    f"mm from it) needs {MIN_WATER_PATH_MM:g} mm more"
                )
            faces = np.empty((3, 6))
            for k in FACE_ORDER:
                qf = aim_wrist(seen_geom, q, -seen_geom.normal(k), off)
                check_joints(profile, qf, f"{label}/{FACE_NAMES[k]}")
                check_face(seen, seen_geom, qf, k, off, f"{label}/{FACE_NAMES[k]}")
                faces[k] = qf
            # where the robot really goes there, as best known: the profile's current offsets
            # and block
            w_now = wrist_centre_local(profile, q, offsets["after"])
            clear = tool_clearance_mm(profile, w_now)
            targets.append(VerifyTarget(pass_name, i, q, faces, clear))
            prev = q
    # tool check: each scan line, from the point of its group nearest the far edge to beyond
    # it, in the two senses about the beam (the down and the turned points) where there are
    edge_points: list[tuple[int, int]] = []
    for g in range(min(len(groups), 2)):
        members = np.flatnonzero(np.array(group_of) == g)
        edge_points += [(axis, int(members[np.argmax(nominal[members, axis])])) for axis in (0, 1)]
    after = [t for t in targets if t.pass_name == "after"]
    for axis, i in edge_points:
        end = nominal[i].copy()
        end[axis] = profile.sample_face_size_mm + EDGE_OVERSHOOT_MM
        label = f"plan {edge_label(axis, groups[group_of[i]][0])}"
        pose = target_matrix(profile, end, rotations[i])
        joints_for(profile, pose, offsets["after"], after[i].joints_deg, label)
    return VerifyPlan(
        nominal,
        float(height_mm),
        offsets,
        tuple(targets),
        tuple(edge_points),
        tuple(g for g, _ in groups),
        group_of,
    )


def edge_label(axis: int, group: PointGroup) -> str:
    """A scan of the tool check in words: "tool check along block X" (down points), "..., tool
    turned" (the turned points)."""
    return f"tool check along block {'XY'[axis]}" + (
        ", tool turned" if group.name == "turned" else ""
    )


# ---------------------------------------------------------------------------------------------
# reconstruction (pure functions)


def wrist_centre_from_distances(distances_mm: np.ndarray, lever_mm: float) -> np.ndarray:
    """W in block coordinates (mm) from the normal-incidence water paths to faces 0, 1, 2.

    ``d_k = n_k·(W − c) − a_T·v`` (``ucal.calibration.model``, eq. 2) → ``W_k = d_k + a_T·v``.
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
        return self.correction @ r06


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
        return (beams + normals).ravel()

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
    return np.asarray(w_local_mm, float) + geom.block_rotation.T @ (r @ v_flange_mm)


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


def deviation_stats(deviations_mm: np.ndarray) -> dict[str, list[float]]:
    """Per-axis statistics (paper 000, Table 5) of deviations (n, 3) mm.

    ``mean``, ``max``, ``std``: of the absolute deviations (std with ddof = 0); ``signed_mean``
    and ``signed_std``: of the signed deviations (bias and scatter).
    """
    d = np.asarray(deviations_mm, float).reshape(-1, 3)
    a = np.abs(d)
    return {
        "mean": a.mean(0).tolist(),
        "max": a.max(0).tolist(),
        "std": a.std(0).tolist(),
        "signed_mean": d.mean(0).tolist(),
        "signed_std": d.std(0).tolist(),
    }


# ---------------------------------------------------------------------------------------------
# measurement


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
        return self.reached_mm - self.nominal_mm


@dataclass(frozen=True)
class EdgeCheck:
    """One edge scan of the tool check (module doc): where the real TCP crosses x = S (y = S)."""

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


def tool_offset(checks: tuple[EdgeCheck, ...]) -> np.ndarray:
    """The bias b (3,) of the down points' scans (block axes, mm): what the tool check adds
    to every wrist-centre estimate of a point commanded straight down."""
    b = np.zeros(3)
    for c in checks[:2]:
        b[c.axis] = c.offset_mm
    return b


@dataclass(frozen=True)
class ToolOffset:
    """The real tool against the profile's, as the edge scans see it (module docstring): κ,
    what the water paths took for the TCP's reach along the beam too little, and Δ⊥, the
    tool's error across the beam (flange frame, mm)."""

    along_mm: float  # κ = a_T'·v' − a_T·v
    across_mm: np.ndarray  # (3,) Δ⊥, flange frame, orthogonal to the profile's beam
    beam_flange: np.ndarray  # (3,) the profile's beam a_T, flange frame
    separated: bool  # scans in both senses about the beam: κ and Δ⊥ apart
    #: the largest misfit of a scan to κ and Δ⊥ (mm; 0 with three scans or fewer): four
    #: scans hold one check. The model takes the profile's beam direction as the real one;
    #: a beam a few tenths of a degree off it (a tool not yet measured) turns the flange
    #: orientation the postures give by as much, differently in each sense about the beam,
    #: and shows here as the misfit (0.42 mm for a tool turned 0.3°, module docstring).
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

    def to_json(self, tolerance_mm: float | None = None) -> dict:
        """The ``verify --json`` object of SPEC.md plus per-point detail (mm, deg)."""
        out: dict = {f"{p}_mm": self.stats(p) for p in PASSES}
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


class _Predictor:
    """Running estimate of offsets and corner from every face measured so far."""

    def __init__(self, geom: CellGeometry, prior_deg: np.ndarray, corner_mm: np.ndarray):
        self.geom = geom
        self.prior = np.asarray(prior_deg, float)
        self.corner_prior = np.asarray(corner_mm, float)
        self.x = np.concatenate([self.prior, self.corner_prior])
        self.meas: list[FaceMeasurement] = []

    @property
    def offsets_deg(self) -> np.ndarray:
        return self.x[:6]

    def add(self, m: FaceMeasurement) -> None:
        self.meas.append(m)
        self.x = np.concatenate(
            estimate_offsets(self.geom, self.meas, self.prior, self.corner_prior, self.x)
        )


def _tilt_deg(
    tilt_map: np.ndarray, joints: tuple[int, int], q: np.ndarray, ref: np.ndarray
) -> float:
    """Beam tilt (deg) between two postures differing in the search joints (map: deg → rad)."""
    j = list(joints)
    return float(np.degrees(np.linalg.norm(tilt_map @ (q[j] - ref[j]))))


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
    temp = profile.water_temperature_c
    ka = ka_of(profile.frequency_mhz, profile.element_diameter_mm, temp)
    v, _ = tool_lever(profile)
    pred = _Predictor(geom, profile.joint_offsets_deg, profile.sample_position_mm)

    # Noise floor with the beam in open water: the first point's posture with the wrist turned
    # 25° away from the XY face's normal (far outside every lobe that matters).
    first = plan.targets[0]
    js0, _ = search_joints(
        geom, first.face_joints_deg[2], plan.offsets_deg["before"], face_basis(geom, 2)
    )
    away = first.joints_deg.copy()
    away[js0[1]] += 25.0
    setup = FaceSetup(profile, ka, acquisition_gain(rig, away))

    last_wrist: dict[int, np.ndarray] = {}
    pred_err_deg: dict[int, float] = {}  # last prediction error per face (deg of tilt)
    results: list[PointResult] = []
    skipped: list[SkippedPoint] = []
    orientations: dict[int, WristOrientation] = {}  # of the "after" points
    total = len(plan.targets) + len(plan.edge_points)
    approach = FinalApproachRig(rig)
    for n_done, target in enumerate(plan.targets):
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
            # A face whose last prediction was within DIRECT_FIT_TILT_DEG goes straight to the
            # fit (its 3×3 grid spans ±0.14° of tilt, the main lobe ±0.2°); one predicted less
            # well is centred on its main lobe first; the first faces are acquired.
            last = pred_err_deg.get(k, np.inf)
            mode = (
                SearchMode.DIRECT
                if last < DIRECT_FIT_TILT_DEG
                else SearchMode.QUICK
                if len(pred.meas) >= 2
                else SearchMode.ACQUIRE
            )
            request = FaceRequest(
                face=Face(k),
                start_deg=start,
                geometry=geom,
                offsets_deg=pred.offsets_deg,
                label=label,
                config=f"{target.pass_name}/{target.index}",
                mode=mode,
                radius_deg=16.0 if not pred.meas else 8.0,
            )
            found = measure(rig, setup, request)
            m = found.measurement
            pred_err_deg[k] = found.prediction_error_deg
            faces[k] = m
            last_wrist[k] = m.joints_deg
            pred.add(m)
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
            progress(MeasureStep(what, len(plan.targets) + n_scan, total, "after", "XY"))
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
    # Leave the robot at the last commanded point (beam down, clear of the block).
    approach.move(plan.targets[-1].joints_deg)
    if progress:
        progress(MeasureStep("solving", total, total))
    return VerifyResult(
        plan,
        results,
        rig.counters.moves,
        rig.counters.reads,
        pred.offsets_deg.copy(),
        checks,
        tuple(skipped),
        tool,
    )


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
        motion."""
        s_mat = profile.sample_matrix
        q = np.asarray(joints_deg, float).reshape(-1, 6)
        measured = np.asarray(measured_mm, float).reshape(-1, 3)
        base = np.asarray(offsets_deg, float)
        reach = float(np.linalg.norm(tool_lever(profile)[0]))

        def build(x: np.ndarray) -> WristMap:
            off = base.copy()
            off[:3] += x[:3]
            rot = Rotation.from_rotvec(x[3:6]).as_matrix() @ s_mat[:3, :3].T
            turn = Rotation.from_rotvec(x[9:12]).as_matrix()
            return cls(profile.model, off, rot, x[6:9] - rot @ s_mat[:3, 3], turn)

        def fun(x: np.ndarray) -> np.ndarray:
            m = build(x)
            res = [(m(q) - measured).ravel(), 1e-4 * x[:3], 0.1 * x[3:6]]
            if rotations is not None:
                miss = np.swapaxes(m.rotation(q), -1, -2) @ rotations
                res.append(reach * Rotation.from_matrix(miss).as_rotvec().ravel())
            else:
                res.append(x[9:12])
            return np.concatenate(res)

        x0 = np.zeros(12)
        x0[6:9] = (measured - build(x0)(q)).mean(0)
        sol = least_squares(fun, x0, method="lm", xtol=1e-15, ftol=1e-15, gtol=1e-15)
        return build(sol.x)

    def __call__(self, joints_deg: np.ndarray) -> np.ndarray:
        """W (block coordinates, mm) at readings (6,) or (n, 6)."""
        w = fk_frames(self.model, np.asarray(joints_deg, float), self.offsets_deg)[..., 4, :3, 3]
        return w @ self.to_block.T + self.origin_mm

    def rotation(self, joints_deg: np.ndarray) -> np.ndarray:
        """The true flange rotation (base frame) at readings (6,) or (n, 6)."""
        frames = fk_frames(self.model, np.asarray(joints_deg, float), self.offsets_deg)
        return self.turn @ frames[..., 6, :3, :3]


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
    """Scan the TCP from an "after" point across the XY face's far edge on ``axis`` (module doc).

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
        a = rig.normalised_amplitude(EDGE_AVERAGES)
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
    rig.level_gain(EDGE_AVERAGES)
    level = rig.normalised_amplitude(EDGE_AVERAGES)
    t = max(0.0, t_edge - EDGE_APPROACH_MM)
    while (a := amplitude(t)) < 0.5 * level and t > 0.0:
        t = max(0.0, t - EDGE_APPROACH_MM)
    t_c = coarse_edge_fall(amplitude, t, a, t_max, EDGE_COARSE_STEP_MM, EDGE_COARSE_MEMORY)
    if t_c is None:
        raise HardwareError(
            f"{rig.pulser.endpoint}: {label}: the echo did not fall at the block's edge "
            f"within {t_max:.0f} mm of point {point.index + 1}: is [sample] face_size_mm "
            "right and the edge clean?"
        )
    try:
        fit = fine_edge_scan(probe, t_c, EDGE_FINE_HALF_MM, EDGE_FINE_PROBES, t_max)
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


def true_reached_local(truth: WorldTruth, joints_deg: np.ndarray) -> np.ndarray:
    """Simulation only: the TCP the true robot reaches at readings ``joints_deg`` in the
    coordinates of the *true* block (mm): what the measurement should find. The commanded
    points are reached from below on every joint, so a joint with backlash lags by half of it
    against a positive motion."""

    tcp = SimulatedCell(truth).true_tcp(joints_deg, motion_sign=np.ones(6))[:3, 3]
    s_mat = truth.sample_matrix
    return s_mat[:3, :3].T @ (tcp - s_mat[:3, 3])


# ---------------------------------------------------------------------------------------------
# the verify command's job in the procedure of ``ucal.procedure``


def plan_summary(plan: VerifyPlan, profile_path: Path) -> str:
    """The plan in words for the confirmation (stderr)."""
    lines = [
        f"verify {profile_path}: {plan.points} points x 2 passes (before/after calibration), "
        f"3 face searches per point ({6 * plan.points} in all):"
    ]
    for n, g in enumerate(plan.groups):
        pts = plan.nominal_mm[np.array(plan.group_of) == n]
        lo, hi = pts.min(0), pts.max(0)
        lines.append(
            f"  {len(pts)} points, {g.description}: block X {lo[0]:.0f}-{hi[0]:.0f} mm, "
            f"Y {lo[1]:.0f}-{hi[1]:.0f} mm, {g.height_mm:g} mm above the XY face"
        )
    senses = "in both senses about the beam" if len(plan.edge_points) > 2 else "straight down"
    lines.append(f"then a tool check across the XY face's two far edges, {senses}.")
    return "\n".join(lines)


def truth_check(
    result: VerifyResult, truth: WorldTruth, profile: CellProfile | None = None
) -> dict[str, Any]:
    """Simulation only: the true reached TCPs and how far the measurement was from them.

    The error splits into a common bias and what remains point by point. ``after_mm`` is what
    the "after" figure should have been (the true TCP against the nominal point, relative to
    the true block, as verify measures it), ``after_figure_error_mm`` how far the reported
    largest deviations are from it; with ``profile``, ``absolute_after_max_mm`` is the true
    TCP in the robot's base frame against the nominal point where the profile places it
    (profile's block axes): what the block gauge does not check.
    """
    reached: dict[str, list[Any]] = {"before": [], "after": []}
    err = []
    true_base = []
    for p in sorted(result.points, key=lambda r: (r.pass_name != "before", r.index)):
        t = true_reached_local(truth, p.commanded_deg)
        reached[p.pass_name].append(t.tolist())
        err.append(p.reached_mm - t)
        if p.pass_name == "after":
            s_mat = truth.sample_matrix
            true_base.append(s_mat[:3, :3] @ t + s_mat[:3, 3])
    err_arr = np.array(err)
    bias = err_arr.mean(0)
    n_before = len(reached["before"])
    after = result.measured("after")
    nominal = np.array([p.nominal_mm for p in after]).reshape(-1, 3)
    true_after = deviation_stats(np.array(reached["after"]).reshape(-1, 3) - nominal)
    out = {
        "joint_offsets_deg": truth.joint_offsets_deg.tolist(),
        "reached_mm": reached,
        "measurement_error_max_mm": np.abs(err_arr).max(0).tolist(),
        "after_error_max_mm": np.abs(err_arr[n_before:]).max(0).tolist(),
        "measurement_bias_mm": bias.tolist(),
        "measurement_scatter_max_mm": np.abs(err_arr - bias).max(0).tolist(),
        "after_mm": {k: true_after[k] for k in ("mean", "max", "std")},
        "after_figure_error_mm": np.abs(
            np.array(result.stats("after")["max"]) - np.array(true_after["max"])
        ).tolist(),
    }
    if profile is not None and true_base:
        s_mat = profile.sample_matrix
        placed = nominal @ s_mat[:3, :3].T + s_mat[:3, 3]
        absolute = (np.array(true_base) - placed) @ s_mat[:3, :3]
        out["absolute_after_max_mm"] = np.abs(absolute).max(0).tolist()
    return out


@dataclass
class VerifyShown:
    """What the result tables are drawn from."""

    result: VerifyResult
    before: BeforeProfile
    sound: SoundSpeed
    tolerance_mm: float
    worst_mm: float
    truth: dict[str, Any] | None
    plot_path: Path | None
    gauge: VerifyGauge = field(default_factory=lambda: VerifyGauge(None, 0.0))
    #: "before" is the profile as it is (no calibration in its history): both passes alike
    before_is_after: bool = False


def tool_notes(tool: ToolOffset | None, profile: CellProfile) -> list[str]:
    """What the tool check says of the profile's ``[tool]``: off by more than its stated std
    (moved since ``tool-frame``, or never measured), or, along the beam, off within it (the
    hand-touched plate's tolerance, which shows in X and Y of the points straight down)."""
    if tool is None:
        return []
    std = np.broadcast_to(np.asarray(profile.tool_position_std_mm, float), 3)
    beam = np.abs(profile.tool_matrix[:3, 2])
    along_std = float(np.sqrt(np.sum((beam * std) ** 2)))
    across_std = float(np.sqrt(np.sum(((1.0 - beam) * std) ** 2)))
    across = float(np.linalg.norm(tool.across_mm))
    notes = []
    if across > max(3.0 * across_std, MEASURED_WITHIN_MM):
        notes.append(
            f"the tool check finds the real tool {across:.3f} mm off the profile's across the "
            f"beam, beyond what [tool] says it is known to (±{across_std:.3f} mm): moved since "
            "`ucal tool-frame` measured it, or never measured? run `ucal tool-frame`"
        )
    along = abs(tool.along_mm)
    longer = f"{along:.3f} mm {'longer' if tool.along_mm > 0 else 'shorter'} along the beam"
    if along > max(3.0 * along_std, MEASURED_WITHIN_MM):
        notes.append(
            f"the tool check finds the real tool {longer} than the profile's, beyond what "
            f"[tool] says it is known to (±{along_std:.3f} mm): run `ucal tool-frame`"
        )
    elif along > MEASURED_WITHIN_MM:
        notes.append(
            f"the real tool is {longer} than the profile's, within what [tool] says it is "
            f"known to (±{along_std:.2f} mm; after `ucal tool-frame`, the touched plate's "
            "tolerance): it shows in X and Y of the points straight down"
        )
    return notes


def tool_misfit_mm(shown: VerifyShown) -> float:
    """The tool check's largest misfit (mm; 0 without a tool check)."""
    tool = shown.result.tool
    return 0.0 if tool is None else tool.misfit_mm


def marginal(shown: VerifyShown) -> bool:
    """The verdict could go the other way within what verify measures to (plus the tool
    check's misfit)."""
    return bool(
        abs(shown.worst_mm - shown.tolerance_mm) <= MEASURED_WITHIN_MM + tool_misfit_mm(shown)
    )


class VerifyJob(CheckingJob):
    """``verify``: the positioning error before and after calibration; writes its picture,
    never the profile."""

    def __init__(
        self,
        profile: CellProfile,
        profile_path: Path,
        n_points: int = DEFAULT_POINTS,
        tolerance_mm: float | None = None,
        plot_path: Path | None = None,
    ) -> None:
        super().__init__(profile, profile_path, tolerance_mm)
        self.n_points = n_points
        self.plot_path = plot_path
        self.before = BeforeProfile(np.zeros(6), "")
        self.sound = SoundSpeed(0.0, 0.0, "")
        self.gauge = VerifyGauge(None, 0.0)

    def check(self, options: RunOptions) -> AbstractContextManager[object]:
        """The "before" offsets and block from the profile's history, the sound speed of its
        last calibration and its J1 gauge; nothing is held (the profile is not written)."""
        self.before = offsets_before_calibration(self.profile_path)
        self.sound = sound_speed_for_verify(self.profile, self.profile_path)
        self.gauge = calibration_gauge(self.profile, self.profile_path)
        return super().check(options)

    def plan(self) -> VerifyPlan:
        return plan_verify(
            self.profile,
            self.n_points,
            before_offsets_deg=self.before.offsets_deg,
            before_placed=self.before.placed(self.profile),
        )

    def summary(self, plan: VerifyPlan) -> str:
        return plan_summary(plan, self.profile_path)

    def estimate(self, plan: VerifyPlan) -> DurationEstimate:
        speed = self.profile.procedure.speed
        postures = [t.face_joints_deg[k] for t in plan.targets for k in FACE_ORDER]
        faces = estimate_run(postures, calibration_pose(self.profile), speed)
        edges = [plan.targets[-1].joints_deg] * len(plan.edge_points)
        return faces + estimate_run(edges, edges[0], speed, search=EDGE_SCAN, first=NO_SEARCH)

    def record_header(self, plan: VerifyPlan) -> dict[str, Any]:
        return {"options": {"points": self.n_points}, "plan": []}

    def measure(self, plan: VerifyPlan, session: CellSession, report: Report) -> VerifyResult:
        # times of flight converted with the measured sound speed (as a water temperature)
        measuring = self.profile.replace(water_temperature_c=self.sound.temperature_c)
        return run_verify(measuring, plan, session.rig, report)

    def solve(self, plan: VerifyPlan, measured: Measured[VerifyResult]) -> VerifyShown:
        result = measured.data
        s_mat = self.profile.sample_matrix
        points_base = plan.nominal_mm @ s_mat[:3, :3].T + s_mat[:3, 3]
        reach = float(np.max(np.hypot(points_base[:, 0], points_base[:, 1])))
        truth = measured.truth
        return VerifyShown(
            result,
            self.before,
            self.sound,
            self.tolerance_mm,
            float(np.max(result.stats("after")["max"])),
            None if truth is None else truth_check(result, truth, self.profile),
            self.plot_path,
            replace(self.gauge, reach_mm=reach),
            self.before.same_as(self.profile),
        )

    def may_write(self, shown: VerifyShown) -> bool:
        return self.plot_path is not None

    def write(self, shown: VerifyShown) -> None:
        assert self.plot_path is not None
        plot_verify(shown.result, self.plot_path, self.picture_text(shown))

    def picture_text(self, shown: VerifyShown) -> PictureText:
        """What the picture says beside its data: the profile, the verdict's terms, why
        "before" is what it is, the gauge and the notes."""
        return PictureText(
            name=self.profile_path.name,
            tolerance_mm=shown.tolerance_mm,
            marginal=marginal(shown),
            before_source=shown.before.source,
            before_is_after=shown.before_is_after,
            gauge_note=shown.gauge.statement(),
            notes=tuple(self.notes(shown)),
        )

    def notes(self, shown: VerifyShown) -> list[str]:
        """``notes`` of the result: what the profile says it does not know, and a tool check
        whose scans disagree."""
        notes = profile_notes(self.profile) + tool_notes(shown.result.tool, self.profile)
        misfit = tool_misfit_mm(shown)
        if misfit > MEASURED_WITHIN_MM:
            notes.append(
                f"the tool check's scans in the two senses about the beam disagree by "
                f"{misfit:.3f} mm: the beam is not where the profile's [tool] puts it in the "
                "flange (not yet measured?), and every 'after' figure may be off by as much; "
                "run `ucal tool-frame`"
            )
        return notes

    def result(
        self, plan: VerifyPlan, measured: Measured[VerifyResult], shown: VerifyShown, written: bool
    ) -> Outcome:
        out = shown.result.to_json(self.tolerance_mm)
        out["before_source"] = self.before.source
        out["sound_speed_m_s"] = self.sound.m_s
        out["sound_speed_source"] = self.sound.source
        out["profile"] = str(self.profile_path)
        out["duration_s"] = measured.duration_s
        out["gauge"] = "block"
        out["gauge_note"] = shown.gauge.statement()
        out["absolute_std_mm"] = shown.gauge.absolute_std_mm
        out["j1_gauge"] = shown.gauge.j1
        out["before_is_after"] = shown.before_is_after
        out["notes"] = self.notes(shown)
        out["marginal"] = marginal(shown)
        out["plot"] = str(self.plot_path) if written else None
        if shown.truth is not None:
            out["truth"] = shown.truth
        if not written:
            shown.plot_path = None
        message = (
            f"verify: a point deviates {shown.worst_mm:.3f} mm after calibration, above the "
            f"tolerance of {self.tolerance_mm:g} mm"
        )
        return Outcome(
            self.command,
            out,
            written,
            out_of_tolerance=not out["passed"],
            message=message,
            shown=shown,
        )
