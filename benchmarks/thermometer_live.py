"""A logger's live wall-clock log against ``ucal sim serve`` on the host clock, end to end.

The world (``--period``, ``--amplitude``): the offsets level's cell of
``tests/system/test_thermometer_cli.py`` in a tank whose heater cycles (20 °C ± 0.25 °C every
1.5 min by default), as a ``[water] temperature_log`` in minutes of the simulator's clock. On the
host clock that clock is the host's, from the moment ``ucal sim serve`` prints its URLs; the
time scale shortens the arm's moves and the pulser's acquisitions, not the water's course. So a
row stamped at wall time W describes the water at (W − W₀)/60 min of the world's log, W₀ the wall
time at which the served cell's first line was read.

Per run: the cell is served (``--time-scale``), a logger thread appends ``time,temperature_c``
rows every ``--interval`` s from then on, each stamped with the logger's clock (``--clock-offset``
s ahead of the host's) in one of the ``--zones`` (``Z``: UTC; ``offset``: ``+01:00``; ``naive``:
no zone, the local time of a host one hour east of UTC, which the ``ucal`` process is given as
``TZ``), reading the tank ``--lag`` s earlier plus a 0.3 °C calibration offset and ``--noise``,
to ``--resolution``; each row is written in two parts ``--cut`` s apart (a reader can meet it cut
off). After ``--lead`` s, ``ucal calibrate`` runs against the served cell on the real-cell path
(``--controller``/``--pulser``, ``--thermometer`` the live file, ``--record``). The same world is
served again and calibrated without the log, and rehearsed in lock step (``--sim WORLD``) with the
probe's log in minutes and without it.

Printed per run: the exit code, wall time, J2–J5's errors in units of their std (every posture
reached from below: the truth is the offset less half the lost motion), the sound speed and its
drift against the truth (the straight line through the true sound speed at the paths' times, at
the solvers' reference time: the mean time of the face readings), and the thermometer's JSON
(span, change, drift, departure against noise, applied) with where the run met the log: the
run's first reading in the log's time, ``first_reading``, against its wall time from the record
(the reading's host clock stamp, ``time.monotonic`` on this host, on the wall clock:
``placed_off_ms``), and how late this script read the served cell's URLs after the cell's clock
started (the simulated pulser's own clock at that reading: ``served_seen_late_ms``, by which
the logged water lags the water the beam crosses).

Usage: ``python benchmarks/thermometer_live.py [--scale 0.2] [--zones Z,offset,naive]
[--interval 2] [--lag 0] [--clock-offset 0] [--json]``; ``--quick``: the lock-step rehearsal only
(with the log), the served runs named as skipped (each takes most of a minute of wall time).
"""

from __future__ import annotations

import argparse
import contextlib
import datetime as dt
import json
import os
import shutil
import tempfile
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from _quick import parse_args
from real_time import ucal

from ucal.acoustics import sound_speed_m_s
from ucal.profile import default_profile_text
from ucal.sim.serve import serving

QUICK = {"zones": "", "without": False}
OFFSETS_DEG = np.array([0.3, -0.2, 0.15, 0.4, -0.25, 0.1])
BACKLASH_DEG = 0.01
#: The probe's calibration offset (°C): the sound speed's prior keeps it, the log's shape counts.
PROBE_OFFSET_C = 0.3
#: The world's log: a row every 0.02 min over 30 min.
TANK_STEP_MIN = 0.02
TANK_SPAN_MIN = 30.0
#: A host one hour east of UTC, without summer time (POSIX TZ), for the naive stamps.
NAIVE_TZ = "CET-1"
EAST = dt.timezone(dt.timedelta(hours=1))


@dataclass(frozen=True)
class Logger:
    """How the logger reads the tank and stamps its rows (module docstring)."""

    interval_s: float = 2.0
    lag_s: float = 0.0
    clock_offset_s: float = 0.0
    noise_c: float = 0.003
    resolution_c: float = 0.01
    cut_s: float = 0.2

    def reading(self, tank: Tank, water_min: float, rng: np.random.Generator) -> float:
        """The probe's reading (°C) when the water is at ``water_min`` of the world's log."""
        value = tank.at(water_min - self.lag_s / 60.0) + PROBE_OFFSET_C
        value += self.noise_c * float(rng.standard_normal())
        return round(value / self.resolution_c) * self.resolution_c

    def stamp(self, wall_s: float, zone: str) -> str:
        """The logger's time of ``wall_s`` (host wall clock, s) in ``zone``'s style."""
        when = dt.datetime.fromtimestamp(wall_s + self.clock_offset_s, dt.UTC)
        if zone == "Z":
            return when.strftime("%Y-%m-%dT%H:%M:%SZ")
        local = when.astimezone(EAST)
        if zone == "offset":
            return local.isoformat(timespec="seconds")
        return local.replace(tzinfo=None).isoformat(sep=" ", timespec="seconds")


