"""``ucal calibrate``: joint zero offsets (paper 000) → ``[calibration]`` in the profile."""

from __future__ import annotations

import contextlib
import datetime as dt
import logging
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING

import click
import numpy as np

from ucal import __version__

if TYPE_CHECKING:
    from ucal.calibration.exact import OffsetSolution
    from ucal.calibration.fit import FitQuality
from ucal.cli.options import (
    CellChoice,
    cell_from_options,
    cell_options_typed,
    check_output,
    confirm_motion,
    controller_option,
    dry_run_option,
    emit_json,
    info,
    json_option,
    pulser_option,
    sim_option,
    yes_option,
)
from ucal.cli.progress import StepProgress

log = logging.getLogger(__name__)

#: A finished run whose observable offsets are less certain than this is out of tolerance.
TOLERANCE_STD_DEG = 0.02


@click.command(
    "calibrate",
    epilog="""\b
Examples:
  ucal calibrate cell.toml --sim --yes
  ucal calibrate cell.toml --sim world.toml --method paper --json --yes
  ucal calibrate cell.toml --controller tcp://10.0.0.5:11000 --pulser modbus-tcp://10.0.0.6:502
  ucal calibrate cell.toml --sim --yes --level full
  ucal calibrate cell.toml --sim --yes --record run.jsonl
  ucal calibrate cell.toml --replay run.jsonl --method paper --json
""",
)
@click.argument("profile_path", metavar="PROFILE", type=click.Path(dir_okay=False, path_type=Path))
@sim_option
@controller_option
@pulser_option
@click.option(
    "--method",
    type=click.Choice(["exact", "paper"]),
    default="exact",
    show_default=True,
    help="exact: nonlinear least squares over the full kinematics; paper: paper 000's "
    "first-order equations 11-21.",
)
@click.option(
    "--beam",
    type=click.Choice(["auto", "fit", "fixed"]),
    default="auto",
    show_default=True,
    help="auto/fit: the beam direction in the flange frame is an unknown with the "
    "profile's tool tolerance as prior; fixed: take the profile's tool as exact.",
)
@click.option(
    "--level",
    type=click.Choice(["offsets", "full"]),
    default="offsets",
    show_default=True,
    help="offsets: the six joint offsets; full: the identifiable kinematic parameters "
    "as well, from many postures, written as [calibration] dh.",
)
@click.option(
    "--postures",
    type=click.IntRange(3, 200),
    default=None,
    help="--level full: at most N postures (default: as many as the D-optimal "
    "criterion finds worth measuring).",
)
@click.option(
    "--force",
    is_flag=True,
    help="Write the result even when the fit is a misfit (the verdict is recorded in "
    "the profile history).",
)
@click.option(
    "--record",
    "record_path",
    type=click.Path(dir_okay=False, path_type=Path),
    help="Write every device call of the run (joint readings, moves, gain, amplitude, "
    "TOF, times), the plan and the profile to FILE as JSON lines, as it goes.",
)
@click.option(
    "--replay",
    "replay_path",
    type=click.Path(dir_okay=False, path_type=Path),
    help="Solve a recorded run again (any --method) without moving anything; writes nothing.",
)
@yes_option
@dry_run_option
@json_option
def cli(
    profile_path: Path,
    sim_world: str | None,
    controller_url: str | None,
    pulser_url: str | None,
    method: str,
    beam: str,
    level: str,
    postures: int | None,
    force: bool,
    record_path: Path | None,
    replay_path: Path | None,
    yes: bool,
    dry_run: bool,
    as_json: bool,
) -> None:
    """Find the six joint zero offsets with the ultrasonic transducer and write them.

    The beam is brought normal to the three faces of the calibration block in three arm
    configurations (the calibration pose, joint 3 stepped, joint 2 stepped); the peak-echo
    postures and time-of-flight distances give the offsets (actual = reading + offset).
    Every target is checked before the first motion. On any fault or Ctrl-C the robot is told
    to stop and the profile is left byte-for-byte unchanged.
    """
    from ucal.models import DEFAULT_MODEL
    from ucal.profile import (
        check_writable,
        create_profile,
        default_profile_text,
        load_profile,
        profile_lock,
    )

    if level == "full" and method != "exact":
        from ucal.errors import InputError

        raise InputError(
            "--level full identifies the kinematic model by least squares: it "
            "takes --method exact only"
        )
    if replay_path is not None:
        if cell_options_typed(click.get_current_context()) or record_path is not None:
            from ucal.errors import InputError

            raise InputError(
                "--replay solves a recorded run: it takes no --sim, --controller, "
                "--pulser or --record"
            )
        finish(replay(profile_path, replay_path, method, beam, as_json), as_json)
        return
    cell = cell_from_options(sim_world, controller_url, pulser_url, yes=yes, dry_run=dry_run)
    if record_path is not None:
        check_output(record_path)
    sim_world, controller_url, pulser_url = cell.sim_world, cell.controller_url, cell.pulser_url
    created = False
    if not profile_path.exists() and sim_world is not None:
        if dry_run:
            scratch = tempfile.TemporaryDirectory(prefix="ucal-")  # removed when the run ends
            tmp = Path(scratch.name) / profile_path.name
            tmp.write_text(default_profile_text(DEFAULT_MODEL), encoding="utf-8")
            profile = load_profile(tmp)
        else:
            create_profile(profile_path, DEFAULT_MODEL)
            created = True
            info(f"created {profile_path} for the default model {DEFAULT_MODEL}")
            profile = load_profile(profile_path)
    else:
        profile = load_profile(profile_path)
    # One run per profile, and room to write the result, checked before the first motion.
    with contextlib.nullcontext() if dry_run else profile_lock(profile_path):
        if not dry_run:
            check_writable(profile_path)
        if level == "full":
            from ucal.cli import calibrate_full

            result = calibrate_full.run(
                profile,
                profile_path,
                sim_world,
                controller_url,
                pulser_url,
                beam,
                yes,
                dry_run,
                as_json,
                force,
                record_path,
                max_postures=postures,
            )
        else:
            result = run(
                profile,
                profile_path,
                sim_world,
                controller_url,
                pulser_url,
                method,
                beam,
                yes,
                dry_run,
                as_json,
                force,
                record_path,
            )
    result["created"] = created
    finish(result, as_json)


