"""A drifting tank and an arm with lost motion: the solvers with both as unknowns, against the
previous ones (drift and lost motion held at 0), on the same measurements of random cells.

Three cases, each over ``--worlds`` simulated cells measured once against the simulated cell
over loopback, the worlds of the benchmark each extends with the tank drifting and lost motion
uniform in 0–0.02° per joint, every profile declaring the default drift tolerance (0.05
°C/min, ``[water] drift_std_c_per_min``; ``--declared-drift`` to change it):

* ``offsets``: ``calibrate`` (the offsets level) on ``realistic.py --fixture``'s worlds (block
  doweled and levelled, 0.5 mm / 0.01°; the DH table within its tolerance; offsets ±3°; 8-bit
  amplitude, an unknown TOF delay), the tool measured (0.05 mm, 0.02°) and drawn within it;
  the tank drifting uniform in ±0.3 °C/min (the first face's water path read again at the end
  is what lets the data see it);
* ``lost-motion``: the same with ``calibrate --lost-motion`` (the calibration pose's faces
  measured again from above, ``ucal.calibration.sequence.with_lost_motion``);
* ``full``: ``calibrate --level full`` on ``full_calibration.py --step``'s worlds (the DH
  tolerance declared 0.3 mm / 0.03° and drawn within twice it, lengths ±0.5 mm, twists and
  Hayati's β₂ ±0.05°; offsets ±1°; a hand-placed block; the water within ±2 °C; a step of
  50 ± 0.002 mm); the tank drifting uniform in ±0.1 °C/min; a few postures reached from above
  (``FullPlan.above``).

Every other posture is reached from below (``ucal.measure.approach.FinalApproachRig``): the
offsets found are the world's less half its lost motion. Printed per case and solver:

* coverage: share of the reported quantities within 3 std of the truth (joint offsets with a
  std; the sound speed at the middle of the run and its drift where fitted; each joint's lost
  motion where measured; at the full level the identified and prior-dominated DH parameters),
  and the largest |z|;
* the lost motion per joint measured in any run: its rms error (deg) and how many runs have it
  within 3 std;
* runs written (``judge``: fit ok and every observable offset within tolerance), why the
  others are refused (a misfit: the effect its message names), and written runs with a
  quantity beyond 4 std (must be none);
* TCP error over the scanning region (calibration pose ± 20° on J1-J3, ± 90/30/90° on the
  wrist; 200 postures) after the best rigid alignment (the base frame is a gauge), mean of
  the runs' means / largest maximum (mm).

Usage: ``python benchmarks/drift.py --worlds 12 [--case offsets|lost-motion|full|both|all]
[--jobs 2] [--declared-drift C]`` (C: the drift tolerance every case declares, °C/min);
``--quick``: one world of the offsets and the full cases (the full level on 8 postures), the
same code path in seconds.
"""

from __future__ import annotations

import argparse
import concurrent.futures
import re
import tempfile
from dataclasses import dataclass
from pathlib import Path

# the worlds and profiles of the two benchmarks this one extends (scripts in this folder)
import full_calibration
import numpy as np
import realistic

from drivers.errors import DriverError
from ucal.acoustics import sound_speed_m_s
from ucal.calibration.exact import solve_exact_with_priors
from ucal.calibration.fit import (
    BACKLASH,
    DRIFT,
    CellFit,
    FitQuality,
    RunEffects,
    prior_from_profile,
)
from ucal.calibration.full import aligned_errors_mm, scanning_postures, solve_full, twists_deg
from ucal.calibration.full_plan import MAX_POSTURES, plan_full
from ucal.calibration.full_run import run_full
from ucal.calibration.procedure import judge
from ucal.calibration.sequence import (
    calibration_pose,
    plan_calibration,
    run_calibration,
    with_lost_motion,
)
from ucal.cell import CellProfile, WorldTruth
from ucal.errors import UcalError
from ucal.kinematics.dh import fk
from ucal.profile import load_profile, write_profile
from ucal.session import check_status, open_cell
from ucal.world import load_world

