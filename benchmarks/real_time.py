"""The main job on a real cell's clock: against ``ucal sim serve`` at several time scales, loaded.

For each time scale (1 = real time; 0.2 and 0.1: the arm five and ten times faster than the
plan commands, as a cell whose speed override differs) the simulated cell is served in another
process with the released VAL3 server's timing (``--server val3``: JOINT_POSITION every 20 ms,
untimestamped, 2 ± 1 ms late by the world's default ``[timing]``), ``--hogs`` busy processes
run beside it, and ``ucal calibrate`` runs against it on the host clock. Printed per scale: the
exit code, moves, reads, wall time, and each of J2–J5's error against the served truth in units
of its reported std; then the same profile rehearsed with ``--sim`` (lock-step simulated time)
and the two results' difference in units of their combined std.

Usage: python benchmarks/real_time.py [--scales 1,0.2,0.1] [--hogs 2] [--model tx90] [--json];
``--quick``: the lock-step rehearsal only, and the served runs named as skipped (each takes
a minute of wall time; ``tests/system/test_real_time.py`` runs one at time scale 0.2).
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ucal.profile import load_profile
from ucal.sim.demo import demo_world
from ucal.sim.serve import serving

if TYPE_CHECKING:
    from multiprocessing.synchronize import Event

#: ``--quick``: the defaults it changes (an option given on the command line still wins):
#: no served run, no hog.
QUICK_SCALES = ""
QUICK_HOGS = 0


def hog(stop: Event) -> None:
    x = 0
    while not stop.is_set():
        x = (x * 31 + 7) % 1000003


def ucal(workdir: Path, *args: str) -> tuple[int, dict[str, Any], float, str]:
    """Run ``ucal ARGS --json`` in ``workdir``: exit code, JSON, wall s, stderr's tail."""
    t0 = time.monotonic()
    out = subprocess.run(
        [sys.executable, "-m", "ucal", *args, "--json"],
        cwd=workdir,
        capture_output=True,
        text=True,
        stdin=subprocess.DEVNULL,
        check=False,
    )
    wall = time.monotonic() - t0
    try:
        result = json.loads(out.stdout)
    except json.JSONDecodeError:
        result = {}
    return out.returncode, result, wall, out.stderr[-400:]


def served_run(
    workdir: Path, scale: float, extra: list[str], server: str | None = "val3"
) -> tuple[int, dict, float, str]:
    """``calibrate`` against ``ucal sim serve --time-scale SCALE --server SERVER`` (None: the
    world's server), on a copy of the fresh profile (a real cell's run writes it: each run
    starts from the same one)."""
    run = workdir / f"scale-{scale:g}"
    run.mkdir()
    shutil.copy(workdir / "cell.toml", run / "cell.toml")
    workdir = run
    args = ["--profile", "cell.toml", "--time-scale", str(scale)]
    args += [] if server is None else ["--server", server]
    with serving(*args, cwd=workdir) as urls:
        return ucal(
            workdir,
            "calibrate",
            "cell.toml",
            "--controller",
            urls["controller"],
            "--pulser",
            urls["pulser"],
            "--yes",
            *extra,
        )


def sigmas(
    result: dict, reference: np.ndarray, ref_std: np.ndarray | None = None
) -> list[float | None]:
    """Each of J2–J5's difference from ``reference`` in units of the (combined) std."""
    got = result.get("joint_offsets_deg")
    std = result.get("std_deg")
    if not got or not std:
        return [None] * 4
    out: list[float | None] = []
    for j in range(1, 5):
        if std[j] is None:
            out.append(None)
            continue
        s = float(std[j]) if ref_std is None else float(np.hypot(std[j], ref_std[j]))
        out.append(round(abs(float(got[j]) - float(reference[j])) / s, 2))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scales", default="1,0.2,0.1", help="time scales of sim serve")
    ap.add_argument("--hogs", type=int, default=2, help="busy processes beside each run")
    ap.add_argument("--model", default="tx90")
    ap.add_argument("--json", action="store_true", help="print one JSON object")
    ap.add_argument("--quick", action="store_true", help="one scale, no hog, smallest plan")
    args = ap.parse_args()
    if args.quick:
        given = set(sys.argv[1:])
        args.scales = args.scales if "--scales" in given else QUICK_SCALES
        args.hogs = args.hogs if "--hogs" in given else QUICK_HOGS
        if not args.scales:
            print("--quick: served runs skipped (a minute of wall time each)", file=sys.stderr)
    extra: list[str] = []
    rows: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory() as tmp:
        workdir = Path(tmp)
        subprocess.run(
            [sys.executable, "-m", "ucal", "profile", "init", args.model, "cell.toml"],
            cwd=workdir,
            check=True,
            capture_output=True,
        )
        truth = demo_world(load_profile(workdir / "cell.toml")).joint_offsets_deg
        code, rehearsal, wall, err = ucal(
            workdir, "calibrate", "cell.toml", "--sim", "--yes", "--dry-run", *extra
        )
        rehearsal_std = np.asarray(
            [np.nan if v is None else v for v in rehearsal.get("std_deg") or [None] * 6], float
        )
        rows.append(
            {
                "run": "--sim (lock-step)",
                "exit": code,
                "moves": rehearsal.get("moves"),
                "reads": rehearsal.get("pulser_reads"),
                "wall_s": round(wall, 1),
                "error_sigmas_J2_J5": sigmas(rehearsal, truth),
                "vs_sim_sigmas_J2_J5": None,
                "message": err.strip().splitlines()[-1] if code not in (0, 1) and err else "",
            }
        )
        sim_offsets = np.asarray(rehearsal.get("joint_offsets_deg") or truth, float)
        for scale in (float(s) for s in args.scales.split(",") if s):
            stop = mp.Event()
            hogs = [mp.Process(target=hog, args=(stop,)) for _ in range(args.hogs)]
            for p in hogs:
                p.start()
            try:
                code, result, wall, err = served_run(workdir, scale, extra)
            finally:
                stop.set()
                for p in hogs:
                    p.join()
            rows.append(
                {
                    "run": f"sim serve, time scale {scale:g}, {args.hogs} hogs",
                    "exit": code,
                    "moves": result.get("moves"),
                    "reads": result.get("pulser_reads"),
                    "wall_s": round(wall, 1),
                    "error_sigmas_J2_J5": sigmas(result, truth),
                    "vs_sim_sigmas_J2_J5": sigmas(result, sim_offsets, rehearsal_std),
                    "message": err.strip().splitlines()[-1] if code not in (0, 1) and err else "",
                }
            )
    if args.json:
        print(json.dumps({"model": args.model, "rows": rows}))
        return
    print(
        f"calibrate (the main job, {args.model}, demo truth, released VAL3 server timing); "
        "errors in units of the reported std"
    )
    head = f"{'run':34} {'exit':>4} {'moves':>6} {'reads':>6} {'wall s':>7}"
    print(f"{head}  J2-J5 vs truth   vs --sim")
    for r in rows:
        truth_s = " ".join("-" if v is None else f"{v:.1f}" for v in r["error_sigmas_J2_J5"])
        vs = r["vs_sim_sigmas_J2_J5"]
        vs_s = "" if vs is None else " ".join("-" if v is None else f"{v:.1f}" for v in vs)
        print(
            f"{r['run']:34} {r['exit']:>4} {r['moves']!s:>6} {r['reads']!s:>6} "
            f"{r['wall_s']:>7.1f}  {truth_s:16} {vs_s}"
        )
        if r["message"]:
            print(f"    {r['message']}")


if __name__ == "__main__":
    main()
