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

``--tank cycling``: the drifting cells' tank is ``drift.py``'s heater (a sine of period 5–15 min
and 0.05–0.2 °C) in place of their drift, their lost motion kept. Each cell is then
commissioned with the tank thermometer's log (``thermometer.py``'s probe: a reading every 3 s,
3–9 s behind the tank, 0.5 °C off, 0.003 °C noise, at ``--thermometer C`` resolution,
0.01 °C by default), and checked twice from the commissioned profile (a copy each, with its
history): with the probe's log (``check --thermometer``) and without. Each of the three checks
meets the heater at a phase of its own (its log started 0–20 min in, as another hour of the day
would), so the water changes between them; the truth of the sound speed is the tank's at the
middle of each run. A row per way of checking.

Usage: ``python benchmarks/verify_check_drift.py --worlds 12 [--jobs 1] [--points 3]
[--region 4] [--state drifting|still|both] [--level offsets|full] [--warm C] [--tank
linear|cycling] [--thermometer C]``;
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
import thermometer
from _quick import parse_args

from ucal.acoustics import sound_speed_m_s
from ucal.check.history import read_checks
from ucal.model.fit import BLOCK, OFFSETS, TOOL
from ucal.profile import load_profile
from ucal.thermometer import read_log
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
#: ``--tank cycling``: each check meets the heater this many minutes (uniform) into its log, a
#: phase of its own (calibrate and verify meet it at 0); the two ways each cell is checked.
CHECK_SHIFT_MIN = (0.0, 20.0)
LOGGED, BARE = "with the log", "without"


@dataclass
class Heated:
    """``--tank cycling``'s drifting cell: its tank's log (``drift.Tank``'s heater), the probe's
    resolution (°C, ``thermometer.thermometer_log``'s probe, its seed) and each check's shift
    into the log (min: reference, good, moved)."""

    log_path: Path
    resolution_c: float
    seed: int
    shifts_min: tuple[float, ...]


@dataclass
class Checks:
    """A cell's three checks (reference, good, moved) in one way of checking it."""

    z: list[float] = field(default_factory=list)  # |error| / std of every quantity
    z_names: list[str] = field(default_factory=list)
    #: (exit code, verdict, what it named) of the reference, good, moved
    checks: list[tuple[int, str, str]] = field(default_factory=list)


@dataclass
class Figures:
    """One cell in one state: what the commands reported against the truth."""

    name: str
    calibrated: bool = False
    #: check's figures, by the way the cell was checked ("": the one way; ``--tank cycling``:
    #: ``LOGGED`` and ``BARE``)
    arms: dict[str, Checks] = field(default_factory=dict)
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
    return true_speed(world, float(np.mean(times)) if times else 0.0)


def true_speed(world, t_min: float) -> float:
    """The world's sound speed (m/s) at ``t_min`` of a run (its drift, or its log)."""
    return float(sound_speed_m_s(drift.tank_at(world, t_min)[0]))


def heated(rng: np.random.Generator, tank: drift.Tank, text: str, path: Path, resolution_c: float):
    """The drifting cell ``text`` with ``--tank cycling``'s heater in place of its drift, the log
    written to ``path`` (named in the text by its full path), and its ``Heated``."""
    text = tank.into(text, 0.0, path).replace(f'"{path.name}"', json.dumps(str(path)))
    shifts = tuple(float(v) for v in rng.uniform(*CHECK_SHIFT_MIN, 3))
    return text, Heated(path, resolution_c, int(rng.integers(1 << 30)), shifts)


def shifted(text: str, heat: Heated, k: int, directory: Path) -> str:
    """The world ``text`` with its tank's log started ``heat.shifts_min[k]`` minutes in: the
    heater at another phase, as another run meets it."""
    log = read_log(heat.log_path, wall_clock=False)
    t_min = log.time_min[log.time_min <= log.time_min[-1] - heat.shifts_min[k]]
    temp_c = np.interp(t_min + heat.shifts_min[k], log.time_min, log.temperature_c)
    path = directory / f"tank-{k}.csv"
    write_log(path, t_min, temp_c)
    return text.replace(json.dumps(str(heat.log_path)), json.dumps(str(path)))


def write_log(path: Path, t_min: np.ndarray, temp_c: np.ndarray) -> Path:
    """A log (``time_min,temperature_c``) at ``path``."""
    rows = "".join(f"{t:.4f},{c:.5f}\n" for t, c in zip(t_min, temp_c, strict=True))
    path.write_text("time_min,temperature_c\n" + rows)
    return path


