"""``check`` on commissioned cells against what moved: is each change named, with its size?

Each cell is ``realistic.py``'s (the DH table within its tolerance, offsets ±3°, lost motion up
to 0.01°, the tank drifting up to ±0.05 °C/min, an 8-bit amplitude, an unknown TOF delay) of
one of the models ``--models`` (TX90, TX90L, TX90XL by default), its block fixtured (declared
0.5 mm / 0.01°) or placed by hand (5 mm / 0.5°), as ``--blocks`` says (``realistic.py``'s
profiles). Each is commissioned and
checked by the commands, as processes, as a user runs them: ``calibrate`` (the offsets level),
the reference ``check``, then one ``check`` of the cell as commissioned (a new noise draw:
it must pass) and one of each change (each against the same reference, ``CHANGES``):

* ``across 0.3`` / ``across 1``: the tool remounted 0.3 mm / 1 mm across its beam (a random
  direction normal to the beam, flange frame);
* ``along 1``: the tool remounted 1 mm along its beam (either way);
* ``J2 0.05``: joint 2's offset moved by 0.05° (either way);
* ``block 0.5``: the block bumped 0.5 mm in a random horizontal direction;
* ``warm 1``: the tank 1 °C warmer (decision 16: the water's change is reported as its own
  cause, exit 0);
* ``arm 5``: the arm 5 K warmer than at the reference (``[arm] offset_k``, aluminium's 23 ppm/K:
  every link 115 ppm longer), the arm's growth named (``ucal.check.growth``).

A change is *named* when the check exits 1 with exactly the expected cause (``causes`` in its
``--json``: the tool across or along the beam, the joint, the block's position, the arm's
growth) within 20 % of the change's size (counted apart: named with a suspect the check says
it cannot tell it from, ``fit.alike``); ``warm 1`` when it exits 0 with the water noted within
20 % of 1 °C. Every check's ``arm_growth_ppm`` is judged against the truth (0, or 115 ppm
warmed): its error over its ``arm_growth_ppm_std``. Printed: per change, how many of the cells
named it, the sizes' largest error, what the others named; the unchanged cells' false alarms;
the arm growth's error against its σ over every check; the largest ``duration_s`` (cell time)
and the plan's estimate; the quantities reported ``ok`` with a σ above their tolerance (must
be none) and the ones reported ``not determined``, by name.

With ``--bent`` every arm gives under its weight and the tool's (``commissioning.py --bent``,
``compliance.py``'s draws), the profile stating the tool's mass as weighed.

Usage: ``python benchmarks/check_changes.py [--bent] [--cells 4] [--jobs 2] [--seed 1] [--models
tx90,tx90l,tx90xl] [--blocks fixtured,hand] [--changes NAME,...]``; ``--quick``: one TX90L
cell with a fixtured block, the unchanged check and three changes (across 0.3, J2 0.05, block
0.5), the same code path in about half a minute of CPU.
"""

from __future__ import annotations

import argparse
import concurrent.futures
import json
import re
import tempfile
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import commissioning
import numpy as np
import realistic
from _quick import parse_args

from ucal.cell import ALUMINIUM_EXPANSION_PER_K
from ucal.profile import load_profile, write_profile

#: ``--quick``: the defaults it changes (an option given on the command line still wins).
QUICK = {
    "cells": 1,
    "jobs": 1,
    "models": "tx90l",
    "blocks": "fixtured",
    "changes": "across 0.3,J2 0.05,block 0.5",
}
#: The changes: name → (expected part, what, size, unit).
CHANGES = {
    "across 0.3": ("tool", "across the beam", 0.3),
    "across 1": ("tool", "across the beam", 1.0),
    "along 1": ("tool", "along the beam", 1.0),
    "J2 0.05": ("J2", "offset", 0.05),
    "block 0.5": ("block", "position", 0.5),
    "warm 1": ("water", "°C", 1.0),
    "arm 5": ("arm", "growth", 5.0 * ALUMINIUM_EXPANSION_PER_K * 1e6),
}
#: ``arm 5``: the arm this much warmer (K).
ARM_WARMER_K = 5.0
#: A size named within this fraction of the change's.
SIZE_WITHIN = 0.2
#: A check is meant to take at most this long on the cell (s).
BUDGET_S = 120.0


@dataclass
class Cell:
    """What the checks of one cell reported."""

    name: str
    error: str = ""
    #: change → (named right, the size's relative error, what it named, exit code, named with
    #: another suspect the check could not tell it from)
    outcomes: dict[str, tuple[bool, float, str, int, bool]] = field(default_factory=dict)
    false_alarm: str | None = None
    durations: list[float] = field(default_factory=list)
    estimates: list[float] = field(default_factory=list)
    ok_beyond: list[str] = field(default_factory=list)  # "ok" with σ above the tolerance
    undetermined: Counter = field(default_factory=Counter)
    #: each check's arm growth: (error against the truth, its std), ppm
    growth: list[tuple[float, float]] = field(default_factory=list)