#: ``--quick``: the defaults it changes (an option given on the command line still wins).
QUICK = {"worlds": 1, "jobs": 1, "postures": 8, "case": "both"}
#: The previous solvers: the drift and the lost motion held at 0.
HELD = DRIFT + BACKLASH
#: The cases of the offsets level: as planned, and with the calibration pose's faces measured
#: again from above (``ucal.calibration.sequence.with_lost_motion``).
OFFSETS_CASES = ("offsets", "lost-motion")
#: Per case: the tank's drift the worlds are drawn with (±°C/min) and the one its profile
#: declares (°C/min, one sigma: the default).
DRIFT_C_PER_MIN = {"offsets": 0.3, "lost-motion": 0.3, "full": 0.1}
DECLARED_DRIFT = {"offsets": 0.05, "lost-motion": 0.05, "full": 0.05}
#: Largest lost motion drawn (deg, uniform from 0 per joint).
BACKLASH_DEG = 0.02


def make_profile(directory: Path, case: str, drift_c_per_min: float) -> Path:
    """The profile of ``case`` (module docstring), declaring the tank's drift tolerance:
    ``realistic.py``'s with a fixture and a measured tool, ``full_calibration.py``'s with the
    step."""
    directory = directory / case
    directory.mkdir()
    updates: dict = {"water": {"drift_std_c_per_min": drift_c_per_min}}
    if case in OFFSETS_CASES:
        path = realistic.make_profile(directory, fixture=True)
        updates["tool"] = {"position_std_mm": [0.05] * 3, "rotation_std_deg": [0.02] * 3}
    else:
        path = full_calibration.make_profile(directory, 2.0, step=True)
    write_profile(path, updates, "benchmark")
    return path


def draw_world(rng: np.random.Generator, profile: CellProfile, case: str, index: int) -> str:
    """World-file text of a cell of ``case``: the other benchmark's world (module docstring)
    with the tank drifting and the lost motion of this one."""
    if case in OFFSETS_CASES:
        text = realistic.draw_world(rng, profile, index)
    else:
        text = full_calibration.draw_world(rng, profile, index)
    drift = rng.uniform(-DRIFT_C_PER_MIN[case], DRIFT_C_PER_MIN[case])
    backlash = rng.uniform(0.0, BACKLASH_DEG, 6).tolist()
    text = re.sub(r"(?m)^drift_c_per_min = .*\n", "", text)
    text = re.sub(r"(?m)^backlash_deg = .*$", f"backlash_deg = {backlash!r}", text)
    return text.replace("[water]\n", f"[water]\ndrift_c_per_min = {drift!r}\n", 1)


@dataclass
class Outcome:
    """One solver's figures on one world."""

    z: np.ndarray  # |error| / std of every reported quantity
    written: bool
    refusal: str  # "" when written
    tcp_mm: np.ndarray  # TCP errors over the scanning region (mm)
    drift_z: float  # the drift's |error| / std (NaN where held)
    #: each joint's lost motion: estimated less true (deg) and |error| / std, NaN where not
    #: measured (read from one side, or held)
    backlash_err_deg: np.ndarray
    backlash_z: np.ndarray


def sound_z(cell: CellFit, world: WorldTruth) -> list[float]:
    """|error| / std of the sound speed at the fit's reference time and of its drift."""
    rate = world.water_drift_c_per_min
    t_mid = world.water_temperature_c + rate * cell.time_ref_min
    effects = RunEffects.of(cell)
    z = [
        abs(cell.value("sound_speed_m_s") - sound_speed_m_s(t_mid)) / cell.sigma("sound_speed_m_s")
    ]
    if cell.table.free[cell.table.index(DRIFT[0])]:
        slope = (sound_speed_m_s(t_mid + 0.01) - sound_speed_m_s(t_mid - 0.01)) / 0.02
        z.append(abs(effects.drift_m_s_per_min - slope * rate) / effects.drift_std_m_s_per_min)
    return z


def backlash_z(cell: CellFit, world: WorldTruth) -> tuple[np.ndarray, np.ndarray]:
    """Each joint's lost motion as fitted less the world's (deg), and |that| / its std; NaN
    where the fit did not measure it."""
    effects = RunEffects.of(cell)
    err = effects.backlash_deg - np.asarray(world.backlash_deg, float)
    return err, np.abs(err) / effects.backlash_std_deg


def true_model(world: WorldTruth):
    return world.model.with_dh(world.model.dh, world.dh_beta_deg)


