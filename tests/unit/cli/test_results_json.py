"""Each moving command prints its typed result: the ``--json`` object is the result's
``to_json`` (with how the run went: the echo timing, ``created``), value for value, and the
tables show the same figures. The job's run is replaced by a result built here."""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import ucal.cli.calibrate as calibrate_cli
import ucal.cli.procedure as cli_procedure
from ucal.calibration.budget import TcpBudget
from ucal.calibration.exact import OffsetSolution
from ucal.calibration.procedure import FullCalibration, OffsetsCalibration
from ucal.calibration.result import FullResult, FullSolved, OffsetsResult, OffsetsSolved, Verdict
from ucal.calibration.weak import WeakJoint
from ucal.cell import CellProfile
from ucal.check.judge import Quantity
from ucal.check.measure import CheckRun
from ucal.check.procedure import CheckJob
from ucal.check.result import CheckFindings, CheckResult
from ucal.cli.options import _to_jsonable
from ucal.model.fit import prior_from_profile
from ucal.model.kinematic import FullSolution, Identifiability, IdentifiedParameter, full_table
from ucal.model.least_squares import CellFit
from ucal.model.postures import FullPlan
from ucal.model.quality import FitQuality, ResidualRow
from ucal.model.stiffness import JointStiffness
from ucal.procedure import CommandResult, Outcome, RunFacts, RunOptions
from ucal.profile import load_profile
from ucal.timing import DurationEstimate
from ucal.toolframe.procedure import ToolFrameCalibration
from ucal.toolframe.result import SimulatedError, ToolFrameResult
from ucal.toolframe.solve import ToolFrameRun
from ucal.verify.inputs import BeforeProfile, SoundSpeed, VerifyGauge
from ucal.verify.measure import PointResult, VerifyResult
from ucal.verify.plan import plan_verify
from ucal.verify.procedure import VerifyJob
from ucal.verify.region import RegionJob
from ucal.verify.result import RegionCheck, RegionResult, Verification, VerifySolved

RunMain = Callable[[list[str]], tuple[int, str, str]]
FIT = FitQuality(
    0.509,
    36,
    6.34e-4,
    7.84e-7,
    "j3/XY",
    "ok",
    residuals=(ResidualRow("base/XY", (1.55, -0.35), -0.01),),
)
ECHO_TIMING: dict[str, object] = {"timing": "gate", "reference_echo": None}


#: Paper 000's calibration pose: the posture whose gravity load the full level's offsets hold.
LOAD_POSTURE_DEG = [30.53, 31.15, 109.49, 0.0, 39.36, 30.54]


@dataclass
class Case:
    """A command's arguments, the job it makes, the outcome its run gives, what the JSON and
    the tables show of it."""

    args: list[str]
    job: type
    outcome: Outcome[CommandResult]
    fields: dict[str, Any]  # fields of the printed JSON, as the result says them
    shown: list[str]  # lines (or parts) of the tables


def outcome(command: str, result: CommandResult, ok: bool = True) -> Outcome[CommandResult]:
    written = bool(result.run.written)  # type: ignore[attr-defined]
    return Outcome(command, result, written, not ok, "", echo_timing=dict(ECHO_TIMING))


