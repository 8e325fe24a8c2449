"""A water-path or edge refusal names the declared tolerance that takes the room and the one
that would lift it (``ucal.model.safety.check_face``; no processes)."""

from __future__ import annotations

import re

import numpy as np
import pytest
import tomlkit

from ucal.errors import SafetyError
from ucal.model.geometry import Face
from ucal.model.safety import MIN_WATER_PATH_MM, check_face, tolerance_margins
from ucal.model.targets import calibration_pose, geometry
from ucal.model.wrist import aim_wrist
from ucal.profile import default_profile_text, profile_from_data


def test_a_tool_known_to_10_mm_is_named_in_a_water_path_refusal_with_the_one_that_lifts_it():
    profile = profile_from_data(tomlkit.parse(default_profile_text("tx90xl")), "xl.toml")
    # the block 60 mm higher than the template's: 40 mm of water from the calibration pose
    profile = profile.replace(
        sample_position_mm=np.asarray(profile.sample_position_mm) + [0.0, 0.0, 60.0]
    )
    geom = geometry(profile)
    offsets = profile.joint_offsets_deg
    q = aim_wrist(geom, calibration_pose(profile), -geom.normal(Face.XY), offsets)
    path = check_face(profile, geom, q, Face.XY, offsets, "base/XY")  # no margin: passes
    loose = profile.replace(tool_position_std_mm=np.array([10.0, 10.0, 10.0]))
    margin = tolerance_margins(loose).block_mm
    assert path < MIN_WATER_PATH_MM + margin  # 3σ of a tool known to 10 mm: 30 mm and more
    with pytest.raises(SafetyError) as e:
        check_face(loose, geom, q, Face.XY, offsets, "base/XY", margin)
    msg = str(e.value)
    assert f"{MIN_WATER_PATH_MM:g} mm and {margin:.3g} mm for where the declared tolerances" in msg
    assert "the tool's position known to ±10 mm one sigma ([tool] position_std_mm)" in msg
    lifted = re.search(r"\[tool\] position_std_mm\) to ±([0-9.]+) mm or less would lift it", msg)
    assert lifted is not None, msg
    better = profile.replace(tool_position_std_mm=np.full(3, float(lifted.group(1))))
    check_face(better, geom, q, Face.XY, offsets, "base/XY", tolerance_margins(better).block_mm)
