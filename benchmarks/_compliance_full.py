"""``compliance.py --level full``: the full level with a step on random bent arms (that
script's docstring); not a benchmark of its own."""

from __future__ import annotations

import argparse
import concurrent.futures
import pickle
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from compliance import bent_worlds
from full_calibration import draw_world, make_profile

from drivers.errors import DriverError
from ucal.calibration.budget import calibration_budget
from ucal.devices.session import check_status, open_cell
from ucal.errors import UcalError
from ucal.kinematics.dh import fk
from ucal.measure.postures import FullRun, run_full
from ucal.model.fit import prior_from_profile
from ucal.model.kinematic import FullSolution, aligned_errors_mm, scanning_postures, solve_full
from ucal.model.load import COMPLIANCE, URAD_DEG, PostureLoad
from ucal.model.postures import MAX_POSTURES, plan_full
from ucal.model.priors import CellPrior
from ucal.model.stiffness import STIFFNESS_TOLERANCE_PCT
from ucal.model.targets import calibration_pose
from ucal.profile import load_profile
from ucal.sim.cell import SimulatedCell
from ucal.world import load_world

#: The joints whose stiffness the issue asks the full level for.
JOINTS = (2, 3)


#: The solvers on the same measurements: whether rigid, and whether what no posture identifies
#: (d5, a5, …: ``Identifiability.redundant``) is held at the truth (nominal in these worlds)
#: to show the identifiable part's error apart from what the result's TCP budget states.
SOLVERS = {
    "compliant": (False, False),
    "compliant, the identifiable part": (False, True),
    "rigid": (True, False),
    "rigid, the identifiable part": (True, True),
}


@dataclass(frozen=True)
class Row:
    """One world's figures: per solver of ``SOLVERS`` whether written and the TCP error under
    load (mean, max mm); the compliant solver's TCP budget (mean, max mm, one sigma:
    ``unidentified_tcp_mm``); per joint of ``JOINTS`` whether identified, the relative error of
    its stiffness (%) and its std (%)."""

    written: tuple[bool, ...]
    tcp_mm: tuple[tuple[float, float], ...]
    budget_mm: tuple[float, float]
    identified: tuple[bool, ...]
    error_pct: tuple[float, ...]
    std_pct: tuple[float, ...]


def loaded_tcp_mm(prior: CellPrior, sol: FullSolution, qs: np.ndarray, tool) -> np.ndarray:
    """The model's tool centre (n, 3) at readings ``qs``: each link at its reading, offset and
    fitted compliance times its torque less the load posture's (``ucal.model.load``)."""
    q = np.asarray(qs, float)
    posture = sol.cell.load_posture_deg
    if prior.bodies is not None and posture is not None:
        load = PostureLoad.of(prior.model, prior.bodies, prior.offsets_deg, posture)
        c = sol.cell.table.get(COMPLIANCE, sol.cell.estimate)
        q = q + load.relative_nm(q) * (URAD_DEG * c)
    return np.asarray(fk(sol.model, q, tool, sol.offsets_deg)[:, :3, 3])


def measure(profile_path: Path, world_path: Path, postures: int) -> Row | str:
    """Measure one world with the full plan (cached beside it), solve it by each of
    ``SOLVERS``."""
    profile = load_profile(profile_path)
    plan = plan_full(profile, max_postures=postures)
    cache = world_path.with_suffix(".pkl")
    if cache.exists():
        run = pickle.loads(cache.read_bytes())
    else:
        try:
            with open_cell(profile, str(world_path), None, None) as cell:
                check_status(cell.rig)
                run = run_full(profile, plan, cell.rig)
        except (UcalError, DriverError) as err:  # a row of its own: the procedure stopped
            return f"{world_path.parent.name}: stopped: {err}"
        cache.write_bytes(pickle.dumps(run))
    assert isinstance(run, FullRun)
    truth = load_world(world_path, profile)
    sim = SimulatedCell(truth)
    qs = scanning_postures(calibration_pose(profile), 200, 1, profile.model)
    tool = profile.tool_matrix
    true_mm = np.array([sim.true_tcp(q, np.ones(6))[:3, 3] for q in qs])
    written, tcp = [], []
    found: FullSolution | None = None
    assert plan.structure is not None
    for rigid, held in SOLVERS.values():
        p = profile.replace(stiffness_nm_per_rad=np.zeros(6)) if rigid else profile
        prior = prior_from_profile(p)
        sol = solve_full(
            prior,
            run.measurements,
            structure=plan.structure,
            steps=run.steps,
            fixed=tuple(plan.structure.redundant) if held else (),
        )
        miss = aligned_errors_mm(loaded_tcp_mm(prior, sol, qs, tool), true_mm)
        written.append(sol.cell.quality.verdict == "ok")
        tcp.append((float(miss.mean()), float(miss.max())))
        found = found or sol
    assert found is not None
    budget = calibration_budget(profile, found.cell, run.measurements, run.steps)
    k_true = truth.arm.stiffness_nm_per_rad
    stiff = [found.stiffness[j - 1] for j in JOINTS]
    error = [
        100.0 * (1e6 / s.compliance_urad_per_nm - k_true[s.joint - 1]) / k_true[s.joint - 1]
        for s in stiff
    ]
    return Row(
        tuple(written),
        tuple(tcp),
        (np.nan, np.nan) if budget is None else (budget.mean_mm, budget.max_mm),
        tuple(s.identified for s in stiff),
        tuple(error),
        tuple(np.nan if s.std_pct is None else s.std_pct for s in stiff),
    )


