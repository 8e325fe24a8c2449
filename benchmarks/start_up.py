"""Start-up: how long a new ``ucal`` process is deaf to an ignored SIGINT, beside the interpreter.

A background job of a non-interactive shell inherits SIGINT as ignored, and the kernel discards
one sent before ucal's first line takes it back (``ucal.entry``); SIGTERM meanwhile meets its
default action and ends the process. The window is the interpreter's start-up plus the import
of ``ucal.entry`` (which imports only ``ucal.interrupt``). Printed side by side, as whole
processes (median and maximum of ``--runs``):

* ``python -c pass``: the interpreter's own start-up, the floor;
* the console script's first lines up to ``interrupt.install()``: the window;
* ``ucal --version`` and ``ucal --help``: the command line loaded (what follows the window).

Usage: python benchmarks/start_up.py [--runs 30]; ``--quick``: three runs each.
"""

from __future__ import annotations

import argparse
import shutil
import statistics
import subprocess
import sys
import time

from _quick import parse_args

#: ``--quick``: the defaults it changes (an option given on the command line still wins).
QUICK = {"runs": 3}
#: What the console script runs before ``main`` (pip's generated wrapper), then ucal's first line.
FIRST_LINE = (
    "import re, sys\nfrom ucal.entry import main\nfrom ucal import interrupt\ninterrupt.install()"
)


def timed_ms(args: list[str], runs: int) -> list[float]:
    """Wall times of ``runs`` whole processes of ``args``, in ms."""
    out = []
    for _ in range(runs):
        t0 = time.perf_counter()
        subprocess.run(args, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, check=True)
        out.append((time.perf_counter() - t0) * 1e3)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--runs", type=int, default=30)
    ap.add_argument("--quick", action="store_true", help="three runs each")
    args = parse_args(ap, QUICK)
    ucal = shutil.which("ucal") or "ucal"
    rows = [
        ("python -c pass (the interpreter)", [sys.executable, "-c", "pass"]),
        ("to ucal's first line (signals taken)", [sys.executable, "-c", FIRST_LINE]),
        ("ucal --version", [ucal, "--version"]),
        ("ucal --help", [ucal, "--help"]),
    ]
    floor = None
    for name, command in rows:
        ms = timed_ms(command, args.runs)
        med = statistics.median(ms)
        floor = med if floor is None else floor
        print(
            f"{name:<40} {len(ms):4d} runs   median {med:8.1f} ms   max {max(ms):8.1f} ms"
            f"   +{med - floor:7.1f} ms over the interpreter"
        )


if __name__ == "__main__":
    main()
