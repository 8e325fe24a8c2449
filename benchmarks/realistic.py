"""Joint calibration on random simulated cells that differ from their profile as real cells do.

Each world is drawn within the profile's declared tolerances: block pose (``[sample]
position_std_mm``, ``rotation_std_deg``), tool frame (``[tool]`` stds), water temperature
(±2 °C uniform, drifting up to ±0.05 °C/min), DH lengths ≤ 0.3 mm and twists ≤ 0.03°,
backlash ≤ 0.01° per joint, an 8-bit amplitude, a TOF delay the solver does not know, TOF
noise 0.5 ns and amplitude noise 1 %; offsets uniform in ±3° on every joint. Every world is
measured once (the whole sequence against the simulated cell over loopback; the measurements
are cached in ``--cache``), then solved by the current solver and by the previous one
(offsets and corner only, profile tool / block orientation / sound speed taken as exact) on
the same measurements. Printed per solver:

* coverage: share of reported joints (std given) with |error| ≤ 3·std, and the largest |z|
  (the error against the world's offsets minus half its backlash: every posture is reached
  from below, where the link lags the encoder by b/2);
* how many runs would be written, and why the others are refused (misfit, std);
* written runs with a joint outside 4·std (must be none);
* TCP error over the workspace (200 random postures, true cell vs calibrated model), before
  calibration (profile offsets) and after, over all runs (mean / max, mm); an unobservable
  joint keeps its profile offset, so J1 with a hand-placed block dominates "after";
* per joint: median |error| and median std over the runs that report it.

Usage: ``python benchmarks/realistic.py --worlds 30 [--fixture] [--jobs 2] [--cache DIR]``;
``--quick``: one world, the same code path in seconds.
"""

from __future__ import annotations

import argparse
import concurrent.futures
import pickle
import tempfile
import time
from dataclasses import dataclass
from dataclasses import replace as dc_replace
from pathlib import Path

import numpy as np
from _quick import parse_args

from ucal.calibration.exact import OffsetSolution, solve_exact
from ucal.calibration.procedure import TOLERANCE_STD_DEG, judge
from ucal.calibration.solve import solve
from ucal.cell import CellProfile, WorldTruth
from ucal.devices.session import check_status, open_cell
from ucal.kinematics.dh import fk_frames
from ucal.measure.sequence import CalibrationRun, run_calibration
from ucal.model.targets import geometry, plan_calibration
from ucal.profile import create_profile, load_profile, write_profile
from ucal.world import load_world

MODEL = "tx90l"
#: ``--quick``: the defaults it changes (an option given on the command line still wins).
QUICK = {"worlds": 1, "jobs": 1}
#: Amplitude quantisation of the simulated pulser (bits of full screen height; 0 = none).
AMPLITUDE_BITS = 8


def make_profile(directory: Path, fixture: bool, model: str = MODEL) -> Path:
    """A default profile of ``model`` with the declared tolerances of a hand-placed or
    fixtured block."""
    path = directory / "cell.toml"
    create_profile(path, model, force=True)
    rot = 0.01 if fixture else 0.5
    pos = 0.5 if fixture else 5.0
    write_profile(
        path,
        {
            "sample": {"position_std_mm": pos, "rotation_std_deg": [rot] * 3},
            "tool": {"position_std_mm": [1.0] * 3, "rotation_std_deg": [0.5] * 3},
            "water": {"temperature_std_c": 2.0},
        },
        "benchmark tolerances",
    )
    return path