def offsets_case(path: Path, cell: CellProfile) -> Case:
    exact = OffsetSolution(
        np.array([0.8011, -1.1982, 1.4988, -2.0028, 1.1009, 0.0]),
        np.array([0.5, 0.0062, 0.0046, 0.0046, 0.035, np.nan]),
        (5, 6),
        100.8,
        "exact",
        fit=FIT,
        sound_speed_m_s=1482.38,
        sound_speed_std_m_s=0.4,
        unobservable_reasons={5: "measured too weakly", 6: "on the beam's axis"},
    )
    weak = {5: WeakJoint(5, 1.1009, 0.035, "measured too weakly")}
    budget = TcpBudget(0.208, 0.387, 25, {"dh5_d_mm": 0.254, "dh5_a_mm": 0.238})
    solved = OffsetsSolved(exact, None, exact, FIT, Verdict(True, False, ""), weak, budget)
    steps: dict[str, float | None] = {"arm": 5.0, "azimuth": 8.0}
    result = OffsetsResult(RunFacts(path, True, 176, 1212, 321.5), None, solved, steps)
    return Case(
        [],
        OffsetsCalibration,
        outcome("calibrate", result),
        {
            "joint_offsets_deg": [0.8011, -1.1982, 1.4988, -2.0028, 1.1009, 0.0],
            "std_deg": [0.5, 0.0062, 0.0046, 0.0046, 0.035, None],
            "weak_joints": {
                "5": {"offset_deg": 1.1009, "std_deg": 0.035, "reason": weak[5].reason}
            },
            "joint_steps_deg": {"arm": 5.0, "azimuth": 8.0},
            "unidentified_tcp_mm": {
                "mean": 0.208,
                "max": 0.387,
                "postures": 25,
                "by_quantity": {"dh5_d_mm": 0.254, "dh5_a_mm": 0.238},
            },
            "level": "offsets",
            "moves": 176,
            "written": True,
            "created": False,
            "timing": "gate",
        },
        [
            "│ J2    │        -1.1982 │       0.0062 │",
            "sound speed 1482.38 ± 0.40 m/s (fitted); condition number 100.8; 176 moves, "
            "1212 pulser reads; profile written",
            "J5 measured at +1.1009 ± 0.035 deg: measured too weakly",
            "J6 unobservable, kept at its profile value: on the beam's axis",
            "0.208 mm mean, 0.387 mm max",
        ],
    )


def full_case(path: Path, cell: CellProfile) -> Case:
    table = full_table(prior_from_profile(cell))
    n_free = int(np.count_nonzero(table.free))
    fit = CellFit(table, table.values, np.eye(n_free), table.prior_stds, FIT, {}, 12.0)
    fit = dataclasses.replace(fit, load_posture_deg=np.array(LOAD_POSTURE_DEG))
    sol = FullSolution(
        fit,
        Identifiability(28, 40, ("dh2_a_mm",), {"dh1_d_mm": "the block's height"}, ()),
        np.array([0.8, -1.2, 1.5, -2.0, 1.1, 0.0]),
        np.array([0.5, 0.01, 0.008, 0.0026, 0.0007, np.nan]),
        {6: "on the beam's axis"},
        cell.model,
        {"dh2_a_mm": IdentifiedParameter(650.012, 0.004, 650.0, "identified")},
        stiffness=tuple(
            JointStiffness(j, 3.5, 0.1, 3.9, 2.5, 4.8, "identified")
            if j == 2
            else JointStiffness(j, 2.0, None, 2.0, 1.0, None, "not determined", "its torque")
            for j in range(1, 7)
        ),
    )
    solved = FullSolved(sol, FIT, Verdict(True, False, ""))
    plan = FullPlan((), 412, 0.8, 31.5, (20.0, 40.0))
    result = FullResult(RunFacts(path, False, 180, 1602, 600.0), None, solved, plan)
    return Case(
        ["--level", "full"],
        FullCalibration,
        outcome("calibrate", result),
        {
            "level": "full",
            "identification": {
                "rank": 28,
                "unknowns": 40,
                "parameters": {
                    "dh2_a_mm": {
                        "value": 650.012,
                        "std": 0.004,
                        "nominal": 650.0,
                        "status": "identified",
                    }
                },
                "not_identifiable": {"dh1_d_mm": "the block's height"},
                "prior_dominated": [],
                "scale": "",
                "length_standard": None,
                "stiffness": [s.to_json() for s in sol.stiffness],
            },
            "stiffness_nm_per_rad": [None, 1e6 / 3.5, None, None, None, None],
            "stiffness_std_nm_per_rad": [None, 0.048e6 / 3.5, None, None, None, None],
            "stiffness_status": ["not determined", "identified", *["not determined"] * 4],
            "plan": {"postures": 0, "candidates": 412, "log_det": 31.5, "d_criterion": 0.8},
            "sound_speed_m_s": float(table.values[table.index("sound_speed_m_s")]),
            "load_posture_deg": LOAD_POSTURE_DEG,
            "written": False,
        },
        [
            "rank 28 of 40 unknowns",
            "dh1_d_mm not identifiable, carried with its tolerance: the block's height",
            "dh2_a_mm │ 650.01200 │ 0.00400",
            "J2 │           2.857e+05 │   4.8",
            "J3 stiffness not determined: its torque",
            "180 moves, 1602 pulser reads; profile not written",
            "load: the offsets hold the arm as its weight bends it at the load posture (30.53,",
        ],
    )


