"""Loopback round-trip times of the drivers against their simulators (the calibration's budget).

Measures, through the same driver code a cell runs:

* one small move-and-settle (0.1° on joint 5) over ROS-Industrial Simple Message: send
  JOINT_TRAJ_PT, get the SERVICE_REPLY, wait for STATUS "not in motion" with the streamed
  JOINT_POSITION at the target (the state stream runs at 50 Hz, so settling waits for the next
  state message);
* one fresh gated pulser reading over Modbus TCP and over Modbus RTU framing (CRC-16) on a
  socket, the two transports side by side;

and prints median / 90th percentile per call with the number of calls, then the time a
calibration of ``--moves`` moves and ``--reads`` reads spends in I/O alone.

Usage: python benchmarks/io.py [--calls 200] [--moves 250] [--reads 20000]; ``--quick``: ten
calls each, the same code path in seconds.
"""

from __future__ import annotations

import argparse
import logging
import time

import numpy as np
from _quick import parse_args

from drivers.controller.client import SimpleMessageController
from drivers.controller.simulator import SimulatedController
from drivers.pulser.base import PulserSettings
from drivers.pulser.modbus import ModbusPulser
from drivers.pulser.simulator import SimulatedPulser

LIMITS_MIN = [-180, -130, -145, -270, -115, -270]
LIMITS_MAX = [180, 147.5, 145, 270, 140, 270]
#: ``--quick``: the defaults it changes (an option given on the command line still wins).
QUICK = {"calls": 10}


def timed(fn, calls: int) -> np.ndarray:
    out = np.empty(calls)
    for i in range(calls):
        t0 = time.perf_counter()
        fn(i)
        out[i] = time.perf_counter() - t0
    return out * 1e3  # ms


def show(name: str, ms: np.ndarray) -> float:
    med, p90 = np.median(ms), np.percentile(ms, 90)
    print(f"{name:<44} {len(ms):6d} calls   median {med:7.3f} ms   p90 {p90:7.3f} ms")
    return float(med)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--calls", type=int, default=200)
    ap.add_argument("--moves", type=int, default=250)
    ap.add_argument("--reads", type=int, default=20000)
    ap.add_argument(
        "--quick", action="store_true", help="--calls 10: the same code path in seconds"
    )
    args = parse_args(ap, QUICK)
    logging.getLogger("pymodbus").setLevel(logging.CRITICAL)
    start = np.array([30.0, 30.0, 110.0, 0.0, 40.0, 30.0])
    with (
        SimulatedController(LIMITS_MIN, LIMITS_MAX, start, time_scale=1.0) as controller_sim,
        SimpleMessageController.from_url(controller_sim.url) as ctl,
    ):

        def move(i: int) -> None:
            target = start.copy()
            target[4] += 0.1 * (i % 2)
            ctl.move_joints(target, speed=0.5, timeout_s=5.0)

        move_ms = show("move-and-settle 0.1° (Simple Message)", timed(move, args.calls))
        read_joints_ms = show(
            "read joints (latest streamed)", timed(lambda i: ctl.read_joints(), args.calls)
        )
    del read_joints_ms
    read_ms = {}
    for framing in ("tcp", "rtu"):
        with (
            SimulatedPulser(lambda s: (0.5, 67459.0), framing=framing) as pulser_sim,
            ModbusPulser.from_url(pulser_sim.url, timeout_s=2.0) as pulser,
        ):
            pulser.configure(PulserSettings())
            pulser.read_gate()
            read_ms[framing] = show(
                f"pulser gate reading (Modbus {framing.upper()})",
                timed(lambda i: pulser.read_gate(fresh=True), args.calls),
            )
    print(
        f"\nI/O budget of a calibration with {args.moves} moves and {args.reads} pulser reads "
        "(sweep readings overlap motion; static probes do not):"
    )
    for framing, ms in read_ms.items():
        total = (args.moves * move_ms + args.reads * ms) / 1e3
        print(
            f"  Modbus {framing.upper()}: {total:6.1f} s  "
            f"({args.moves} × {move_ms:.2f} ms + {args.reads} × {ms:.3f} ms)"
        )


if __name__ == "__main__":
    main()
