"""Full kinematic calibration against offsets-only, on the same measurements of random cells.

Each world differs from its TX90L profile the way a real robot does: DH lengths (every length
of links 1-5, ``d₅`` and ``a₅`` included, whose nominal value is zero; ``--lengths nonzero``:
only the non-zero ones, as this benchmark drew them before) uniform in ±0.5 mm, twists in
±0.05°, Hayati's β₂ in ±0.05°, joint offsets in ±1°, backlash ≤ 0.01°, the block within its
declared tolerance (hand-placed: 5 mm, 0.5°; normal, clipped at 2σ), the water within the
thermometer's (``--thermometer``, one sigma in °C, uniform ±2σ), TOF noise 0.5 ns and
amplitude noise 1 %, the pulser's 8 ns delay. Link 6 and the tool are one rigid body that
``tool-frame`` measures; they are nominal here. The profile declares the DH tolerance (0.3 mm,
0.03°: the σ of those uniform draws).

Every world is measured once with ``calibrate --level full``'s plan and run (the whole sequence
against the simulated cell over loopback), then solved twice from the same measurements: the
offsets level (``solve_exact_with_priors``: offsets with the DH table as a tolerance) and the
full level (``solve_full``), and a third time by the full level as it was, the parameters it
cannot identify held at their nominal values (the baseline; ``solve_full`` now carries them as
nuisances with their priors). Printed:

* TCP error over the scanning region (calibration pose ± 20° on J1-J3, ± 90° on J4/J6, ± 30°
  on J5; 200 postures), true cell against each calibrated model after the best rigid
  alignment (the base frame is a gauge), mean and max per world and over all; for the full
  level also after the best similarity (the common scale of lengths and sound speed, which
  time of flight cannot see, taken out);
* coverage of the full level's std: share of the reported quantities (joint offsets J2-J5
  against the truth minus half the backlash, identified and prior-dominated DH parameters)
  with |error| ≤ 3·std, and the largest |z|;
* moves, pulser reads, simulated duration (what a real cell takes over Modbus TCP) and the
  plan's own estimate for Modbus TCP and RTU;
* a nominal robot (no DH error): the largest |value − nominal| / std of the table found.

Usage: ``python benchmarks/full_calibration.py --worlds 10 [--thermometer 0.1] [--jobs 2]``;
``--quick``: one world (and the nominal robot) of at most 8 postures, the same code path in
seconds.
"""

from __future__ import annotations

import argparse
import concurrent.futures
import functools
import pickle
import tempfile
import time
from pathlib import Path

import numpy as np
from _quick import parse_args

from drivers.errors import DriverError
from ucal.calibration.exact import solve_exact_with_priors
from ucal.devices.session import check_status, open_cell
from ucal.errors import UcalError
from ucal.kinematics.dh import fk
from ucal.measure.postures import FullRun, estimate_postures, run_full
from ucal.model.fit import prior_from_profile
from ucal.model.kinematic import aligned_errors_mm, scanning_postures, solve_full, twists_deg
from ucal.model.postures import MAX_POSTURES, plan_full
from ucal.model.targets import calibration_pose
from ucal.profile import create_profile, load_profile, write_profile
from ucal.world import load_world

MODEL = "tx90l"
#: ``--quick``: the defaults it changes (an option given on the command line still wins).
QUICK = {"worlds": 1, "jobs": 1, "postures": 8}


#: The step of ``--step``: a ground step block on the XY face, height certified to 2 µm.
STEP = {"height_mm": 50.0, "height_std_mm": 0.002, "centre_mm": [250.0, 250.0], "size_mm": 60.0}


def make_profile(
    directory: Path, thermometer_c: float, step: bool = False, model: str = MODEL
) -> Path:
    path = directory / "cell.toml"
    create_profile(path, model, force=True)
    updates: dict = {
        "robot": {"dh_length_std_mm": 0.3, "dh_angle_std_deg": 0.03},
        "water": {"temperature_std_c": thermometer_c},
    }
    if step:
        updates["step"] = STEP
    write_profile(path, updates, "benchmark")
    return path


