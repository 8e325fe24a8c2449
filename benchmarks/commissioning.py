"""Commissioning fresh cells: tool-frame and calibrate in both orders, against the hidden truth.

Each world is a fresh cell that differs from its new profile (``ucal profile init tx90l``) as a
real one does: joint offsets uniform in ±2° on every joint (never calibrated: the profile says
0 with no ``[calibration] std_deg``), the tool up to 1.7 mm per axis and 0.85° per axis off its
drawing, a beam squint of 0.5–1° at a random azimuth, the plate up to 2 mm above or below and
0.3° tilted from the plane of its touched points, with rounded edges (0.5–2 mm) and a bow of up
to 0.02 mm, the near-field directivity, the block placed by hand (2 mm, 0.2°), the water ±3 °C
from the profile's temperature, TOF noise 0.5 ns and amplitude noise 1 %. The profile declares
tolerances that cover these draws (tool 1.5 mm / 1°, touched points 1.2 mm, water 2 °C).

Every cell is commissioned twice from the same fresh profile, once in each order (``ucal
tool-frame`` then ``ucal calibrate``, and the reverse), as a user runs them (``--yes --json``,
each a process against the simulated cell). Printed:

* how many runs end with both written, and why the others did not (the commands' messages);
* the tool frame against the truth in the flange frame the profile's J6 offset defines (J6's
  offset and the tool's azimuth are one rotation): across the beam, along it, the beam angle;
* the joint offsets against the truth (the joints calibrate reports with a std);
* coverage: for every reported std (tool across the beam ×2, along it, the beam's two tilts,
  each calibrated joint) the share of |error| ≤ 3·std, the share beyond 4·std, the largest |z|;
* then ``ucal verify`` on the commissioned profile (``--points 6``): its "after" figure (the
  largest deviation on any axis), the true one of the same points (the simulator's kinematics
  and tool), and how far the measured reached TCPs are from the true ones, with how many
  runs pass the profile's tolerance and how many should (the true error within it), the
  tool check's misfit and how many verdicts verify called marginal.

With ``--fixture`` the block sits in a doweled, levelled fixture (declared 0.1 mm / 0.01°,
drawn within 0.05 mm / 0.005° one sigma) and the plate was touched with a calibrated robot
(declared 0.05 mm, drawn within ±0.05 mm and 0.01°): J1 and the tool's length along the beam
are then measured too, the real TCP can come within verify's tolerance, and verify's verdict
is put to the test both ways.

With ``--bent`` the arm gives under its weight and the tool's as ``compliance.py`` draws it
(J2/J3 stiffness log-uniform in 1e5…1e6 N·m/rad, the others in proportion, link masses ±10 %,
centres ±5 mm, a tool of 0.3–2 kg), the profile stating the tool's mass within 5 % and its
centre within 5 mm; the offsets are judged against the world's plus each link's sag at the
load posture calibrate reports (what they hold, ``ucal.model.load``). ``--rigid-profile``
(with ``--bent``): the same worlds, the profile stating a rigid arm (stiffness 0): the solvers
as they were, beside.

Usage: ``python benchmarks/commissioning.py --worlds 20 [--jobs 2] [--seed 1] [--fixture]
[--bent [--rigid-profile]]``;
``--quick``: one world, one order (calibrate then tool-frame): the same code path in seconds.
"""

from __future__ import annotations

import argparse
import concurrent.futures
import functools
import json
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from _quick import parse_args
from compliance import draw_arm

from ucal.kinematics.rotations import tangent_basis
from ucal.profile import create_profile, load_profile, write_profile
from ucal.sim.cell import SimulatedCell
from ucal.toolframe.fit import truth_in_profile_flange
from ucal.toolframe.plane import fit_plane
from ucal.world import load_world

MODEL = "tx90l"
#: The two orders by their short names (``t`` tool-frame, ``c`` calibrate).
ORDERS = {"t-c": ("tool-frame", "calibrate"), "c-t": ("calibrate", "tool-frame")}
VERIFY_POINTS = 6
#: verify's measured reached TCP should agree with the true one within this (mm).
VERIFY_GOAL_MM = 0.05
#: ``--quick``: the defaults it changes (an option given on the command line still wins).
QUICK = {"worlds": 1, "jobs": 1, "order": "c-t"}


