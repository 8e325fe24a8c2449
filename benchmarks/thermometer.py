"""The tank's thermometer log as a measurement: the solvers with each water path moved to the
middle of the run by the logged change (``ucal.thermometer``), beside the same solvers without
it, on the same measurements of ``drift.py``'s random cells.

Cases (``--case``): ``offsets`` (``calibrate``'s offsets level on ``drift.py``'s offsets worlds,
the tank drifting within ±0.3 °C/min) and ``full`` (``calibrate --level full`` on its full-level
worlds with a step, ±0.1 °C/min), each world measured once over loopback, its tank as
``--tank`` draws it (``drift.py``'s ``linear``, ``exponential`` or ``cycling``; the default
``cycling``: a heater that turns the drift during the run, what a fitted straight line misses).

The thermometer is not the tank: its log is what a logging probe elsewhere in the tank reads,
not the water the beam crosses. Per world: a reading every 3 s, the tank's temperature
``THERMOMETER_LAG_MIN`` earlier (the probe's time constant and the water between, uniform),
plus a calibration offset within ±0.5 °C (the sound speed's prior keeps it), a reading noise of
``THERMOMETER_NOISE_C`` and the logger's 0.01 °C resolution. The profiles declare
``[water] thermometer_std_c`` = 0.02 °C (the default).

Printed per case and solver (``drift.py``'s columns): the share of the reported quantities
within 3 std of the truth (offsets, sound speed at the middle of the run and its drift, lost
motion where measured; the full level's DH parameters) and the largest |z|, runs written and
written beyond 4 std, the TCP error over the scanning region; then each world with its largest
|z| both ways and the drift's std both ways.

Usage: ``python benchmarks/thermometer.py --worlds 8 [--case offsets|full|both] [--tank
linear|exponential|cycling] [--jobs 2] [--postures N] [--resolution C] [--noise C]`` (the
logger's resolution and reading noise, °C); ``--quick``: one world of each case
(the full level on 8 postures), the same code path in seconds.
"""

from __future__ import annotations

import argparse
import concurrent.futures
import tempfile
from pathlib import Path

import drift
import numpy as np
from _quick import parse_args

from drivers.errors import DriverError
from ucal.cell import TemperatureLog
from ucal.devices.session import check_status, open_cell
from ucal.errors import UcalError
from ucal.measure.postures import FullRun, run_full
from ucal.measure.sequence import CalibrationRun, run_calibration
from ucal.model.postures import MAX_POSTURES, FullPlan, plan_full
from ucal.model.targets import CalibrationPlan, plan_calibration
from ucal.profile import load_profile, write_profile
from ucal.thermometer import on_run, reading_span_min
from ucal.world import load_world

QUICK = {"worlds": 1, "jobs": 1, "postures": 8, "case": "both"}
#: The probe's lag behind the water the beam crosses (min, uniform), its reading noise (°C, one
#: sigma), the logger's resolution (°C) and how far its calibration may be off (°C, uniform).
THERMOMETER_LAG_MIN = (0.05, 0.15)
THERMOMETER_NOISE_C = 0.003
RESOLUTION_C = 0.01
THERMOMETER_OFFSET_C = 0.5
#: What the profiles declare the thermometer follows the water to (°C, one sigma).
THERMOMETER_STD_C = 0.02


def thermometer_log(
    world_path: Path,
    profile_path: Path,
    seed: int,
    resolution_c: float = RESOLUTION_C,
    noise_c: float = THERMOMETER_NOISE_C,
) -> TemperatureLog:
    """The probe's log of the world's tank (module docstring), on the simulated cell's clock:
    ``resolution_c`` the logger's, ``noise_c`` its reading noise (one sigma)."""
    world = load_world(world_path, load_profile(profile_path))
    rng = np.random.default_rng([seed, 2])
    lag = rng.uniform(*THERMOMETER_LAG_MIN)
    offset = rng.uniform(-THERMOMETER_OFFSET_C, THERMOMETER_OFFSET_C)
    t = np.arange(0.0, drift.LOG_SPAN_MIN + 0.5 * drift.LOG_STEP_MIN, drift.LOG_STEP_MIN)
    truth = np.array([drift.tank_at(world, max(ti - lag, 0.0))[0] for ti in t])
    read = truth + offset + noise_c * rng.standard_normal(len(t))
    return TemperatureLog(world_path, t, np.round(read / resolution_c) * resolution_c)