def draw_world(
    rng: np.random.Generator, profile, index: int, nominal: bool = False, every: bool = True
) -> str:
    """World-file text of a cell drawn as the module docstring says (``every``: every length of
    links 1-5 off, else only the non-zero ones)."""
    dh = profile.model.dh.copy()
    beta = 0.0
    if not nominal:
        off = rng.uniform(-0.5, 0.5, (5, 2))
        dh[:5, 1:3] += off if every else np.where(dh[:5, 1:3] != 0, off, 0.0)
        dh[:5, 3] += rng.uniform(-0.05, 0.05, 5)
        beta = rng.uniform(-0.05, 0.05)
    rows = ",\n".join(
        f"  {{ theta_offset_deg = {r[0]!r}, d_mm = {r[1]!r}, a_mm = {r[2]!r}, "
        f"alpha_deg = {r[3]!r}" + (f", beta_deg = {beta!r}" if i == 1 else "") + " }"
        for i, r in enumerate(dh.tolist())
    )
    # placed by hand within its declared tolerance: normal, clipped at 2σ
    pos_std = np.broadcast_to(profile.sample_position_std_mm, 3)
    rot_std = np.broadcast_to(profile.sample_rotation_std_deg, 3)
    pos = profile.sample_position_mm + np.clip(rng.normal(0.0, pos_std), -2 * pos_std, 2 * pos_std)
    rot = profile.sample_rotation_deg + np.clip(rng.normal(0.0, rot_std), -2 * rot_std, 2 * rot_std)
    t_std = profile.water_temperature_std_c
    step = ""
    if profile.step is not None:  # placed by hand, height within its certificate, top not flat
        st = profile.step
        step = f"""[step]
height_mm = {st.height_mm + rng.uniform(-2, 2) * st.height_std_mm!r}
centre_mm = {(st.centre_mm + rng.uniform(-2.0, 2.0, 2)).tolist()!r}
tilt_deg = {rng.uniform(-0.005, 0.005, 2).tolist()!r}
"""
    return (
        step
        + f"""[robot]
dh = [
{rows}
]
joint_offsets_deg = {rng.uniform(-1.0, 1.0, 6).tolist()!r}
backlash_deg = {rng.uniform(0.0, 0.01, 6).tolist()!r}
[sample]
position_mm = {pos.tolist()!r}
rotation_deg = {rot.tolist()!r}
[water]
temperature_c = {profile.water_temperature_c + rng.uniform(-2 * t_std, 2 * t_std)!r}
[noise]
tof_ns = 0.5
amplitude = 0.01
seed = {index + 1}
"""
    )


def run_world(
    profile_path: Path,
    world_path: Path,
    save: Path | None = None,
    max_postures: int = MAX_POSTURES,
) -> dict:
    """``measure_world``, once more if the link to the simulated cell failed (a loaded machine
    can starve the in-process simulator past the drivers' guard timeout); a run the procedure
    stops (a posture refused for safety, an echo not found) is a row of its own."""
    try:
        try:
            return measure_world(profile_path, world_path, save, max_postures)
        except DriverError as err:
            print(f"{world_path.name}: {err}; measuring again", flush=True)
            return measure_world(profile_path, world_path, save, max_postures)
    except (UcalError, DriverError) as err:  # as a row: a driver's error does not pickle
        print(f"{world_path.name}: stopped: {err}", flush=True)
        return {"stopped": str(err)}