def finish(result: dict, as_json: bool) -> None:
    """Print the JSON result; out of tolerance, exit 1 (with ``--json`` the CLI prints the
    result with the error fields)."""
    message = result.pop("_message", None)
    if result["out_of_tolerance"]:
        from ucal.errors import OutOfToleranceError

        raise OutOfToleranceError(message, result)
    if as_json:
        emit_json(result)


def replay(profile_path: Path, record_path: Path, method: str, beam: str, as_json: bool) -> dict:
    """Solve a recorded run again: its profile, plan and device traffic; nothing moves."""
    import tomlkit

    from ucal.profile import profile_from_data
    from ucal.record import read_record

    record = read_record(record_path)
    profile = profile_from_data(
        tomlkit.parse(record.profile_text), f"{record_path} (recorded profile)"
    )
    if record.options.get("level") == "full":
        from ucal.cli import calibrate_full

        result = calibrate_full.run(
            profile,
            profile_path,
            None,
            None,
            None,
            beam,
            True,
            True,
            as_json,
            record=record,
            max_postures=record.options.get("max_postures"),
        )
    else:
        result = run(
            profile,
            profile_path,
            None,
            None,
            None,
            method,
            beam,
            True,
            True,
            as_json,
            record=record,
        )
    result["replayed"] = str(record_path)
    if record.result is None:
        log.warning("%s has no end line: the recorded run was cut off", record_path)
    return result