def probe(world_path: Path, profile_path: Path, heat: Heated, name: str) -> Path:
    """The tank thermometer's log of the world at ``world_path`` (``thermometer.py``'s probe:
    lagging, offset, noisy, at ``heat.resolution_c``), written beside it as ``name``."""
    log = thermometer.thermometer_log(world_path, profile_path, heat.seed, heat.resolution_c)
    return write_log(world_path.parent / name, log.time_min, log.temperature_c)


def check_z(figures: Checks, out: dict, truth: dict[str, float]) -> None:
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
    heat: Heated | None = None,
):
    """Commission and check one cell (module docstring, steps 1-4) in ``directory``; a
    ``heat``ed one (``--tank cycling``) commissioned with its thermometer's log and checked
    both with it and without."""
    directory.mkdir()
    profile_path = directory / "cell.toml"
    shutil.copy(template, profile_path)
    world_path, moved_path = directory / "world.toml", directory / "moved.toml"
    world_path.write_text(text)
    moved_path.write_text(moved(text))
    fig = Figures(name)
    logged = (
        ()
        if heat is None
        else ("--thermometer", str(probe(world_path, template, heat, "probe.csv")))
    )
    done = commissioning.run("calibrate", profile_path, world_path, "--level", level, *logged)
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
    if heat is None:
        fig.arms[""] = run_checks(profile_path, [world_path, world_path, moved_path], [], fig)
    else:  # each check at its own phase of the heater, in a copy of the commissioned cell
        worlds, probes = [], []
        for k in range(3):
            path = directory / f"check-{k}.toml"
            path.write_text(shifted(moved(text) if k == 2 else text, heat, k, directory))
            worlds.append(path)
            probes.append(probe(path, template, heat, f"probe-{k}.csv"))
        for arm, logs in ((LOGGED, probes), (BARE, [])):
            copy = directory / arm.replace(" ", "-") / "cell.toml"
            copy.parent.mkdir()
            shutil.copy(profile_path, copy)
            history = profile_path.with_name(profile_path.name + ".history")
            shutil.copytree(history, copy.with_name(history.name))
            fig.arms[arm] = run_checks(copy, worlds, logs, fig)
    fig.verify.append(verify_figures(profile_path, moved_path, points, fig, world))
    if warm_c:
        warm_path = directory / "warm.toml"
        warm_path.write_text(warmed(text, warm_c))
        warm = load_world(warm_path, profile)
        fig.warm.append(verify_figures(profile_path, warm_path, points, fig, warm, world))
    return fig


def run_checks(profile_path: Path, worlds: list[Path], logs: list[Path], fig: Figures) -> Checks:
    """``check`` three times on ``profile_path`` (module docstring, step 3): the reference and
    the good cell on ``worlds[0]`` and ``[1]``, the moved one on ``[2]``, each with its
    thermometer's log of ``logs`` if given; against the truth."""
    found = Checks()
    profile = load_profile(profile_path)
    truths = [load_world(w, profile) for w in worlds]
    reached = truths[0].joint_offsets_deg - 0.5 * np.asarray(truths[0].backlash_deg, float)
    world_of: dict[int, object] = {}  # each check's world, by its history entry
    for k, path in enumerate(worlds):
        logged = ("--thermometer", str(logs[k])) if logs else ()
        out = commissioning.run("check", profile_path, path, *logged)
        found.checks.append(
            (out["returncode"], out.get("verdict", "error"), "; ".join(out.get("moved", [])))
        )
        if "quantities" not in out:
            fig.errors.append(f"check {k}: {out.get('error', '')[:200]}")
            continue
        entries = {e.id: e for e in read_checks(profile_path)}
        this = entries[max(entries)]
        world_of[this.id] = truths[k]
        if out["reference"] is None:  # a reference: the fitted offsets and sound speed
            truth = {f"J{j + 1}": float(reached[j]) for j in range(6)}
            truth["sound_speed_m_s"] = speed_at(truths[k], this)
        else:  # the changes since the reference
            ref = out["reference"]["id"]
            truth = dict.fromkeys(SUSPECTED, 0.0)
            truth["sound_speed_m_s"] = speed_at(truths[k], this) - speed_at(
                world_of[ref], entries[ref]
            )
            if k == 2:
                truth[f"J{MOVED_JOINT}"] = MOVED_DEG
        check_z(found, out, truth)
    return found


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
        true_c = true_speed(world, start["time_min"])
        z = abs(start["sound_speed_m_s"] - true_c) / tank["sound_speed_std_m_s"]
        # the change since calibrate's readings, against the tank's (calibrate's run started
        # at the world's temperature too)
        then_c = true_speed(then, tank["calibrate_time_min"])
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