def tool_frame_case(path: Path, cell: CellProfile) -> Case:
    run = ToolFrameRun(
        "paper",
        np.array([0.3023, -0.2011, 80.1683]),
        np.array([0.2026, -0.2179, 0.0]),
        np.array([-0.0038, -0.0035, 0.99998]),
        np.array([0.0053, 0.0053, 0.011]),
        0.0123,
        0.0021,
        100,
        57,
        412,
        notes=["the plate's height is taken as touched"],
    )
    error = SimulatedError(
        np.array([0.001, -0.002, 0.003]), 0.003, np.array([0.001, -0.002]), 0.004
    )
    result = ToolFrameResult(run, RunFacts(path, True, 57, 412, 93.5), error)
    return Case(
        [],
        ToolFrameCalibration,
        outcome("tool-frame", result),
        {
            "position_mm": [0.3023, -0.2011, 80.1683],
            "std": {"position_mm": [0.0053, 0.0053, 0.011], "beam_deg": 0.0123},
            "simulated_error": {
                "position_mm": [0.001, -0.002, 0.003],
                "along_beam_mm": 0.003,
                "across_beam_mm": [0.001, -0.002],
                "beam_deg": 0.004,
                "frame": "flange of the profile's J6 offset and last DH link",
            },
            "pulser_reads": 412,
            "written": True,
        },
        [
            "method:          paper (100 points, 57 moves, 412 pulser reads)",
            "position (mm):   0.3023, -0.2011, 80.1683   ± 0.0053, 0.0053, 0.0110",
            "simulated error: +0.0010, -0.0020, +0.0030 mm (along the beam +0.0030",
            "note: the plate's height is taken as touched",
            "[tool] written",
        ],
    )


def verify_case(path: Path, cell: CellProfile) -> Case:
    plan = plan_verify(cell, 1)
    points = [
        PointResult(
            name,
            0,
            plan.nominal_mm[0],
            np.zeros(6),
            (),
            np.zeros(3),
            plan.nominal_mm[0] + np.array(dev),
            0.01,
        )
        for name, dev in (("before", [1.5, -0.25, 0.5]), ("after", [0.02, -0.01, 0.005]))
    ]
    measured = VerifyResult(plan, points, 40, 300)
    solved = VerifySolved(
        measured,
        BeforeProfile(np.zeros(6), "no calibration in the profile's history: zero offsets"),
        SoundSpeed(1482.4, 20.0, "the last calibration's"),
        0.5,
        0.02,
        VerifyGauge("block", 0.5, 600.0),
    )
    picture = path.with_suffix(".verify.png")
    result = Verification(solved, RunFacts(path, True, 40, 300, 80.0), ["a note"], picture)
    return Case(
        ["--points", "1"],
        VerifyJob,
        outcome("verify", result),
        {
            "after_mm": {
                "mean": [0.02, 0.01, 0.005],
                "max": [0.02, 0.01, 0.005],
                "std": [0.0, 0.0, 0.0],
                "signed_mean": [0.02, -0.01, 0.005],
                "signed_std": [0.0, 0.0, 0.0],
            },
            "passed": True,
            "marginal": False,
            "approach": "positive",
            "before_source": "no calibration in the profile's history: zero offsets",
            "plot": str(picture),
            "notes": ["a note"],
        },
        [
            "after: largest deviation 0.0200 mm, tolerance 0.5 mm: passed",
            "before: no calibration in the profile's history: zero offsets",
            f"picture: {picture}",
            "note: a note",
            "40 moves, 300 pulser readings",
        ],
    )


