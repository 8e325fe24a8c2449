"""A drifting tank and an arm with lost motion: the solvers with both as unknowns, against the
previous ones (drift and lost motion held at 0), on the same measurements of random cells.

Four cases, each over ``--worlds`` simulated cells measured once against the simulated cell
over loopback, the worlds of the benchmark each extends with the tank drifting and lost motion
uniform in 0–0.02° per joint, every profile declaring the default drift tolerance (0.05
°C/min, ``[water] drift_std_c_per_min``; ``--declared-drift`` to change it):

* ``offsets``: ``calibrate`` (the offsets level) on ``realistic.py --fixture``'s worlds (block
  doweled and levelled, 0.5 mm / 0.01°; the DH table within its tolerance; offsets ±3°; 8-bit
  amplitude, an unknown TOF delay), the tool measured (0.05 mm, 0.02°) and drawn within it;
  the tank drifting uniform in ±0.3 °C/min (the first face's water path read again at the end
  is what lets the data see it);
* ``lost-motion``: the same with ``calibrate --lost-motion`` (the calibration pose's faces
  measured again from above, ``ucal.measure.sequence.with_lost_motion``);
* ``full``: ``calibrate --level full`` on ``full_calibration.py --step``'s worlds (the DH
  tolerance declared 0.3 mm / 0.03° and drawn within twice it, lengths ±0.5 mm, twists and
  Hayati's β₂ ±0.05°; offsets ±1°; a hand-placed block; the water within ±2 °C; a step of
  50 ± 0.002 mm); the tank drifting uniform in ±0.1 °C/min; a few postures reached from above
  (``FullPlan.above``). ``--model`` runs it on another shipped model's template (its block,
  calibration pose and the same step); ``--placed`` gives each world a profile of its own whose
  declared block is where a technician put it, uniform within ±2σ of the template's (as
  ``plans.py``'s blocks), the plan made on it and the true block drawn about it. Each world
  is printed on a line of its own: its plan, written or why not, the TCP error beside what the
  unidentified priors allow (``ucal.calibration.budget``, one sigma), its coverage; a plan
  refused before any motion is listed with the stopped runs, with its message;
* ``tool-frame``: fresh commissionings, ``commissioning.py``'s cells (offsets ±2° never
  calibrated, the tool 1.7 mm / 0.85° off its drawing, a squinting beam, the plate off its
  touched points, the water ±3 °C) whose drawing is a tool of 80–150 mm, 2–5 mm off the flange
  axis, in a straight, 10° or 20° holder (in turn); the tank drifting uniform in ±0.1 °C/min.
  Each is commissioned in both orders (``--orders``): ``t-c`` tool-frame on the fresh profile,
  ``c-t`` tool-frame after ``ucal calibrate`` wrote it (a process, as a user runs it), ``f-t``
  after ``ucal calibrate --level full`` wrote the offsets and the DH table with its stds, ``cf-t``
  after the offsets level and then the full level (as the method note advises); each
  tool-frame run measured once and solved by the current fit, by the fit with the drift's
  curvature held at 0 (``linear drift only``: as it was before it carried it) and by the
  previous one. Coverage counts the tool across the beam (2) and along it, the beam's two
  tilts, the sound speed at the middle of the run and its drift where fitted, against the true
  tool in the profile's flange frame; the last column is the largest error across the beam
  (mm) and of the beam (deg) of the written runs, with how many meet the targets (0.02 mm,
  0.01°); each run is printed with why it was refused.

``--tank``: how the tank's temperature changes over a run. ``linear`` (the default): the drift
above, ``[water] drift_c_per_min``. The others write the tank thermometer's log beside each
world (``[water] temperature_log``, a reading every 3 s over half an hour), the world otherwise
the linear tank's on the same seed: ``exponential``, the water approaching the room's
temperature with a time constant of 20–60 min, its initial rate the drift above (±0.3 °C/min
at the offsets level, ±0.1 at the full level and for tool-frame); ``cycling``, a heater holding
the tank, a sine of period 5–15 min and amplitude 0.05–0.2 °C at a random phase. The solvers
still fit a linear drift: the truth of the sound speed and of its drift is the log's at the
fit's reference time (the middle of the run).

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
  the runs' means / largest maximum (mm);
* then each run: its tank, its largest |z| and whether it was written.

Usage: ``python benchmarks/drift.py --worlds 12
[--case offsets|lost-motion|full|tool-frame|both|all] [--jobs 2] [--declared-drift C]
[--orders t-c|c-t|f-t|cf-t|both] [--tank linear|exponential|cycling] [--only I,J] [--model tx90xl
--placed]`` (C: the drift tolerance every calibration case declares, °C/min; ``--only``: the
tool-frame case's worlds of those indices, drawn as in the whole sweep); ``--quick``: one world
of the offsets, the full and the tool-frame cases (the full level on 8 postures, tool-frame in
the order t-c), the same code path in seconds.
"""