@dataclass(frozen=True)
class Fixture:
    """The block and plate of a cell with a fixture (module docstring)."""

    block_mm: tuple[float, float] = (0.1, 0.05)  # declared, drawn sigma
    block_deg: tuple[float, float] = (0.01, 0.005)  # declared, drawn sigma
    plate_mm: tuple[float, float] = (0.05, 0.05)  # declared sigma, drawn within ±
    plate_deg: float = 0.01  # tilt drawn within


FIXTURE = Fixture()


def draw_world(
    rng: np.random.Generator, profile_path: Path, path: Path, fixture: bool = False
) -> None:
    """A fresh cell's truth (module docstring) as a world file."""
    prof = load_profile(profile_path)
    plane = fit_plane(prof.reflector_points_mm)
    tilt_axis = rng.normal(size=3)
    tilt_axis -= (tilt_axis @ plane.normal) * plane.normal
    tilt_axis /= np.linalg.norm(tilt_axis)
    tilt = np.radians(rng.uniform(0.0, FIXTURE.plate_deg if fixture else 0.3))
    k = np.array(
        [
            [0, -tilt_axis[2], tilt_axis[1]],
            [tilt_axis[2], 0, -tilt_axis[0]],
            [-tilt_axis[1], tilt_axis[0], 0],
        ]
    )
    normal = (np.eye(3) + np.sin(tilt) * k + (1 - np.cos(tilt)) * k @ k) @ plane.normal
    plate_mm = FIXTURE.plate_mm[1] if fixture else 2.0
    point = plane.centroid_mm + rng.uniform(-plate_mm, plate_mm) * plane.normal
    offsets = rng.uniform(-2.0, 2.0, 6)
    tool = np.asarray(prof.tool_position_mm) + rng.uniform(-1.7, 1.7, 3)
    rot = np.asarray(prof.tool_rotation_deg) + rng.uniform(-0.85, 0.85, 3)
    block_mm, block_deg = (FIXTURE.block_mm[1], FIXTURE.block_deg[1]) if fixture else (2, 0.2)
    block = np.asarray(prof.sample_position_mm) + rng.normal(0.0, block_mm, 3)
    block_rot = np.asarray(prof.sample_rotation_deg) + rng.normal(0.0, block_deg, 3)

    def fmt(v):
        return "[" + ", ".join(f"{x:.6f}" for x in v) + "]"

    path.write_text(f"""\
[robot]
joint_offsets_deg = {fmt(offsets)}
[tool]
position_mm = {fmt(tool)}
rotation_deg = {fmt(rot)}
[sample]
position_mm = {fmt(block)}
rotation_deg = {fmt(block_rot)}
[reflector]
point_mm = {fmt(point)}
normal = {fmt(normal)}
edge_radius_mm = {rng.uniform(0.5, 2.0):.3f}
flatness_mm = {rng.uniform(0.0, 0.02):.4f}
[water]
temperature_c = {prof.water_temperature_c + rng.uniform(-3.0, 3.0):.3f}
[transducer]
squint_deg = {rng.uniform(0.5, 1.0):.3f}
squint_azimuth_deg = {rng.uniform(-180.0, 180.0):.1f}
near_field = true
[noise]
tof_ns = 0.5
amplitude = 0.01
seed = {int(rng.integers(1, 2**31))}
""")


@dataclass(frozen=True)
class Arm:
    """``--bent``: the world's arm keys (``compliance.draw_arm``), the tool as the profile
    states it, and whether the profile states a rigid arm."""

    robot: str
    tool: str
    stated_tool: dict
    rigid_profile: bool = False

    @classmethod
    def draw(cls, rng: np.random.Generator, rigid_profile: bool, model: str = MODEL) -> Arm:
        arm, tool_kg, tool_mm = draw_arm(rng, model)
        robot, tool = arm.split("\x00")
        stated = {
            "mass_kg": tool_kg * float(rng.uniform(0.95, 1.05)),
            "centre_of_mass_mm": (np.asarray(tool_mm) + rng.uniform(-5.0, 5.0, 3)).tolist(),
        }
        return cls(robot, tool, stated, rigid_profile)

    def bend(self, world: Path) -> None:
        text = world.read_text().replace("[robot]\n", "[robot]\n" + self.robot, 1)
        world.write_text(text.replace("[tool]\n", "[tool]\n" + self.tool, 1))