def run(
    profile,
    profile_path: Path,
    sim_world,
    controller_url,
    pulser_url,
    method: str,
    beam: str,
    yes: bool,
    dry_run: bool,
    as_json: bool,
    force: bool = False,
    record_path: Path | None = None,
    record=None,
) -> dict:
    """Plan, confirm, measure, solve, write; returns the JSON result of SPEC.md (+ extras).

    ``record_path``: record the run's device traffic there (``ucal.record``); ``record``: a
    recorded run to replay instead of opening a cell (nothing moves, nothing is written).
    """
    from rich.console import Console

    from ucal.calibration.sequence import plan_calibration

    console = Console()  # the result on stdout; the plan and progress go to stderr
    plan = plan_calibration(profile)
    if record is None:
        confirm_motion(
            yes, plan_summary(plan, profile), CellChoice(sim_world, controller_url, pulser_url)
        )
    return in_session(
        profile,
        sim_world,
        controller_url,
        pulser_url,
        record_path,
        record,
        {"method": method, "beam": beam, "level": "offsets"},
        [
            {
                "label": t.label,
                "joints_deg": t.joints_deg.tolist(),
                "water_path_mm": t.water_path_mm,
            }
            for t in plan.targets
        ],
        lambda cell: _measure_and_solve(
            profile,
            profile_path,
            plan,
            cell,
            console,
            method,
            beam,
            dry_run or record is not None,
            as_json,
            force,
        ),
    )


def in_session(
    profile,
    sim_world,
    controller_url,
    pulser_url,
    record_path: Path | None,
    record,
    options: dict,
    plan_rows: list[dict],
    body,
) -> dict:
    """Open the cell (or the replayed one), record its traffic if asked, run ``body(cell)`` and
    return its result (also the record's end line)."""
    from ucal.record import Recorder, sha256_text
    from ucal.session import open_cell, replay_cell

    recorder = None
    if record_path is not None:
        text = profile.path.read_text(encoding="utf-8")
        recorder = Recorder(record_path).open(
            {
                "command": "calibrate",
                "ucal": __version__,
                "profile_path": str(profile.path),
                "profile_sha256": sha256_text(text),
                "profile_text": text,
                "cell": "simulated cell" if sim_world is not None else controller_url,
                "options": options,
                "plan": plan_rows,
            }
        )
    with contextlib.ExitStack() as stack:
        if recorder is not None:
            stack.enter_context(recorder)
        cell = stack.enter_context(
            replay_cell(profile, record)
            if record is not None
            else open_cell(profile, sim_world, controller_url, pulser_url, recorder)
        )
        result = body(cell)
        if recorder is not None:
            recorder.end({k: v for k, v in result.items() if not k.startswith("_")})
    return result


def measure_with_progress(cell, what: str, measure):
    """``measure(report)`` with one progress line per step (``StepProgress``), after checking
    the controller's status."""
    from ucal.session import check_status

    check_status(cell.rig)
    with StepProgress("calibrate") as progress:

        def report(label: str, i: int, n: int) -> None:
            counters = cell.rig.counters
            progress.step(
                f"{what} {label}" if label != "done" else "solving",
                i,
                n,
                f"{counters.moves} moves, {counters.reads} reads",
            )

        return measure(report)