from __future__ import annotations

import argparse
import concurrent.futures
import re
import tempfile
from dataclasses import dataclass
from pathlib import Path

# the worlds and profiles of the benchmarks this one extends (scripts in this folder)
import commissioning
import full_calibration
import numpy as np
import realistic
from _quick import parse_args

from drivers.errors import DriverError
from ucal.acoustics import sound_speed_m_s, sound_speed_slope_m_s_per_c
from ucal.calibration.budget import calibration_budget
from ucal.calibration.exact import solve_exact_with_priors
from ucal.calibration.procedure import judge
from ucal.cell import CellProfile, WorldTruth
from ucal.devices.session import check_status, open_cell
from ucal.errors import UcalError
from ucal.kinematics.dh import fk
from ucal.kinematics.rotations import angle_between_deg, tangent_basis
from ucal.measure.postures import run_full
from ucal.measure.sequence import run_calibration, with_lost_motion
from ucal.model.fit import (
    BACKLASH,
    DRIFT,
    AugmentedFit,
    CellFit,
    FitQuality,
    RunEffects,
    prior_from_profile,
)
from ucal.model.kinematic import aligned_errors_mm, scanning_postures, solve_full, twists_deg
from ucal.model.least_squares import CURVATURE
from ucal.model.postures import MAX_POSTURES, plan_full
from ucal.model.targets import calibration_pose, plan_calibration
from ucal.profile import load_profile, write_profile
from ucal.profile.models import KNOWN_MODELS
from ucal.toolframe.fit import ToolFrameFit, truth_in_profile_flange
from ucal.toolframe.measure import measure_tool_frame
from ucal.toolframe.plan import plan_tool_frame
from ucal.toolframe.solve import solve_measured
from ucal.world import load_world

#: ``--quick``: the defaults it changes (an option given on the command line still wins).
QUICK = {"worlds": 1, "jobs": 1, "postures": 8, "case": "quick", "orders": "t-c"}
#: The previous solvers: the drift and the lost motion held at 0.
HELD = DRIFT + BACKLASH
#: The tool-frame fit before it carried the drift's curvature (the curvature held at 0).
STRAIGHT = (CURVATURE,)
#: The tool-frame case's solvers, in the order each run's outcomes are listed.
TOOL_SOLVERS = {"current": (), "linear drift only": STRAIGHT, "previous (held at 0)": HELD}
#: The cases of the offsets level: as planned, and with the calibration pose's faces measured
#: again from above (``ucal.measure.sequence.with_lost_motion``).
OFFSETS_CASES = ("offsets", "lost-motion")
#: Per case: the tank's drift the worlds are drawn with (±°C/min) and the one its profile
#: declares (°C/min, one sigma: the default).
DRIFT_C_PER_MIN = {"offsets": 0.3, "lost-motion": 0.3, "full": 0.1, "tool-frame": 0.1}
DECLARED_DRIFT = {"offsets": 0.05, "lost-motion": 0.05, "full": 0.05, "tool-frame": 0.05}
#: The tank's histories ``--tank`` draws (module docstring): the linear drift, or a thermometer's
#: log of an exponential approach to the room's temperature or of a heater cycling.
TANKS = ("linear", "exponential", "cycling")
#: The exponential approach's time constant (min); the heater's period (min) and amplitude (°C).
TIME_CONSTANT_MIN = (20.0, 60.0)
HEATER_PERIOD_MIN = (5.0, 15.0)
HEATER_AMPLITUDE_C = (0.05, 0.2)
#: A logged tank: a reading every 3 s over half an hour (every run is shorter: held after it).
LOG_STEP_MIN = 0.05
LOG_SPAN_MIN = 30.0
#: Largest lost motion drawn (deg, uniform from 0 per joint).
BACKLASH_DEG = 0.02
#: The tool-frame case's tools: length (mm), distance off the flange axis (mm) and the
#: holder's angle (deg), as its profile's [tool] states them.
TOOL_LENGTH_MM = (80.0, 150.0)
TOOL_OFF_AXIS_MM = (2.0, 5.0)
HOLDERS_DEG = (0.0, 10.0, 20.0)
#: Its orders: tool-frame on the fresh profile, or after ``calibrate`` wrote the offsets
#: (``--orders both``); and the calibrations each order runs before tool-frame: ``f-t``
#: ``calibrate --level full`` (the offsets and the table), ``cf-t`` the offsets level first.
ORDERS = ("t-c", "c-t")
CALIBRATIONS: dict[str, tuple[tuple[str, ...], ...]] = {
    "t-c": (),
    "c-t": ((),),
    "f-t": (("--level", "full"),),
    "cf-t": ((), ("--level", "full")),
}
#: Tool-frame's targets: across the beam (mm) and the beam (deg).
ACROSS_GOAL_MM = 0.02
BEAM_GOAL_DEG = 0.01
#: The cases ``--case`` runs, by the names that stand for several.
CASES = {
    "both": ("offsets", "full"),
    "all": ("offsets", "lost-motion", "full", "tool-frame"),
    "quick": ("offsets", "full", "tool-frame"),
}