def run_world(
    case: str,
    profile_path: Path,
    world_path: Path,
    postures: int,
    seed: int,
    logger: tuple[float, float] = (RESOLUTION_C, THERMOMETER_NOISE_C),
) -> list[drift.Outcome] | str:
    """Measure one world once; solve it with the thermometer's log and without."""
    profile = load_profile(profile_path)
    world = load_world(world_path, profile)
    try:
        plan = (
            plan_calibration(profile)
            if case == "offsets"
            else plan_full(profile, max_postures=postures)
        )
        with open_cell(profile, str(world_path), None, None) as cell:
            check_status(cell.rig)
            data: CalibrationRun | FullRun = (
                run_calibration(profile, plan, cell.rig)
                if isinstance(plan, CalibrationPlan)
                else run_full(profile, plan, cell.rig)
            )
            assert cell.rig.first_read_s is not None
            first_min = (cell.rig.first_read_s - cell.started_s) / 60.0
    except (UcalError, DriverError) as err:
        return f"{world_path.name}: stopped: {err}"
    log = thermometer_log(world_path, profile_path, seed, *logger)
    water = on_run(log, profile.thermometer_std_c, first_min, reading_span_min(data))
    assert water is not None, "the log covers every run"
    logged, logged_profile = water.corrected(data), water.profile(profile, data)
    outs = []
    for run, cell_profile in ((logged, logged_profile), (data, profile)):
        if isinstance(run, FullRun) and isinstance(plan, FullPlan):
            out = drift.solve_full_level(
                cell_profile, world, run.measurements, run.steps, plan.structure, ()
            )
        else:
            out = drift.solve_offsets(cell_profile, world, run.measurements, ())
        out.run = (
            f"{world_path.stem}: {drift.tank_words(world)}, readings over "
            f"{reading_span_min(data):.1f} min, logged change "
            f"{water.summary(data)['change_c']:+.3f} °C, turning "
            f"{water.departure_c(data):.4f} °C against its noise "
            f"{water.course_noise_c(data):.4f} ("
            + ("applied" if water.turns(data) else "not applied")
            + ")"
        )
        outs.append(out)
    return outs


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--worlds", type=int, default=8)
    ap.add_argument("--case", choices=("offsets", "full", "both"), default="both")
    ap.add_argument("--tank", choices=drift.TANKS, default="cycling")
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--postures", type=int, default=MAX_POSTURES)
    ap.add_argument(
        "--resolution", type=float, default=RESOLUTION_C, help="the logger's resolution (°C)"
    )
    ap.add_argument(
        "--noise", type=float, default=THERMOMETER_NOISE_C, help="its reading noise (°C)"
    )
    ap.add_argument("--quick", action="store_true", help="one world per case, 8 postures")
    args = parse_args(ap, QUICK, argv)
    work = Path(tempfile.mkdtemp(prefix="ucal-thermometer-"))
    cases = ("offsets", "full") if args.case == "both" else (args.case,)
    print(
        "| case | solver | coverage (|err| ≤ 3σ) | drift within 3σ | lost motion: rms error, "
        "within 3σ | written | refused (why) | written beyond 4σ | TCP error mean / max mm |"
    )
    print("| --- " * 9 + "|")
    stopped: list[str] = []
    for case in cases:
        declared = drift.DECLARED_DRIFT[case]
        profile_path = drift.make_profile(work, case, declared)
        write_profile(profile_path, {"water": {"thermometer_std_c": THERMOMETER_STD_C}}, "bench")
        rng = np.random.default_rng(args.seed)
        tank = drift.Tank(args.tank, np.random.default_rng([args.seed, 1]))
        profile = load_profile(profile_path)
        worlds = []
        for i in range(args.worlds):
            path = work / f"{case}-{i:03d}.toml"
            path.write_text(drift.draw_world(rng, profile, case, i, tank, path.with_suffix(".csv")))
            worlds.append(path)
        n = len(worlds)
        with concurrent.futures.ProcessPoolExecutor(args.jobs) as pool:
            rows = list(
                pool.map(
                    run_world,
                    [case] * n,
                    [profile_path] * n,
                    worlds,
                    [args.postures] * n,
                    [args.seed * 1000 + i for i in range(n)],
                    [(args.resolution, args.noise)] * n,
                )
            )
        solved = [r for r in rows if not isinstance(r, str)]
        name = f"{case}, {declared:g} °C/min, {args.tank} tank"
        print(drift.summary(f"{name} | thermometer log", [r[0] for r in solved]))
        print(drift.summary(f"{name} | without (drift fitted)", [r[1] for r in solved]))
        for logged, fitted in solved:
            print(
                f"  {logged.run}: max |z| {np.max(logged.z):.1f} with the log "
                f"({logged.refusal or 'written'}), {np.max(fitted.z):.1f} without "
                f"({fitted.refusal or 'written'}); TCP max {logged.tcp_mm.max():.3f} / "
                f"{fitted.tcp_mm.max():.3f} mm"
            )
        stopped.extend(r for r in rows if isinstance(r, str))
    print(f"runs stopped by the procedure: {len(stopped)}")
    for line in stopped:
        print("  ", line)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
