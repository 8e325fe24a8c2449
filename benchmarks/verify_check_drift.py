"""``verify`` and ``check`` on an arm with lost motion and a warming tank, against the same cells
still: what they report and the verdicts they reach, on cells commissioned as a user does.

Each of ``--worlds`` cells is ``realistic.py --fixture``'s (block doweled and levelled, 0.5 mm /
0.01°; the DH table within its tolerance; offsets ±3°; 8-bit amplitude, an unknown TOF delay;
the tool measured, 0.05 mm / 0.02°), its profile declaring the default drift and lost motion
tolerances (0.05 °C/min, 0.01°), in two states: ``drifting`` (the tank drifting uniform in
±0.1 °C/min, lost motion uniform in 0–0.02° per joint: ``drift.py``'s linear tank) and
``still`` (the same cell with neither). Each state is commissioned and checked by the
commands, as processes, in the order a user runs them:

1. ``calibrate`` (the offsets level), written into a fresh copy of the profile;
2. ``verify --points N`` and ``verify --region M`` on the cell as commissioned;
3. ``check`` three times: the reference (the first after the calibration), the same cell
   again (a good cell: it must pass), and the cell with joint 2 moved by ``MOVED_DEG`` after
   the commissioning (it must fail, naming J2); then ``verify --points N`` on that moved cell;
4. with ``--warm C``, ``verify --points N`` once more on the good cell with its tank C °C
   warmer than calibrate found it (the water since: an hour of a slow drift, or a tank
   refilled), printed on a line of its own.

Printed per state:

* check's coverage: the share of the quantities it reports with a std within 3 std of the
  simulator's truth, and the largest |z| (the reference's offsets, against the world's less
  half its lost motion, every posture being reached from below, and its sound speed at the
  middle of its run; the compared checks' changes of every suspect, joints, tool, block and
  sound speed, against the true change, 0 but for the moved joint and the water's drift
  between the two runs' middles);
* check's verdicts: false alarms (the reference or the good check not passing, with what it
  named) and misses (the moved cell passing, or failing without naming J2);
* verify: its "after" figure against the true one (``truth``: largest error, mm, and how many
  runs are within what it promises, ``measured_within_mm``: 0.05 mm with the DH table exact,
  more with its unidentified share), its verdicts on the good and the moved cell (whether the
  truth's agrees, and how many it calls marginal), and the region check's verdicts with its
  χ²ᵣ.

``--level full``: the same on ``drift.py``'s full-level cells (``full_calibration.py --step``'s
worlds: the DH table within twice its declared 0.3 mm / 0.03°, offsets ±1°, a hand-placed
block, the water within ±2 °C, a step of 50 ± 0.002 mm; lost motion up to 0.01° per joint in
the world, 0.02° drawn here), commissioned with ``calibrate --level full``: what verify promises
with the DH table identified, and whether the truth lies within it.

Printed with verify's figures: how many of its runs read the tank again and what they saw
(``tank`` in its ``--json``), and the sound speed it read at its start against the simulator's
(its largest |z|; the simulated tank starts each command at its world's temperature, so
verify's run begins where calibrate's began, the tank having drifted over calibrate's run).

Usage: ``python benchmarks/verify_check_drift.py --worlds 12 [--jobs 1] [--points 3]
[--region 4] [--state drifting|still|both] [--level offsets|full] [--warm C]``;
``--quick``: one world, drifting only, verify on one point and the region on three postures,
the same code path in half a minute.
"""

from __future__ import annotations

import argparse
import concurrent.futures
import json
import re
import shutil
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import commissioning
import drift
import full_calibration
import numpy as np
import realistic
from _quick import parse_args

from ucal.acoustics import sound_speed_m_s
from ucal.calibration.fit import BLOCK, OFFSETS, TOOL
from ucal.check.history import read_checks
from ucal.profile import load_profile
from ucal.verify.result import MEASURED_WITHIN_MM
from ucal.world import load_world

#: ``--quick``: the defaults it changes (an option given on the command line still wins).
QUICK = {"worlds": 1, "jobs": 1, "state": "drifting", "points": 1, "region": 3}
#: The tank's drift (±°C/min, uniform) and the largest lost motion (deg, uniform from 0).
DRIFT_C_PER_MIN = 0.1
BACKLASH_DEG = 0.02
#: The joint moved after the commissioning, and by how much (deg).
MOVED_JOINT = 2
MOVED_DEG = 0.05
STATES = ("drifting", "still")
#: The unknowns of check's suspects but the water's (``ucal.check.solve.suspects``).
SUSPECTED = OFFSETS + TOOL + BLOCK


