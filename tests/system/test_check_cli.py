"""``ucal check`` against the simulated cell: the commissioned cell passes, a moved joint 2 is
named, so is the arm grown by a warm-up, in less than two minutes of real-cell time; both checks
go into the profile's history."""

from __future__ import annotations

import json
import re
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from ucal.cell import ALUMINIUM_EXPANSION_PER_K
from ucal.profile import load_profile
from ucal.report import gather_report, render_page
from ucal.sim import demo

pytestmark = pytest.mark.system

RunMain = Callable[[list[str]], tuple[int, str, str]]


def demo_world(
    profile_path: Path,
    path: Path,
    j2_moved_deg: float,
    seed: int,
    tool_moved_mm: tuple[float, float, float] = (0.0, 0.0, 0.0),
    arm_warmer_k: float = 0.0,
) -> Path:
    """The demo truth (``ucal.sim.demo``) as a world file, joint 2 moved, the tool remounted
    by ``tool_moved_mm`` (flange frame), the arm ``arm_warmer_k`` warmer than at the
    commissioning and another noise seed (another day's readings)."""
    nominal = load_profile(profile_path).as_described()
    offsets = demo.DEMO_JOINT_OFFSETS_DEG + [0.0, j2_moved_deg, 0.0, 0.0, 0.0, 0.0]
    tool = nominal.tool_position_mm + demo.DEMO_TOOL_POSITION_ERROR_MM + np.asarray(tool_moved_mm)

    def vec(values: np.ndarray) -> str:
        return "[" + ", ".join(repr(float(v)) for v in values) + "]"

    path.write_text(
        f"[robot]\njoint_offsets_deg = {vec(offsets)}\n"
        f"[tool]\nposition_mm = {vec(tool)}"
        f"\nrotation_deg = {vec(nominal.tool_rotation_deg + demo.DEMO_TOOL_ROTATION_ERROR_DEG)}\n"
        f"[sample]\nposition_mm = "
        f"{vec(nominal.sample_position_mm + demo.DEMO_SAMPLE_POSITION_ERROR_MM)}\n"
        f"rotation_deg = {vec(nominal.sample_rotation_deg)}\n"
        f"[noise]\ntof_ns = {demo.DEMO_NOISE.tof_ns}\namplitude = {demo.DEMO_NOISE.amplitude}\n"
        f"seed = {seed}\n[arm]\noffset_k = {arm_warmer_k!r}\n",
        encoding="utf-8",
    )
    return path


def commissioned(tmp_path: Path, run_main: RunMain) -> Path:
    """The demo cell calibrated and its reference check recorded: its profile."""
    profile = tmp_path / "cell.toml"
    code, _, err = run_main(["calibrate", str(profile), "--sim", "--yes", "-q"])
    assert code == 0, err
    code, _, err = run_main(["check", str(profile), "--sim", "--yes", "-q"])
    assert code == 0, err
    return profile


def test_passes_the_commissioned_cell_and_names_a_moved_joint_2(
    tmp_path: Path, run_main: RunMain
) -> None:
    profile = tmp_path / "cell.toml"
    code, _, err = run_main(["calibrate", str(profile), "--sim", "--yes", "-q"])
    assert code == 0, err
    calibrated = profile.read_bytes()

    # the first check after the calibration: judged against it, recorded as the reference
    code, out, err = run_main(["check", str(profile), "--sim", "--yes"])
    assert code == 0, err
    assert "Estimated time on a real cell" in err and "as the reference" in err
    assert "verdict: ok; reference recorded" in out and "history: check 1" in out

    world = demo_world(profile, tmp_path / "j2.toml", 0.05, seed=7)
    code, out, err = run_main(["check", str(profile), "--sim", str(world), "--yes", "--json"])
    assert code == 1, err
    result = json.loads(out)
    assert result["exit_code"] == 1 and result["moved"] == ["J2"]
    said = re.search(r"joint 2 \(J2\) moved by \+(\d\.\d+) deg", result["error"])
    assert said and abs(float(said.group(1)) - 0.05) < 0.002, result["error"]
    q = {q["name"]: q for q in result["quantities"]}
    assert q["J2"]["verdict"] == "out of tolerance"
    assert abs(q["J2"]["difference"] - 0.05) < 0.002
    assert [n for n, v in q.items() if v["verdict"] == "out of tolerance"] == ["J2"]
    assert {"value", "baseline", "difference", "std", "verdict"} <= set(q["amplitude_db"])
    assert q["centre_frequency_mhz"]["verdict"] == "ok"  # the A-scans: the transducer as it was
    assert result["reference"]["id"] == 1 and result["written"] is False
    assert 0 < result["duration_s"] <= 120
    assert profile.read_bytes() == calibrated  # a check never writes the profile

    code, out, _ = run_main(["profile", "history", str(profile), "--json"])
    checks = json.loads(out)["checks"]
    assert [(c["verdict"], c["reference"]) for c in checks] == [
        ("ok", True),
        ("out of tolerance", False),
    ]
    assert checks[1]["compared_with"] == 1 and "J2" in checks[1]["summary"]
    code, out, _ = run_main(["profile", "history", str(profile)])
    assert code == 0 and "calibrate" in out and out.count("check") >= 2