def draw_world(rng: np.random.Generator, profile: CellProfile, index: int) -> str:
    """World-file text of a cell drawn within ``profile``'s declared tolerances."""
    dh = profile.model.dh.copy()
    dh[:, 1] += np.where(dh[:, 1] != 0, rng.uniform(-0.3, 0.3, 6), 0.0)  # d_mm
    dh[:, 2] += np.where(dh[:, 2] != 0, rng.uniform(-0.3, 0.3, 6), 0.0)  # a_mm
    dh[:, 3] += rng.uniform(-0.03, 0.03, 6)  # alpha_deg
    rows = ",\n".join(
        f"  {{ theta_offset_deg = {r[0]!r}, d_mm = {r[1]!r}, a_mm = {r[2]!r}, "
        f"alpha_deg = {r[3]!r} }}"
        for r in dh.tolist()
    )
    pos = profile.sample_position_mm + rng.normal(0.0, profile.sample_position_std_mm, 3)
    rot = profile.sample_rotation_deg + rng.normal(0.0, profile.sample_rotation_std_deg, 3)
    tpos = profile.tool_position_mm + rng.normal(0.0, profile.tool_position_std_mm, 3)
    trot = profile.tool_rotation_deg + np.append(
        rng.normal(0.0, profile.tool_rotation_std_deg[:2], 2), 0.0
    )
    text = f"""[robot]
dh = [
{rows}
]
joint_offsets_deg = {rng.uniform(-3.0, 3.0, 6).tolist()!r}
backlash_deg = {rng.uniform(0.0, 0.01, 6).tolist()!r}
[tool]
position_mm = {tpos.tolist()!r}
rotation_deg = {trot.tolist()!r}
[sample]
position_mm = {pos.tolist()!r}
rotation_deg = {rot.tolist()!r}
[water]
temperature_c = {profile.water_temperature_c + rng.uniform(-2.0, 2.0)!r}
drift_c_per_min = {rng.uniform(-0.05, 0.05)!r}
[pulser]
amplitude_bits = {AMPLITUDE_BITS}
delay_ns = {rng.uniform(0.0, 50.0)!r}
[noise]
tof_ns = 0.5
amplitude = 0.01
seed = {index + 1}
"""
    return text


def measure_world(profile_path: Path, world_path: Path, cache: Path) -> Path:
    """Run the whole sequence against the simulated world; pickle the measurements."""
    if cache.exists():
        return cache
    profile = load_profile(profile_path)
    plan = plan_calibration(profile)
    t0 = time.monotonic()
    run: CalibrationRun | None = None
    error: str | None = None
    try:
        with open_cell(profile, str(world_path), None, None) as cell:
            check_status(cell.rig)
            run = run_calibration(profile, plan, cell.rig)
        run.measurements[:] = [dc_replace(m, probes=None) for m in run.measurements]
    except Exception as e:
        run, error = None, f"{type(e).__name__}: {e}"
    data = {"run": run, "error": error, "seconds": time.monotonic() - t0}
    cache.write_bytes(pickle.dumps(data))
    return cache


@dataclass
class Outcome:
    z: np.ndarray  # |error| / std of the reported joints
    err: np.ndarray  # error per joint (deg)
    std: np.ndarray  # std per joint (deg, NaN = unobservable)
    written: bool
    refusal: str
    tcp_before_mm: np.ndarray
    tcp_after_mm: np.ndarray


def effective_offsets_deg(truth: WorldTruth) -> np.ndarray:
    """The offsets a calibration that reaches every posture from below can see: the world's
    offsets minus half the backlash (the link lags the encoder by b/2 after a positive move)."""
    return truth.joint_offsets_deg - 0.5 * np.asarray(truth.backlash_deg, float)


def tcp_errors_mm(
    truth: WorldTruth, profile: CellProfile, offsets_deg: np.ndarray, postures_deg: np.ndarray
) -> np.ndarray:
    """|TCP(true cell) − TCP(model with ``offsets_deg``)| (mm) at the postures."""
    true = fk_frames(truth.model, postures_deg, truth.joint_offsets_deg)[:, 6] @ truth.tool_matrix
    model = fk_frames(profile.model, postures_deg, offsets_deg)[:, 6] @ profile.tool_matrix
    return np.linalg.norm(true[:, :3, 3] - model[:, :3, 3], axis=1)


def outcome(
    sol: OffsetSolution,
    fit,
    truth: WorldTruth,
    profile: CellProfile,
    postures: np.ndarray,
    old: bool,
) -> Outcome:
    ok = np.isfinite(sol.std_deg)
    z = np.abs(sol.offsets_deg[ok] - effective_offsets_deg(truth)[ok]) / sol.std_deg[ok]
    if old:
        loose = np.any(sol.std_deg[ok] > TOLERANCE_STD_DEG)
        written, refusal = not loose, "std" if loose else ""
    else:
        verdict = judge(sol, fit)
        written = verdict.ok
        refusal = "" if written else ("misfit" if fit.verdict == "misfit" else "std")
    before = tcp_errors_mm(truth, profile, profile.joint_offsets_deg, postures)
    after = tcp_errors_mm(truth, profile, sol.offsets_deg, postures)
    err = sol.offsets_deg - effective_offsets_deg(truth)
    return Outcome(z, err, sol.std_deg, written, refusal, before, after)