def _measure_and_solve(
    profile,
    profile_path: Path,
    plan,
    cell,
    console,
    method: str,
    beam: str,
    dry_run: bool,
    as_json: bool,
    force: bool,
) -> dict:
    """Measure the plan on an open cell, solve, judge and write; the JSON result."""
    from ucal.calibration.sequence import run_calibration, solve
    from ucal.profile import write_profile

    measurements = measure_with_progress(
        cell, "face", lambda report: run_calibration(profile, plan, cell.rig, progress=report)
    )
    truth = cell.truth
    duration_s = cell.elapsed_s
    exact, paper = solve(profile, measurements, beam)
    chosen = exact if method == "exact" else paper
    if chosen is None:
        from ucal.errors import UcalError

        raise UcalError("the paper's method could not be applied to these measurements")
    fit = exact.fit
    assert fit is not None
    verdict = judge(chosen, fit)
    write = not dry_run and (verdict.ok or force)
    written = False
    if write:
        reason = f"calibrate --method {method}: fit {fit.verdict} (χ²ᵣ {fit.chi2_reduced:.3g})"
        if not verdict.ok:
            reason += f", written with --force: {verdict.message}"
        write_profile(
            profile_path,
            {
                "calibration": {
                    **written_keys(chosen, exact.sound_speed_m_s, fit),
                    "condition_number": round(float(chosen.condition_number), 3),
                }
            },
            reason=reason,
        )
        written = True
    result = {
        **result_fields(
            chosen, "offsets", measurements, duration_s, profile_path, written, exact, fit
        ),
        "condition_number": chosen.condition_number,
        "joint_steps_deg": {"arm": plan.step_deg, "azimuth": plan.azimuth_step_deg},
        "out_of_tolerance": not verdict.ok,
        "_message": verdict.message if not verdict.ok else None,
    }
    if truth is not None:
        result["truth_offsets_deg"] = truth.joint_offsets_deg
    if not as_json:
        show_result(console, chosen, exact, paper, truth, result)
    return result


def written_keys(chosen, sound_speed_m_s: float, fit: FitQuality) -> dict:
    """The ``[calibration]`` keys every level writes: offsets, their std, the fit."""
    return {
        "joint_offsets_deg": [round(float(v), 6) for v in chosen.offsets_deg],
        "unobservable_joints": list(chosen.unobservable_joints),
        "method": chosen.method,
        "std_deg": [round(float(v), 6) if np.isfinite(v) else -1.0 for v in chosen.std_deg],
        "sound_speed_m_s": round(float(sound_speed_m_s), 3),
        "fit_verdict": fit.verdict,
        "chi2_reduced": round(float(fit.chi2_reduced), 4),
        "date": dt.datetime.now(dt.UTC).isoformat(timespec="seconds"),
    }


def result_fields(
    chosen,
    level: str,
    measurements,
    duration_s: float,
    profile_path: Path,
    written: bool,
    sound,
    fit: FitQuality,
) -> dict:
    """The fields of SPEC.md's ``calibrate --json`` object every level reports (``sound``: the
    solution that fitted the sound speed)."""
    return {
        "joint_offsets_deg": chosen.offsets_deg,
        "std_deg": [float(v) if np.isfinite(v) else None for v in chosen.std_deg],
        "unobservable_joints": list(chosen.unobservable_joints),
        "unobservable_reasons": {str(j): r for j, r in chosen.unobservable_reasons.items()},
        "method": chosen.method,
        "level": level,
        "moves": measurements.moves,
        "pulser_reads": measurements.reads,
        # time the run took on the cell: simulated time on the simulated cell (what a real
        # cell would take over Modbus TCP)
        "duration_s": duration_s,
        "profile": str(profile_path),
        "written": written,
        "sound_speed_m_s": sound.sound_speed_m_s,
        "sound_speed_std_m_s": sound.sound_speed_std_m_s,
        "fit": fit.to_json(),
        "residuals": [
            {"label": r.label, "tilt": list(r.tilt), "distance": r.distance} for r in fit.residuals
        ],
    }


class Verdict:
    """Whether a solution may be written, and the one-line message when not."""

    def __init__(self, ok: bool, misfit_only: bool, message: str):
        self.ok = ok
        self.misfit_only = misfit_only
        self.message = message