def fresh_profile(path: Path, fixture: bool = False, arm: Arm | None = None) -> Path:
    create_profile(path, MODEL)
    keys: dict = {
        "tool": {
            "position_std_mm": 1.5,
            "rotation_std_deg": 1.0,
            **({} if arm is None else arm.stated_tool),
        },
        "reflector": {"points_std_mm": FIXTURE.plate_mm[0] if fixture else 1.2},
    }
    if fixture:
        keys["sample"] = {
            "position_std_mm": FIXTURE.block_mm[0],
            "rotation_std_deg": [FIXTURE.block_deg[0]] * 3,
        }
    if arm is not None and arm.rigid_profile:
        keys["robot"] = {"stiffness_nm_per_rad": [0.0] * 6}
    write_profile(path, keys, "the drawing and the touch")
    return path


def run(cmd: str, profile: Path, world: Path, *extra: str) -> dict:
    r = subprocess.run(
        [
            sys.executable,
            "-m",
            "ucal",
            cmd,
            str(profile),
            "--sim",
            str(world),
            "--yes",
            "--json",
            "-q",
            *extra,
        ],
        capture_output=True,
        text=True,
        check=False,
        stdin=subprocess.DEVNULL,
        timeout=1800,
    )
    try:
        out = json.loads(r.stdout)
    except ValueError:
        out = {"error": r.stderr.strip()[-300:]}
    out["returncode"] = r.returncode
    return out


def commission(
    index: int,
    seed: int,
    fixture: bool = False,
    orders: tuple[str, ...] = tuple(ORDERS),
    bent: bool = False,
    rigid_profile: bool = False,
) -> list[dict]:
    """The orders (names in ``ORDERS``) on one drawn world; per order the outcome, errors and
    z-scores."""
    rng = np.random.default_rng([seed, index])
    # the arm from its own stream: a bent world is the rigid one's, bent
    arm = Arm.draw(np.random.default_rng([seed, index, 36]), rigid_profile) if bent else None
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        draw_world(rng, fresh_profile(d / "template.toml", fixture), d / "world.toml", fixture)
        if arm is not None:
            arm.bend(d / "world.toml")
        for name in orders:
            profile = fresh_profile(d / f"{name}.toml", fixture, arm)
            outs = {c: run(c, profile, d / "world.toml") for c in ORDERS[name]}
            outs["verify"] = run(
                "verify",
                profile,
                d / "world.toml",
                "--points",
                str(VERIFY_POINTS),
                "--plot",
                str(d / f"{name}.png"),
            )
            final = load_profile(profile)
            truth = load_world(d / "world.toml", final)
            rows.append(evaluate(index, name, outs, final, truth))
    return rows