def summary(name: str, outs: list[Outcome]) -> str:
    z = np.concatenate([o.z for o in outs]) if outs else np.zeros(0)
    written = [o for o in outs if o.written]
    bad = sum(1 for o in written if np.any(o.z > 4.0))
    reasons: dict[str, int] = {}
    for o in outs:
        if not o.written:
            reasons[o.refusal] = reasons.get(o.refusal, 0) + 1
    before = np.concatenate([o.tcp_before_mm for o in outs])
    after = np.concatenate([o.tcp_after_mm for o in outs])
    return (
        f"| {name} | {np.mean(z <= 3.0) * 100:.1f} % of {len(z)} (max |z| {np.max(z):.1f}) "
        f"| {len(written)} / {len(outs)} | "
        f"{', '.join(f'{k} {v}' for k, v in sorted(reasons.items())) or '—'} | {bad} | "
        f"{before.mean():.2f} / {before.max():.2f} | {after.mean():.3f} / {after.max():.3f} |"
    )


def joint_errors(name: str, outs: list[Outcome]) -> str:
    """Median |error| / median std per joint (deg) over the runs that report the joint."""
    cells = []
    for j in range(6):
        e = [o.err[j] for o in outs if np.isfinite(o.std[j])]
        s = [o.std[j] for o in outs if np.isfinite(o.std[j])]
        cells.append(f"{np.median(np.abs(e)):.4f} / {np.median(s):.4f} ({len(e)})" if e else "—")
    return f"| {name} | " + " | ".join(cells) + " |"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--worlds", type=int, default=30)
    ap.add_argument("--seed", type=int, default=2026)
    ap.add_argument(
        "--fixture",
        action="store_true",
        help="declare (and draw) a fixtured block: 0.5 mm, 0.01 deg",
    )
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument(
        "--cache",
        type=Path,
        default=None,
        help="directory for worlds and measurements (kept between runs)",
    )
    ap.add_argument(
        "--quick", action="store_true", help="--worlds 1 --jobs 1: the same code path in seconds"
    )
    args = parse_args(ap, QUICK)
    work = args.cache or Path(tempfile.mkdtemp(prefix="ucal-realistic-"))
    work.mkdir(parents=True, exist_ok=True)
    profile_path = make_profile(work, args.fixture)
    profile = load_profile(profile_path)
    rng = np.random.default_rng(args.seed)
    tag = "fixture" if args.fixture else "hand"
    worlds = []
    for i in range(args.worlds):
        w = work / f"world-{tag}-{i:03d}.toml"
        text = draw_world(rng, profile, i)
        if not w.exists():
            w.write_text(text)
        worlds.append(w)
    caches = [w.with_suffix(".pkl") for w in worlds]
    t0 = time.monotonic()
    with concurrent.futures.ProcessPoolExecutor(args.jobs) as pool:
        list(pool.map(measure_world, [profile_path] * len(worlds), worlds, caches))
    print(f"measured {len(worlds)} worlds in {time.monotonic() - t0:.0f} s ({work})")
    postures = np.random.default_rng(1).uniform(
        profile.model.joint_min_deg * 0.8, profile.model.joint_max_deg * 0.8, (200, 6)
    )
    new, old, failed = [], [], []
    for w, c in zip(worlds, caches, strict=True):
        data = pickle.loads(c.read_bytes())
        if data["run"] is None:
            failed.append(f"{w.name}: {data['error']}")
            continue
        truth = load_world(w, profile)
        run: CalibrationRun = data["run"]
        exact, _ = solve(profile, run)
        new.append(outcome(exact, exact.fit, truth, profile, postures, old=False))
        prev = solve_exact(geometry(profile), run.measurements, profile.joint_offsets_deg)
        old.append(outcome(prev, None, truth, profile, postures, old=True))
    print(f"{len(new)} runs solved, {len(failed)} failed to measure")
    for f in failed:
        print("  ", f)
    print(
        "| solver | coverage (|err| ≤ 3σ) | written | refused (why) | written outside 4σ "
        "| TCP error before, mean / max mm | after, mean / max mm |"
    )
    print("| --- | --- | --- | --- | --- | --- | --- |")
    print(summary("current (priors, sound speed, fit test)", new))
    print(summary("previous (offsets + corner)", old))
    print()
    print("| solver | " + " | ".join(f"J{j} median |err| / std (runs)" for j in range(1, 7)) + " |")
    print("| --- " * 7 + "|")
    print(joint_errors("current", new))
    print(joint_errors("previous", old))


if __name__ == "__main__":
    main()
