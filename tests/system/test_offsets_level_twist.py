"""The offsets level on a TX90L whose axes 2 and 3 are not quite parallel: Hayati's twist β₂ of
0.027°, 1.35 times the profile's DH angle tolerance (0.02°), as a real arm may have it. The
level carries β₂ with its prior (``ucal.model.least_squares.cell_table``); without it,
J1 relative to the block was written 0.030° off at a reported 0.0036° (8.4σ) and J2 at 3.8σ."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from ucal.profile import create_profile

from doubles import ucal_here

pytestmark = pytest.mark.system

WORLD = """
[robot]
joint_offsets_deg = [0.8, -1.2, 1.5, -2.0, 1.1, 0.6]
dh = [
  {{ theta_offset_deg = 0.0, d_mm = 0.0, a_mm = 50.0, alpha_deg = -90.0 }},
  {{ theta_offset_deg = -90.0, d_mm = 50.0, a_mm = 500.0, alpha_deg = 0.0, beta_deg = 0.027 }},
  {{ theta_offset_deg = 90.0, d_mm = 0.0, a_mm = 0.0, alpha_deg = 90.0 }},
  {{ theta_offset_deg = 0.0, d_mm = 550.0, a_mm = 0.0, alpha_deg = -90.0 }},
  {{ theta_offset_deg = 0.0, d_mm = 0.0, a_mm = 0.0, alpha_deg = 90.0 }},
  {{ theta_offset_deg = 0.0, d_mm = 100.0, a_mm = 0.0, alpha_deg = 0.0 }},
]
[noise]
tof_ns = 0.5
amplitude = 0.01
seed = {seed}
"""


@pytest.mark.parametrize("seed", [11, 3])
def test_a_twist_between_axes_2_and_3_is_carried_in_the_offsets_stds(
    tmp_path: Path, seed: int
) -> None:
    profile = tmp_path / "cell.toml"
    create_profile(profile, "tx90l")
    world = tmp_path / "world.toml"
    world.write_text(WORLD.format(seed=seed))
    done = ucal_here("calibrate", str(profile), "--sim", str(world), "--yes", "--json")
    assert done.returncode == 0, done.stderr
    out = json.loads(done.stdout)
    assert out["written"] and out["gauge"] == "block"
    found = np.array(out["joint_offsets_deg"][:5])
    truth = np.array(out["truth_offsets_block_deg"][:5])
    std = np.array(out["std_block_deg"][:5])
    z = (found - truth) / std
    # J1 relative to the block within 3σ (8.4σ on seed 11 when β₂ was not carried), and no
    # offset written beyond 4σ
    assert abs(z[0]) <= 3.0 and np.all(np.abs(z) <= 4.0), z
