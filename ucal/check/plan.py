"""The check's plan: a few of calibrate's normal-incidence measurements and the echo chain.

Postures. The calibration configuration (the beam normal to each of the block's three faces,
arm still) and the second joint-1 azimuth of ``calibrate`` (``ucal.measure.sequence``):
six of its normal-incidence measurements, planned and checked by the same code. Seen from one
azimuth only, a change of joint 2's offset is one rotation with a tilt of the block about the
joint-2 axis (and joint 1's with its yaw, from any azimuth); from two, joints 2 to 5, the tool,
the block and the water are each told apart (``ucal.check.solve``). Where the cell leaves no
room for the second azimuth, joint 2 is stepped instead, and the check says which joints it
cannot tell from the block.

The echo chain. Every face measurement gives its time of flight and its peak amplitude (brought
to 0 dB gain); the noise floor measured in open water at the start gives the SNR. At the
calibration configuration's three postures the pulser's A-scan is read as well, where it gives
one (a window of ``ASCAN_WINDOW_US`` around the echo): the echo's centre frequency and −6 dB
bandwidth (``ucal.echo``, ASTM E1065's convention).

The edges. From the planned ``base/XY`` posture the TCP is moved across the XY face's two far
edges (``ucal.check.edges``): the tool across the beam, which no water path sees, is then
told from the block and the joints. What each measurement sees, and which quantities the
postures determine, is computed from the fit the check solves (``ucal.check.observe``) and
stated in the plan.

Duration: ``ucal.timing`` (the same model the simulated cell charges), plus the A-scan
transfers; a check is meant to fit in ``BUDGET_S`` on a real cell.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from ucal.cell import CellProfile
from ucal.check.edges import SCAN, EdgeLine, EdgeReading, plan_edges
from ucal.check.history import CheckEntry
from ucal.kinematics.ik import ik
from ucal.model.geometry import FACE_NAMES, Configuration
from ucal.model.targets import CalibrationPlan, PlannedTarget, plan_calibration
from ucal.procedure import WRIST_SEARCH, plan_line
from ucal.profile.models import joint_accelerations_deg_s2, joint_speeds_deg_s
from ucal.timing import (
    APPROACH_DEG,
    SETTLED_FRAME_S,
    DurationEstimate,
    SearchCost,
    estimate_run,
    move_s,
    read_s,
    transport_s,
)

#: The configurations a check measures: the calibration pose and the second joint-1 azimuth;
#: without room for the azimuth, joint 2 stepped.
CONFIGURATIONS = (Configuration.BASE, Configuration.J1)
FALLBACK_CONFIGURATIONS = (Configuration.BASE, Configuration.J2)
#: Where the A-scans are read.
ECHO_CONFIGURATION = Configuration.BASE
#: Width of the A-scan window around the echo (µs of round-trip time).
ASCAN_WINDOW_US = 2.0
#: Sample rate assumed for the A-scan transfer in the estimate (MHz): SPEC's default digitiser.
ASCAN_RATE_MHZ = 200.0
#: Registers per Modbus read of the A-scan's samples.
ASCAN_BLOCK = 125
#: Averages of the reading the A-scan is frozen from.
ASCAN_AVERAGES = 8
#: The echo chain at a posture: the move there, the gain levelled (a few reads), the reading
#: the A-scan is frozen from.
ECHO_READ = SearchCost(moves=0, reads=6, motion_s=0.0)
#: What a check should take on a real cell at most (s).
BUDGET_S = 120.0


@dataclass(frozen=True)
class CheckPlan:
    """What a check measures and what it compares against."""

    calibration: CalibrationPlan  # the postures: a subset of calibrate's
    echo_labels: tuple[str, ...]  # the postures where the A-scan is read
    reference: CheckEntry | None  # the reference check; None: this check records it
    baseline_asked: bool = False  # ``--baseline``: a new reference whatever the history holds
    edges: tuple[EdgeLine, ...] = ()  # the scans across the XY face's far edges
    edge_notes: tuple[str, ...] = ()  # the scans left out, and why

    @property
    def targets(self) -> tuple[PlannedTarget, ...]:
        return self.calibration.targets

    @property
    def configurations(self) -> tuple[Configuration, ...]:
        return self.calibration.configs


def plan_check(
    profile: CellProfile, reference: CheckEntry | None, baseline_asked: bool = False
) -> CheckPlan:
    """Plan and check every posture before the first motion (``SafetyError``, exit 4): the
    configurations of ``CONFIGURATIONS`` out of calibrate's plan (``FALLBACK_CONFIGURATIONS``
    when it has no second azimuth)."""
    full = plan_calibration(profile)
    wanted = CONFIGURATIONS if Configuration.J1 in full.configs else FALLBACK_CONFIGURATIONS
    targets = tuple(t for t in full.targets if t.config in wanted)
    echo = tuple(t.label for t in targets if t.config == ECHO_CONFIGURATION)
    crossed = () if reference is None else tuple(EdgeReading.from_json(e) for e in reference.edges)
    edges, notes = plan_edges(profile, targets, crossed)
    # the check compares its faces with a reference's: no water path read again at the end
    return CheckPlan(
        replace(full, targets=targets, path_again=False),
        echo,
        reference,
        baseline_asked,
        edges,
        notes,
    )


def ascan_transfer_s(framing: str, window_us: float = ASCAN_WINDOW_US) -> float:
    """Time to read one A-scan of ``window_us`` at ``ASCAN_RATE_MHZ`` over ``framing`` (s):
    its header, then its samples in blocks of ``ASCAN_BLOCK`` registers."""
    samples = int(window_us * ASCAN_RATE_MHZ) + 1
    blocks = math.ceil(samples / ASCAN_BLOCK)
    header = transport_s(framing, registers=8)
    return header + sum(
        transport_s(framing, registers=min(ASCAN_BLOCK, samples - i * ASCAN_BLOCK))
        for i in range(blocks)
    )


def estimate_check(plan: CheckPlan, profile: CellProfile) -> DurationEstimate:
    """The check's duration on a real cell: calibrate's measurements of its postures, the echo
    chain at ``plan.echo_labels`` and their A-scan transfers."""
    speed = profile.procedure.speed
    joints = joint_speeds_deg_s(profile.model)
    targets = plan.targets
    faces = estimate_run(
        [t.joints_deg for t in targets], plan.calibration.pose_deg, speed, speeds_deg_s=joints
    )
    by_label = {t.label: t for t in targets}
    echo_postures = [by_label[label].joints_deg for label in plan.echo_labels]
    echoes = estimate_run(
        echo_postures,
        targets[0].joints_deg,
        speed,
        speeds_deg_s=joints,
        averages=ASCAN_AVERAGES,
        search=ECHO_READ,
        first=SearchCost(0, 0, 0.0),
    )
    n = len(echo_postures)
    transfers = DurationEstimate(
        0, 0, 0.0, n * ascan_transfer_s("tcp"), n * ascan_transfer_s("rtu")
    )
    return faces + echoes + transfers + estimate_edges(plan, profile)


#: An edge scan beyond the move to its line: the level read twice at its start, the coarse
#: steps from there to the edge (and one beyond), then back to the fine probes across the fall;
#: each probe one reading of ``SCAN.averages`` and a move reached from below on every joint,
#: the motion model's (``ucal.timing.move_s``) over the joints' step along the line, and the
#: state frame that reports it done (``SETTLED_FRAME_S``).


def edge_probes(line: EdgeLine) -> int:
    """The probes of one edge scan (above)."""
    return 2 + _coarse_steps(line) + SCAN.fine_probes


def _coarse_steps(line: EdgeLine) -> int:
    return math.ceil((line.edge_mm - line.start_mm) / SCAN.coarse_step_mm) + 1


def edge_motion_s(line: EdgeLine, profile: CellProfile, accel_deg_s2: np.ndarray) -> float:
    """The motion of one edge scan's probes after its first (s): each probe's step along the
    line (mm) times the joints' rate along it at its start (deg/mm, the profile's kinematics)
    is a move with its approach from below. The level's second reading steps 0 (the arm still
    goes through its pre-point), each coarse step ``SCAN.coarse_step_mm``, the fine scan's
    first probe back from the coarse fall by its half width and half a coarse step, each
    later one the fine spacing; each stop reported by a state frame (``SETTLED_FRAME_S``)."""
    model, tool = profile.model, profile.tool_matrix
    offsets = np.asarray(profile.joint_offsets_deg, float)
    q0 = ik(model, line.at(line.start_mm), tool, offsets, near_deg=line.start_deg)
    rate = ik(model, line.at(line.start_mm + 1.0), tool, offsets, near_deg=q0) - q0
    speed, joints = profile.procedure.speed, joint_speeds_deg_s(model)

    def step_s(mm: float) -> float:
        move = move_s(q0, q0 + mm * rate, speed, joints, accel_deg_s2, APPROACH_DEG)
        return move + SETTLED_FRAME_S

    fine_mm = 2.0 * SCAN.fine_half_mm / (SCAN.fine_probes - 1)
    back_mm = SCAN.fine_half_mm + 0.5 * SCAN.coarse_step_mm
    return (
        step_s(0.0)
        + _coarse_steps(line) * step_s(SCAN.coarse_step_mm)
        + step_s(-back_mm)
        + (SCAN.fine_probes - 1) * step_s(fine_mm)
    )


def estimate_edges(plan: CheckPlan, profile: CellProfile) -> DurationEstimate:
    """The edge scans' duration: the move from the check's first posture to each line's
    start, then ``edge_probes`` probes a line, their moves ``edge_motion_s``, one reading of
    ``SCAN.averages`` each."""
    speed = profile.procedure.speed
    joints = joint_speeds_deg_s(profile.model)
    accel = joint_accelerations_deg_s2(profile.model)
    per_read = {f: read_s(f, SCAN.averages) for f in ("tcp", "rtu")}
    total = DurationEstimate(0, 0, 0.0, 0.0, 0.0)
    here = plan.targets[0].joints_deg
    for line in plan.edges:
        n = edge_probes(line)
        motion = move_s(here, line.start_deg, speed, joints, accel, APPROACH_DEG) + SETTLED_FRAME_S
        motion += edge_motion_s(line, profile, accel)
        total = total + DurationEstimate(
            n, n, motion, motion + n * per_read["tcp"], motion + n * per_read["rtu"]
        )
        here = line.start_deg
    return total


def plan_summary(plan: CheckPlan, profile: CellProfile, estimate: DurationEstimate) -> str:
    """The plan in words for the confirmation (stderr), with what each measurement sees and
    what the postures determine (``ucal.check.observe``); the procedure adds the estimate."""
    from ucal.check.observe import observability, observability_lines  # it fits: solve's

    configs = plan.configurations
    steps = []
    if Configuration.J1 in configs:
        steps.append(f"joint 1 by ±{plan.calibration.azimuth_step_deg:g} deg (second azimuth)")
    if Configuration.J2 in configs:
        steps.append(
            f"joint 2 by ±{plan.calibration.step_deg:g} deg (no room for a second azimuth: "
            "joint 2 cannot be told from a tilt of the block)"
        )
    if plan.reference is not None:
        against = (
            f"against the reference check {plan.reference.id} ({plan.reference.time}): what "
            "moved since is named"
        )
    elif plan.baseline_asked:
        against = "as the new reference (--baseline): later checks compare against it"
    else:
        against = (
            "as the reference (the first check of the profile as it now is): later checks "
            "compare against it"
        )
    lines = [
        (
            f"Check plan for {profile.model.name}: {len(plan.targets)} normal-incidence "
            f"measurements of calibrate's, in the calibration configuration and "
            f"{' and '.join(steps)}; {against}"
        ),
        (
            f"Echo chain: time of flight, amplitude (0 dB gain) and SNR at every posture; "
            f"centre frequency and -6 dB bandwidth from the A-scan at "
            f"{', '.join(plan.echo_labels)} (where the pulser gives one); transducer "
            f"{profile.frequency_mhz:g} MHz"
        ),
        "  target      J1       J2       J3       J4       J5       J6    water path",
        *(plan_line(f"{t.config:>4}/{FACE_NAMES[t.face]:<3}", t) for t in plan.targets),
        WRIST_SEARCH,
        *(
            f"Edge scan {line.label}: the TCP moved {line.end_mm - line.start_mm:.0f} mm along "
            f"block {'xy'[line.axis]} with the beam normal to the XY face, across the edge "
            f"{line.edge_mm:.1f} mm along the line (where the reference crossed it, else where "
            "the profile puts it): the tool across the beam"
            for line in plan.edges
        ),
        *plan.edge_notes,
        *observability_lines(
            observability(profile, plan.targets, plan.edges), profile, bool(plan.edges)
        ),
    ]
    if estimate.tcp_s > BUDGET_S:
        lines.append(
            f"note: more than the {BUDGET_S:g} s a check is meant to take (slow speed in "
            "[procedure] speed?)"
        )
    return "\n".join(lines)
