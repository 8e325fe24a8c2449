"""The offsets and the full level on random arms that bend under their own weight and the tool's.

Each world is ``realistic.py``'s (block, tool, water, DH table, lost motion, drift within the
declared tolerances) with an arm that gives: J2 and J3 of stiffness log-uniform in 1e5…1e6
N·m/rad (the range published for arms of this class), J1 and J4–J6 in proportion to the
model table's nominal stiffness, the links' masses ±10 % and their centres of mass ±5 mm off
the model table's, a tool of 0.3–2 kg whose centre lies 20–80 mm out on its axis; the profile
states the tool's mass within ±5 % and its centre within 5 mm, as a user who weighed it would.
Every world is measured once over loopback and solved twice on the same measurements: by the
solvers as they are (each joint's compliance an unknown with the model table's prior,
``ucal.model.load``) and as a rigid arm (the compliance held at 0). Each is judged against
the offsets the written ones stand for: the world's offsets less half its lost motion plus
each link's sag at the load posture (``calibrate --json``'s ``load_posture_deg``); the rigid
solver against the same. Printed per solver: coverage (|error| ≤ 3σ), the largest |z|, runs
written and written with a joint beyond 4σ, and per joint the median |error| and std.

Then where ``path --for-controller``'s targets land the bent arm (``landing_mm``): on each
world, for the cell as the full level writes it (its true table and tool, the offsets of its
load posture), the targets of 60 poses the arm reaches over the scanning region about the
run's load posture, executed by the world's arm: not corrected for its sag, corrected with
the world's stiffness and the masses the profile states (the model table's links, the tool as
weighed), and corrected with the model table's stiffness (a profile whose stiffness no level
has identified). Printed: mean and max distance from the asked poses over all worlds.

``--level full``: the full level with a step on worlds of its own (``full_calibration.py``'s:
the non-zero DH lengths, the twists and the step off within their tolerances; ``d₅``, ``a₅``,
which no posture identifies, nominal) with the same bent arm, solved as ``calibrate --level
full`` and as a rigid arm on the same measurements. Printed per solver: runs written, the TCP
error over the scanning region *under the tool's load* (the bent arm's true tool centre
against the model's, each joint given by its fitted compliance times its torque's difference
from the load posture's; after the best rigid alignment), and for J2 and J3 how often the
stiffness was reported (``ucal.model.stiffness``: three stds within ±20 %), within ±20 % of
the truth where reported, and its coverage (|error| ≤ 3σ) where reported and over every run.
``--level both`` (the default) prints both levels' figures.

Usage: ``python benchmarks/compliance.py --worlds 12 [--fixture] [--level offsets|full|both]
[--jobs 2] [--cache DIR]``; ``--quick``: one world each (the full level's of 8 postures).
"""

from __future__ import annotations

import argparse
import concurrent.futures
import pickle
import tempfile
import time
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import numpy as np
from _quick import parse_args
from realistic import draw_world, effective_offsets_deg, make_profile, measure_world

from ucal.calibration.procedure import judge
from ucal.calibration.solve import solve
from ucal.cell import CellProfile, WorldTruth
from ucal.kinematics.filtering import controller_targets
from ucal.kinematics.rotations import matrix_to_pose
from ucal.model.kinematic import scanning_postures
from ucal.model.load import Deflection, model_bodies
from ucal.model.priors import GRAVITY_M_S2
from ucal.profile import load_profile, write_profile
from ucal.profile.models import controller_model, model_sheet
from ucal.sim.cell import SimulatedCell
from ucal.world import load_world

QUICK = {"worlds": 1, "jobs": 1, "postures": 8}


def draw_arm(rng: np.random.Generator, model: str) -> tuple[str, float, list[float]]:
    """The world's ``[robot]`` and ``[tool]`` arm keys (text), the tool's mass and centre."""
    sheet = model_sheet(model)
    nominal = np.asarray(sheet.stiffness_nm_per_rad, float)
    k23 = 10.0 ** rng.uniform(5.0, 6.0, 2)
    scale = float(np.mean(k23 / nominal[1:3]))
    k = nominal * scale
    k[1:3] = k23
    masses = sheet.link_mass_kg * rng.uniform(0.9, 1.1, 6)
    centres = sheet.link_centre_of_mass_mm + rng.uniform(-5.0, 5.0, (6, 3))
    tool_kg = float(rng.uniform(0.3, 2.0))
    tool_mm = [0.0, 0.0, float(rng.uniform(20.0, 80.0))]
    rows = ", ".join(str(list(map(float, c))) for c in centres)
    robot = (
        f"stiffness_nm_per_rad = {k.tolist()!r}\n"
        f"link_mass_kg = {masses.tolist()!r}\n"
        f"link_centre_of_mass_mm = [{rows}]\n"
    )
    tool = f"mass_kg = {tool_kg!r}\ncentre_of_mass_mm = {tool_mm!r}\n"
    return robot + "\x00" + tool, tool_kg, tool_mm