def solve_offsets(profile: CellProfile, world: WorldTruth, meas: list, held: tuple) -> Outcome:
    sol = solve_exact_with_priors(prior_from_profile(profile), meas, fixed=held)
    assert sol.cell_fit is not None and sol.fit is not None
    truth = world.joint_offsets_deg - 0.5 * world.backlash_deg  # reached from below
    ok = np.isfinite(sol.std_deg)
    z = list(np.abs(sol.offsets_deg[ok] - truth[ok]) / sol.std_deg[ok])
    z += sound_z(sol.cell_fit, world)
    verdict = judge(sol, sol.fit)
    qs = scanning_postures(calibration_pose(profile), 200, 1, profile.model)
    true_tcp = fk(true_model(world), qs, world.tool_matrix, truth)[:, :3, 3]
    tcp = fk(profile.model, qs, profile.tool_matrix, sol.offsets_deg)[:, :3, 3]
    lost = backlash_z(sol.cell_fit, world)
    return outcome(z, verdict, sol.fit, aligned_errors_mm(tcp, true_tcp), held, lost)


#: What a misfit's message names, by the words it uses (the first that appears).
CAUSES = (("a drift of the", "drift"), ("lost motion of", "lost motion"), ("DH table", "DH"))


def outcome(
    z: list[float],
    verdict,
    fit: FitQuality,
    tcp: np.ndarray,
    held: tuple,
    lost: tuple[np.ndarray, np.ndarray],
) -> Outcome:
    """One solver's figures; ``lost``: ``backlash_z``'s (its z joins the coverage)."""
    refusal = ""
    if not verdict.ok:
        named = next((short for words, short in CAUSES if words in fit.cause), "other")
        refusal = f"misfit naming {named}" if fit.verdict == "misfit" else "std"
    drift_z = float("nan") if held else z[-1]
    measured = np.isfinite(lost[1])
    z_all = np.concatenate([z, lost[1][measured]])
    return Outcome(z_all, verdict.ok, refusal, tcp, drift_z, lost[0], lost[1])


def solve_full_level(
    profile: CellProfile, world: WorldTruth, meas: list, steps: list, structure, held: tuple
) -> Outcome:
    sol = solve_full(
        prior_from_profile(profile), meas, fixed=held, structure=structure, steps=steps
    )
    model = true_model(world)
    truth = world.joint_offsets_deg - 0.5 * world.backlash_deg
    ok = np.isfinite(sol.std_deg)
    z = list(np.abs(sol.offsets_deg[ok] - truth[ok]) / sol.std_deg[ok])
    true_p = {
        f"dh{i + 1}_{k}": model.dh[i, c + 1]
        for i in range(6)
        for c, k in enumerate(("d_mm", "a_mm", "alpha_deg"))
    }
    true_p["dh2_beta_deg"] = twists_deg(model)[1]
    z += [abs(p.value - true_p[n]) / p.std for n, p in sol.parameters.items() if p.std]
    z += sound_z(sol.cell, world)
    qs = scanning_postures(calibration_pose(profile), 200, 1, profile.model)
    tool = profile.tool_matrix
    tcp = aligned_errors_mm(
        fk(sol.model, qs, tool, sol.offsets_deg)[:, :3, 3], fk(model, qs, tool, truth)[:, :3, 3]
    )
    lost = backlash_z(sol.cell, world)
    return outcome(z, judge(sol, sol.cell.quality), sol.cell.quality, tcp, held, lost)


def run_world(
    case: str, profile_path: Path, world_path: Path, postures: int
) -> list[Outcome] | str:
    """Measure one world and solve it with the current and the previous solver; a run the
    procedure stops (a posture refused for safety, an echo not found) is its message."""
    profile = load_profile(profile_path)
    world = load_world(world_path, profile)
    try:
        with open_cell(profile, str(world_path), None, None) as cell:
            check_status(cell.rig)
            if case in OFFSETS_CASES:
                offsets_plan = plan_calibration(profile)
                if case == "lost-motion":
                    offsets_plan = with_lost_motion(offsets_plan)
                run = run_calibration(profile, offsets_plan, cell.rig)
            else:
                plan = plan_full(profile, max_postures=postures)
                full_run = run_full(profile, plan, cell.rig)
    except (UcalError, DriverError) as err:  # as a row: a driver's error does not pickle
        return f"{world_path.name}: stopped: {err}"
    if case in OFFSETS_CASES:
        return [solve_offsets(profile, world, run.measurements, h) for h in ((), HELD)]
    return [
        solve_full_level(
            profile, world, full_run.measurements, full_run.steps, plan.structure, held
        )
        for held in ((), HELD)
    ]


