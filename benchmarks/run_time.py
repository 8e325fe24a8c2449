"""The main job's wall time, its determinism under load, and the real-cell duration estimate.

1. ``ucal calibrate cell.toml --sim --yes --dry-run`` in a fresh directory: wall time, idle.
2. The same with two CPU hogs (busy Python processes) running beside it: wall time, and
   whether the offsets are the same bit for bit (simulated time, ``drivers.clock.SimClock``).
3. The duration the plan estimates for a real cell (``ucal.timing.estimate_run``), beside the
   run's own simulated duration (what it would take over Modbus TCP) and beside the wall time
   of the same calibration against ``ucal sim serve --time-scale 1`` (real time, another
   process, the drivers on the host clock) — unless ``--no-real-time``.
4. With ``--commands``: every moving command on the demo cell, as a commissioning runs them
   on a fresh profile (tool-frame, calibrate, verify with 4 and 20 points, calibrate --level
   full, verify --region 12): the plan's real-cell estimate (Modbus TCP / RTU), the run's
   simulated duration and its wall time.
5. With ``--cpu``: the CPU (user + sys, the process and its threads: the drivers and the
   simulated cell they speak to) of ``calibrate``, ``tool-frame`` and ``calibrate --sim
   examples/world.toml``, each on a fresh demo profile, the median of ``--runs`` runs; per
   command and per 1000 pulser reads.

Usage: python benchmarks/run_time.py [--no-real-time] [--commands] [--cpu [--runs N]];
``--quick``: no warm-up run, one hog, no real-time run (step 3 is the plan's estimate and the
simulated duration), with ``--commands`` the smallest run of each command, with ``--cpu`` one
run of each: in seconds.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import re
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import TYPE_CHECKING

from _quick import parse_args

from ucal.sim.serve import serving

if TYPE_CHECKING:
    from multiprocessing.synchronize import Event

#: ``--quick``: the defaults it changes (an option given on the command line still wins).
QUICK = {"warm_up": 0, "hogs": 1, "no_real_time": True, "runs": 1}


def hog(stop: Event) -> None:
    x = 0
    while not stop.is_set():
        x = (x * 31 + 7) % 1000003


def calibrate(workdir: Path, *extra: str) -> tuple[float, dict, str]:
    """Run the calibration (``--dry-run`` on the simulated cell); wall s, JSON, plan estimate."""
    dry = ["--dry-run"] if "--sim" in extra else []
    t0 = time.monotonic()
    out = subprocess.run(
        [sys.executable, "-m", "ucal", "calibrate", "cell.toml", "--yes", "--json", *dry, *extra],
        cwd=workdir,
        capture_output=True,
        text=True,
        stdin=subprocess.DEVNULL,
    )
    wall = time.monotonic() - t0
    if out.returncode not in (0, 1):
        raise SystemExit(f"calibrate failed ({out.returncode}): {out.stderr[-500:]}")
    estimate = next((ln for ln in out.stderr.splitlines() if "Estimated time" in ln), "")
    return wall, json.loads(out.stdout), estimate


#: A commissioning's moving commands, in order, on one fresh demo profile.
COMMANDS = (
    ("tool-frame",),
    ("calibrate",),
    ("verify", "--points", "4"),
    ("verify",),
    ("calibrate", "--level", "full"),
    ("verify", "--region", "12"),
)
#: ``--commands --quick``: the same commands, each with the fewest points or postures it takes.
QUICK_COMMANDS = (
    ("tool-frame",),
    ("calibrate",),
    ("verify", "--points", "1"),
    ("calibrate", "--level", "full", "--postures", "3"),
    ("verify", "--region", "3"),
)


def new_profile(workdir: Path) -> None:
    """``ucal profile init tx90l cell.toml`` in ``workdir``."""
    subprocess.run(
        [sys.executable, "-m", "ucal", "profile", "init", "tx90l", "cell.toml"],
        cwd=workdir,
        check=True,
        capture_output=True,
    )


def commands(quick: bool = False) -> None:
    """Step 4 of the module docstring (``QUICK_COMMANDS`` if ``quick``)."""
    with tempfile.TemporaryDirectory() as d:
        work = Path(d)
        new_profile(work)
        print("every moving command on the demo cell (--sim --yes), in a commissioning's order")
        print(f"  {'command':<34} {'estimate TCP / RTU':>20} {'simulated':>10} {'wall':>8}")
        for cmd in QUICK_COMMANDS if quick else COMMANDS:
            t0 = time.monotonic()
            out = subprocess.run(
                [sys.executable, "-m", "ucal", *cmd[:1], "cell.toml", *cmd[1:], "--sim"]
                + ["--yes", "--json"],
                cwd=work,
                capture_output=True,
                text=True,
                stdin=subprocess.DEVNULL,
            )
            wall = time.monotonic() - t0
            res = json.loads(out.stdout) if out.stdout.strip() else {}
            m = re.search(r"([\d.]+ (?:s|min)) over Modbus TCP, ([\d.]+ (?:s|min))", out.stderr)
            estimate = f"{m.group(1)} / {m.group(2)}" if m else "-"
            simulated = f"{res['duration_s']:.0f} s" if "duration_s" in res else "-"
            name = " ".join(cmd) + ("" if out.returncode == 0 else f" (exit {out.returncode})")
            print(f"  {name:<34} {estimate:>20} {simulated:>10} {wall:>6.1f} s", flush=True)


#: ``--cpu``: the simulated runs, as (command, world file or None for the demo cell).
CPU_RUNS = (
    ("calibrate", None),
    ("tool-frame", None),
    ("calibrate", Path(__file__).resolve().parents[1] / "examples" / "world.toml"),
)


def cpu(runs: int) -> None:
    """Step 5 of the module docstring."""
    print(f"CPU (user + sys) of each simulated run, median of {runs}, a fresh demo profile each")
    print(f"  {'run':<44} {'CPU':>7} {'reads':>6} {'per 1000 reads':>15}")
    for command, world in CPU_RUNS:
        seconds, reads = [], 0
        for _ in range(runs):
            with tempfile.TemporaryDirectory() as d:
                new_profile(Path(d))
                sim = ["--sim"] if world is None else ["--sim", str(world)]
                before = resource.getrusage(resource.RUSAGE_CHILDREN)
                out = subprocess.run(
                    [sys.executable, "-m", "ucal", command, "cell.toml", *sim, "--yes", "--json"],
                    cwd=d,
                    capture_output=True,
                    text=True,
                    stdin=subprocess.DEVNULL,
                )
                after = resource.getrusage(resource.RUSAGE_CHILDREN)
            if out.returncode not in (0, 1):
                raise SystemExit(f"{command} failed ({out.returncode}): {out.stderr[-500:]}")
            seconds.append(after.ru_utime - before.ru_utime + after.ru_stime - before.ru_stime)
            reads = json.loads(out.stdout)["pulser_reads"]
        name = f"{command} --sim" + ("" if world is None else f" examples/{world.name}")
        median = statistics.median(seconds)
        print(f"  {name:<44} {median:5.2f} s {reads:>6} {1000 * median / reads:11.2f} s")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--no-real-time", action="store_true")
    ap.add_argument("--commands", action="store_true", help="step 4 instead of 1-3")
    ap.add_argument(
        "--warm-up",
        type=int,
        default=1,
        help="untimed runs first, to warm the interpreter's caches (imports, bytecode)",
    )
    ap.add_argument("--hogs", type=int, default=2, help="busy processes beside the loaded run")
    ap.add_argument("--cpu", action="store_true", help="step 5 instead of 1-3")
    ap.add_argument("--runs", type=int, default=3, help="--cpu: runs of each, the median")
    ap.add_argument(
        "--quick",
        action="store_true",
        help="--warm-up 0 --hogs 1 --no-real-time (with --commands: the smallest run of each "
        "command): the same code paths in seconds",
    )
    args = parse_args(ap, QUICK)
    if args.commands:
        commands(args.quick)
        return
    if args.cpu:
        cpu(args.runs)
        return
    with tempfile.TemporaryDirectory() as d:
        work = Path(d)
        new_profile(work)
        for _ in range(args.warm_up):
            calibrate(work, "--sim")
        idle_wall, idle, estimate = calibrate(work, "--sim")
        stop = mp.Event()
        hogs = [mp.Process(target=hog, args=(stop,)) for _ in range(args.hogs)]
        for p in hogs:
            p.start()
        try:
            busy_wall, busy, _ = calibrate(work, "--sim")
        finally:
            stop.set()
            for p in hogs:
                p.join()
        same = (
            idle["joint_offsets_deg"] == busy["joint_offsets_deg"]
            and idle["std_deg"] == busy["std_deg"]
        )
        print("ucal calibrate cell.toml --sim --yes (demo cell)")
        print(
            f"  idle:             {idle_wall:6.1f} s wall, {idle['moves']} moves, "
            f"{idle['pulser_reads']} pulser reads"
        )
        loaded = f"{args.hogs} CPU hog{'' if args.hogs == 1 else 's'}:"
        print(
            f"  {loaded:<18}{busy_wall:6.1f} s wall; offsets and stds bit for bit the same as "
            f"idle: {same}"
        )
        print(f"  plan: {estimate.strip()}")
        print(
            f"  simulated duration of the run (a real cell over Modbus TCP): "
            f"{idle['duration_s']:.1f} s"
        )
        if args.no_real_time:
            return
        with serving("--profile", "cell.toml", "--time-scale", "1", cwd=work) as urls:
            real_wall, real, _ = calibrate(
                work, "--controller", urls["controller"], "--pulser", urls["pulser"]
            )
        print(
            f"  against `ucal sim serve --time-scale 1` (real time): {real_wall:.1f} s wall, "
            f"{real['moves']} moves, {real['pulser_reads']} pulser reads"
        )


if __name__ == "__main__":
    main()