def bent_world(
    rng: np.random.Generator, profile: CellProfile, index: int, draw=draw_world
) -> tuple[str, dict]:
    """A world of ``draw`` (``realistic.py``'s) with a bending arm, and the tool the profile
    states."""
    text = draw(rng, profile, index)
    arm, tool_kg, tool_mm = draw_arm(rng, profile.model.name)
    robot, tool = arm.split("\x00")
    text = text.replace("[robot]\n", "[robot]\n" + robot, 1)
    if "[tool]\n" not in text:
        text += "[tool]\n"
    text = text.replace("[tool]\n", "[tool]\n" + tool, 1)
    stated = {
        "mass_kg": tool_kg * float(rng.uniform(0.95, 1.05)),
        "centre_of_mass_mm": (np.asarray(tool_mm) + rng.uniform(-5.0, 5.0, 3)).tolist(),
    }
    return text, stated


def bent_worlds(
    work: Path, n: int, seed: int, profile_in: Callable[[Path], Path], draw: Callable
) -> tuple[list[Path], list[Path]]:
    """``n`` profiles (``profile_in``: one made in a directory) and bent worlds of ``draw``
    (``bent_world``) under ``work``, the tool stated in each profile as weighed."""
    rng = np.random.default_rng(seed)
    profiles, worlds = [], []
    for i in range(n):
        d = work / f"{i:03d}"
        d.mkdir(parents=True, exist_ok=True)
        path = profile_in(d)
        text, stated = bent_world(rng, load_profile(path), i, draw)
        write_profile(path, {"tool": stated}, "the tool as weighed")
        w = d / "world.toml"
        if not w.exists():
            w.write_text(text)
        profiles.append(path)
        worlds.append(w)
    return profiles, worlds


def judged(
    profile: CellProfile, run, truth, rigid: bool
) -> tuple[np.ndarray, bool, float, np.ndarray]:
    """|z| of the reported joints, whether written, the worst |error| (deg), the load
    posture."""
    if rigid:
        profile = replace(profile, stiffness_nm_per_rad=np.zeros(6))
    sol, _ = solve(profile, run)
    cell = sol.cell_fit
    assert cell is not None
    want = effective_offsets_deg(truth)
    posture = cell.load_posture_deg
    if posture is None:  # the rigid profile's fit has no load posture: the compliant one's
        posture = run.measurements[0].joints_deg
    want = want + SimulatedCell(truth).sag_deg(posture, np.ones(6))
    ok = np.isfinite(sol.std_deg)
    err = sol.offsets_deg - want
    z = np.abs(err[ok]) / sol.std_deg[ok]
    joints = ok & (np.arange(6) > 0)  # J1: absolute, as placed by hand
    worst = float(np.max(np.abs(err[joints]), initial=0.0))
    return z, judge(sol, cell.quality).ok, worst, np.asarray(posture, float)


#: The targets ``landing_mm`` compares: not corrected, corrected with the world's stiffness,
#: with the model table's.
LANDINGS = ("not corrected", "world's stiffness", "table's stiffness")


