"""verify's plan keeps the room the offsets the last calibration left undetermined can take:
the "after" points' clearance from the faces and the tool check's ends (no processes)."""

from __future__ import annotations

import numpy as np
import pytest
import tomlkit

from ucal.cell import CellProfile
from ucal.errors import SafetyError
from ucal.model.safety import MIN_WATER_PATH_MM
from ucal.profile import default_profile_text, profile_from_data
from ucal.verify import plan as verify_plan
from ucal.verify.plan import (
    plan_verify,
    tool_clearance_mm,
    undetermined_joints,
    undetermined_spread,
    wrist_centre_local,
)

#: A tx90l with a 20° holder, calibrated with joints 2, 5 and 6 left undetermined
#: ([calibration] std_deg -1): a cell whose true joint-2 offset was 2.5° had its "after"
#: points 36 mm lower than the profile put them, and verify refused after 257 moves, the
#: tool centre predicted in the block at the first "after" point.
HOLDER_20 = {
    "tool_position_mm": np.array([42.018, 0.995, 112.424]),
    "tool_rotation_deg": np.array([0.785, 20.625, 0.0]),
    "joint_offsets_deg": np.array([-0.850445, 0.0, 0.312683, 0.523887, 0.0, 0.0]),
    "joint_offsets_std_deg": np.array([0.500035, -1.0, 0.005786, 0.007092, -1.0, -1.0]),
}


def template(model: str = "tx90l") -> CellProfile:
    return profile_from_data(tomlkit.parse(default_profile_text(model)), f"{model}.toml")


def test_only_a_calibrated_profiles_undetermined_arm_joints_count():
    fresh = template()
    assert undetermined_joints(fresh) == ()  # never calibrated: its "after" is its "before"
    cell = fresh.replace(**HOLDER_20)
    assert undetermined_joints(cell) == (1,)  # joint 2; 5 and 6 do not move the wrist centre
    q = np.array([32.9, 37.7, 102.9, -27.4, 23.2, 55.2])
    unknown = undetermined_spread(cell, q, cell.joint_offsets_deg)
    # joint 2's 3° (3σ of a fresh cell's 1°) moves W some 30 mm, most of it along block Z
    assert unknown.joint == 1
    assert 25.0 < unknown.wrist_mm[2] < 45.0
    assert np.all(undetermined_spread(fresh, q, fresh.joint_offsets_deg).wrist_mm == 0.0)


def test_the_after_points_keep_the_water_path_the_undetermined_offsets_can_take():
    cell = template().replace(**HOLDER_20)
    as_drawn = plan_verify(template().replace(**{k: HOLDER_20[k] for k in list(HOLDER_20)[:2]}), 3)
    assert as_drawn.height_mm == pytest.approx(30.0)
    plan = plan_verify(cell, 3)
    assert plan.height_mm > 30.0  # raised: 30 mm over the face is not enough
    for t in plan.targets:
        if t.pass_name != "after":
            continue
        unknown = undetermined_spread(cell, t.joints_deg, cell.joint_offsets_deg)
        w = wrist_centre_local(cell, t.joints_deg, cell.joint_offsets_deg)
        assert tool_clearance_mm(cell, w - unknown.wrist_mm) >= MIN_WATER_PATH_MM


def test_a_refusal_names_the_undetermined_offset_and_what_lifts_it(monkeypatch):
    cell = template().replace(**HOLDER_20)
    monkeypatch.setattr(verify_plan, "PLAN_RAISES_MM", (0.0,))
    with pytest.raises(SafetyError) as e:
        plan_verify(cell, 3)
    msg = str(e.value)
    assert "plan after point 1" in msg and "face XY" in msg
    assert "joint(s) 2 (not determined by the last calibration" in msg
    assert "[calibration] std_deg" in msg
    assert "a calibration that determines joint 2's offset would lift it" in msg
