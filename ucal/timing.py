"""How long a cell takes: pulser reads, moves and settling, for the simulator and the plan.

One model serves two purposes, so that they agree: the simulated cell charges these durations
to its clock (``ucal.sim.serve``), and a plan's estimate of the real-cell duration adds them up
(``estimate_duration_s``).

* A pulser read is one Modbus request for the measurement block plus the acquisition itself
  (``averages`` pulses at the pulse repetition frequency). Over Modbus RTU the request is 8
  bytes and the answer ``5 + 2·n`` bytes (n registers), 11 bits a character, with a 3.5
  character silence before each frame: at 19,200 baud and n = 10 that is 22.9 ms, the figure
  measured on serial pulser-receivers. Over Modbus TCP a request costs about a millisecond on a
  cell network plus the instrument's own turnaround, ``TCP_READ_S`` in all.
* A move is the motion model's (``drivers.controller.motion``, the simulated controller's
  too): a joint-interpolated trapezoid at the speed fraction of the joints' speeds at 1.0
  (``ucal.profile.models.joint_speeds_deg_s``: the model file's ``speed_deg_s``), at most the
  joints' accelerations (``joint_accelerations_deg_s2``), then the servo settling that move
  needs before the controller reports it done. A static posture is reached from below through
  a pre-point ``APPROACH_DEG`` short of it, sent with it as one trajectory of two queued points
  (``move_s``): the arm rests on the pre-point only for the instant the VAL3 server takes to
  start the next point, and settles once, at the target.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from drivers.controller.motion import DEFAULT_MAX_ACCEL_DEG_S2, trajectory_s
from drivers.controller.server_variants import SERVERS
from drivers.pulser.modbus_words import rtu_read_line_s
from drivers.pulser.registers import MEASUREMENT_COUNT

#: Modbus TCP request/response on a cell network plus instrument turnaround (s): the
#: instrument's turnaround and the network's round trip (``NETWORK_LATENCY_S``, the default of
#: a world's ``[timing] pulser_latency_ms``).
NETWORK_LATENCY_S = 0.001
TCP_TURNAROUND_S = 0.001
TCP_READ_S = TCP_TURNAROUND_S + NETWORK_LATENCY_S
#: Instrument turnaround after a Modbus RTU request (s).
RTU_TURNAROUND_S = 0.001
#: How far short of a static posture its approach's pre-point lies on each joint (deg), more
#: than any joint's lost motion (``ucal.measure.approach``).
APPROACH_DEG = 0.05
#: What a stop costs beyond the motion model's settling (s): the client calls a move done on
#: the first state frame after it settled, half the VAL3 server's period (20 ms) late on
#: average, and that frame arrives its latency (``CellTiming.state_latency_s``, 2 ms) later.
#: The searches' measured costs (``FACE_SEARCH`` …) hold it; a plan that counts its stops one
#: by one adds it to each.
SETTLED_FRAME_S = 0.5 / SERVERS["val3"].state_rate_hz + 0.002


def transport_s(framing: str, baud: int = 19200, registers: int = MEASUREMENT_COUNT) -> float:
    """Time of one measurement-block request over ``framing`` ("tcp" or "rtu"), in s."""
    return device_transport_s(framing, baud, registers) + NETWORK_LATENCY_S


def device_transport_s(
    framing: str, baud: int = 19200, registers: int = MEASUREMENT_COUNT
) -> float:
    """The instrument's own part of a request (s): its turnaround, and over RTU the bytes on
    the serial line; the network's latency comes on top (a world's ``[timing]``)."""
    if framing == "tcp":
        return TCP_TURNAROUND_S
    if framing != "rtu":
        raise ValueError(f"framing must be 'tcp' or 'rtu', got {framing!r}")
    return rtu_read_line_s(registers, baud) + RTU_TURNAROUND_S


def read_s(framing: str, averages: int = 1, prf_hz: float = 1000.0, baud: int = 19200) -> float:
    """Time of one pulser read: the transport plus ``averages`` pulses at ``prf_hz`` (s)."""
    return transport_s(framing, baud) + max(int(averages), 1) / float(prf_hz)


def move_s(
    start_deg: np.ndarray,
    target_deg: np.ndarray,
    speed: float,
    speeds_deg_s: np.ndarray,
    accel_deg_s2: np.ndarray | tuple[float, ...] = DEFAULT_MAX_ACCEL_DEG_S2,
    approach_deg: float = 0.0,
) -> float:
    """Duration of a joint move at ``speed`` (fraction of the joints' ``speeds_deg_s``, their
    speeds at 1.0), the joints accelerating at most at ``accel_deg_s2``, settling included
    (s): the motion model's. With ``approach_deg`` (``APPROACH_DEG``: a static posture reached
    from below) one trajectory through the pre-point that far short of ``target_deg`` on every
    joint, settling once."""
    target = np.asarray(target_deg, float)
    points = [np.asarray(start_deg, float), target - approach_deg, target]
    return trajectory_s(points if approach_deg else points[::2], speed, speeds_deg_s, accel_deg_s2)


@dataclass(frozen=True)
class SearchCost:
    """What a search costs at each target beyond the move to it: moves, pulser reads and
    motion time at speed 0.3 (s)."""

    moves: int
    reads: int
    motion_s: float


#: The peak search on a block face, measured on the built-in demo cell
#: (benchmarks/run_time.py); the first face of a run adds an acquisition raster.
FACE_SEARCH = SearchCost(moves=15, reads=60, motion_s=1.5)
FIRST_FACE = SearchCost(moves=0, reads=700, motion_s=6.0)
#: The tool-frame run on the built-in demo cell, its profile not yet calibrated: a
#: normal-incidence posture on the plate (fits with 8 averages, a side lobe acquired again
#: where the uncalibrated offsets predict it degrees off), and a coarse and fine edge scan.
PLATE_PEAK = SearchCost(moves=85, reads=800, motion_s=6.0)
EDGE_SCAN = SearchCost(moves=75, reads=500, motion_s=6.0)
NO_SEARCH = SearchCost(moves=0, reads=0, motion_s=0.0)


@dataclass(frozen=True)
class DurationEstimate:
    """A run's estimated duration on a real cell (s), for Modbus TCP and for RTU."""

    moves: int
    reads: int
    motion_s: float
    tcp_s: float
    rtu_s: float

    def __add__(self, other: DurationEstimate) -> DurationEstimate:
        """Two parts of one run."""
        return DurationEstimate(
            self.moves + other.moves,
            self.reads + other.reads,
            self.motion_s + other.motion_s,
            self.tcp_s + other.tcp_s,
            self.rtu_s + other.rtu_s,
        )

    def describe(self) -> str:
        """One line for a plan summary."""
        return (
            f"Estimated time on a real cell: about {self.moves} moves and {self.reads} "
            f"pulser reads: {_minutes(self.tcp_s)} over Modbus TCP, {_minutes(self.rtu_s)} "
            f"over Modbus RTU at 19,200 baud"
        )