def make_profile(
    directory: Path, case: str, drift_c_per_min: float, model: str = full_calibration.MODEL
) -> Path:
    """The profile of ``case`` (module docstring), declaring the tank's drift tolerance:
    ``realistic.py``'s with a fixture and a measured tool, ``full_calibration.py``'s with the
    step (on ``model``)."""
    directory = directory / case
    directory.mkdir()
    updates: dict = {"water": {"drift_std_c_per_min": drift_c_per_min}}
    if case in OFFSETS_CASES:
        path = realistic.make_profile(directory, fixture=True)
        updates["tool"] = {"position_std_mm": [0.05] * 3, "rotation_std_deg": [0.02] * 3}
    else:
        path = full_calibration.make_profile(directory, 2.0, step=True, model=model)
    write_profile(path, updates, "benchmark")
    return path


def placed_profile(rng: np.random.Generator, template: Path, path: Path) -> Path:
    """A copy of ``template`` at ``path`` whose declared block is where a technician put it:
    uniform within ±2σ of the template's declared corner and orientation (``plans.py``'s
    blocks), the cell's true block then drawn about it."""
    path.write_bytes(template.read_bytes())
    profile = load_profile(path)
    pos2 = 2.0 * np.broadcast_to(profile.sample_position_std_mm, 3)
    rot2 = 2.0 * np.broadcast_to(profile.sample_rotation_std_deg, 3)
    sample = {
        "position_mm": (profile.sample_position_mm + rng.uniform(-pos2, pos2)).round(3).tolist(),
        "rotation_deg": (profile.sample_rotation_deg + rng.uniform(-rot2, rot2)).round(4).tolist(),
    }
    write_profile(path, {"sample": sample}, "placed by hand")
    return path


def draw_world(
    rng: np.random.Generator,
    profile: CellProfile,
    case: str,
    index: int,
    tank: Tank,
    log_path: Path | None = None,
) -> str:
    """World-file text of a cell of ``case``: the other benchmark's world (module docstring)
    with the tank (``Tank.into``) and the lost motion of this one."""
    if case in OFFSETS_CASES:
        text = realistic.draw_world(rng, profile, index)
    else:
        text = full_calibration.draw_world(rng, profile, index)
    drift = rng.uniform(-DRIFT_C_PER_MIN[case], DRIFT_C_PER_MIN[case])
    backlash = rng.uniform(0.0, BACKLASH_DEG, 6).tolist()
    text = re.sub(r"(?m)^backlash_deg = .*$", f"backlash_deg = {backlash!r}", text)
    return tank.into(text, drift, log_path)