def _vector(text: str, section: str, key: str) -> tuple[re.Match, list[float]]:
    m = re.search(rf"(?ms)^\[{section}\].*?^{key} = (\[.*?\])$", text)
    assert m is not None, (section, key)
    return m, [float(v) for v in json.loads(m.group(1))]


def _put(text: str, section: str, key: str, value) -> str:
    m, _ = _vector(text, section, key)
    return text[: m.start(1)] + repr([float(v) for v in value]) + text[m.end(1) :]


def changed(text: str, change: str, rng: np.random.Generator) -> str:
    """The world ``text`` with ``change`` (module docstring) made."""
    if change.startswith(("across", "along")):
        _, pos = _vector(text, "tool", "position_mm")
        _, rot = _vector(text, "tool", "rotation_deg")
        rx, ry = np.radians(rot[:2])
        beam = np.array([np.sin(ry), -np.sin(rx) * np.cos(ry), np.cos(rx) * np.cos(ry)])
        size = CHANGES[change][2]
        if change.startswith("along"):
            step = rng.choice([-1.0, 1.0]) * size * beam
        else:
            u = np.cross(beam, rng.normal(size=3))
            step = size * u / np.linalg.norm(u)
        return _put(text, "tool", "position_mm", np.add(pos, step))
    if change.startswith("J2"):
        _, off = _vector(text, "robot", "joint_offsets_deg")
        off[1] += rng.choice([-1.0, 1.0]) * CHANGES[change][2]
        return _put(text, "robot", "joint_offsets_deg", off)
    if change.startswith("block"):
        _, pos = _vector(text, "sample", "position_mm")
        a = rng.uniform(0.0, 2.0 * np.pi)
        step = CHANGES[change][2] * np.array([np.cos(a), np.sin(a), 0.0])
        return _put(text, "sample", "position_mm", np.add(pos, step))
    if change.startswith("arm"):
        return text + f"\n[arm]\noffset_k = {ARM_WARMER_K!r}\n"
    m = re.search(r"(?m)^temperature_c = (.*)$", text)
    assert m is not None
    return text.replace(m.group(0), f"temperature_c = {float(m.group(1)) + CHANGES[change][2]!r}")


def reseeded(text: str, seed: int) -> str:
    """The world ``text`` with another noise draw."""
    return re.sub(r"(?m)^seed = .*$", f"seed = {seed}", text)


def judged(out: dict, change: str) -> tuple[bool, float, str]:
    """Whether ``out`` (a check's ``--json``) named ``change`` right, the size's relative error
    and what it named, in short."""
    part, what, size = CHANGES[change]
    if part == "water":
        m = re.search(r"about ([+-][0-9.]+) °C", " ".join(out.get("noted", [])))
        got = float(m.group(1)) if m else float("nan")
        error = abs(got - size) / size
        named = f"water {got:+.2f} °C" if m else "; ".join(out.get("moved", [])) or "nothing"
        return out["returncode"] == 0 and error <= SIZE_WITHIN, error, named
    found = [(c["part"], c["what"], c["size"]) for c in out.get("causes", [])]
    named = (
        ", ".join(f"{p} {w} {s:+.3g}" for p, w, s in found)
        or (out.get("error", "") or "nothing")[:120]
    )
    right = [abs(abs(s) - size) / size for p, w, s in found if (p, w) == (part, what)]
    error = right[0] if right else float("nan")
    ok = out["returncode"] == 1 and len(found) == 1 and bool(right) and error <= SIZE_WITHIN
    return ok, error, named


def audit(cell: Cell, out: dict, growth_ppm: float = 0.0) -> None:
    """The check's quantities: "ok" with σ above the tolerance, "not determined", its time,
    its arm growth against the true ``growth_ppm``."""
    if out.get("arm_growth_ppm") is not None:
        cell.growth.append((out["arm_growth_ppm"] - growth_ppm, out["arm_growth_ppm_std"]))
    for q in out.get("quantities", []):
        std, tol = q.get("std"), q.get("tolerance")
        if q["verdict"] == "ok" and std is not None and tol is not None and std > tol:
            cell.ok_beyond.append(q["name"])
    cell.undetermined.update(q["name"] for q in out.get("not_determined", []))
    if out.get("duration_s") is not None:
        cell.durations.append(float(out["duration_s"]))
        cell.estimates.append(float(out["estimated_s"]["tcp"]))