@dataclass
class Figures:
    """One cell in one state: what the commands reported against the truth."""

    name: str
    calibrated: bool = False
    z: list[float] = field(default_factory=list)  # check: |error| / std of every quantity
    z_names: list[str] = field(default_factory=list)
    #: check's verdicts: (exit code, verdict, what it named) of the reference, good, moved
    checks: list[tuple[int, str, str]] = field(default_factory=list)
    #: verify on the good and the moved cell: (passed, truly within, after error max mm,
    #: marginal, what it promises its figure to: ``measured_within_mm``)
    verify: list[tuple[bool, bool, float, bool, float]] = field(default_factory=list)
    #: verify's tank read again: what it saw ("sound speed", "moved"), the |z| of its sound
    #: speed at the start and of its change since calibrate's readings against the simulator's
    #: (None: not read again)
    tanks: list[tuple[str, float, float] | None] = field(default_factory=list)
    #: verify's water share of its promise (two sigma of a wall's path, mm) and its "after"
    #: figure's largest error along the down points' beam (Z, mm: the XY face's water path,
    #: free of the DH table)
    water: list[tuple[float, float]] = field(default_factory=list)
    #: one line per verify run: its error per axis, its promise and what its tank read
    lines: list[str] = field(default_factory=list)
    region: tuple[bool, float] | None = None  # (passed, χ²ᵣ)
    #: verify on the good cell with its tank warmer than calibrate left it (``--warm``)
    warm: list[tuple[bool, bool, float, bool, float]] = field(default_factory=list)
    errors: list[str] = field(default_factory=list)


def draw_cells(rng: np.random.Generator, profile, index: int, level: str) -> dict[str, str]:
    """World-file text of one cell of ``level`` in each state (module docstring)."""
    if level == "full":
        text = full_calibration.draw_world(rng, profile, index)
    else:
        text = realistic.draw_world(rng, profile, index)
    rate = rng.uniform(-DRIFT_C_PER_MIN, DRIFT_C_PER_MIN)
    backlash = rng.uniform(0.0, BACKLASH_DEG, 6).tolist()
    return {
        "drifting": with_tank_and_arm(text, rate, backlash),
        "still": with_tank_and_arm(text, 0.0, [0.0] * 6),
    }


def with_tank_and_arm(text: str, drift_c_per_min: float, backlash_deg: list[float]) -> str:
    """World-file text ``text`` with the tank drifting at ``drift_c_per_min`` and each joint's
    lost motion ``backlash_deg`` in place of its own."""
    text = re.sub(r"(?m)^drift_c_per_min = .*\n", "", text)
    text = re.sub(r"(?m)^backlash_deg = .*$", f"backlash_deg = {backlash_deg!r}", text)
    return text.replace("[water]\n", f"[water]\ndrift_c_per_min = {drift_c_per_min!r}\n", 1)


def moved(text: str) -> str:
    """The world ``text`` with joint ``MOVED_JOINT``'s offset moved by ``MOVED_DEG``."""
    line = re.search(r"(?m)^joint_offsets_deg = (.*)$", text)
    assert line is not None
    offsets = json.loads(line.group(1))
    offsets[MOVED_JOINT - 1] += MOVED_DEG
    return text.replace(line.group(0), f"joint_offsets_deg = {offsets!r}")


def speed_at(world, entry) -> float:
    """The true sound speed (m/s) at the middle of a check's run (its faces' mean time)."""
    times = [f["time_min"] for f in entry.faces if f.get("time_min") is not None]
    t_mid = float(np.mean(times)) if times else 0.0
    return float(sound_speed_m_s(world.water_temperature_c + world.water_drift_c_per_min * t_mid))


def check_z(figures: Figures, out: dict, truth: dict[str, float]) -> None:
    """Add the |error| / std of every quantity of a check's ``out`` (``--json``) that has a
    std and a truth (``truth``: by name, the true value of a reference's quantity or the true
    change of a compared check's)."""
    for q in out.get("quantities", []):
        name, std = q["name"], q["std"]
        if name not in truth or std is None or not std > 0:
            continue
        reported = q["value"] if q["verdict"] == "recorded" else q["difference"]
        if reported is None:
            continue
        figures.z.append(abs(reported - truth[name]) / std)
        figures.z_names.append(f"{'ref ' if q['verdict'] == 'recorded' else ''}{name}")