def landing_mm(
    profile: CellProfile, truth: WorldTruth, load_posture: np.ndarray, n: int = 60
) -> dict[str, np.ndarray]:
    """How far (mm, (n,) each of ``LANDINGS``) the bent arm lands from poses it reaches over
    the scanning region about ``load_posture``, on ``path --for-controller``'s targets for the
    cell as the full level writes it (module docstring; the lost motion left out)."""
    cell = SimulatedCell(truth)
    model = truth.model.with_dh(truth.model.dh, truth.dh_beta_deg)
    q = scanning_postures(load_posture, n, seed=1, model=model)
    frames = np.array([cell.true_tcp(x) for x in q])
    reached, asked = frames[:, :3, 3], matrix_to_pose(frames)
    offsets = truth.joint_offsets_deg + cell.sag_deg(load_posture)
    bodies = model_bodies(
        model,
        profile.link_mass_kg,
        profile.link_centre_of_mass_mm,
        profile.tool_mass_kg,
        profile.tool_centre_of_mass_mm,
        GRAVITY_M_S2,
    )
    stiffness = (None, truth.arm.stiffness_nm_per_rad, profile.stiffness_nm_per_rad)
    out = {}
    for name, k in zip(LANDINGS, stiffness, strict=True):
        bend = None
        if k is not None:
            c = np.divide(1e6, k, out=np.zeros(6), where=np.asarray(k) > 0.0)
            bend = Deflection.of(model, bodies, offsets, load_posture, c)
        targets = controller_targets(
            model,
            controller_model(profile.model),
            asked,
            truth.beam_matrix,
            offsets,
            start_deg=q[0],
            sag_deg=None if bend is None else bend.sag_deg,
        )
        landed = np.array([cell.true_tcp(x)[:3, 3] for x in targets.joints_deg])
        out[name] = np.linalg.norm(landed - reached, axis=1)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--worlds", type=int, default=12)
    ap.add_argument("--seed", type=int, default=36)
    ap.add_argument("--fixture", action="store_true")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--cache", type=Path, default=None)
    ap.add_argument("--level", choices=("offsets", "full", "both"), default="both")
    ap.add_argument("--postures", type=int, default=None, help="--level full: at most N")
    ap.add_argument("--quick", action="store_true", help="one world (the full level: 8 postures)")
    args = parse_args(ap, QUICK)
    if args.level != "offsets":
        from _compliance_full import main_full

        main_full(args)
    if args.level != "full":
        main_offsets(args)


def main_offsets(args: argparse.Namespace) -> None:
    """The offsets level's figures (module docstring)."""
    work = args.cache or Path(tempfile.mkdtemp(prefix="ucal-compliance-"))
    work.mkdir(parents=True, exist_ok=True)
    tag = "fixture" if args.fixture else "hand"
    profiles, worlds = bent_worlds(
        work / tag, args.worlds, args.seed, lambda d: make_profile(d, args.fixture), draw_world
    )
    caches = [w.with_suffix(".pkl") for w in worlds]
    t0 = time.monotonic()
    with concurrent.futures.ProcessPoolExecutor(args.jobs) as pool:
        list(pool.map(measure_world, profiles, worlds, caches))
    print(f"measured {len(worlds)} worlds in {time.monotonic() - t0:.0f} s ({work})")
    rows: dict[str, list[tuple[np.ndarray, bool, float, np.ndarray]]] = {
        "compliant": [],
        "rigid": [],
    }
    landed: dict[str, list[np.ndarray]] = {name: [] for name in LANDINGS}
    for p, w, c in zip(profiles, worlds, caches, strict=True):
        data = pickle.loads(c.read_bytes())
        if data["run"] is None:
            print(f"  {w}: {data['error']}")
            continue
        profile = load_profile(p)
        truth = load_world(w, profile)
        for name in rows:
            rows[name].append(judged(profile, data["run"], truth, rigid=name == "rigid"))
        for name, mm in landing_mm(profile, truth, rows["compliant"][-1][3]).items():
            landed[name].append(mm)
    print(
        "| solver | coverage (|err| ≤ 3σ) | max |z| | written | written beyond 4σ "
        "| worst |err| J2-J6, deg |"
    )
    print("| --- | --- | --- | --- | --- | --- |")
    for name, outs in rows.items():
        if not outs:
            continue
        z = np.concatenate([o[0] for o in outs])
        written = [o for o in outs if o[1]]
        beyond = sum(1 for o in written if np.any(o[0] > 4.0))
        print(
            f"| {name} | {np.mean(z <= 3.0) * 100:.1f} % of {len(z)} | {np.max(z):.1f} "
            f"| {len(written)} / {len(outs)} | {beyond} | {max(o[2] for o in outs):.4f} |"
        )
    print("\n| path --for-controller targets | landed mean, mm | max, mm |")
    print("| --- | --- | --- |")
    for name, runs in landed.items():
        if runs:
            mm = np.concatenate(runs)
            print(f"| {name} | {np.mean(mm):.4f} | {np.max(mm):.4f} |")


if __name__ == "__main__":
    main()
