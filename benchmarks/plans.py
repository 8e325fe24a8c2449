"""Planning sweep: which cells the five planners plan, and why the others are refused.

For every shipped model (``ucal profile init MODEL``: its block, plate and calibration pose),
the profile is changed as a technician changes it before a first run: the block's corner and
orientation declared up to ±2σ of its tolerances away from where the template puts it
(``[sample] position_std_mm``, ``rotation_std_deg``), a tool 80–150 mm long and 0–5 mm off the
flange axis, mounted on a holder that turns the beam 0°, 10° or 20° off the flange axis (about
an axis across it), and the README's step (``docs/method/full-calibration.md``: 50 mm high,
60 mm square, at the XY face's centre) declared or not. On each such profile the four
planners run exactly as the commands run them before moving, on the profile's nominal values:
``calibrate`` (``plan_calibration``), ``calibrate --level full`` (``plan_full``),
``tool-frame`` (``plan_tool_frame``), ``verify`` (``plan_verify``) and ``verify --region 12``
(``plan_region``). Nothing moves. The profiles are never calibrated (each joint offset known
to a degree, ``ucal.model.safety.FRESH_OFFSET_STD_DEG``); ``--calibrated`` declares
``[calibration] std_deg`` as ``calibrate`` writes it (``CALIBRATED_STD_DEG``).

The sweep prints how many plans each planner finds and how many it refuses, and the refusals
grouped by their message (numbers masked, so that one cause is one line). For the planners
whose run re-places its postures on the block as measured (the full level, the region check),
it checks where each plan's first posture, reached before anything is measured, meets its
face with the offsets of J1-J3 three sigma off together (each sign; ``first_room``): how many
plans put the tool centre within ``MIN_WATER_PATH_MM`` of the face or the beam within
``EDGE_MARGIN_MM`` of the face's edge, and the least water path and edge distance (mm).

Run::

    python benchmarks/plans.py              # 3 models x 4 blocks x 4 tools x 3 holders x 2
    python benchmarks/plans.py --quick      # one block, one tool, the TX90L and the TX2-90XL
                                            # x 3 holders: 6 cells
    python benchmarks/plans.py --model tx90xl --blocks 8 --json
    python benchmarks/plans.py --model tx90xl --blocks 12 --planner "calibrate --level full"
    python benchmarks/plans.py --planner "verify --region" --calibrated
"""

from __future__ import annotations

import argparse
import itertools
import json
import re
import sys
import time
from collections import Counter, defaultdict
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from _quick import parse_args
from scipy.spatial.transform import Rotation

from ucal.cell import CellProfile, Step
from ucal.errors import SafetyError, UcalError
from ucal.kinematics.rotations import matrix_to_rpy
from ucal.model.postures import FullPlan, first_postures, plan_full
from ucal.model.safety import EDGE_MARGIN_MM, MIN_WATER_PATH_MM, face_hit, offsets_std_deg
from ucal.model.targets import geometry, plan_calibration
from ucal.profile import default_profile_text, profile_from_text
from ucal.profile.models import KNOWN_MODELS
from ucal.toolframe.plan import QUARTER_TURNS_TILT_DEG, ToolFramePlan, plan_tool_frame
from ucal.verify.plan import plan_verify
from ucal.verify.region import plan_region

#: The README's example step (docs/method/full-calibration.md).
README_STEP = Step(50.0, np.array([250.0, 250.0]), 60.0, 0.002)
HOLDERS_DEG = (0.0, 10.0, 20.0)
TOOL_LENGTHS_MM = (80.0, 150.0)
TOOL_OFF_AXIS_MM = (0.0, 5.0)
#: ``--quick``: the defaults it changes (an option given on the command line still wins).
QUICK = {"blocks": 1, "tools": 1, "one_step": True, "model": ["tx90l", "tx2-90xl"]}
#: Postures of the region check (the `verify --region 12` of the CLI's examples).
REGION_POSTURES = 12
#: ``--calibrated``: each offset's std (deg) as ``calibrate`` writes it on a simulated cell.
CALIBRATED_STD_DEG = 0.003

PLANNERS: dict[str, Callable[[CellProfile], object]] = {
    "calibrate": plan_calibration,
    "calibrate --level full": plan_full,
    "tool-frame": plan_tool_frame,
    "verify": plan_verify,
    "verify --region": lambda profile: plan_region(profile, REGION_POSTURES),
}


@dataclass(frozen=True)
class Case:
    """One cell of the sweep, as its profile declares it."""

    model: str
    block_mm: np.ndarray  # offset of the declared corner from the template's (mm)
    block_deg: np.ndarray  # declared block orientation (deg)
    tool_mm: np.ndarray  # tool centre in the flange frame (mm)
    holder_deg: float  # beam off the flange axis (deg)
    holder_axis_deg: float  # the axis it turns about, from flange x (deg)
    step: bool

    def describe(self) -> str:
        return (
            f"{self.model} block {np.round(self.block_mm, 1).tolist()} mm "
            f"{np.round(self.block_deg, 2).tolist()} deg, tool "
            f"{np.round(self.tool_mm, 1).tolist()} mm, holder {self.holder_deg:g} deg"
            f"{', step' if self.step else ''}"
        )