def test_names_a_tool_remounted_across_the_beam_from_the_edges(
    tmp_path: Path, run_main: RunMain
) -> None:
    profile = commissioned(tmp_path, run_main)

    # 0.3 mm across the beam: no water path changes, the edge crossings do
    world = demo_world(profile, tmp_path / "across.toml", 0.0, seed=7, tool_moved_mm=(0.3, 0, 0))
    code, out, err = run_main(["check", str(profile), "--sim", str(world), "--yes", "--json"])
    assert code == 1, err
    result = json.loads(out)
    assert result["moved"] == ["tool"]
    (cause,) = result["causes"]
    assert (cause["part"], cause["what"]) == ("tool", "across the beam")
    assert abs(cause["size"] - 0.3) < 0.06 and cause["std"] < 0.05, cause
    assert "the tool moved: across the beam +0." in result["error"]
    q = {q["name"]: q for q in result["quantities"]}
    # nothing is "ok" whose sigma is above its tolerance
    assert not [
        n for n, v in q.items() if v["verdict"] == "ok" and v["std"] > (v["tolerance"] or 1e9)
    ]
    assert q["J6"]["verdict"] == "not determined"
    assert "J6" in [n["name"] for n in result["not_determined"]]


def test_names_the_arm_grown_by_a_warm_up_of_5_k_not_a_joint(
    tmp_path: Path, run_main: RunMain
) -> None:
    profile = commissioned(tmp_path, run_main)

    # unwarmed, another day's readings: as commissioned, the arm's growth within 3σ of none
    world = demo_world(profile, tmp_path / "cold.toml", 0.0, seed=7)
    code, out, err = run_main(["check", str(profile), "--sim", str(world), "--yes", "--json"])
    assert code == 0, err
    result = json.loads(out)
    assert abs(result["arm_growth_ppm"]) < 3 * result["arm_growth_ppm_std"]

    # 5 K warmer: every link 115 ppm longer (aluminium's 23 ppm/K)
    world = demo_world(profile, tmp_path / "warm.toml", 0.0, seed=8, arm_warmer_k=5.0)
    code, out, err = run_main(["check", str(profile), "--sim", str(world), "--yes", "--json"])
    assert code == 1, err
    result = json.loads(out)
    truth = 5.0 * ALUMINIUM_EXPANSION_PER_K * 1e6
    assert result["moved"] == ["arm"]
    assert abs(result["arm_growth_ppm"] - truth) < 0.2 * truth
    assert abs(result["arm_growth_ppm"] - truth) < 4 * result["arm_growth_ppm_std"] + 1.0
    assert abs(result["arm_temperature_rise_k"] - 5.0) < 1.0
    assert "the arm grew (warm-up) by +1" in result["error"] and "K warmer" in result["error"]
    q = {q["name"]: q for q in result["quantities"]}
    out_of = [n for n, v in q.items() if v["verdict"] == "out of tolerance"]
    assert out_of == ["arm_growth_ppm", "arm_temperature_rise_k"]
    (cause,) = result["causes"]
    assert (cause["part"], cause["what"], cause["unit"]) == ("arm", "growth", "ppm")

    # the report's history shows the checks and the growth's trend: the reference at none,
    # the cold check within its sigma, the warm one at its 115 ppm
    report = gather_report(profile)
    growth = [(c.reference, c.growth_ppm) for c in report.checks]
    assert [r for r, _ in growth] == [True, False, False], growth
    assert growth[0][1] is None and abs(growth[2][1] - result["arm_growth_ppm"]) < 1e-6
    page = render_page(report)
    stated = f"{result['arm_growth_ppm']:.1f} ± {result['arm_growth_ppm_std']:.1f}"
    assert f"measured the arm {stated} ppm longer than at its reference" in page
    assert page.count("<h3>Checks</h3>") == 1 and "arm growth (ppm, 1σ)" in page