@dataclass
class Tank:
    """How the worlds' tanks change over a run (``--tank``): ``linear``, the drawn drift as
    ``drift_c_per_min``; else a thermometer's log (``[water] temperature_log``) written to
    ``log_path``: ``exponential``, from the world's temperature towards a room's with a time
    constant uniform in ``TIME_CONSTANT_MIN``, its initial rate the drawn drift; ``cycling``, a
    heater holding the world's temperature, a sine of period and amplitude uniform in
    ``HEATER_PERIOD_MIN`` and ``HEATER_AMPLITUDE_C`` at a random phase. Its own draws come from
    ``rng``, so the worlds are otherwise those of the linear tank on the same seed."""

    kind: str
    rng: np.random.Generator

    def into(self, text: str, drift: float, log_path: Path | None = None) -> str:
        """World text with this tank in its ``[water]``: the drift (°C/min, the initial rate of
        an exponential tank), or the log written to ``log_path``."""
        text = re.sub(r"(?m)^drift_c_per_min = .*\n", "", text)
        if self.kind == "linear":
            return text.replace("[water]\n", f"[water]\ndrift_c_per_min = {drift!r}\n", 1)
        assert log_path is not None
        found = re.search(r"(?m)^temperature_c = (.*)\n", text)
        assert found is not None
        start_c = float(found.group(1))
        t_min = np.arange(0.0, LOG_SPAN_MIN + 0.5 * LOG_STEP_MIN, LOG_STEP_MIN)
        if self.kind == "exponential":
            tau_min = self.rng.uniform(*TIME_CONSTANT_MIN)
            room_c = start_c + drift * tau_min
            temp_c = room_c + (start_c - room_c) * np.exp(-t_min / tau_min)
        else:
            period_min = self.rng.uniform(*HEATER_PERIOD_MIN)
            amplitude_c = self.rng.uniform(*HEATER_AMPLITUDE_C)
            phase = self.rng.uniform(0.0, 2.0 * np.pi)
            wave = np.sin(2.0 * np.pi * t_min / period_min + phase) - np.sin(phase)
            temp_c = start_c + amplitude_c * wave
        rows = "".join(f"{t:.2f},{c:.5f}\n" for t, c in zip(t_min, temp_c, strict=True))
        log_path.write_text("time_min,temperature_c\n" + rows)
        return text.replace(found.group(0), f'temperature_log = "{log_path.name}"\n')


def tank_at(world: WorldTruth, t_min: float) -> tuple[float, float]:
    """The world's water at ``t_min`` minutes: its temperature (°C) and how fast it changes
    (°C/min; a log's over a reading either side, within the log)."""
    log = world.water_temperature_log
    if log is None:
        rate = world.water_drift_c_per_min
        return world.water_temperature_c + rate * t_min, rate
    lo = max(t_min - LOG_STEP_MIN, float(log.time_min[0]))
    hi = min(t_min + LOG_STEP_MIN, float(log.time_min[-1]))
    return log.at(t_min), (log.at(hi) - log.at(lo)) / (hi - lo)


def tank_words(world: WorldTruth) -> str:
    """The tank of a run, in words: its drift, or its logged rate at the start and the end of
    the log."""
    log = world.water_temperature_log
    if log is None:
        return f"drift {world.water_drift_c_per_min:+.3f} °C/min"
    return (
        f"logged tank {tank_at(world, 0.0)[1]:+.3f} °C/min at the start, "
        f"{np.ptp(log.temperature_c[log.time_min <= 5.0]):.3f} °C over 5 min"
    )


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
    #: The run (world and plan, or world, order and tool) and why it was refused, in words.
    run: str = ""
    message: str = ""
    #: The full level: what the unidentified priors allow at the tool centre over the
    #: scanning region, one sigma (mean, max; mm: ``ucal.calibration.budget``), and the
    #: quantities that allow most (name: largest displacement, mm).
    budget_mm: tuple[float, float] | None = None
    budget_by: str = ""
    #: The tool-frame case: the larger of the tool's two stds across the beam (mm).
    across_std_mm: float = float("nan")


