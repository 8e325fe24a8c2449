"""The commissioning rehearsal on the built-in simulated cell, as a new user runs it.

The README's rehearsal block, line by line as written (each with ``--json`` added to read its
result): a fresh profile, then ``calibrate``, ``tool-frame`` and ``verify`` with ``--sim`` (the
demo truth of ``ucal.sim.demo``), which must end in a pass, relative to the block (the gauge of
``ucal.model.gauge``), each point's measurement with its sigma and "marginal" only where
the tolerance lies within two of them, with the simulator's truth confirming the "after"
figure; then the
shipped world with faults, which must fail. Each line runs the command line in the test's
process (the same code a shell runs, without a new interpreter's imports), once for the test
run: the ``rehearsal`` fixture of ``tests/system/conftest.py``, whose cell
``test_report_rehearsal.py`` reports on. One test, because the whole workflow costs seconds of
CPU; ``test_readme_examples`` leaves this block to it.
"""

from __future__ import annotations

import json
import tomllib
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from ucal.verify.result import MEASURED_WITHIN_MM

pytestmark = pytest.mark.system

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


@pytest.mark.long
@pytest.mark.timeout(420)
def test_the_rehearsal_ends_in_a_pass_and_the_faulty_world_fails(
    rehearsal: tuple[Path, list[dict[str, Any]]],
) -> None:
    directory, steps = rehearsal  # the README's lines (tests/system/conftest.py)
    assert [s["args"][0] for s in steps] == [
        "profile",
        "calibrate",
        "tool-frame",
        "verify",
        "verify",
    ]
    init, calibrate, tool_frame, verify, faulty = steps
    assert faulty["args"][faulty["args"].index("--sim") + 1] == "examples/faulty_world.toml"
    assert init["returncode"] == 0, init["stderr"]
    placed = tomllib.loads(init["profile"])["sample"]

    assert calibrate["returncode"] == 0, calibrate["stderr"]
    cal = json.loads(calibrate["stdout"])
    # J1 measured relative to the hand-placed block, not kept: its absolute std carries the
    # block's yaw tolerance, its block-relative std the data's
    assert cal["unobservable_joints"] == [6] and cal["gauge"] == "block"
    assert "relative to the block as placed" in cal["gauge_note"]
    assert cal["std_deg"][0] >= 0.5 and cal["std_block_deg"][0] < 0.01
    truth_block = np.array(cal["truth_offsets_block_deg"])
    error = np.abs(np.array(cal["joint_offsets_deg"][:5]) - truth_block[:5])
    assert np.all(error <= 3 * np.array(cal["std_block_deg"][:5])), error
    # the block as the calibration measured it goes into [sample] (its stds as declared)
    written = tomllib.loads(calibrate["profile"])
    assert written["sample"]["position_mm"] == cal["block"]["position_mm"]
    assert written["sample"]["position_std_mm"] == placed["position_std_mm"]
    assert written["calibration"]["gauge"] == "block"

    # the tool with the offsets calibrated: the order that leaves the least along the beam
    assert tool_frame["returncode"] == 0, tool_frame["stderr"]
    written = tomllib.loads(tool_frame["profile"])

    assert verify["returncode"] == 0, verify["stderr"]
    out = json.loads(verify["stdout"])
    assert out["passed"] is True and out["tolerance_mm"] == 0.5
    assert out["gauge"] == "block" and out["j1_gauge"] == "block"
    assert out["absolute_std_mm"] > 1.0  # the yaw as placed, at the points' reach
    assert "relative to the block as placed" in out["gauge_note"]
    after = np.array(out["after_mm"]["max"])
    assert np.max(after) < 0.5 - MEASURED_WITHIN_MM
    # the offsets level leaves the DH table at its tolerance (0.2 mm, 0.02°): what it allows
    # at the tool centre is in verify's figure as in the robot's; and what the tank did since
    # calibrate, read again at calibrate's readings at the start
    # and the end of the run (six moves), as a wall's 150 mm
    assert out["tank"]["used"] and out["tank"]["extra_moves"] == 6
    water = 150.0 * out["tank"]["change_std_m_s"] / out["sound_speed_now_m_s"]
    assert 0.0 < water < 0.02
    # what verify measures each point to: its own noise, the run's common errors, the table's
    # share at that point (ucal.verify.uncertainty), two sigma of the worst point and axis
    stds = np.array(out["measurement_std_points_mm"])
    assert stds.shape == (3, 3) and np.all(stds > 0.0) and np.all(stds < 0.2)
    assert out["measured_within_mm"] == pytest.approx(2.0 * stds.max())
    # marginal only where the tolerance lies within two sigma of a measured deviation
    dev = np.abs(np.array(out["deviations_mm"]["after"]))
    assert out["marginal"] is bool(np.any(0.5 - dev < 2.0 * stds)), (dev, stds)
    assert any("DH table is not identified" in n for n in out["notes"])
    assert np.max(out["before_mm"]["max"]) > 5.0  # the profile before its calibration
    # the simulator's truth of the same points, relative to the true block: the figure is
    # honest to what verify says it measures to, and the truth passes too
    truth = out["truth"]
    assert np.all(np.array(truth["after_figure_error_mm"]) <= MEASURED_WITHIN_MM), truth
    assert np.max(truth["after_mm"]["max"]) < 0.5
    assert (directory / "cell.verify.png").read_bytes()[:8] == PNG_MAGIC
    # verify never writes the profile
    assert tomllib.loads(verify["profile"]) == written

    # one command away: the same cell after a remount, a collision and a bumped block
    assert faulty["returncode"] == 1, faulty["stderr"]
    bad = json.loads(faulty["stdout"])
    assert bad["passed"] is False and "above the tolerance" in bad["error"]
    assert np.max(bad["truth"]["after_mm"]["max"]) > 0.5  # the truth fails it too
    # the tool check finds the transducer's millimetre across the beam
    across = np.array(bad["tool_check"]["across_beam_flange_mm"])
    assert np.linalg.norm(across) == pytest.approx(1.0, abs=0.1)