def evaluate(index: int, order: str, outs: dict, final, truth) -> dict:
    tf, cal = outs["tool-frame"], outs["calibrate"]
    z: list[float] = []  # every reported quantity's error / std
    why = [f"{c}: {o['error']}" for c, o in outs.items() if o.get("error")]
    row: dict[str, object] = {
        "world": index,
        "order": order,
        "tool_written": bool(tf.get("written")),
        "cal_written": bool(cal.get("written")),
        "why": why,
        "z": z,
    }
    # tool frame as the last tool-frame run reported it, in the flange frame of the final J6
    if "position_mm" in tf:
        true_tool = truth_in_profile_flange(final, truth)
        beam = np.asarray(tf["beam_direction"])
        err = np.asarray(tf["position_mm"]) - true_tool[:3, 3]
        tb = tangent_basis(beam)
        across = tb @ err
        row["across_mm"] = np.abs(across).tolist()
        row["along_mm"] = float(abs(beam @ err))
        row["beam_deg"] = float(np.degrees(np.arccos(np.clip(beam @ true_tool[:3, 2], -1, 1))))
        z += (across / np.asarray(tf["across_beam_std_mm"])).tolist()
        z.append(float(beam @ err / tf["along_beam"]["std_mm"]))
        tilt = np.degrees(tb @ true_tool[:3, 2])
        z += (tilt / tf["beam_std_deg"]).tolist()
        row["tool_std_across_mm"] = max(tf["across_beam_std_mm"])
    if "joint_offsets_deg" in cal:
        est = np.asarray(cal["joint_offsets_deg"], float)
        want = np.asarray(truth.joint_offsets_deg, float)
        if cal.get("load_posture_deg") is not None:  # what they hold: the load posture's sag
            want = want + SimulatedCell(truth).sag_deg(
                np.asarray(cal["load_posture_deg"]), np.ones(6)
            )
        err = est - want
        std = [np.nan if s is None else s for s in cal["std_deg"]]
        row["offset_err_deg"] = [
            float(e) if np.isfinite(s) else None for e, s in zip(err, std, strict=True)
        ]
        z += [float(e / s) for e, s in zip(err, std, strict=True) if np.isfinite(s)]
    ver = outs["verify"]
    if "truth" in ver:
        nominal = np.asarray(ver["nominal_mm"])
        true_after = np.abs(np.asarray(ver["truth"]["reached_mm"]["after"]) - nominal)
        row["verify"] = {
            "after_max_mm": float(np.max(ver["after_mm"]["max"])),
            "true_after_max_mm": float(np.max(true_after)),
            "agreement_mm": float(np.max(ver["truth"]["after_error_max_mm"])),
            "tool_check_mm": ver["tool_check"]["offset_mm"][:2],
            "misfit_mm": ver["tool_check"]["misfit_mm"],
            "marginal": bool(ver["marginal"]),
            "passed": bool(ver["passed"]),
            "should_pass": bool(np.max(true_after) <= ver["tolerance_mm"]),
        }
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--worlds", type=int, default=20)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--first", type=int, default=0, help="index of the first world")
    ap.add_argument(
        "--out", type=Path, help="append every row as a JSON line as soon as its world ends"
    )
    ap.add_argument("--summary", type=Path, help="only print the summary of rows saved by --out")
    ap.add_argument(
        "--fixture",
        action="store_true",
        help="a fixtured block, a plate touched with a calibrated robot (module docstring)",
    )
    ap.add_argument("--bent", action="store_true", help="an arm that bends (module docstring)")
    ap.add_argument(
        "--rigid-profile",
        action="store_true",
        help="with --bent: the profile states a rigid arm (the solvers as they were)",
    )
    ap.add_argument(
        "--order",
        choices=("both", *ORDERS),
        default="both",
        help="t-c: tool-frame then calibrate, c-t: the reverse",
    )
    ap.add_argument(
        "--quick",
        action="store_true",
        help="--worlds 1 --jobs 1 --order c-t: the same code path in seconds",
    )
    args = parse_args(ap, QUICK)
    orders = tuple(ORDERS) if args.order == "both" else (args.order,)
    if args.summary:
        rows_saved = [json.loads(line) for line in args.summary.read_text().splitlines()]
        print(
            f"{len({r['world'] for r in rows_saved})} fresh cells × "
            f"{len({r['order'] for r in rows_saved})} orders (saved)"
        )
        summarize(rows_saved)
        return
    t0 = time.monotonic()
    rows: list[dict] = []
    with concurrent.futures.ProcessPoolExecutor(args.jobs) as pool:
        indices = range(args.first, args.first + args.worlds)
        seeds, fixtures = [args.seed] * args.worlds, [args.fixture] * args.worlds
        one = functools.partial(
            commission, orders=orders, bent=args.bent, rigid_profile=args.rigid_profile
        )
        for res in pool.map(one, indices, seeds, fixtures):
            rows += res
            if args.out:
                with args.out.open("a") as f:
                    f.write("".join(json.dumps(r) + "\n" for r in res))
            for r in res:
                print(
                    f"world {r['world']:2d} {r['order']}: tool "
                    f"{'written' if r['tool_written'] else 'not written'}, offsets "
                    f"{'written' if r['cal_written'] else 'not written'}"
                    + (
                        f"; across {np.round(r.get('across_mm', []), 4).tolist()} mm, along "
                        f"{r.get('along_mm', float('nan')):.3f} mm, beam "
                        f"{r.get('beam_deg', float('nan')):.4f} deg"
                        if "across_mm" in r
                        else ""
                    )
                    + (
                        f"; verify after {r['verify']['after_max_mm']:.3f} mm (true "
                        f"{r['verify']['true_after_max_mm']:.3f}, measured − true "
                        f"{r['verify']['agreement_mm']:.4f} mm), "
                        f"{'passed' if r['verify']['passed'] else 'failed'}"
                        if "verify" in r
                        else ""
                    )
                    + "".join(f"\n    {w}" for w in r["why"]),
                    flush=True,
                )
    print(f"\n{args.worlds} fresh cells × {len(orders)} orders, {time.monotonic() - t0:.0f} s")
    summarize(rows)