@dataclass(frozen=True)
class Tank:
    """The water the beam crosses: ``temperature_c`` at ``time_min`` of the simulator's clock."""

    time_min: np.ndarray
    temperature_c: np.ndarray

    def at(self, t_min: float | np.ndarray) -> Any:
        return np.interp(t_min, self.time_min, self.temperature_c)


def heated_cell(workdir: Path, period_min: float, amplitude_c: float) -> Tank:
    """Write ``cell.toml``, the tank's log ``tank.csv`` and ``world.toml`` into ``workdir``."""
    (workdir / "cell.toml").write_text(default_profile_text("tx90l"))
    t = np.arange(0.0, TANK_SPAN_MIN + TANK_STEP_MIN / 2, TANK_STEP_MIN)
    tank = Tank(t, 20.0 + amplitude_c * np.sin(2.0 * np.pi * t / period_min))
    rows = "".join(f"{a:.2f},{b:.5f}\n" for a, b in zip(t, tank.temperature_c, strict=True))
    (workdir / "tank.csv").write_text("time_min,temperature_c\n" + rows)
    (workdir / "world.toml").write_text(
        f'[robot]\nmodel = "tx90l"\njoint_offsets_deg = {OFFSETS_DEG.tolist()}\n'
        f"backlash_deg = {[BACKLASH_DEG] * 6}\n"
        '[water]\ntemperature_log = "tank.csv"\n'
        "[noise]\ntof_ns = 1.0\namplitude = 0.01\nseed = 3\n"
    )
    return tank


def probe_log(path: Path, tank: Tank, logger: Logger) -> None:
    """The probe's log in minutes of the simulated cell's clock (the lock-step rehearsal's)."""
    rng = np.random.default_rng(11)
    t = np.arange(0.0, TANK_SPAN_MIN, logger.interval_s / 60.0)
    rows = "".join(f"{m:.5f},{logger.reading(tank, m, rng):.2f}\n" for m in t)
    path.write_text("time_min,temperature_c\n" + rows)


def log_live(
    path: Path, tank: Tank, logger: Logger, zone: str, t0_wall: float, stop: threading.Event
) -> None:
    """Append the logger's rows to ``path`` every ``interval_s`` from ``t0_wall`` until ``stop``:
    the water at (W − ``t0_wall``)/60 min, each row written in two parts."""
    rng = np.random.default_rng(7)
    with path.open("a", encoding="utf-8") as f:
        f.write("time,temperature_c\n")
        f.flush()
        due = t0_wall
        while not stop.is_set():
            if time.time() < due:
                stop.wait(min(due - time.time(), 0.1))
                continue
            reading = logger.reading(tank, (due - t0_wall) / 60.0, rng)
            row = f"{logger.stamp(due, zone)},{reading:.2f}\n"
            half = len(row) - 4  # cut in the reading: 21.4 of 21.40, or 2 of 21.40
            f.write(row[:half])
            f.flush()
            stop.wait(logger.cut_s)
            f.write(row[half:])
            f.flush()
            due += logger.interval_s


@dataclass
class Run:
    """One calibrate run: its result and the truth to hold it against."""

    name: str
    code: int
    wall_s: float
    result: dict[str, Any]
    stderr: str
    #: The host's wall clock less its monotonic clock (s), when the run was served.
    wall_minus_monotonic_s: float = 0.0
    #: The water's time (s of the world's log) at the run's first reading, and the readings'
    #: times on the run's clock (min) with the faces' mean (the solvers' reference time).
    first_water_s: float = float("nan")
    first_host_s: float = float("nan")
    #: The simulated pulser's own clock at the first reading (s since the served cell started).
    first_device_s: float = float("nan")
    path_times_min: list[float] = field(default_factory=list)
    reference_min: float = float("nan")