def template(model: str) -> CellProfile:
    """The profile ``ucal profile init MODEL`` writes."""
    return profile_from_text(default_profile_text(model), f"{model}.toml")


def profile_of(case: Case, base: CellProfile, calibrated: bool = False) -> CellProfile:
    """``base`` with the case's block, tool and step declared (``calibrated``: and the
    offsets' std, ``CALIBRATED_STD_DEG``)."""
    axis = np.radians(case.holder_axis_deg)
    holder = Rotation.from_rotvec(
        np.radians(case.holder_deg) * np.array([np.cos(axis), np.sin(axis), 0.0])
    ).as_matrix()
    return base.replace(
        sample_position_mm=base.sample_position_mm + case.block_mm,
        sample_rotation_deg=np.asarray(case.block_deg, float),
        tool_position_mm=np.asarray(case.tool_mm, float),
        tool_rotation_deg=matrix_to_rpy(holder),
        step=README_STEP if case.step else None,
        joint_offsets_std_deg=(
            np.full(6, CALIBRATED_STD_DEG) if calibrated else base.joint_offsets_std_deg
        ),
    )


def cases(
    models: tuple[str, ...], blocks: int, tools: int, seed: int, one_step: bool = False
) -> list[Case]:
    """The sweep's cells: per model, ``blocks`` declared block poses (the first at the corner
    of the ±2σ box that lowers and turns it most, the others drawn uniformly in the box) ×
    ``tools`` tools (the longest, farthest off axis first, then drawn) × holders × step
    (``one_step``: the step declared on the 10° holder's cells only, not both ways on each)."""
    rng = np.random.default_rng(seed)
    out = []
    for model in models:
        base = template(model)
        pos2 = 2.0 * np.asarray(base.sample_position_std_mm, float)
        rot2 = 2.0 * np.asarray(base.sample_rotation_std_deg, float)
        poses = [(np.array([pos2[0], pos2[1], -pos2[2]]), rot2.copy())]
        poses += [(rng.uniform(-pos2, pos2), rng.uniform(-rot2, rot2)) for _ in range(blocks - 1)]
        kinds = [(max(TOOL_LENGTHS_MM), max(TOOL_OFF_AXIS_MM), 0.0)]
        kinds += [
            (
                rng.uniform(*TOOL_LENGTHS_MM[:2]),
                rng.uniform(*TOOL_OFF_AXIS_MM[:2]),
                rng.uniform(0.0, 360.0),
            )
            for _ in range(tools - 1)
        ]
        for block_mm, block_deg in poses:
            for length, off, az in kinds:
                a = np.radians(az)
                tool = np.array([off * np.cos(a), off * np.sin(a), length])
                for k, holder in enumerate(HOLDERS_DEG):
                    for step in (k == 1,) if one_step else (False, True):
                        out.append(
                            Case(model, block_mm, block_deg, tool, holder, 90.0 * k + az, step)
                        )
    return out


def first_room(profile: CellProfile, plan: FullPlan) -> tuple[float, float]:
    """The least water path and distance of the beam's hit from the face's edge (mm) of the
    first posture the run reaches (the offsets level's first face where the plan measures it
    first) at its planned readings, over true offsets of J1-J3 three sigma off together (each
    joint ``offsets_std_deg`` × 3/√3, each sign), the block as declared."""
    first = (first_postures(plan.first) + list(plan.postures))[0]
    std = offsets_std_deg(profile)
    geom = geometry(profile)
    corner = profile.sample_matrix[:3, 3]
    hits = []
    for signs in itertools.product((-1.0, 1.0), repeat=3):
        true = np.array(profile.joint_offsets_deg, float)
        true[:3] += np.sqrt(3.0) * np.array(signs) * std[:3]  # 3σ together: 3/√3 σ each
        size = profile.sample_face_size_mm
        hits.append(face_hit(geom, first.joints_deg, true, corner, first.face, size))
    return min(h[0] for h in hits), min(h[1] for h in hits)


def mask(message: str) -> str:
    """A refusal's message with its numbers masked: one cause, one line."""
    return re.sub(r"-?\d+(\.\d+)?", "#", message)


def first_rooms(rooms: list[tuple[float, float]]) -> dict:
    """What ``first_room`` found over a planner's plans (nothing for a planner without it)."""
    if not rooms:
        return {}
    path, edge = np.array(rooms).T
    return {
        "first_short": int(np.sum((path < MIN_WATER_PATH_MM) | (edge < EDGE_MARGIN_MM))),
        "first_min_path_mm": float(path.min()),
        "first_min_edge_mm": float(edge.min()),
    }


