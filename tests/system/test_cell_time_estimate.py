"""The plan's estimate of a cell's time against the simulated run it estimates: both take the
one motion model (``drivers.controller.motion``)."""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from doubles import once_per_run, ucal_here

pytestmark = pytest.mark.system

TRUTH = np.array([0.8, -1.2, 1.5, -2.0, 1.1])  # the demo cell's joint offsets (J6 unobservable)


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, Any]]:
    """A fresh demo profile calibrated on the simulated cell: its directory, calibrate's
    ``--json`` and the plan's estimate over Modbus TCP (s) under ``"estimate_s"``."""

    def make(directory: Path) -> dict[str, Any]:
        assert ucal_here("profile", "init", "tx90l", "cell.toml", cwd=directory).returncode == 0
        out = ucal_here("calibrate", "cell.toml", "--sim", "--yes", "--json", cwd=directory)
        assert out.returncode == 0, out.stderr
        m = re.search(r"([\d.]+) s over Modbus TCP", out.stderr)
        assert m, out.stderr
        return {**json.loads(out.stdout), "estimate_s": float(m.group(1))}

    return once_per_run(tmp_path_factory, "calibrated-demo", make)


@pytest.mark.long
def test_calibrates_estimate_is_within_15_percent_of_the_simulated_run(
    calibrated: tuple[Path, dict[str, Any]],
) -> None:
    _, run = calibrated
    assert abs(run["estimate_s"] - run["duration_s"]) <= 0.15 * run["duration_s"]
    # the approach through a queued pre-point keeps every posture reached from below: the
    # offsets within 3 std of the truth
    offsets = np.array(run["joint_offsets_deg"][:5])
    std = np.array(run["std_deg"][:5], float)
    np.testing.assert_array_less(np.abs(offsets - TRUTH), 3.0 * std)
    assert run["approach"] == "positive"


@pytest.mark.long
def test_checks_estimate_is_within_15_percent_of_the_simulated_run(
    calibrated: tuple[Path, dict[str, Any]], tmp_path: Path
) -> None:
    # the reference check, whose edge lines reach wide, then one against it, centred on the
    # reference's crossings: each probe of their edge scans a move of the motion model
    shutil.copytree(calibrated[0], tmp_path, dirs_exist_ok=True)
    for records_reference in (True, False):
        out = ucal_here("check", "cell.toml", "--sim", "--yes", "--json", cwd=tmp_path)
        assert out.returncode in (0, 1), out.stderr
        run = json.loads(out.stdout)
        assert run["records_reference"] is records_reference
        estimate, duration = run["estimated_s"]["tcp"], run["duration_s"]
        assert abs(estimate - duration) <= 0.15 * duration, (estimate, duration)
        assert len(run["postures"]) == 6 and run["moves"] > 250  # the edges were scanned