@contextlib.contextmanager
def local_zone(zone: str | None) -> Iterator[None]:
    """The ``ucal`` processes started within on a host in ``zone`` (POSIX ``TZ``; None: as is)."""
    before = os.environ.get("TZ")
    if zone is not None:
        os.environ["TZ"] = zone
    try:
        yield
    finally:
        if before is None:
            os.environ.pop("TZ", None)
        else:
            os.environ["TZ"] = before


def from_record(run: Run, record: Path, water_t0_s: float) -> None:
    """The run's first reading (host clock) and its paths' times from its ``record``; the
    water's time of the first reading is its host clock less ``water_t0_s``."""
    faces: list[float] = []
    for line in record.read_text().splitlines():
        obj = json.loads(line)
        if obj.get("kind") == "call" and obj.get("call") == "pulser.read_gate":
            if np.isnan(run.first_host_s):
                run.first_host_s = float(obj["result"]["v"]["host_time_s"])
                run.first_device_s = float(obj["result"]["v"]["device_time_s"])
        elif obj.get("kind") == "measurement" and isinstance(obj.get("value"), dict):
            t = obj["value"].get("v", {}).get("time_min")
            if t is not None:
                run.path_times_min.append(float(t))
                if obj.get("of") == "measurements":
                    faces.append(float(t))
    run.first_water_s = run.first_host_s - water_t0_s
    run.reference_min = float(np.mean(faces)) if faces else float("nan")


def served_run(
    workdir: Path,
    name: str,
    scale: float,
    tank: Tank,
    logger: Logger | None,
    zone: str,
    lead_s: float,
) -> Run:
    """``calibrate`` against ``ucal sim serve --world world.toml --time-scale SCALE`` on a copy
    of the fresh profile, with the live log in ``zone`` (none when ``logger`` is None)."""
    run_dir = workdir / name
    run_dir.mkdir()
    for f in ("cell.toml", "world.toml", "tank.csv"):
        shutil.copy(workdir / f, run_dir / f)
    stop = threading.Event()
    live = run_dir / "live.csv"
    args = ["--world", "world.toml", "--time-scale", f"{scale:g}"]
    with serving("--profile", "cell.toml", *args, cwd=run_dir) as urls:
        t0_mono, t0_wall = time.monotonic(), time.time()
        thread = None
        extra: list[str] = []
        if logger is not None:
            thread = threading.Thread(
                target=log_live, args=(live, tank, logger, zone, t0_wall, stop), daemon=True
            )
            thread.start()
            extra = ["--thermometer", live.name]
        time.sleep(lead_s)
        cell = ["--controller", urls["controller"], "--pulser", urls["pulser"]]
        with local_zone(NAIVE_TZ if zone == "naive" else None):
            code, result, wall, err = ucal(
                run_dir, "calibrate", "cell.toml", *cell, *extra, "--record", "run.jsonl", "--yes"
            )
        stop.set()
        if thread is not None:
            thread.join()
    run = Run(name, code, wall, result, err, t0_wall - t0_mono)
    from_record(run, run_dir / "run.jsonl", t0_mono)
    return run


def lockstep_run(workdir: Path, name: str, with_log: bool) -> Run:
    """The rehearsal: ``calibrate --sim world.toml --dry-run`` (with the probe's minutes log)."""
    extra = ["--thermometer", "probe.csv"] if with_log else []
    record = workdir / f"{name}.jsonl"
    args = ["calibrate", "cell.toml", "--sim", "world.toml", *extra, "--record", record.name]
    code, result, wall, err = ucal(workdir, *args, "--dry-run", "--yes")
    run = Run(name, code, wall, result, err)
    from_record(run, record, 0.0)  # the simulated clock starts at 0 with the cell
    return run


def truth_line(run: Run, tank: Tank) -> tuple[float, float]:
    """The true sound speed (m/s) at the run's reference time and its drift (m/s per min): the
    straight line through the tank's sound speed at the paths' times."""
    times = np.asarray(run.path_times_min, float)
    water_min = run.first_water_s / 60.0 + times
    c = np.asarray(sound_speed_m_s(tank.at(water_min)), float)
    slope, at0 = np.polyfit(times - run.reference_min, c, 1)
    return float(at0), float(slope)