def _minutes(seconds: float) -> str:
    return f"{seconds / 60:.1f} min" if seconds >= 90 else f"{seconds:.0f} s"


def estimate_run(
    targets_deg: list[np.ndarray],
    start_deg: np.ndarray,
    speed: float,
    *,
    speeds_deg_s: np.ndarray,
    averages: int = 1,
    prf_hz: float = 1000.0,
    baud: int = 19200,
    search: SearchCost = FACE_SEARCH,
    first: SearchCost = FIRST_FACE,
    accel_deg_s2: np.ndarray | tuple[float, ...] = DEFAULT_MAX_ACCEL_DEG_S2,
) -> DurationEstimate:
    """Estimate a run that visits ``targets_deg`` in order, each reached from below
    (``move_s`` with ``APPROACH_DEG``), and searches at each (``search``; ``first``: what the
    first target adds), its moves at ``speed`` of the joints' ``speeds_deg_s`` (deg/s at
    speed 1.0: the robot model's, ``joint_speeds_deg_s``), accelerating at most at
    ``accel_deg_s2``."""
    motion = 0.0
    here = np.asarray(start_deg, float)
    for q in targets_deg:
        motion += move_s(here, q, speed, speeds_deg_s, accel_deg_s2, APPROACH_DEG)
        here = np.asarray(q, float)
    n = len(targets_deg)
    motion += n * search.motion_s * 0.3 / speed + first.motion_s * 0.3 / speed
    moves = n * (1 + search.moves) + first.moves
    reads = n * search.reads + first.reads
    per_read = {f: read_s(f, averages, prf_hz, baud) for f in ("tcp", "rtu")}
    return DurationEstimate(
        moves, reads, motion, motion + reads * per_read["tcp"], motion + reads * per_read["rtu"]
    )
