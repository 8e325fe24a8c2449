"""Today's arms as shipped models: ``ucal profile init tx2-90l`` calibrates on the simulated
cell as the TX90 family does (the other TX2 arms' plans: tests/unit/test_models.py)."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from doubles import ucal_here

pytestmark = pytest.mark.system


def test_a_tx2_90l_profile_calibrates_and_recovers_the_demo_offsets(tmp_path) -> None:
    path = tmp_path / "cell.toml"
    assert ucal_here("profile", "init", "tx2-90l", str(path)).returncode == 0
    done = subprocess.run(
        [sys.executable, "-m", "ucal", "calibrate", str(path), "--sim", "--yes", "--json"],
        capture_output=True,
        text=True,
        check=False,
        timeout=300,
        stdin=subprocess.DEVNULL,
    )
    assert done.returncode == 0, done.stderr
    result = json.loads(done.stdout)
    assert result["written"]
    found = np.array(result["joint_offsets_deg"])
    truth = np.array(result["truth_offsets_deg"])
    stds = result["std_deg"]
    reported = [i for i, s in enumerate(stds) if s is not None]
    assert len(reported) >= 5
    std = np.array([stds[i] for i in reported])
    assert np.all(np.abs(found[reported] - truth[reported]) <= 3 * std), (found, truth, stds)