def judge(chosen: OffsetSolution, fit: FitQuality) -> Verdict:
    """Judge a solution: a misfit, or an observable offset less certain than the tolerance.

    A misfit names the worst measurement and the likely cause; a std above
    ``TOLERANCE_STD_DEG`` names the joint and what its uncertainty comes from (noise, or the
    method's truncation for the paper method).
    """
    from ucal.calibration.fit import PRIOR_MEANING

    observable = [j for j in range(6) if j + 1 not in chosen.unobservable_joints]
    std = chosen.std_deg
    loose = [j for j in observable if not np.isfinite(std[j]) or std[j] > TOLERANCE_STD_DEG]
    if fit.verdict == "misfit":
        msg = (
            f"calibration misfit: the measurements disagree with the model (χ²ᵣ "
            f"{fit.chi2_reduced:.3g} on {fit.dof} degrees of freedom; worst: {fit.worst}); "
            f"likely cause: {fit.cause}; the profile was not written (--force writes it)"
        )
        return Verdict(False, not loose, msg)
    if loose:
        j = max(loose, key=lambda k: std[k] if np.isfinite(std[k]) else np.inf)
        why = ""
        trunc = chosen.extra.get("truncation_deg")
        cell = chosen.extra.get("cell_fit")
        shares = cell.variance_share.get(f"J{j + 1}", {}) if cell is not None else {}
        source = max(shares, key=shares.get) if shares else "data"
        if trunc is not None and trunc[j] > 0.5 * std[j]:
            why = (
                f", mostly the paper method's first-order truncation error ({trunc[j]:.3g} "
                "deg, about half the joint step); use --method exact"
            )
        elif source != "data":
            why = (
                f", mostly from {PRIOR_MEANING.get(source, source)} "
                f"({100 * shares[source]:.0f} % of its variance)"
            )
        else:
            worst = max(fit.residuals, key=lambda r: r.norm).label if fit.residuals else "?"
            why = (
                f": the measurements' own scatter ({100 * shares.get('data', 1.0):.0f} % of "
                f"its variance; the peak postures are uncertain, worst fitted {worst}); check "
                "the water, the gain and the transducer, or measure again"
            )
        return Verdict(
            False,
            False,
            f"calibration out of tolerance: J{j + 1}'s std {std[j]:.3g} deg exceeds "
            f"{TOLERANCE_STD_DEG} deg{why}; the profile was not written",
        )
    return Verdict(True, False, "")


def plan_summary(plan, profile) -> str:
    """The plan as text for the confirmation prompt (stderr)."""
    from ucal.acoustics import sound_speed_m_s
    from ucal.calibration.fit import prior_from_profile
    from ucal.calibration.model import FACE_NAMES

    temp = profile.water_temperature_c
    c_std = prior_from_profile(profile).sound_speed_std_m_s
    azimuth = (
        f", joint 1 by ±{plan.azimuth_step_deg:g} deg (second azimuth)"
        if plan.azimuth_step_deg
        else ", no room for a second J1 azimuth"
    )
    lines = [
        (
            f"Calibration plan for {profile.model.name}: {len(plan.targets)} normal-incidence "
            f"measurements; joints 2 and 3 stepped by ±{plan.step_deg:g} deg{azimuth} (the sign is "
            "chosen on the way for clearance)"
        ),
        (
            f"Water {temp:g} ± {profile.water_temperature_std_c:g} °C: sound speed "
            f"{sound_speed_m_s(temp):.2f} ± {c_std:.2f} m/s (Marczak), fitted with the offsets; "
            f"transducer {profile.frequency_mhz:g} MHz, {profile.element_diameter_mm:g} mm"
        ),
    ]
    if plan.sound_speed_gain_deg_per_m_s is not None:
        gain = plan.sound_speed_gain_deg_per_m_s
        noise = plan.distance_noise_gain_deg_per_um
        j = int(np.argmax(gain[1:5])) + 1
        k = int(np.argmax(noise[1:5])) + 1
        per_c = c_std / max(profile.water_temperature_std_c, 1e-9)  # m/s per °C
        lines.append(
            f"Amplification of this plan: 1 °C of water temperature ({per_c:.2f} m/s), if not "
            f"fitted, would move J{j + 1} by {gain[j] * per_c:.3f} deg; 1 µm of water-path "
            f"noise gives J{k + 1} a std of {noise[k]:.4f} deg"
        )
    lines.append("  target      J1       J2       J3       J4       J5       J6    water path")
    for t in plan.targets:
        lines.append(
            f"  {t.config:>4}/{FACE_NAMES[t.face]:<3}"
            + "".join(f"{v:9.2f}" for v in t.joints_deg)
            + f"   {t.water_path_mm:6.1f} mm"
        )
    from ucal.timing import estimate_run

    lines.append(
        estimate_run(
            [t.joints_deg for t in plan.targets], plan.pose_deg, profile.procedure.speed
        ).describe()
    )
    lines.append(
        "The wrist searches around each target for the echo (joints 4-6 only); every "
        "move ends approaching from below on each joint (backlash)."
    )
    return "\n".join(lines)


