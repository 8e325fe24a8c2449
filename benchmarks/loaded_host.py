"""Whole calibrations against ``ucal sim serve`` on a loaded host: written, or why not.

For each time scale (1 = real time; 0.2 and 0.1: the arm five and ten times faster than the
plan commands, its state frames still 20 ms apart and 2 ± 1 ms late) ``--runs`` calibrations
each run on a fresh profile of ``--model`` against the simulated cell served in another process
(the world's default server, as ``ucal sim serve`` starts), with ``--hogs`` busy processes
beside them: the host's scheduler then lets the client's threads wait, so a state frame or a
pulser answer is read late. Printed per run: the exit code, whether the result was written, the
wall time and, for a run not written, the last line of its stderr; then per scale how many runs
were written and how many were refused as a side lobe (the search misreading a stretched host
clock: readings paired with the wrong posture centre the crosses off the main lobe).

Usage: python benchmarks/loaded_host.py [--scales 1,0.2,0.1] [--runs 3] [--hogs 2]
[--model tx90l] [--json]; ``--quick``: no served run (each takes about a minute of wall time),
the table's header and the scales named as skipped.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

from _quick import parse_args
from real_time import served_run

#: ``--quick``: the defaults it changes (an option given on the command line still wins).
QUICK = {"runs": 0}
#: A busy process beside the runs (pure Python: it holds a core).
HOG = "while True: pass"


def calibrate(workdir: Path, scale: float, model: str) -> dict[str, Any]:
    """One whole calibration of a fresh ``model`` profile against the cell served at
    ``scale``: its exit code, whether it was written, its wall time, its last error line."""
    subprocess.run(
        [sys.executable, "-m", "ucal", "profile", "init", model, "cell.toml"],
        cwd=workdir,
        check=True,
        capture_output=True,
    )
    code, result, wall, stderr = served_run(workdir, scale, [], server=None)
    written = bool(result.get("written"))
    lines = stderr.strip().splitlines()
    message = lines[-1] if lines and not written else ""
    return {
        "scale": scale,
        "exit": code,
        "written": written,
        "side_lobe": "side lobe" in message,
        "wall_s": round(wall, 1),
        "message": message[:300],
    }


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scales", default="1,0.2,0.1", help="time scales of sim serve")
    ap.add_argument("--runs", type=int, default=3, help="calibrations per time scale")
    ap.add_argument("--hogs", type=int, default=2, help="busy processes beside the runs")
    ap.add_argument("--model", default="tx90l")
    ap.add_argument("--json", action="store_true", help="print one JSON object")
    ap.add_argument("--quick", action="store_true", help="no served run")
    args = parse_args(ap, QUICK, argv)
    scales = [float(s) for s in args.scales.split(",") if s]
    rows: list[dict[str, Any]] = []
    hogs = [
        subprocess.Popen([sys.executable, "-c", HOG]) for _ in range(args.hogs * (args.runs > 0))
    ]
    try:
        with tempfile.TemporaryDirectory() as tmp:
            for scale in scales:
                for i in range(args.runs):
                    run = Path(tmp) / f"scale-{scale:g}-{i}"
                    run.mkdir()
                    rows.append(calibrate(run, scale, args.model))
                    if not args.json:
                        r = rows[-1]
                        print(
                            f"time scale {scale:<4g} run {i + 1}: exit {r['exit']}, "
                            f"{'written' if r['written'] else 'NOT written'}, {r['wall_s']} s",
                            flush=True,
                        )
                        if r["message"]:
                            print(f"    {r['message']}", flush=True)
    finally:
        for p in hogs:
            p.kill()
            p.wait()
    tally = {
        f"{scale:g}": {
            "runs": sum(r["scale"] == scale for r in rows),
            "written": sum(r["scale"] == scale and r["written"] for r in rows),
            "side_lobe": sum(r["scale"] == scale and r["side_lobe"] for r in rows),
        }
        for scale in scales
    }
    if args.json:
        print(json.dumps({"model": args.model, "hogs": args.hogs, "rows": rows, "tally": tally}))
        return
    print(f"calibrate against sim serve ({args.model}, demo truth), {args.hogs} CPU hogs beside")
    print(f"{'time scale':>10} {'runs':>5} {'written':>8} {'side lobe':>10}")
    for name, t in tally.items():
        runs = str(t["runs"] or "skipped")
        print(f"{name:>10} {runs:>5} {t['written']:>8} {t['side_lobe']:>10}")


if __name__ == "__main__":
    main()