def check_columns(name: str, done: list[Figures], arm: str) -> tuple[str, list[str], list[str]]:
    """The check's columns of one way of checking (``arm``) the ``done`` cells: coverage, false
    alarms and misses, and the lines naming each alarm and miss."""
    checked = [(f, f.arms[arm]) for f in done if arm in f.arms]
    z = np.array([v for _, c in checked for v in c.z])
    worst = max(
        ((v, n) for _, c in checked for v, n in zip(c.z, c.z_names, strict=True)), default=None
    )
    cover = (
        f"{np.mean(z <= 3.0) * 100:.1f} % of {z.size} (max |z| {worst[0]:.1f}, {worst[1]})"
        if worst
        else "—"
    )
    alarms = [
        f"false alarm: {f.name} {('reference', 'good')[k]}: {v[1]} ({v[2] or 'nothing named'})"
        for f, c in checked
        for k, v in enumerate(c.checks[:2])
        if v[0] != 0
    ]
    misses = [
        f"miss: {f.name}: {c.checks[2][1]} ({c.checks[2][2] or 'nothing named'})"
        for f, c in checked
        if len(c.checks) == 3 and (c.checks[2][0] == 0 or f"J{MOVED_JOINT}" not in c.checks[2][2])
    ]
    row = (
        f"| {name} | {len(done)} | {cover} | {len(alarms)} of {2 * len(checked)} | "
        f"{len(misses)} of {len(checked)} |"
    )
    return (
        row,
        [f"  {arm + ': ' if arm else ''}{line}" for line in alarms],
        [f"  {arm + ': ' if arm else ''}{line}" for line in misses],
    )


def summary(state: str, figs: list[Figures]) -> list[str]:
    """The rows of one state (module docstring): one per way its cells were checked."""
    done = [f for f in figs if f.calibrated]
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
    verify = (
        f" {verdicts(good)} | {verdicts(bad)} | "
        f"{max(errs, default=float('nan')):.4f} ({kept} of {len(errs)} within "
        f"±{min((v[4] for v in good + bad), default=float('nan')):.2f}–"
        f"{max((v[4] for v in good + bad), default=float('nan')):.2f}) | "
        f"{sum(p for p, _ in regions)} / {len(regions)} (χ²ᵣ median "
        f"{np.median([c for _, c in regions]) if regions else float('nan'):.3g}) | {tank} |"
    )
    arms = list(dict.fromkeys(a for f in done for a in f.arms)) or [""]
    rows, notes = [], []
    for k, arm in enumerate(arms):
        name = f"{state}, check {arm}" if arm else state
        row, alarms, misses = check_columns(name, done, arm)
        rows.append(row.replace(f"| {len(done)} |", f"| {len(done)} / {len(figs)} |", 1))
        rows[-1] += verify if k == 0 else " as above |" * 5
        notes += alarms + misses
    warm = [v for f in done for v in f.warm if np.isfinite(v[2])]
    if warm:
        rows.append(
            f"  warmer tank: verify after − true max {max(v[2] for v in warm):.4f} mm, "
            f"{sum(v[2] <= v[4] for v in warm)} of {len(warm)} within its ±"
            f"{min(v[4] for v in warm):.3f}–{max(v[4] for v in warm):.3f}"
        )
    rows += notes
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
        "--tank",
        choices=("linear", "cycling"),
        default="linear",
        help="the drifting cells' tank: a steady drift, or a heater cycling (drift.py's), the "
        "cell then commissioned with its thermometer's log and checked with it and without",
    )
    ap.add_argument(
        "--thermometer",
        type=float,
        default=thermometer.RESOLUTION_C,
        metavar="C",
        help="--tank cycling: the thermometer logger's resolution (°C)",
    )
    ap.add_argument(
        "--quick",
        action="store_true",
        help="--worlds 1 --jobs 1 --state drifting --points 1 --region 3: the same code path "
        "in half a minute",
    )
    args = parse_args(ap, QUICK, argv)
    if args.warm and args.tank != "linear":
        ap.error("--warm warms a steady tank: it takes --tank linear")
    work = Path(tempfile.mkdtemp(prefix="ucal-vcdrift-"))
    template = drift.make_profile(work, args.level, drift.DECLARED_DRIFT[args.level])
    profile = load_profile(template)
    rng = np.random.default_rng(args.seed)
    cells = [draw_cells(rng, profile, i, args.level) for i in range(args.worlds)]
    heats: dict[int, Heated] = {}
    if args.tank == "cycling":  # the drifting cells' tank a heater (their lost motion kept)
        tank = drift.Tank("cycling", np.random.default_rng([args.seed, 1]))
        heat_rng = np.random.default_rng([args.seed, 2])
        for i, cell in enumerate(cells):
            path = work / f"tank-{i:03d}.csv"
            cell["drifting"], heats[i] = heated(
                heat_rng, tank, cell["drifting"], path, args.thermometer
            )
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
                [heats.get(i) if s == "drifting" else None for s, i in jobs],
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