def row(run: Run, tank: Tank) -> dict[str, Any]:
    """What the table prints of ``run``."""
    r = run.result
    out: dict[str, Any] = {"run": run.name, "exit": run.code, "wall_s": round(run.wall_s, 1)}
    if "joint_offsets_deg" not in r:
        out["error"] = r.get("error") or run.stderr
        return out
    got = np.asarray(r["joint_offsets_deg"], float)
    std = np.asarray([np.nan if s is None else s for s in r["std_deg"]], float)
    truth = OFFSETS_DEG - 0.5 * BACKLASH_DEG
    out["z_j2_j5"] = [round(float(v), 1) for v in (np.abs(got - truth) / std)[1:5]]
    c_true, drift_true = truth_line(run, tank)
    out["sound_speed_z"] = round(abs(r["sound_speed_m_s"] - c_true) / r["sound_speed_std_m_s"], 1)
    drift, drift_std = r["sound_speed_drift_m_s_per_min"], r["sound_speed_drift_m_s_per_min_std"]
    out["drift_m_s_per_min"] = [round(drift, 3), round(drift_true, 3)]
    out["drift_z"] = round(abs(drift - drift_true) / drift_std, 1)
    out["verdict"] = r["fit"]["verdict"]
    water = r.get("thermometer")
    if water is not None:
        out["thermometer"] = {
            k: water[k]
            for k in ("span_min", "change_c", "drift_c_per_min", "departure_c", "noise_c")
        } | {"applied": water["applied"]}
        if "first_reading" in water:
            met = dt.datetime.fromisoformat(water["first_reading"]).timestamp()
            first_wall = run.first_host_s + run.wall_minus_monotonic_s
            out["placed_off_ms"] = round((met - first_wall) * 1000.0, 1)
            # how late the URLs were read after the served cell's clock started (its pulser's)
            out["served_seen_late_ms"] = round((run.first_device_s - run.first_water_s) * 1e3)
        elif "first_reading_min" in water:
            off_s = water["first_reading_min"] * 60.0 - run.first_water_s
            out["placed_off_ms"] = round(off_s * 1000.0, 1)
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scale", type=float, default=0.2, help="sim serve's --time-scale")
    ap.add_argument("--zones", default="Z,offset,naive", help="the logged runs' time styles")
    ap.add_argument(
        "--without",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="also the served run without the log",
    )
    ap.add_argument("--period", type=float, default=1.5, help="the heater's period (min)")
    ap.add_argument("--amplitude", type=float, default=0.25, help="its amplitude (°C)")
    ap.add_argument("--interval", type=float, default=2.0, help="the logger's period (s)")
    ap.add_argument("--lag", type=float, default=0.0, help="the probe behind the water (s)")
    ap.add_argument("--clock-offset", type=float, default=0.0, help="the logger's clock (s)")
    ap.add_argument("--resolution", type=float, default=0.01, help="the logger's (°C)")
    ap.add_argument("--noise", type=float, default=0.003, help="its reading noise (°C)")
    ap.add_argument("--cut", type=float, default=0.2, help="a row's two parts apart (s)")
    ap.add_argument("--lead", type=float, default=20.0, help="the log before the run (s)")
    ap.add_argument("--json", action="store_true", help="one JSON object per run")
    ap.add_argument("--quick", action="store_true", help="the lock-step rehearsal only")
    args = parse_args(ap, QUICK, argv)
    logger = Logger(
        args.interval, args.lag, args.clock_offset, args.noise, args.resolution, args.cut
    )
    work = Path(tempfile.mkdtemp(prefix="ucal-thermometer-live-"))
    tank = heated_cell(work, args.period, args.amplitude)
    probe_log(work / "probe.csv", tank, logger)
    runs = [lockstep_run(work, "--sim, log", True)]
    if not args.quick:
        runs.append(lockstep_run(work, "--sim, no log", False))
    zones = [z for z in args.zones.split(",") if z]
    for zone in zones:
        runs.append(
            served_run(work, f"served, log {zone}", args.scale, tank, logger, zone, args.lead)
        )
    if args.without and zones:
        runs.append(served_run(work, "served, no log", args.scale, tank, None, "Z", args.lead))
    if not zones:
        print("served runs skipped (--zones empty: each takes most of a minute of wall time)")
    for run in runs:
        shown = row(run, tank)
        print(json.dumps(shown) if args.json else "  ".join(f"{k}={v}" for k, v in shown.items()))
    return 0 if all(run.code in (0, 1) for run in runs) else 1


if __name__ == "__main__":
    raise SystemExit(main())