def run_cell(
    template: Path,
    directory: Path,
    name: str,
    text: str,
    points: int,
    region: int,
    level: str,
    warm_c: float = 0.0,
):
    """Commission and check one cell (module docstring, steps 1-4) in ``directory``."""
    directory.mkdir()
    profile_path = directory / "cell.toml"
    shutil.copy(template, profile_path)
    world_path, moved_path = directory / "world.toml", directory / "moved.toml"
    world_path.write_text(text)
    moved_path.write_text(moved(text))
    fig = Figures(name)
    done = commissioning.run("calibrate", profile_path, world_path, "--level", level)
    fig.calibrated = bool(done.get("written"))
    if not fig.calibrated:
        fig.errors.append(f"calibrate not written: {done.get('error', '')[:200]}")
        return fig
    profile = load_profile(profile_path)
    world = load_world(world_path, profile)
    fig.verify.append(verify_figures(profile_path, world_path, points, fig, world))
    out = commissioning.run("verify", profile_path, world_path, "--region", str(region))
    if "region" in out:
        fig.region = (bool(out["passed"]), float(out["region"]["chi2_reduced"]))
    else:
        fig.errors.append(f"region: {out.get('error', '')[:200]}")
    reached = world.joint_offsets_deg - 0.5 * np.asarray(world.backlash_deg, float)
    for k, path in enumerate((world_path, world_path, moved_path)):
        out = commissioning.run("check", profile_path, path)
        fig.checks.append(
            (out["returncode"], out.get("verdict", "error"), "; ".join(out.get("moved", [])))
        )
        if "quantities" not in out:
            fig.errors.append(f"check {k}: {out.get('error', '')[:200]}")
            continue
        entries = {e.id: e for e in read_checks(profile_path)}
        this = entries[max(entries)]
        if out["reference"] is None:  # a reference: the fitted offsets and sound speed
            truth = {f"J{j + 1}": float(reached[j]) for j in range(6)}
            truth["sound_speed_m_s"] = speed_at(world, this)
        else:  # the changes since the reference
            truth = dict.fromkeys(SUSPECTED, 0.0)
            truth["sound_speed_m_s"] = speed_at(world, this) - speed_at(
                world, entries[out["reference"]["id"]]
            )
            if path == moved_path:
                truth[f"J{MOVED_JOINT}"] = MOVED_DEG
        check_z(fig, out, truth)
    fig.verify.append(verify_figures(profile_path, moved_path, points, fig, world))
    if warm_c:
        warm_path = directory / "warm.toml"
        warm_path.write_text(warmed(text, warm_c))
        warm = load_world(warm_path, profile)
        fig.warm.append(verify_figures(profile_path, warm_path, points, fig, warm, world))
    return fig


def warmed(text: str, warm_c: float) -> str:
    """The world ``text`` with its tank ``warm_c`` warmer than calibrate found it."""
    line = re.search(r"(?m)^temperature_c = (.*)$", text)
    assert line is not None
    return text.replace(line.group(0), f"temperature_c = {float(line.group(1)) + warm_c!r}")