def true_sound(world: WorldTruth, t_min: float) -> tuple[float, float]:
    """The world's sound speed (m/s) at ``t_min`` minutes and its drift there (m/s per min)."""
    temp_c, rate = tank_at(world, t_min)
    slope = sound_speed_slope_m_s_per_c(temp_c)
    return float(sound_speed_m_s(temp_c)), slope * rate


def sound_z(cell: CellFit, world: WorldTruth) -> list[float]:
    """|error| / std of the sound speed at the fit's reference time and of its drift."""
    c_m_s, drift = true_sound(world, cell.time_ref_min)
    effects = RunEffects.of(cell)
    z = [abs(cell.value("sound_speed_m_s") - c_m_s) / cell.sigma("sound_speed_m_s")]
    if cell.table.free[cell.table.index(DRIFT[0])]:
        z.append(abs(effects.drift_m_s_per_min - drift) / effects.drift_std_m_s_per_min)
    return z


def backlash_z(cell: CellFit | AugmentedFit, world: WorldTruth) -> tuple[np.ndarray, np.ndarray]:
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
    verdict = judge(sol, sol.cell.quality)
    out = outcome(z, verdict, sol.cell.quality, tcp, held, lost)
    budget = calibration_budget(profile, sol.cell, meas, steps)
    if budget is not None:
        out.budget_mm = (budget.mean_mm, budget.max_mm)
        out.budget_by = ", ".join(f"{k} {v:.3f}" for k, v in list(budget.by_quantity.items())[:3])
    out.message = "" if verdict.ok else verdict.message or sol.cell.quality.cause
    return out


def run_world(
    case: str, profile_path: Path, world_path: Path, postures: int
) -> list[Outcome] | str:
    """Measure one world and solve it with the current and the previous solver; a run the
    procedure stops (a posture refused for safety, an echo not found) is its message."""
    profile = load_profile(profile_path)
    world = load_world(world_path, profile)
    try:
        if case in OFFSETS_CASES:
            offsets_plan = plan_calibration(profile)
            if case == "lost-motion":
                offsets_plan = with_lost_motion(offsets_plan)
        else:
            plan = plan_full(profile, max_postures=postures)
    except UcalError as err:
        return f"{world_path.name}: refused before motion: {err}"
    try:
        with open_cell(profile, str(world_path), None, None) as cell:
            check_status(cell.rig)
            if case in OFFSETS_CASES:
                run = run_calibration(profile, offsets_plan, cell.rig)
            else:
                full_run = run_full(profile, plan, cell.rig)
    except (UcalError, DriverError) as err:  # as a row: a driver's error does not pickle
        return f"{world_path.name}: stopped: {err}"
    if case in OFFSETS_CASES:
        outs = [solve_offsets(profile, world, run.measurements, h) for h in ((), HELD)]
    else:
        outs = [
            solve_full_level(
                profile, world, full_run.measurements, full_run.steps, plan.structure, held
            )
            for held in ((), HELD)
        ]
    for o in outs:
        o.run = f"{world_path.stem}: {tank_words(world)}"
        if case not in OFFSETS_CASES:
            o.run += f", planned {len(plan.postures)} postures"
    return outs


def tool_frame_world(directory: Path, rng: np.random.Generator, index: int, tank: Tank) -> Path:
    """A fresh commissioning of the tool-frame case in ``directory`` (its template profile
    ``template.toml``: a fresh cell whose [tool] is a drawn tool and holder, declaring the
    default lost motion and the drift tolerance) and its world ``world.toml``:
    ``commissioning.py``'s fresh cell with the tank drifting and the lost motion of this
    benchmark. Returns ``directory``."""
    directory.mkdir()
    template = commissioning.fresh_profile(directory / "template.toml")
    length = rng.uniform(*TOOL_LENGTH_MM)
    off, azimuth = rng.uniform(*TOOL_OFF_AXIS_MM), rng.uniform(0.0, 2.0 * np.pi)
    holder = np.radians(HOLDERS_DEG[index % len(HOLDERS_DEG)])
    position = [
        off * np.cos(azimuth) + length * np.sin(holder),
        off * np.sin(azimuth),
        length * np.cos(holder),
    ]
    write_profile(
        template,
        {
            "tool": {
                "position_mm": [round(float(v), 3) for v in position],
                "rotation_deg": [0.0, round(float(np.degrees(holder)), 3), 0.0],
            },
            "water": {"drift_std_c_per_min": DECLARED_DRIFT["tool-frame"]},
        },
        "the drawing",
    )
    world = directory / "world.toml"
    commissioning.draw_world(rng, template, world)
    drift = rng.uniform(-DRIFT_C_PER_MIN["tool-frame"], DRIFT_C_PER_MIN["tool-frame"])
    backlash = rng.uniform(0.0, BACKLASH_DEG, 6).tolist()
    text = world.read_text().replace("[robot]\n", f"[robot]\nbacklash_deg = {backlash!r}\n", 1)
    world.write_text(tank.into(text, drift, directory / "tank.csv"))
    return directory


