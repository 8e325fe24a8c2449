"""verify's stated measurement uncertainty against its measurement error, over random worlds.

Each world is ``realistic.py``'s (``--fixture``: the block doweled; the DH table, the tool, the
block and the water drawn within the profile's declared tolerances; offsets to ±2°, never
calibrated), commissioned as a user does (``ucal calibrate``, the offsets level, then ``ucal
tool-frame``), then verified (``ucal verify --points N``). For every "after" point and block
axis, the measurement error is the reached point verify measured less the true one (the
simulator's truth), set against the point's stated one sigma (``measurement_std_points_mm``).
Printed per axis: the share of errors within 3 sigmas, the share beyond 4, the largest |z|,
and the rms of the stated sigmas over the rms of the errors (neither too small nor too large:
between 0.5 and 2); then the same for half of ``measured_within_mm`` (stated as two sigma),
and how many runs verify called marginal.

Usage: ``python benchmarks/verify_uncertainty.py --worlds 20 --points 20 [--seed 5]``;
``--quick``: one world, six points.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
from _quick import parse_args
from realistic import draw_world, make_profile

from ucal.profile import load_profile


def ucal(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "ucal", *args], capture_output=True, text=True, check=False
    )


def one_world(seed: int, points: int, work: Path) -> dict | str:
    """One world's errors and stated sigmas (mm, per point and axis), or why none."""
    directory = work / f"w{seed}"
    directory.mkdir()
    path = make_profile(directory, fixture=True)
    world = directory / "world.toml"
    world.write_text(draw_world(np.random.default_rng(seed), load_profile(path), seed))
    for command in ("calibrate", "tool-frame"):
        done = ucal(command, str(path), "--sim", str(world), "--yes", "--json")
        if done.returncode != 0:
            return f"{command} exit {done.returncode}"
    run = ucal("verify", str(path), "--sim", str(world), "--yes", "--json", "--points", str(points))
    if run.returncode not in (0, 1) or not run.stdout.strip():
        return f"verify exit {run.returncode}: {run.stderr.strip().splitlines()[-1:]}"
    out = json.loads(run.stdout)
    measured = np.array(out["reached_mm"]["after"])
    true = np.array(out["truth"]["reached_mm"]["after"])
    return {
        "err": (measured - true).tolist(),
        "std": out["measurement_std_points_mm"],
        "within": out["measured_within_mm"],
        "marginal": bool(out["marginal"]),
    }


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--worlds", type=int, default=20)
    parser.add_argument("--points", type=int, default=20)
    parser.add_argument("--seed", type=int, default=5)
    parser.add_argument("--quick", action="store_true")
    args = parse_args(parser, {"worlds": 1, "points": 6}, argv)
    err, std, within, failed, marginal = [], [], [], [], 0
    with tempfile.TemporaryDirectory() as tmp:
        for w in range(args.worlds):
            got = one_world(args.seed * 1000 + w, args.points, Path(tmp))
            if isinstance(got, str):
                failed.append(got)
                continue
            err += got["err"]
            std += got["std"]
            within += [got["within"]] * len(got["err"])
            marginal += got["marginal"]
    e, s = np.array(err).reshape(-1, 3), np.array(std).reshape(-1, 3)
    why = ": " + "; ".join(failed) if failed else ""
    print(
        f"verify's measurement over {args.worlds} worlds, {args.points} points each: "
        f"{len(e)} points ({len(failed)} worlds gave none{why})"
    )
    if not len(e):
        return
    print(
        f"{'axis':12} {'≤3σ':>6} {'>4σ':>6} {'max|z|':>7} {'rms err':>9} {'rms σ':>9} {'ratio':>6}"
    )
    for k, axis in enumerate("XYZ"):
        z = np.abs(e[:, k] / s[:, k])
        rms_e = float(np.sqrt(np.mean(e[:, k] ** 2)))
        rms_s = float(np.sqrt(np.mean(s[:, k] ** 2)))
        print(
            f"{'point σ ' + axis:12} {np.mean(z <= 3):6.0%} {np.mean(z > 4):6.0%} "
            f"{z.max():7.2f} {rms_e:9.4f} {rms_s:9.4f} {rms_s / max(rms_e, 1e-12):6.2f}"
        )
    half = np.array(within) / 2.0  # measured_within_mm is stated as two sigma
    z = np.abs(e).max(axis=1) / half
    print(
        f"{'within/2':12} {np.mean(z <= 3):6.0%} {np.mean(z > 4):6.0%} {z.max():7.2f} "
        f"{float(np.sqrt(np.mean(np.abs(e).max(axis=1) ** 2))):9.4f} "
        f"{float(np.sqrt(np.mean(half**2))):9.4f} "
        f"{float(np.sqrt(np.mean(half**2))) / max(float(np.sqrt(np.mean(e**2))), 1e-12):6.2f}"
    )
    print(f"marginal (measured_within_mm): {marginal} of {args.worlds - len(failed)} runs")


if __name__ == "__main__":
    main()