def summary(name: str, outs: list[Outcome]) -> str:
    if not outs:
        return f"| {name} | no run solved |"
    z = np.concatenate([o.z for o in outs])
    written = [o for o in outs if o.written]
    beyond = sum(1 for o in written if np.any(o.z > 4.0))
    refused: dict[str, int] = {}
    for o in outs:
        if not o.written:
            refused[o.refusal] = refused.get(o.refusal, 0) + 1
    drift = np.array([o.drift_z for o in outs])
    drift_cov = (
        f"{np.mean(drift <= 3.0) * 100:.0f} %" if np.all(np.isfinite(drift)) else "not fitted"
    )
    return (
        f"| {name} | {np.mean(z <= 3.0) * 100:.1f} % of {len(z)} (max |z| {np.max(z):.1f}) "
        f"| {drift_cov} | {lost_motion(outs)} | {len(written)} / {len(outs)} | "
        f"{', '.join(f'{k} {v}' for k, v in sorted(refused.items())) or '—'} | {beyond} | "
        f"{np.mean([o.tcp_mm.mean() for o in outs]):.3f} / "
        f"{np.max([o.tcp_mm.max() for o in outs]):.3f} |"
    )


def lost_motion(outs: list[Outcome]) -> str:
    """The lost motion column: per joint measured in any run, the rms error (deg) and how
    many of its estimates lie within 3 std; "not measured" where no run measured one."""
    err = np.array([o.backlash_err_deg for o in outs])
    z = np.array([o.backlash_z for o in outs])
    cells = []
    for j in range(6):
        ok = np.isfinite(z[:, j])
        if ok.any():
            rms = float(np.sqrt(np.mean(err[ok, j] ** 2)))
            cells.append(f"J{j + 1} {rms:.1e}° {np.sum(z[ok, j] <= 3.0)}/{ok.sum()}")
    return ", ".join(cells) or "not measured"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--worlds", type=int, default=12)
    ap.add_argument(
        "--case", choices=("offsets", "lost-motion", "full", "both", "all"), default="all"
    )
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument(
        "--declared-drift",
        type=float,
        help="the drift tolerance the profiles declare (°C/min; default per case: "
        + ", ".join(f"{k} {v:g}" for k, v in DECLARED_DRIFT.items())
        + ")",
    )
    ap.add_argument(
        "--postures", type=int, default=MAX_POSTURES, help="at most N postures at the full level"
    )
    ap.add_argument(
        "--quick",
        action="store_true",
        help="--worlds 1 --jobs 1 --postures 8 --case both: the same code path in seconds",
    )
    args = ap.parse_args(argv)
    if args.quick:
        ap.set_defaults(**QUICK)
        args = ap.parse_args(argv)
    work = Path(tempfile.mkdtemp(prefix="ucal-drift-"))
    cases = {"both": ("offsets", "full"), "all": ("offsets", "lost-motion", "full")}.get(
        args.case, (args.case,)
    )
    stopped: list[str] = []
    print(
        "| case | solver | coverage (|err| ≤ 3σ) | drift within 3σ | lost motion: rms error, "
        "within 3σ | written | refused (why) | written beyond 4σ | TCP error mean / max mm |"
    )
    print("| --- " * 9 + "|")
    for case in cases:
        declared = args.declared_drift or DECLARED_DRIFT[case]
        profile_path = make_profile(work, case, declared)
        profile = load_profile(profile_path)
        rng = np.random.default_rng(args.seed)
        worlds = []
        for i in range(args.worlds):
            path = work / f"{case}-{i:03d}.toml"
            path.write_text(draw_world(rng, profile, case, i))
            worlds.append(path)
        with concurrent.futures.ProcessPoolExecutor(args.jobs) as pool:
            rows = list(
                pool.map(
                    run_world,
                    [case] * len(worlds),
                    [profile_path] * len(worlds),
                    worlds,
                    [args.postures] * len(worlds),
                )
            )
        solved = [r for r in rows if not isinstance(r, str)]
        print(summary(f"{case}, {declared:g} °C/min | current", [r[0] for r in solved]))
        print(
            summary(f"{case}, {declared:g} °C/min | previous (held at 0)", [r[1] for r in solved])
        )
        stopped.extend(r for r in rows if isinstance(r, str))
    print(f"runs stopped by the procedure: {len(stopped)}")
    for line in stopped:
        print("  ", line)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