def sweep(
    all_cases: list[Case], planners: tuple[str, ...] = tuple(PLANNERS), calibrated: bool = False
) -> dict:
    """Run the planners (by name, all five by default) on every case (``calibrated``: its
    profile with the offsets' std ``calibrate`` writes); counts, refusals grouped, CPU time."""
    chosen = {name: PLANNERS[name] for name in planners}
    bases = {m: template(m) for m in dict.fromkeys(c.model for c in all_cases)}
    counts: dict[str, Counter[str]] = {name: Counter() for name in chosen}
    grouped: dict[str, Counter[str]] = {name: Counter() for name in chosen}
    example: dict[tuple[str, str], str] = {}
    by_model: dict[str, Counter[str]] = defaultdict(Counter)
    rooms: dict[str, list[tuple[float, float]]] = defaultdict(list)
    t0 = time.process_time()
    for case in all_cases:
        profile = profile_of(case, bases[case.model], calibrated)
        for name, plan in chosen.items():
            try:
                found = plan(profile)
            except (SafetyError, UcalError) as e:
                counts[name]["refused"] += 1
                key = mask(str(e))
                grouped[name][key] += 1
                example.setdefault((name, key), f"{case.describe()}: {e}")
                by_model[case.model][f"{name} refused"] += 1
            else:
                counts[name]["planned"] += 1
                by_model[case.model][f"{name} planned"] += 1
                if isinstance(found, FullPlan) and found.postures:
                    rooms[name].append(first_room(profile, found))
                if isinstance(found, ToolFramePlan):
                    # the edge scans' orientations: a quarter turn apart for a holder, or half
                    # (a straight tool, or a holder whose quarter turns the arm cannot follow)
                    kind = "quarter" if len(found.edge_turns_deg) == 4 else "half"
                    fell = case.holder_deg > QUARTER_TURNS_TILT_DEG and kind == "half"
                    key = f"{name} edges {kind} turns" + (" (holder)" if fell else "")
                    by_model[case.model][key] += 1
    return {
        "cases": len(all_cases),
        "cpu_s": time.process_time() - t0,
        "planners": {
            name: {
                "planned": counts[name]["planned"],
                "refused": counts[name]["refused"],
                "refusals": [
                    {"count": n, "message": key, "example": example[(name, key)]}
                    for key, n in grouped[name].most_common()
                ],
                **first_rooms(rooms[name]),
            }
            for name in chosen
        },
        "by_model": {m: dict(c) for m, c in by_model.items()},
    }


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--model", choices=KNOWN_MODELS, action="append", help="(default: all)")
    p.add_argument("--blocks", type=int, default=4, help="declared block poses per model")
    p.add_argument("--tools", type=int, default=4, help="tools per block pose")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--json", action="store_true", help="one JSON object on stdout")
    p.add_argument(
        "--one-step",
        action="store_true",
        help="the step on the 10-degree holder's cells only, instead of with and without it",
    )
    p.add_argument(
        "--planner",
        choices=PLANNERS,
        action="append",
        help="only this planner (again for more; default: all five)",
    )
    p.add_argument(
        "--calibrated",
        action="store_true",
        help="profiles with [calibration] std_deg as calibrate writes it (default: never "
        "calibrated, each offset known to a degree)",
    )
    p.add_argument("--quick", action="store_true", help="--blocks 1 --tools 1 --one-step: 9 cells")
    args = parse_args(p, QUICK, argv)
    models = tuple(args.model or KNOWN_MODELS)
    planners = tuple(args.planner or PLANNERS)
    all_cases = cases(models, args.blocks, args.tools, args.seed, args.one_step)
    result = sweep(all_cases, planners, args.calibrated)
    if args.json:
        print(json.dumps(result))
        return 0
    print(
        f"{result['cases']} cells, {len(planners)} planner(s) each: {result['cpu_s']:.1f} s of CPU"
    )
    for name, r in result["planners"].items():
        print(f"{name}: {r['planned']} planned, {r['refused']} refused")
        if "first_short" in r:
            print(
                f"  first posture, J1-J3 offsets 3 sigma off: {r['first_short']} within "
                f"{MIN_WATER_PATH_MM:g} mm of the face or {EDGE_MARGIN_MM:g} mm of its edge; "
                f"least water path {r['first_min_path_mm']:.1f} mm, edge "
                f"{r['first_min_edge_mm']:.1f} mm"
            )
        for g in r["refusals"]:
            print(f"  {g['count']:4d} x {g['message']}")
            print(f"         e.g. {g['example']}", file=sys.stderr)
    for model, c in result["by_model"].items():
        print(f"{model}: " + ", ".join(f"{k} {v}" for k, v in sorted(c.items())))
    return 0


if __name__ == "__main__":
    sys.exit(main())