def draw_nominal_d5(rng: np.random.Generator, profile, index: int) -> str:
    """``full_calibration.py``'s world with only the non-zero DH lengths off: ``d₅`` and
    ``a₅``, which no posture identifies (their budget is the result's), at nominal."""
    return draw_world(rng, profile, index, every=False)


def main_full(args: argparse.Namespace) -> None:
    """``compliance.py --level full`` (``args``: that script's options)."""
    work = args.cache or Path(tempfile.mkdtemp(prefix="ucal-compliance-full-"))
    work.mkdir(parents=True, exist_ok=True)
    postures = args.postures or MAX_POSTURES
    profiles, worlds = bent_worlds(
        work / "full", args.worlds, args.seed, lambda d: make_profile(d, 2.0, step=True),
        draw_nominal_d5,
    )  # fmt: skip
    t0 = time.monotonic()
    with concurrent.futures.ProcessPoolExecutor(args.jobs) as pool:
        out = list(pool.map(measure, profiles, worlds, [postures] * len(worlds)))
    print(f"full level, {len(worlds)} worlds in {time.monotonic() - t0:.0f} s ({work})")
    rows = [r for r in out if isinstance(r, Row)]
    for r in out:
        if isinstance(r, str):
            print(f"  {r}")
    if not rows:
        return
    budget = np.array([r.budget_mm for r in rows])
    print(
        "| solver | written | TCP under load, mean of means / max of maxima, mm |\n"
        "| --- | --- | --- |"
    )
    for i, name in enumerate(SOLVERS):
        tcp = np.array([r.tcp_mm[i] for r in rows])
        ok = sum(r.written[i] for r in rows)
        print(f"| {name} | {ok} / {len(rows)} | {tcp[:, 0].mean():.3f} / {tcp[:, 1].max():.3f} |")
    print(
        "the compliant result's TCP budget (what no posture identifies, one sigma): "
        f"{np.nanmean(budget[:, 0]):.3f} / {np.nanmax(budget[:, 1]):.3f} mm"
    )
    tol = STIFFNESS_TOLERANCE_PCT
    print(
        f"| joint | reported | within ±{tol:g} % where reported | coverage (≤ 3σ) where "
        "reported | coverage over every run | median std where reported |"
    )
    print("| --- | --- | --- | --- | --- | --- |")
    for i, j in enumerate(JOINTS):
        err = np.array([r.error_pct[i] for r in rows])
        std = np.array([r.std_pct[i] for r in rows])
        seen = np.array([r.identified[i] for r in rows])
        z = np.abs(err) / std
        n = int(seen.sum())
        within = int(np.sum(np.abs(err[seen]) <= tol))
        cov = int(np.sum(z[seen] <= 3.0))
        every = int(np.sum(z[np.isfinite(z)] <= 3.0))
        med = f"{np.median(std[seen]):.1f} %" if n else "—"
        print(
            f"| J{j} | {n} / {len(rows)} | {within} / {n} | {cov} / {n} "
            f"| {every} / {int(np.isfinite(z).sum())} | {med} |"
        )