def tool_z(tf: ToolFrameFit, profile: CellProfile, world: WorldTruth) -> tuple[list, float, float]:
    """|error| / std of the tool across the beam (2), along it, the beam's two tilts, the
    sound speed at the fit's reference time and its drift where fitted; the largest error
    across the beam (mm) and the beam's error (deg)."""
    true_tool = truth_in_profile_flange(profile, world)
    err = tf.position_mm - true_tool[:3, 3]
    tb = tangent_basis(tf.beam)
    across = tb @ err
    z = list(np.abs(across) / tf.across_beam_std_mm)
    z.append(abs(tf.beam @ err) / tf.along_beam_std_mm)
    z += list(np.abs(np.degrees(tb @ true_tool[:3, 2])) / tf.beam_std_deg)
    c_m_s, drift = true_sound(world, tf.time_ref_min)
    z.append(abs(tf.sound_speed_m_s - c_m_s) / tf.sound_speed_std_m_s)
    effects = tf.effects
    assert effects is not None and tf.solution is not None
    table = tf.solution.table
    if table.free[table.index(DRIFT[0])]:
        z.append(abs(effects.drift_m_s_per_min - drift) / effects.drift_std_m_s_per_min)
    beam_deg = float(angle_between_deg(tf.beam, true_tool[:3, 2]))
    return z, float(np.max(np.abs(across))), beam_deg


def run_tool_frame_world(directory: Path, order: str) -> list[Outcome] | str:
    """Commission the cell of ``directory`` (``tool_frame_world``) in ``order``: ``t-c`` runs
    tool-frame on the fresh profile, ``c-t`` after ``ucal calibrate`` wrote it (as a user
    runs it); the measurements solved with each of ``TOOL_SOLVERS``."""
    path = directory / f"{order}.toml"
    path.write_bytes((directory / "template.toml").read_bytes())
    world_path = directory / "world.toml"
    for level in CALIBRATIONS[order]:
        done = commissioning.run("calibrate", path, world_path, *level)
        if not done.get("written"):
            return (
                f"{directory.name} {order}: calibrate {' '.join(level)} not written: "
                f"{done.get('error', '')}"
            )
    profile = load_profile(path)
    world = load_world(world_path, profile)
    holder = float(np.degrees(np.arccos(profile.tool_matrix[2, 2])))
    run = (
        f"{directory.name} {order}: tool {np.linalg.norm(profile.tool_position_mm):.0f} mm, "
        f"holder {holder:.0f}°, lost motion ≤ {np.max(world.backlash_deg):.3f}°, "
        f"{tank_words(world)}"
    )
    try:
        plan = plan_tool_frame(profile)
        with open_cell(profile, str(world_path), None, None) as cell:
            check_status(cell.rig)
            measured = measure_tool_frame(profile, plan, cell.rig)
    except (UcalError, DriverError) as err:
        return f"{directory.name} {order}: stopped: {err}"
    outs = []
    for held in TOOL_SOLVERS.values():
        tf = solve_measured(profile, plan, measured, held).fit
        assert tf is not None
        z, across, beam = tool_z(tf, profile, world)
        refusal = ""
        if tf.refusal:
            named = next((short for words, short in CAUSES if words in tf.quality.cause), "other")
            refusal = f"misfit naming {named}" if tf.quality.verdict == "misfit" else "std"
        drift_z = float("nan") if held == HELD or len(z) < 7 else z[-1]
        assert tf.solution is not None
        lost_err, lost_z = backlash_z(tf.solution, world)
        seen = np.isfinite(lost_z)
        outs.append(
            Outcome(
                np.concatenate([z, lost_z[seen]]),
                not tf.refusal,
                refusal,
                np.array([across, beam]),
                drift_z,
                lost_err,
                lost_z,
                run,
                tf.refusal,
                across_std_mm=float(np.max(tf.across_beam_std_mm)),
            )
        )
    return outs


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