def summarize(rows: list[dict]) -> None:
    """Print the per-order summary of the rows (module docstring)."""
    for order in ORDERS:
        rs = [r for r in rows if r["order"] == order]
        if not rs:
            continue
        both = sum(r["tool_written"] and r["cal_written"] for r in rs)
        print(
            f"\norder {'tool-frame → calibrate' if order == 't-c' else 'calibrate → tool-frame'}"
            f": both written {both}/{len(rs)}, tool written "
            f"{sum(r['tool_written'] for r in rs)}, offsets written "
            f"{sum(r['cal_written'] for r in rs)}"
        )
        tool = [r for r in rs if r["tool_written"] and "across_mm" in r]
        if tool:
            across = np.array([r["across_mm"] for r in tool]).ravel()
            print(
                f"  tool across the beam (written): median {np.median(across):.4f}, max "
                f"{np.max(across):.4f} mm; along: median "
                f"{np.median([r['along_mm'] for r in tool]):.3f}, max "
                f"{np.max([r['along_mm'] for r in tool]):.3f} mm; beam: median "
                f"{np.median([r['beam_deg'] for r in tool]):.4f}, max "
                f"{np.max([r['beam_deg'] for r in tool]):.4f} deg"
            )
        offs = [r["offset_err_deg"] for r in rs if r["cal_written"] and "offset_err_deg" in r]
        for j in range(6):
            e = [abs(o[j]) for o in offs if o[j] is not None]
            if e:
                print(
                    f"  J{j + 1} |error| (written, reported): median {np.median(e):.4f}, max "
                    f"{np.max(e):.4f} deg over {len(e)}"
                )
        ver = [r["verify"] for r in rs if "verify" in r]
        if ver:
            agree = np.array([v["agreement_mm"] for v in ver])
            both = [r["verify"]["agreement_mm"] for r in rs if "verify" in r and r["tool_written"]]
            print(
                f"  verify ({len(ver)} runs): after figure minus the true reached TCP, max over "
                f"the points: median {np.median(agree):.4f}, max {np.max(agree):.4f} mm, "
                f"within {VERIFY_GOAL_MM:g} mm in {np.sum(agree <= VERIFY_GOAL_MM)}"
                + (f" (tool written: max {np.max(both):.4f} mm)" if both else "")
                + f"; passed {sum(v['passed'] for v in ver)}, true error within the "
                f"tolerance {sum(v['should_pass'] for v in ver)}, verdicts agree "
                f"{sum(v['passed'] == v['should_pass'] for v in ver)}/{len(ver)}"
            )
            misfit = [v["misfit_mm"] for v in ver if "misfit_mm" in v]
            if misfit:
                wrong = [v for v in ver if v["passed"] != v["should_pass"]]
                print(
                    f"  verify's tool check misfit: median {np.median(misfit):.4f}, max "
                    f"{np.max(misfit):.4f} mm; marginal verdicts "
                    f"{sum(v['marginal'] for v in ver)}, of the verdicts the truth disagrees "
                    f"with {sum(v['marginal'] for v in wrong)}/{len(wrong)} marginal"
                )
        z = np.abs(np.concatenate([r["z"] for r in rs])) if rs else np.zeros(0)
        if len(z):
            print(
                f"  coverage of every reported std: {100 * np.mean(z <= 3):.1f} % within 3σ, "
                f"{100 * np.mean(z > 4):.1f} % beyond 4σ (of {len(z)}; max |z| {z.max():.2f})"
            )


if __name__ == "__main__":
    main()
