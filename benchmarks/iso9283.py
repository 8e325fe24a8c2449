"""ISO 9283 figures (``ucal verify --iso9283``) against the world's, over random worlds.

Each world is a TX90L cell whose arm scatters as a real one does (``[robot] repeatability_deg``:
joints 1-3 0.001-0.003°, joints 4-6 0.002-0.005°, one sigma per move), whose true joint offsets
differ from the profile's calibrated ones by up to 0.02° (the robot misses its poses by tenths
of a millimetre), whose DH table is off the profile's within its declared tolerances (lengths
±0.2 mm, twists ±0.02°; ``--nominal-table``: the profile's own) and whose tool is up to 0.1 mm
off its profile; the block is fixtured. Each is
run with ``--iso9283 --cycles N`` as a user runs it (a process against the simulated cell), and
its figures are set against those the standard's formulas give from the world's truth (the
``truth`` section: AP of the robot's mean attained position, RP the expected value over N
cycles of the scatter the world gives the tool centre). Printed per figure (AP, RP, the AP
components X, Y, Z and a, b): the share of errors within 3 stated sigmas, the share beyond 4,
the largest |z|, and the rms of the errors against the rms of the stated sigmas (a std neither
too small nor too large: the ratio between 0.5 and 2).

Usage: ``python benchmarks/iso9283.py --worlds 8 --cycles 10 [--seed 1]``; ``--quick``: two
worlds of three cycles.
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

from ucal.acoustics import sound_speed_m_s
from ucal.profile import create_profile, load_profile, write_profile

OFFSETS_DEG = np.array([0.4, -0.5, 0.6, -0.7, 0.5, 0.3])


def one_world(
    seed: int, cycles: int, work: Path, table: bool = True
) -> dict[str, list[float]] | str:
    """One world's normalised errors and stds per figure, or why the run gave none."""
    rng = np.random.default_rng(seed)
    truth = OFFSETS_DEG + rng.uniform(-0.02, 0.02, 6)
    arm = rng.uniform(0.001, 0.003, 3)
    wrist = rng.uniform(0.002, 0.005, 3)
    tool = np.array([0.0, 0.0, 80.0]) + rng.uniform(-0.1, 0.1, 3)
    dh = load_profile(create_profile(work / f"nominal{seed}.toml", "tx90l")).model.dh.copy()
    if table:  # the true table within the profile's declared tolerances (0.2 mm, 0.02°)
        dh[:, 1] += np.where(dh[:, 1] != 0, rng.uniform(-0.2, 0.2, 6), 0.0)
        dh[:, 2] += np.where(dh[:, 2] != 0, rng.uniform(-0.2, 0.2, 6), 0.0)
        dh[:, 3] += rng.uniform(-0.02, 0.02, 6)
    rows = ", ".join(
        f"{{ theta_offset_deg = {r[0]!r}, d_mm = {r[1]!r}, a_mm = {r[2]!r}, alpha_deg = {r[3]!r} }}"
        for r in dh.tolist()
    )
    world = work / f"world{seed}.toml"
    world.write_text(
        "[robot]\n"
        f"dh = [{rows}]\n"
        f"joint_offsets_deg = {truth.round(5).tolist()}\n"
        f"repeatability_deg = {np.r_[arm, wrist].round(5).tolist()}\n"
        f"[tool]\nposition_mm = {tool.round(4).tolist()}\n"
        f"[noise]\nseed = {seed}\n",
        encoding="utf-8",
    )
    path = create_profile(work / f"cell{seed}.toml", "tx90l")
    write_profile(
        path,
        {"sample": {"position_std_mm": 0.5, "rotation_std_deg": [0.01, 0.01, 0.01]}},
        "fixtured block",
    )
    cal = {
        "joint_offsets_deg": OFFSETS_DEG.tolist(),
        "std_deg": [0.02] * 6,
        "sound_speed_m_s": round(float(sound_speed_m_s(20.0)), 3),
    }
    write_profile(path, {"calibration": cal}, "calibrate")
    run = subprocess.run(
        [sys.executable, "-m", "ucal", "verify", str(path), "--sim", str(world), "--yes"]
        + ["--json", "--iso9283", "--cycles", str(cycles)],
        capture_output=True,
        text=True,
        check=False,
    )
    if run.returncode not in (0, 1) or not run.stdout.strip():
        return f"exit {run.returncode}: {run.stderr.strip().splitlines()[-1:]}"
    out = json.loads(run.stdout)
    iso, true = out["iso9283"], out["truth"]["iso9283"]
    figures: dict[str, list[float]] = {}

    def add(name: str, got: float, want: float, std: float) -> None:
        figures.setdefault(f"{name} err", []).append(got - want)
        figures.setdefault(f"{name} std", []).append(std)

    for i, p in enumerate(iso["poses"]):
        add("AP", p["ap_mm"], true["ap_mm"][i], p["ap_std_mm"])
        add("RP", p["rp_mm"], true["rp_mm"][i], p["rp_std_mm"])
        for k, axis in enumerate("XYZ"):
            add(f"AP{axis}", p["ap_xyz_mm"][k], true["ap_xyz_mm"][i][k], p["ap_xyz_std_mm"][k])
        for k, axis in enumerate("ab"):
            add(f"AP{axis}", p["ap_abc_deg"][k], true["ap_abc_deg"][i][k], p["ap_abc_std_deg"][k])
    return figures


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--worlds", type=int, default=8)
    parser.add_argument("--cycles", type=int, default=10)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument(
        "--nominal-table", action="store_true", help="the true DH table the profile's own"
    )
    parser.add_argument("--quick", action="store_true")
    args = parse_args(parser, {"worlds": 2, "cycles": 3}, argv)
    pooled: dict[str, list[float]] = {}
    failed = []
    with tempfile.TemporaryDirectory() as tmp:
        for w in range(args.worlds):
            got = one_world(args.seed * 1000 + w, args.cycles, Path(tmp), not args.nominal_table)
            if isinstance(got, str):
                failed.append(got)
                continue
            for key, values in got.items():
                pooled.setdefault(key, []).extend(values)
    print(
        f"ISO 9283 over {args.worlds} worlds, {args.cycles} cycles, 5 poses each "
        f"({len(failed)} runs gave no figures{': ' + '; '.join(failed) if failed else ''})"
    )
    print(
        f"{'figure':8} {'≤3σ':>6} {'>4σ':>6} {'max|z|':>7} {'rms err':>9} {'rms σ':>9} {'ratio':>6}"
    )
    for name in ("AP", "RP", "APX", "APY", "APZ", "APa", "APb"):
        err = np.array(pooled.get(f"{name} err", []))
        std = np.array(pooled.get(f"{name} std", []))
        if not len(err):
            continue
        z = np.abs(err / std)
        rms_err, rms_std = float(np.sqrt(np.mean(err**2))), float(np.sqrt(np.mean(std**2)))
        print(
            f"{name:8} {np.mean(z <= 3):6.0%} {np.mean(z > 4):6.0%} {z.max():7.2f} "
            f"{rms_err:9.4f} {rms_std:9.4f} {rms_std / max(rms_err, 1e-12):6.2f}"
        )


if __name__ == "__main__":
    main()