def verify_figures(
    profile_path: Path, world_path: Path, points: int, fig: Figures, world, then=None
) -> tuple[bool, bool, float, bool, float]:
    """``verify --points``'s verdict, the truth's (every true "after" deviation within the
    tolerance), how far its "after" points are from the true reached ones (mm), whether it
    called the verdict marginal and what it promises its figure to (mm); the tank it read
    again into ``fig.tanks`` (``world``: the cell verified, ``then``: the cell calibrate
    measured, if another)."""
    then = world if then is None else then
    out = commissioning.run("verify", profile_path, world_path, "--points", str(points))
    truth = out.get("truth")
    if truth is None:
        fig.errors.append(f"verify: {out.get('error', '')[:200]}")
        return False, False, float("nan"), False, float("nan")
    budget = out.get("unidentified_tcp_mm") or {}
    table = budget.get("at_points") or budget.get("max", 0.0)
    half = (out["measured_within_mm"] - MEASURED_WITHIN_MM) / 2.0
    share = 2.0 * float(np.sqrt(max(half**2 - table**2, 0.0)))
    fig.water.append((share, float(truth["after_error_max_mm"][2])))
    tank = out.get("tank")
    if tank is None:
        fig.tanks.append(None)
    else:
        start = tank["start"]
        true_c = sound_speed_m_s(
            world.water_temperature_c + world.water_drift_c_per_min * start["time_min"]
        )
        z = abs(start["sound_speed_m_s"] - true_c) / tank["sound_speed_std_m_s"]
        # the change since calibrate's readings, against the tank's (calibrate's run started
        # at the world's temperature too)
        then_c = sound_speed_m_s(
            then.water_temperature_c + then.water_drift_c_per_min * tank["calibrate_time_min"]
        )
        change = start["sound_speed_m_s"] - tank["calibrate_sound_speed_m_s"]
        z_change = abs(change - (true_c - then_c)) / tank["change_std_m_s"]
        fig.tanks.append((tank["seen"], float(z), float(z_change)))
    err = np.round(truth["after_error_max_mm"], 4).tolist()
    read = (
        "not read again"
        if tank is None
        else f"tank: {tank['seen']}, speed now − true {start['sound_speed_m_s'] - true_c:+.3f} "
        f"(±{tank['sound_speed_std_m_s']:.3f}), change − true "
        f"{change - (true_c - then_c):+.3f} (±{tank['change_std_m_s']:.3f}) m/s, drift in run "
        f"{tank['drift_m_s_per_min']:+.3f} m/s/min"
    )
    fig.lines.append(
        f"{fig.name} {world_path.stem}: after − true {err} mm, promise ±"
        f"{out['measured_within_mm']:.3f} (water ±{share:.3f}); {read}"
    )
    within = bool(np.max(truth["after_mm"]["max"]) <= out["tolerance_mm"])
    return (
        bool(out["passed"]),
        within,
        float(np.max(truth["after_error_max_mm"])),
        bool(out["marginal"]),
        float(out["measured_within_mm"]),
    )


def verdicts(runs: list[tuple[bool, bool, float, bool, float]]) -> str:
    """verify's verdicts on ``runs``: passed, how many the truth agrees with, how many marginal
    (and of those the truth disagrees with, how many were)."""
    wrong = [v for v in runs if v[0] != v[1]]
    return (
        f"{sum(v[0] for v in runs)} / {len(runs)} ({len(runs) - len(wrong)} agree; "
        f"{sum(v[3] for v in runs)} marginal, {sum(v[3] for v in wrong)} of the "
        f"{len(wrong)} disagreeing)"
    )


