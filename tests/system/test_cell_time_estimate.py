"""The plan's estimate of a cell's time against the simulated run it estimates: both take the
one motion model (``drivers.controller.motion``)."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np

TRUTH = np.array([0.8, -1.2, 1.5, -2.0, 1.1])  # the demo cell's joint offsets (J6 unobservable)


def test_calibrates_estimate_is_within_15_percent_of_the_simulated_run(tmp_path: Path) -> None:
    def ucal(*args: str) -> subprocess.CompletedProcess[str]:
        return subprocess.run(
            [sys.executable, "-m", "ucal", *args],
            cwd=tmp_path,
            capture_output=True,
            text=True,
            timeout=600,
            stdin=subprocess.DEVNULL,
        )

    assert ucal("profile", "init", "tx90l", "cell.toml").returncode == 0
    out = ucal("calibrate", "cell.toml", "--sim", "--yes", "--json")
    assert out.returncode == 0, out.stderr
    m = re.search(r"([\d.]+) s over Modbus TCP", out.stderr)
    assert m, out.stderr
    estimate, run = float(m.group(1)), json.loads(out.stdout)
    assert abs(estimate - run["duration_s"]) <= 0.15 * run["duration_s"]
    # the approach through a queued pre-point keeps every posture reached from below: the
    # offsets within 3 std of the truth
    offsets = np.array(run["joint_offsets_deg"][:5])
    std = np.array(run["std_deg"][:5], float)
    np.testing.assert_array_less(np.abs(offsets - TRUTH), 3.0 * std)
    assert run["approach"] == "positive"
