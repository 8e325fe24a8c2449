"""Calibrate timed from the A-scans on worlds whose echoes change shape with their water path
(``[water] absorption``: each echo's spectrum through α₀·f² over its own path, both ways, the
multiple and the other faces' echoes at theirs) and carry a baseline offset: written, J2–J5
within 3 reported sigmas of the world's truth, and their stds no larger than the instrument's
own gate's on the same world (within what the runs' own draws move them,
``doubles.DRAW_STD_RATIO``). In the test's process, on simulated time."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from ucal.profile import default_profile_text
from ucal.sim.demo import DEMO_JOINT_OFFSETS_DEG, DEMO_NOISE

from doubles import DRAW_STD_RATIO, std_of, ucal_here

pytestmark = pytest.mark.system


def world(seed: int) -> str:
    return (
        f"[robot]\njoint_offsets_deg = {DEMO_JOINT_OFFSETS_DEG.tolist()}\n"
        f"[noise]\ntof_ns = {DEMO_NOISE.tof_ns}\namplitude = {DEMO_NOISE.amplitude}\n"
        f"seed = {seed}\n[water]\nabsorption = true\n[pulser]\nbits = 12\n"
        "baseline_offset = 0.02\n"
    )


def calibrate(directory: Path, timing: str, seed: int) -> dict:
    (directory / "world.toml").write_text(world(seed))
    profile = directory / f"{timing}.toml"
    # the simulated arm is rigid and the profile says so: the echoes' timing alone is at stake
    rigid = "backlash_std_deg = 0.01"
    text = default_profile_text("tx90l").replace(
        rigid, f"stiffness_nm_per_rad = {[0.0] * 6}\n{rigid}"
    )
    profile.write_text(text + f'\n[pulser]\ntiming = "{timing}"\n')
    r = ucal_here(
        "calibrate", str(profile), "--sim", str(directory / "world.toml"), "--yes", "--json"
    )
    assert r.returncode == 0, r.stderr[-2000:]
    return dict(json.loads(r.stdout))


@pytest.mark.long
@pytest.mark.parametrize("seed", [1, 2])
def test_shaped_echoes_timed_from_the_ascans_are_covered_and_no_less_precise_than_the_gate(
    tmp_path: Path, seed: int
) -> None:
    ascan, gate = calibrate(tmp_path, "ascan", seed), calibrate(tmp_path, "gate", seed)
    assert ascan["written"] and ascan["timing"] == "ascan"
    assert ascan["reference_echo"]["source"] == "captured"
    j2_j5 = slice(1, 5)
    std = std_of(ascan)[j2_j5]
    error = np.abs(np.array(ascan["joint_offsets_deg"]) - DEMO_JOINT_OFFSETS_DEG)[j2_j5]
    assert np.all(error <= 3 * std), (error, std)
    assert np.all(std <= DRAW_STD_RATIO * std_of(gate)[j2_j5]), (std, std_of(gate)[j2_j5])