def world_line(o: Outcome) -> str:
    """One world of the full case: its plan, written or why not, the TCP error over the
    scanning region beside what the unidentified priors allow, its coverage."""
    budget = (
        ""
        if o.budget_mm is None
        else f" (priors allow {o.budget_mm[0]:.3f} / {o.budget_mm[1]:.3f}: {o.budget_by})"
    )
    return (
        f"{o.run}; {'written' if o.written else 'refused: ' + o.message[:200]}; TCP "
        f"{o.tcp_mm.mean():.3f} / {o.tcp_mm.max():.3f} mm{budget}; "
        f"{np.mean(o.z <= 3.0) * 100:.0f} % of {len(o.z)} within 3σ (max |z| {np.max(o.z):.1f})"
        + ("; beyond 4σ" if o.written and np.any(o.z > 4.0) else "")
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


def tool_summary(name: str, outs: list[Outcome]) -> str:
    """A row of the tool-frame case: as ``summary``'s, the last column the largest error across
    the beam (mm) and of the beam (deg) of the written runs, and how many meet the targets."""
    row = summary(name, outs).rsplit("|", 2)[0]
    written = [o for o in outs if o.written]
    if not written:
        return row + "| — |"
    errs = np.array([o.tcp_mm for o in written])
    goal = np.sum((errs[:, 0] <= ACROSS_GOAL_MM) & (errs[:, 1] <= BEAM_GOAL_DEG))
    return (
        row + f"| {errs[:, 0].max():.4f} / {errs[:, 1].max():.4f} ({goal} within "
        f"{ACROSS_GOAL_MM:g} mm / {BEAM_GOAL_DEG:g}°) |"
    )


def tool_frame_case(
    work: Path,
    worlds: int,
    seed: int,
    jobs: int,
    orders: tuple[str, ...],
    tank: str,
    only: frozenset[int] | None = None,
) -> list:
    """The tool-frame case (module docstring): its rows printed, its stopped runs returned;
    ``only``: the indices of the worlds run (every world is drawn, so each keeps its draws)."""
    rng = np.random.default_rng(seed)
    drawn = Tank(tank, np.random.default_rng([seed, 1]))
    dirs = [tool_frame_world(work / f"tool-frame-{i:03d}", rng, i, drawn) for i in range(worlds)]
    dirs = [d for i, d in enumerate(dirs) if only is None or i in only]
    jobs_in = [(d, order) for d in dirs for order in orders]
    with concurrent.futures.ProcessPoolExecutor(jobs) as pool:
        rows = list(pool.map(run_tool_frame_world, *zip(*jobs_in, strict=True)))
    print(
        "\n| tool-frame, order | solver | coverage (|err| ≤ 3σ) | drift within 3σ | lost motion "
        "| written | refused (why) | written beyond 4σ | written: across mm / beam deg, max |"
    )
    print("| --- " * 9 + "|")
    declared = DECLARED_DRIFT["tool-frame"]
    for order in orders:
        solved = [
            r for (_, o), r in zip(jobs_in, rows, strict=True) if o == order and isinstance(r, list)
        ]
        name = f"{order}, {declared:g} °C/min, {tank} tank"
        for k, solver in enumerate(TOOL_SOLVERS):
            print(tool_summary(f"{name} | {solver}", [r[k] for r in solved]))
    for r in rows:
        if isinstance(r, list):
            now, straight, before = r
            print(
                f"  {now.run}: across {now.tcp_mm[0]:.4f} mm (std {now.across_std_mm:.4f}; "
                f"linear drift only {straight.across_std_mm:.4f}), beam {now.tcp_mm[1]:.4f}°, "
                f"max |z| {np.max(now.z):.1f} ({np.max(straight.z):.1f}); "
                + ("written" if now.written else f"refused: {now.message.split('; ')[0][:240]}")
                + ("" if now.written == straight.written else " (linear drift only: the other way)")
                + ("" if now.written == before.written else " (previous: the other way)")
            )
    return [r for r in rows if isinstance(r, str)]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--worlds", type=int, default=12)
    ap.add_argument(
        "--case",
        choices=("offsets", "lost-motion", "full", "tool-frame", *CASES),
        default="all",
    )
    ap.add_argument(
        "--orders",
        choices=(*CALIBRATIONS, "both"),
        default="both",
        help="the tool-frame case's orders: t-c tool-frame on the fresh profile, c-t after "
        "calibrate, f-t after calibrate --level full, cf-t after both levels (both: t-c and c-t)",
    )
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument(
        "--tank",
        choices=TANKS,
        default="linear",
        help="the tank's history: a linear drift, or a thermometer's log of an exponential "
        "approach to the room's temperature or of a heater cycling",
    )
    ap.add_argument(
        "--only",
        type=lambda text: frozenset(int(i) for i in text.split(",")),
        help="the tool-frame case: run only these worlds (indices from 0, comma-separated; "
        "each drawn as in the whole sweep)",
    )
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
        "--model",
        choices=KNOWN_MODELS,
        default=full_calibration.MODEL,
        help="the full case's robot (its template's block, calibration pose and step)",
    )
    ap.add_argument(
        "--placed",
        action="store_true",
        help="the full case: each world's profile declares its block where a technician put "
        "it, uniform within ±2σ of the template's, and plans on it",
    )
    ap.add_argument(
        "--quick",
        action="store_true",
        help="--worlds 1 --jobs 1 --postures 8, the offsets, full and tool-frame cases (t-c): "
        "the same code path in seconds",
    )
    args = parse_args(ap, QUICK, argv)
    work = Path(tempfile.mkdtemp(prefix="ucal-drift-"))
    chosen = CASES.get(args.case, (args.case,))
    cases = tuple(c for c in chosen if c != "tool-frame")
    stopped: list[str] = []
    if cases:
        print(
            "| case | solver | coverage (|err| ≤ 3σ) | drift within 3σ | lost motion: rms error, "
            "within 3σ | written | refused (why) | written beyond 4σ | TCP error mean / max mm |"
        )
        print("| --- " * 9 + "|")
    for case in cases:
        declared = args.declared_drift or DECLARED_DRIFT[case]
        profile_path = make_profile(work, case, declared, args.model)
        rng = np.random.default_rng(args.seed)
        tank = Tank(args.tank, np.random.default_rng([args.seed, 1]))
        worlds, profiles = [], []
        for i in range(args.worlds):
            placed = args.placed and case not in OFFSETS_CASES
            path = work / f"{case}-{i:03d}.toml"
            own = work / case / f"cell-{i:03d}.toml"
            profiles.append(placed_profile(rng, profile_path, own) if placed else profile_path)
            cell = load_profile(profiles[-1])
            path.write_text(draw_world(rng, cell, case, i, tank, path.with_suffix(".csv")))
            worlds.append(path)
        with concurrent.futures.ProcessPoolExecutor(args.jobs) as pool:
            rows = list(
                pool.map(
                    run_world,
                    [case] * len(worlds),
                    profiles,
                    worlds,
                    [args.postures] * len(worlds),
                )
            )
        solved = [r for r in rows if not isinstance(r, str)]
        name = case if case in OFFSETS_CASES else f"{case} {args.model}"
        name = f"{name}, {declared:g} °C/min, {args.tank} tank"
        print(summary(f"{name} | current", [r[0] for r in solved]))
        print(summary(f"{name} | previous (held at 0)", [r[1] for r in solved]))
        for now, _ in solved:
            if case in OFFSETS_CASES:
                print(f"  {now.run}: max |z| {np.max(now.z):.1f}, " + (now.refusal or "written"))
            else:
                print("  " + world_line(now))
        stopped.extend(r for r in rows if isinstance(r, str))
    if "tool-frame" in chosen:
        orders = ORDERS if args.orders == "both" else (args.orders,)
        stopped += tool_frame_case(
            work, args.worlds, args.seed, args.jobs, orders, args.tank, args.only
        )
    print(f"runs stopped by the procedure: {len(stopped)}")
    for line in stopped:
        print("  ", line)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