def run_cell(
    seed: int, index: int, model: str, block: str, changes: tuple[str, ...], bent: bool = False
) -> Cell:
    """Commission one cell and check it unchanged and after each change (module docstring)."""
    rng = np.random.default_rng([seed, index])
    cell = Cell(f"{model} {block} {index}")
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        profile_path = realistic.make_profile(d, block == "fixtured", model)
        text = realistic.draw_world(rng, load_profile(profile_path), index)
        world = d / "world.toml"
        world.write_text(text)
        if bent:  # the arm from its own stream: the rigid cell's, bent
            arm = commissioning.Arm.draw(np.random.default_rng([seed, index, 36]), False, model)
            arm.bend(world)
            text = world.read_text()
            write_profile(profile_path, {"tool": arm.stated_tool}, "the tool as weighed")
        done = commissioning.run("calibrate", profile_path, world)
        if not done.get("written"):
            cell.error = f"calibrate: {done.get('error', 'not written')[:160]}"
            return cell
        ref = commissioning.run("check", profile_path, world)
        if ref["returncode"] != 0:
            cell.error = f"reference check: {ref.get('error', '')[:160]}"
            return cell
        audit(cell, ref)
        same = d / "same.toml"
        same.write_text(reseeded(text, index + 1000))
        out = commissioning.run("check", profile_path, same)
        audit(cell, out)
        if out["returncode"] != 0:
            cell.false_alarm = "; ".join(out.get("moved", [])) or out.get("error", "")[:120]
        for change in changes:
            path = d / f"{change.replace(' ', '-')}.toml"
            path.write_text(reseeded(changed(text, change, rng), index + 2000))
            out = commissioning.run("check", profile_path, path)
            audit(cell, out, CHANGES[change][2] if change.startswith("arm") else 0.0)
            ok, error, named = judged(out, change)
            part = CHANGES[change][0]
            alike = bool(out.get("fit", {}).get("alike", {}).get(part))
            cell.outcomes[change] = (ok, error, named, out["returncode"], alike)
    return cell


def summarize(cells: list[Cell]) -> None:
    good = [c for c in cells if not c.error]
    print(f"cells: {len(cells)}, commissioned and referenced: {len(good)}")
    for c in cells:
        if c.error:
            print(f"  {c.name}: {c.error}")
    for change, (part, what, _) in CHANGES.items():
        rows = [c.outcomes[change] for c in good if change in c.outcomes]
        if not rows:
            continue
        right = sum(r[0] for r in rows)
        alike = sum(r[0] and r[4] for r in rows)
        errors = [r[1] for r in rows if np.isfinite(r[1])]
        worst = f"{100 * max(errors):.1f} %" if errors else "—"
        print(
            f"{change:<11} named right {right} / {len(rows)} ({part} {what}, size error max "
            f"{worst}; {alike} named with another suspect alike)"
        )
        for c in good:
            ok, _, named, code, _ = c.outcomes.get(change, (True, 0.0, "", 0, False))
            if not ok:
                print(f"    {c.name}: exit {code}, named {named}")
    alarms = [c for c in good if c.false_alarm is not None]
    print(f"unchanged cells: {len(good)}, false alarms {len(alarms)}")
    for c in alarms:
        print(f"    {c.name}: {c.false_alarm}")
    durations = [t for c in good for t in c.durations]
    estimates = [t for c in good for t in c.estimates]
    if durations:
        print(
            f"cell time per check: max {max(durations):.1f} s, median {np.median(durations):.1f} "
            f"s (budget {BUDGET_S:g} s); plan's estimate over Modbus TCP max {max(estimates):.1f} s"
        )
    growth = np.array([g for c in good for g in c.growth]).reshape(-1, 2)
    if growth.size:
        z = np.abs(growth[:, 0]) / growth[:, 1]
        print(
            f"arm growth over {len(z)} checks: error rms {np.sqrt(np.mean(growth[:, 0] ** 2)):.2f} "
            f"ppm, sigma median {np.median(growth[:, 1]):.2f} ppm; within 3 sigma "
            f"{np.mean(z <= 3):.0%}, beyond 4 sigma {int(np.sum(z > 4))}, max |z| {z.max():.1f}, "
            f"rms z {np.sqrt(np.mean(z**2)):.2f}"
        )
    beyond = Counter(n for c in good for n in c.ok_beyond)
    print(f"quantities 'ok' with sigma above their tolerance: {sum(beyond.values())}")
    undetermined = sum((c.undetermined for c in good), Counter())
    checks = sum(len(c.durations) for c in good)
    print(
        f"'not determined' over {checks} checks: "
        + (", ".join(f"{n} {k}" for n, k in undetermined.most_common()) or "none")
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--cells", type=int, default=4, help="cells per model and block")
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--models", default="tx90,tx90l,tx90xl")
    parser.add_argument("--blocks", default="fixtured,hand")
    parser.add_argument("--changes", default=",".join(CHANGES), help="of CHANGES, by name")
    parser.add_argument("--bent", action="store_true", help="arms that bend (module docstring)")
    parser.add_argument("--quick", action="store_true")
    args = parse_args(parser, QUICK, argv)
    changes = tuple(args.changes.split(","))
    unknown = [c for c in changes if c not in CHANGES]
    if unknown:
        parser.error(f"unknown changes {unknown}: choose among {list(CHANGES)}")
    jobs = [
        (args.seed, i, model, block, changes, args.bent)
        for model in args.models.split(",")
        for block in args.blocks.split(",")
        for i in range(args.cells)
    ]
    if args.jobs > 1:
        with concurrent.futures.ProcessPoolExecutor(args.jobs) as pool:
            cells = list(pool.map(run_cell, *zip(*jobs, strict=True)))
    else:
        cells = [run_cell(*job) for job in jobs]
    summarize(cells)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