def measure_world(
    profile_path: Path,
    world_path: Path,
    save: Path | None = None,
    max_postures: int = MAX_POSTURES,
) -> dict:
    """Measure one world with the full plan of at most ``max_postures`` (or take its
    measurements from ``save``, where an earlier run of the same worlds kept them); solve both
    levels; the figures of one row."""
    profile = load_profile(profile_path)
    plan = plan_full(profile, max_postures=max_postures)
    kept = None if save is None else save / f"{world_path.stem}.pickle"
    t0 = time.monotonic()
    if kept is not None and kept.exists():
        with open(kept, "rb") as f:
            saved = pickle.load(f)
        if saved["world"] != world_path.read_text():
            raise ValueError(f"{kept} holds another world")
        run = FullRun(saved["measurements"], saved["steps"], *saved.get("counts", (0, 0)))
        duration = saved.get("duration_s", float("nan"))
    else:
        with open_cell(profile, str(world_path), None, None) as cell:
            check_status(cell.rig)
            run = run_full(profile, plan, cell.rig)
            duration = cell.elapsed_s
        if kept is not None:  # the measurements, to solve again with other assumptions
            kept.parent.mkdir(parents=True, exist_ok=True)
            with open(kept, "wb") as f:
                pickle.dump(
                    {
                        "measurements": run.measurements,
                        "steps": run.steps,
                        "counts": (run.moves, run.reads),
                        "duration_s": duration,
                        "world": world_path.read_text(),
                    },
                    f,
                )
    wall = time.monotonic() - t0
    world = load_world(world_path, profile)
    prior = prior_from_profile(profile)
    full = solve_full(prior, run.measurements, structure=plan.structure, steps=run.steps)
    unseen = full.ident.redundant  # the plan's structure, or these measurements'
    held = solve_full(
        prior, run.measurements, structure=full.ident, steps=run.steps, fixed=tuple(unseen)
    )
    level1 = solve_exact_with_priors(prior, run.measurements)
    true_model = world.model.with_dh(world.model.dh, world.dh_beta_deg)
    true_offsets = world.joint_offsets_deg - 0.5 * world.backlash_deg  # reached from below
    qs = scanning_postures(calibration_pose(profile), 200, 1, profile.model)
    tool = profile.tool_matrix
    truth = fk(true_model, qs, tool, true_offsets)[:, :3, 3]
    err_full = aligned_errors_mm(fk(full.model, qs, tool, full.offsets_deg)[:, :3, 3], truth)
    err_sim = aligned_errors_mm(
        fk(full.model, qs, tool, full.offsets_deg)[:, :3, 3], truth, scale=True
    )
    err_l1 = aligned_errors_mm(fk(profile.model, qs, tool, level1.offsets_deg)[:, :3, 3], truth)
    err_held = aligned_errors_mm(fk(held.model, qs, tool, held.offsets_deg)[:, :3, 3], truth)
    z = [
        (full.offsets_deg[j] - true_offsets[j]) / full.std_deg[j]
        for j in range(6)
        if np.isfinite(full.std_deg[j])
    ]
    true_p = {
        f"dh{i + 1}_{k}": true_model.dh[i, c + 1]
        for i in range(6)
        for c, k in enumerate(("d_mm", "a_mm", "alpha_deg"))
    }
    true_p["dh2_beta_deg"] = twists_deg(true_model)[1]
    z += [(v.value - true_p[n]) / v.std for n, v in full.parameters.items() if v.std is not None]
    est = estimate_postures(plan, profile)
    return {
        "full": (err_full.mean(), err_full.max()),
        "offsets": (err_l1.mean(), err_l1.max()),
        "full_similar": (err_sim.mean(), err_sim.max()),
        "z": np.array(z),
        "moves": run.moves,
        "reads": run.reads,
        "duration_s": duration,
        "wall_s": wall,
        "estimate": (est.tcp_s, est.rtu_s),
        "postures": len(plan.postures),
        "verdict": full.cell.quality.verdict,
        "chi2": full.cell.quality.chi2_reduced,
        "held": (
            held.cell.quality.verdict,
            held.cell.quality.chi2_reduced,
            err_held.mean(),
            err_held.max(),
        ),
        "nominal_z": max(
            abs((v.value - v.nominal) / v.std)
            for v in full.parameters.values()
            if v.std is not None
        ),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--worlds", type=int, default=10)
    ap.add_argument(
        "--thermometer",
        type=float,
        default=2.0,
        help="one sigma of the water thermometer (°C), declared and drawn within",
    )
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument(
        "--save",
        type=Path,
        help="keep each world's measurements there (pickle); a world already there is solved "
        "from them, not measured again",
    )
    ap.add_argument(
        "--step", action="store_true", help="a step of known height on the XY face (the scale)"
    )
    ap.add_argument(
        "--lengths",
        choices=("every", "nonzero"),
        default="every",
        help="which DH lengths of links 1-5 the worlds put off (default every, d5 and a5 included)",
    )
    ap.add_argument(
        "--postures",
        type=int,
        default=MAX_POSTURES,
        help="at most N postures (calibrate --level full --postures N)",
    )
    ap.add_argument(
        "--quick",
        action="store_true",
        help="--worlds 1 --jobs 1 --postures 8: the same code path in seconds",
    )
    args = parse_args(ap, QUICK)
    work = Path(tempfile.mkdtemp(prefix="ucal-full-bench-"))
    profile_path = make_profile(work, args.thermometer, args.step)
    profile = load_profile(profile_path)
    rng = np.random.default_rng(args.seed)
    worlds = []
    for i in range(args.worlds + 1):
        path = work / f"world{i}.toml"
        path.write_text(
            draw_world(rng, profile, i, nominal=(i == args.worlds), every=args.lengths == "every")
        )
        worlds.append(path)
    plan = plan_full(profile, max_postures=args.postures)
    print(
        f"profile {MODEL}, thermometer ±{args.thermometer:g} °C, DH tolerance 0.3 mm / "
        f"0.03°{', step 50 ± 0.002 mm' if args.step else ''}; lengths off: {args.lengths}; "
        f"{plan.describe()}"
    )
    with concurrent.futures.ProcessPoolExecutor(args.jobs) as pool:
        measure = functools.partial(run_world, save=args.save, max_postures=args.postures)
        rows = list(pool.map(measure, [profile_path] * len(worlds), worlds))
    print(
        "world  postures  moves  reads  sim min  est TCP/RTU min  verdict  χ²ᵣ   "
        "offsets-only mean/max mm  full mean/max mm  (scale out)  max|z|   "
        "held at nominal: verdict χ²ᵣ mean/max mm"
    )
    for i, r in enumerate(rows):
        tag = "nominal" if i == args.worlds else f"{i:7d}"
        if "stopped" in r:
            print(f"{tag:>7} stopped: {r['stopped']}")
            continue
        print(
            f"{tag:>7} {r['postures']:6d} {r['moves']:7d} {r['reads']:6d} "
            f"{r['duration_s'] / 60:7.1f} {r['estimate'][0] / 60:8.1f}/{r['estimate'][1] / 60:.1f}"
            f"   {r['verdict']:>6} {r['chi2']:5.2f}   {r['offsets'][0]:8.3f} / "
            f"{r['offsets'][1]:.3f}        {r['full'][0]:7.3f} / {r['full'][1]:.3f}"
            f"  ({r['full_similar'][0]:.3f} / {r['full_similar'][1]:.3f})"
            f"   {np.max(np.abs(r['z'])):.2f}"
            f"   {r['held'][0]:>6} {r['held'][1]:5.2f} {r['held'][2]:.3f} / {r['held'][3]:.3f}"
        )
    stopped = [r for r in rows[: args.worlds] if "stopped" in r]
    print(f"runs stopped by the procedure: {len(stopped)} of {args.worlds}")
    drawn = [r for r in rows[: args.worlds] if "stopped" not in r]
    if not drawn:
        return
    z = np.concatenate([r["z"] for r in drawn])
    full = np.array([r["full"] for r in drawn])
    l1 = np.array([r["offsets"] for r in drawn])
    sim = np.array([r["full_similar"] for r in drawn])
    print(
        f"TCP error over the scanning region after rigid alignment, over {len(drawn)} worlds "
        f"(mean of means / max of maxima): offsets-only {l1[:, 0].mean():.3f} / "
        f"{l1[:, 1].max():.3f} mm; full {full[:, 0].mean():.3f} / {full[:, 1].max():.3f} mm "
        f"({sim[:, 0].mean():.3f} / {sim[:, 1].max():.3f} mm with the common scale taken out)"
    )
    written = [r for r in drawn if r["verdict"] == "ok"]
    held_ok = [r for r in drawn if r["held"][0] == "ok"]
    held = np.array([r["held"][2:] for r in drawn])
    print(
        f"fit verdict ok (would be written) in {len(written)} of {len(drawn)} worlds; with the "
        f"unidentifiable parameters held at nominal {len(held_ok)} of {len(drawn)}, TCP "
        f"{held[:, 0].mean():.3f} / {held[:, 1].max():.3f} mm"
    )
    print(
        f"coverage of the full level's std: {100 * np.mean(np.abs(z) <= 3):.1f} % of {len(z)} "
        f"reported quantities within 3σ (max |z| {np.max(np.abs(z)):.2f})"
    )
    print(
        f"moves {np.mean([r['moves'] for r in drawn if r['moves']]):.0f} on average; simulated "
        f"duration {np.nanmean([r['duration_s'] for r in drawn]) / 60:.1f} min (Modbus TCP); wall "
        f"{np.mean([r['wall_s'] for r in drawn]):.0f} s per world on this machine"
    )
    if "nominal_z" in rows[-1]:
        print(
            "nominal robot: largest |found − nominal| / std over the table "
            f"{rows[-1]['nominal_z']:.2f}"
        )


if __name__ == "__main__":
    main()