def summary(state: str, figs: list[Figures]) -> list[str]:
    """The rows of one state (module docstring)."""
    done = [f for f in figs if f.calibrated]
    z = np.array([v for f in done for v in f.z])
    worst = max(((v, n) for f in done for v, n in zip(f.z, f.z_names, strict=True)), default=None)
    cover = (
        f"{np.mean(z <= 3.0) * 100:.1f} % of {z.size} (max |z| {worst[0]:.1f}, {worst[1]})"
        if worst
        else "—"
    )
    alarms = [
        f"{f.name} {('reference', 'good')[k]}: {c[1]} ({c[2] or 'nothing named'})"
        for f in done
        for k, c in enumerate(f.checks[:2])
        if c[0] != 0
    ]
    misses = [
        f"{f.name}: {f.checks[2][1]} ({f.checks[2][2] or 'nothing named'})"
        for f in done
        if len(f.checks) == 3 and (f.checks[2][0] == 0 or f"J{MOVED_JOINT}" not in f.checks[2][2])
    ]
    good = [f.verify[0] for f in done if f.verify]
    bad = [f.verify[1] for f in done if len(f.verify) == 2]
    errs = [v[2] for v in good + bad if np.isfinite(v[2])]
    kept = sum(v[2] <= v[4] for v in good + bad if np.isfinite(v[2]))
    regions = [f.region for f in done if f.region is not None]
    tanks = [t for f in done for t in f.tanks]
    read = [t for t in tanks if t is not None]
    water_seen = [t for t in read if t[0] == "sound speed"]
    water = [w for f in done for w in f.water]
    tank = (
        f"{len(read)} of {len(tanks)} ({len(water_seen)} the water, "
        f"{sum(t[0] == 'moved' for t in read)} moved; |z| max "
        f"{max((t[1] for t in water_seen), default=float('nan')):.1f}, of the change "
        f"{max((t[2] for t in water_seen), default=float('nan')):.1f}); water share "
        f"±{min((w[0] for w in water), default=float('nan')):.3f}–"
        f"{max((w[0] for w in water), default=float('nan')):.3f} mm, Z error max "
        f"{max((w[1] for w in water), default=float('nan')):.4f} mm"
    )
    rows = [
        f"| {state} | {len(done)} / {len(figs)} | {cover} | "
        f"{sum(1 for f in done for c in f.checks[:2] if c[0] != 0)} of {2 * len(done)} | "
        f"{len(misses)} of {len(done)} | "
        f"{verdicts(good)} | {verdicts(bad)} | "
        f"{max(errs, default=float('nan')):.4f} ({kept} of {len(errs)} within "
        f"±{min((v[4] for v in good + bad), default=float('nan')):.2f}–"
        f"{max((v[4] for v in good + bad), default=float('nan')):.2f}) | "
        f"{sum(p for p, _ in regions)} / {len(regions)} (χ²ᵣ median "
        f"{np.median([c for _, c in regions]) if regions else float('nan'):.3g}) | {tank} |"
    ]
    warm = [v for f in done for v in f.warm if np.isfinite(v[2])]
    if warm:
        rows.append(
            f"  warmer tank: verify after − true max {max(v[2] for v in warm):.4f} mm, "
            f"{sum(v[2] <= v[4] for v in warm)} of {len(warm)} within its ±"
            f"{min(v[4] for v in warm):.3f}–{max(v[4] for v in warm):.3f}"
        )
    rows += [f"  false alarm: {a}" for a in alarms]
    rows += [f"  miss: {m}" for m in misses]
    rows += [f"  {f.name}: {e}" for f in figs for e in f.errors]
    rows += [f"  {line}" for f in figs for line in f.lines]
    return rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--worlds", type=int, default=12)
    ap.add_argument("--seed", type=int, default=11)
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--points", type=int, default=3, help="verify's points")
    ap.add_argument("--region", type=int, default=4, help="verify --region's postures")
    ap.add_argument("--state", choices=(*STATES, "both"), default="both")
    ap.add_argument(
        "--warm",
        type=float,
        default=0.0,
        help="verify once more with the tank this much warmer (°C) than calibrate left it",
    )
    ap.add_argument(
        "--level",
        choices=("offsets", "full"),
        default="offsets",
        help="the calibration's level, and its benchmark's cells (module docstring)",
    )
    ap.add_argument(
        "--quick",
        action="store_true",
        help="--worlds 1 --jobs 1 --state drifting --points 1 --region 3: the same code path "
        "in half a minute",
    )
    args = parse_args(ap, QUICK, argv)
    work = Path(tempfile.mkdtemp(prefix="ucal-vcdrift-"))
    template = drift.make_profile(work, args.level, drift.DECLARED_DRIFT[args.level])
    profile = load_profile(template)
    rng = np.random.default_rng(args.seed)
    cells = [draw_cells(rng, profile, i, args.level) for i in range(args.worlds)]
    states = STATES if args.state == "both" else (args.state,)
    jobs = [(s, i) for i in range(args.worlds) for s in states]
    with concurrent.futures.ProcessPoolExecutor(args.jobs) as pool:
        figs = list(
            pool.map(
                run_cell,
                [template] * len(jobs),
                [work / f"{s}-{i:03d}" for s, i in jobs],
                [f"world {i}" for _, i in jobs],
                [cells[i][s] for s, i in jobs],
                [args.points] * len(jobs),
                [args.region] * len(jobs),
                [args.level] * len(jobs),
                [args.warm] * len(jobs),
            )
        )
    print(
        "| state | calibrated | check: coverage (|err| ≤ 3σ) | check: false alarms | "
        f"check: misses (J{MOVED_JOINT} +{MOVED_DEG:g}°) | verify good: passed (truth agrees) "
        "| verify moved: passed (truth agrees) | verify: after − true, max mm (within its ±) "
        "| region: passed | verify: tank read again (|z| of its sound speed, of its change "
        "since calibrate); water share, Z error |"
    )
    print("| --- " * 10 + "|")
    for state in states:
        for row in summary(state, [f for (s, _), f in zip(jobs, figs, strict=True) if s == state]):
            print(row)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