def region_case(path: Path, cell: CellProfile) -> Case:
    region = RegionResult(
        5,
        2.5e-6,
        2.8e-6,
        0.00095,
        0.0019,
        0.265,
        "ok",
        "r05/YZ",
        0.5,
        (0.2274, 0.41),
        unidentified_names=("d5", "a5"),
    )
    result = RegionCheck(region, RunFacts(path, False, 60, 500, 120.0))
    return Case(
        ["--region", "5"],
        RegionJob,
        outcome("verify", result),
        {
            "region": {
                "postures": 5,
                "rms_distance_mm": 2.5e-6,
                "max_distance_mm": 2.8e-6,
                "rms_tilt_deg": 0.00095,
                "max_tilt_deg": 0.0019,
                "chi2_reduced": 0.265,
                "verdict": "ok",
                "worst": "r05/YZ",
                "approach": "positive",
                "unidentified_tcp_mm": {"mean": 0.2274, "max": 0.41, "quantities": ["d5", "a5"]},
            },
            "tolerance_mm": 0.5,
            "passed": True,
            "moves": 60,
            "duration_s": 120.0,
        },
        [
            "region: 5 postures;",
            "tolerance 0.5 mm: passed",
            "quantities (d5, a5) allow 0.227 mm mean, 0.410 mm max",
        ],
    )


def check_case(path: Path, cell: CellProfile) -> Case:
    quantities = [
        Quantity("J2", "joint 2", "deg", -1.2, -1.2003, 0.003, 0.02, "ok"),
        Quantity("amplitude_db", "the transducer", "dB", None, None, None, 2.0, "not measured"),
    ]
    findings = CheckFindings(quantities, [], [], None, run=CheckRun([], [], None, 120, 1080))
    estimate = DurationEstimate(10, 100, 20.0, 30.0, 60.0)
    result = CheckResult(findings, RunFacts(path, True, 120, 1080, 61.0), estimate, ["base/XY"])
    return Case(
        [],
        CheckJob,
        outcome("check", result),
        {
            "verdict": "ok",
            "records_reference": True,
            "recorded": True,
            "written": False,
            "postures": ["base/XY"],
            "estimated_s": {"tcp": estimate.tcp_s, "rtu": estimate.rtu_s},
            "quantities": [q.to_json() for q in quantities],
            "approach": "positive",
        },
        [
            "Reference check (against the profile's calibration)",
            "│ J2       │ joint 2 │  -1.2 │      -1.2 │ +0.0003 │ 0.003 │      0.02 │ ok      │",
            "120 moves, 1080 pulser reads, 61 s on the cell",
            "verdict: ok; reference recorded",
        ],
    )


CASES = {
    "calibrate": offsets_case,
    "calibrate --level full": full_case,
    "tool-frame": tool_frame_case,
    "verify": verify_case,
    "verify --region": region_case,
    "check": check_case,
}


def close(a: Any, b: Any) -> bool:
    """``a`` and ``b`` alike, numbers to 1e-9 (the printed figures are the result's, through
    sums and differences)."""
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(close(a[k], b[k]) for k in a)
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(close(x, y) for x, y in zip(a, b, strict=True))
    if isinstance(a, float | int) and isinstance(b, float | int) and not isinstance(a, bool):
        return bool(np.isclose(a, b, rtol=1e-9, atol=1e-12))
    return bool(a == b)


@pytest.mark.parametrize("name", list(CASES))
def test_the_json_and_the_tables_are_the_typed_result(
    name: str, profile: Path, run_main: RunMain, monkeypatch: pytest.MonkeyPatch
) -> None:
    case = CASES[name](profile, load_profile(profile))
    jobs: list[object] = []

    def run_job(job: object, options: RunOptions) -> Outcome[CommandResult]:
        jobs.append(job)
        return case.outcome

    monkeypatch.setattr(cli_procedure, "run_job", run_job)
    monkeypatch.setattr(calibrate_cli, "run_job", run_job)
    command = name.split()[0]
    args = [command, str(profile), "--sim", "--yes", *case.args]

    code, out, err = run_main([*args, "--json"])
    assert code == 0, err
    printed = json.loads(out)
    assert printed == json.loads(json.dumps(case.outcome.to_json(), default=_to_jsonable))
    assert close({k: printed[k] for k in case.fields}, case.fields)
    assert [type(j) for j in jobs] == [case.job]

    code, out, err = run_main(args)
    assert code == 0, err
    for line in case.shown:
        assert line in out, f"{line!r} not in:\n{out}"
    if name == "calibrate":
        assert "warning: J5 measured at +1.1009 ± 0.035 deg: measured too weakly" in err
