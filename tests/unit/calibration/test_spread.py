"""What the unknowns can turn a planned posture's wrist by (``ucal.model.spread``), the
checks that keep that room, and the refusals that name it (no processes)."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
import tomlkit

from ucal.cell import CellProfile
from ucal.errors import SafetyError
from ucal.model.geometry import Configuration
from ucal.model.safety import SEARCH_MARGIN_DEG, check_joints
from ucal.model.spread import OFFSETS, TOOL, aim_spread
from ucal.model.targets import geometry, plan_calibration
from ucal.model.wrist import aim_wrist
from ucal.profile import default_profile_text, profile_from_data


def template(model: str = "tx90l") -> CellProfile:
    return profile_from_data(tomlkit.parse(default_profile_text(model)), f"{model}.toml")


def test_a_fresh_cells_offsets_turn_joint_5_by_at_least_its_own_three_sigma():
    profile = template()
    plan = plan_calibration(profile)
    geom = geometry(profile)
    for t in plan.targets:
        spread = aim_spread(profile, geom, t.joints_deg, t.face, profile.joint_offsets_deg)
        # joint 5's own offset turns its reading one for one, and it is known to 1° (3σ: 3°)
        assert spread.parts[OFFSETS][4] >= 3.0 - 1e-6
        assert np.all(spread.deg[:3] == 0.0)  # the arm stands as commanded


def test_every_step_checked_keeps_the_wrist_inside_its_ranges_for_any_cell_within_tolerance():
    """The run chooses a stepped configuration's sign and may step less than planned; each
    such step is checked before the first motion. On a fresh tx90l with a 10° holder the
    second azimuth stepped −8° puts joint 5 within 8° of its limit (a cell within every
    tolerance was refused there after 159 moves): the run may not take it."""
    profile = template().replace(
        tool_position_mm=np.array([18.635, 2.161, 80.783]),
        tool_rotation_deg=np.array([0.0, 10.0, 0.0]),
    )
    plan = plan_calibration(profile)
    geom = geometry(profile)
    assert plan.steps_checked is not None
    assert -8.0 not in plan.steps_checked[Configuration.J1]
    assert plan.steps_checked[Configuration.J1]  # a J1 step is still planned
    model = profile.model
    for config, steps in plan.steps_checked.items():
        targets = [t for t in plan.targets if t.config == config]
        for step, t in itertools.product(steps, targets):
            arm = np.array(plan.pose_deg, float)
            arm[{Configuration.J1: 0, Configuration.J2: 1, Configuration.J3: 2}[config]] += step
            arm[3:] = t.joints_deg[3:]
            # true offsets 3σ (3°) off on the joints that turn the wrist most, each sign
            for signs in itertools.product((-1.0, 1.0), repeat=3):
                true = np.zeros(6)
                true[[1, 2, 4]] = np.sqrt(3.0) * np.array(signs)  # 3σ together
                q = aim_wrist(geom, arm, -geom.normal(t.face), true)
                assert np.all(q[3:] >= model.joint_min_deg[3:] + SEARCH_MARGIN_DEG - 1e-6)
                assert np.all(q[3:] <= model.joint_max_deg[3:] - SEARCH_MARGIN_DEG + 1e-6)


def test_a_refusal_near_the_singularity_names_the_tools_tolerance_and_what_would_lift_it():
    profile = template("tx90xl").replace(tool_rotation_std_deg=np.full(3, 5.0))
    geom = geometry(profile)
    plan = plan_calibration(template("tx90xl"))
    t = plan.targets[0]  # base/XY: joint 5 some 30-40° from the singularity
    spread = aim_spread(profile, geom, t.joints_deg, t.face, profile.joint_offsets_deg)
    assert spread.cause(4) == TOOL
    q = t.joints_deg.copy()
    q[4] = 20.0 - profile.model.theta_offset_deg[4]
    with pytest.raises(SafetyError) as e:
        check_joints(profile, q, "base/XY", spread=spread)
    message = str(e.value)
    assert "wrist singularity" in message and "singularity_margin_deg" in message
    assert "the tool's declared orientation tolerance (±5 deg one sigma)" in message
    assert "[tool] rotation_std_deg) to ±" in message and "would lift it" in message


def test_a_refusal_at_a_joint_limit_names_the_room_kept_and_its_cause():
    profile = template()
    plan = plan_calibration(profile)
    geom = geometry(profile)
    t = next(t for t in plan.targets if t.face != 0)
    spread = aim_spread(profile, geom, t.joints_deg, t.face, profile.joint_offsets_deg)
    q = t.joints_deg.copy()
    q[4] = profile.model.joint_max_deg[4] - SEARCH_MARGIN_DEG - 0.5 * spread.deg[4]
    with pytest.raises(SafetyError) as e:
        check_joints(profile, q, "x", spread=spread)
    message = str(e.value)
    assert message.startswith("plan x: joint 5 at ")
    assert f"{SEARCH_MARGIN_DEG:g} deg for the wrist search" in message
    assert "the joint offsets (each known to ±1 deg one sigma" in message


def test_calibrate_refuses_a_tool_known_to_5_degrees_naming_the_tools_tolerance():
    """The tx90xl "tool known to 10 mm / 5°" cell: every calibration pose leaves joint 5
    within the 36° kept (the profile's margin and three sigma of the tool's and the block's
    orientation tolerances), the tool's the greater share: the refusal says so, and what
    would lift it."""
    profile = template("tx90xl").replace(
        tool_position_mm=np.array([20.0, 0.0, 113.0]),
        tool_rotation_deg=np.array([0.0, 10.0, 0.0]),
        tool_position_std_mm=np.array([10.0, 10.0, 10.0]),
        tool_rotation_std_deg=np.array([5.0, 5.0, 5.0]),
    )
    with pytest.raises(SafetyError) as e:
        plan_calibration(profile)
    msg = str(e.value)
    assert "wrist singularity: 10 deg the profile's margin" in msg
    assert "from the tool's declared orientation tolerance (±5 deg one sigma)" in msg
    assert "the tool's orientation known better (`ucal tool-frame`" in msg
    assert "would lift it" in msg


def test_a_declared_tolerance_is_named_by_its_share_and_keeps_the_same_room():
    """``check_joints`` with ``tolerance_deg`` refuses where it did, naming the tool or the
    block, whichever declares more."""
    profile = template().replace(
        tool_rotation_std_deg=np.array([0.1, 0.1, 0.1]),
        sample_rotation_std_deg=np.array([2.0, 2.0, 2.0]),
    )
    q = np.array([0.0, 30.0, 100.0, 0.0, 25.0, 0.0])
    check_joints(profile, q, "near", tolerance_deg=4.0)  # 10 + 4 < 25
    with pytest.raises(SafetyError) as e:
        check_joints(profile, q, "near", tolerance_deg=16.0)
    assert "within 26 deg of the wrist singularity" in str(e.value)
    assert "the block's declared orientation tolerance (±2 deg one sigma)" in str(e.value)
    assert "[sample] rotation_std_deg" in str(e.value)