def show_result(console, chosen, exact, paper, truth, result) -> None:
    """The result as tables on stdout (without --json): offsets with σ, fit quality, residual
    per measurement."""
    from rich.markup import escape
    from rich.table import Table

    table = Table(title=f"Joint offsets ({chosen.method} method)")
    table.add_column("joint")
    table.add_column("offset (deg)", justify="right")
    table.add_column("σ (deg)", justify="right")
    if paper is not None and chosen is exact:
        table.add_column("paper method", justify="right")
        table.add_column("paper σ", justify="right")
    if truth is not None:
        table.add_column("simulator truth", justify="right")
        table.add_column("error", justify="right")
    for j in range(6):
        unobs = j + 1 in chosen.unobservable_joints
        row = [
            f"J{j + 1}",
            f"{chosen.offsets_deg[j]:+.4f}" + (" (kept)" if unobs else ""),
            "unobservable" if unobs else f"{chosen.std_deg[j]:.4f}",
        ]
        if paper is not None and chosen is exact:
            row.append(f"{paper.offsets_deg[j]:+.4f}")
            row.append("—" if not np.isfinite(paper.std_deg[j]) else f"{paper.std_deg[j]:.4f}")
        if truth is not None:
            row.append(f"{truth.joint_offsets_deg[j]:+.4f}")
            row.append(
                "—" if unobs else f"{chosen.offsets_deg[j] - truth.joint_offsets_deg[j]:+.4f}"
            )
        table.add_row(*row)
    console.print(table)
    show_fit(console, exact.fit)
    console.print(
        f"sound speed {result['sound_speed_m_s']:.2f} ± "
        f"{result['sound_speed_std_m_s']:.2f} m/s (fitted); condition number "
        f"{chosen.condition_number:.1f}; {result['moves']} moves, "
        f"{result['pulser_reads']} pulser reads; profile "
        f"{'written' if result['written'] else 'not written'}: {result['profile']}"
    )
    for j, why in sorted(chosen.unobservable_reasons.items()):
        console.print(escape(f"J{j} unobservable, kept at its profile value: {why}"))


def show_fit(console, fit) -> None:
    """The fit's normalised residual per measurement, its verdict and the likely cause."""
    from rich.markup import escape
    from rich.table import Table

    res = Table(title="Fit: normalised residual per measurement (residual / its σ)")
    for col in ("measurement", "tilt a", "tilt b", "distance"):
        res.add_column(col, justify="right")
    for r in fit.residuals:
        res.add_row(r.label, f"{r.tilt[0]:+.2f}", f"{r.tilt[1]:+.2f}", f"{r.distance:+.2f}")
    console.print(res)
    console.print(
        escape(
            f"fit {fit.verdict}: χ²ᵣ {fit.chi2_reduced:.3g} on {fit.dof} degrees of "
            f"freedom; rms tilt {fit.rms_tilt_deg:.2e} deg, rms distance "
            f"{fit.rms_distance_mm:.2e} mm; worst {fit.worst}"
        )
    )
    if fit.cause:
        console.print(escape(f"likely cause: {fit.cause}"))
