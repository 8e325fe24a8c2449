"""Tool-frame's plan with a tool on a 20° holder: the beam 20° off the flange axis (no
processes). The orientation about the beam that suits the straight tool puts the edge scans'
wrist at its range or the peaks' joint 5 at the singularity; the plan takes another."""

from __future__ import annotations

import re

import numpy as np
import pytest
import tomlkit
from scipy.spatial.transform import Rotation

from ucal.cell import CellProfile
from ucal.errors import SafetyError
from ucal.kinematics.dh import fk
from ucal.kinematics.rotations import matrix_to_rpy
from ucal.model.safety import check_joints
from ucal.profile import default_profile_text, profile_from_data
from ucal.toolframe import plan as tool_plan
from ucal.toolframe.plan import (
    HALF_TURNS,
    QUARTER_TURNS,
    WRIST_MARGIN_DEG,
    plan_tool_frame,
    solve_target,
    tcp_pose,
)


def on_holder(model: str, holder_deg: float, axis: tuple[float, float, float]) -> CellProfile:
    """The template's profile with the tool turned ``holder_deg`` about ``axis`` (flange
    frame, across the flange axis)."""
    profile = profile_from_data(tomlkit.parse(default_profile_text(model)), f"{model}.toml")
    turn = Rotation.from_rotvec(np.radians(holder_deg) * np.asarray(axis)).as_matrix()
    return profile.replace(tool_rotation_deg=matrix_to_rpy(turn))


@pytest.mark.parametrize(
    ("model", "axis"), [("tx90l", (0.0, 1.0, 0.0)), ("tx90", (0.0, -1.0, 0.0))]
)
def test_a_twenty_degree_holder_plans_its_peaks_and_edge_scans(model, axis) -> None:
    profile = on_holder(model, 20.0, axis)
    plan = plan_tool_frame(profile, "exact", 4)
    assert len(plan.peaks) == 4 and len(plan.edges) == 2
    for t in plan.peaks:
        check_joints(profile, t.joints_deg, t.label, WRIST_MARGIN_DEG)
        reached = fk(profile.model, t.joints_deg, profile.tool_matrix)
        assert np.allclose(reached, tcp_pose(plan.plane, t.point_mm, t.water_path_mm, t.phi_deg))
    for e in plan.edges:
        assert e.search_mm >= 20.0, e  # main refused: "beyond 0 mm"
    # the edges scanned a quarter turn apart, each line's far end reachable in every turn
    assert plan.edge_turns_deg == QUARTER_TURNS and plan.edge_lines == 16
    for e in plan.edges:
        for turn in plan.edge_turns_deg:
            for lateral in e.lateral_mm:
                far = plan.centre_mm + (e.start_mm + e.search_mm) * e.direction + lateral * e.along
                phi = plan.phi0_deg + turn
                q = solve_target(
                    profile,
                    plan.plane,
                    profile.tool_matrix,
                    far,
                    50.0,
                    phi,
                    plan.peaks[0].joints_deg,
                    "e",
                    0,
                )
                check_joints(profile, q, "far end", 0.0)
    assert "/".join(f"{plan.phi0_deg + t:+.0f}" for t in QUARTER_TURNS) in plan.summary()


def test_a_straight_tool_scans_the_edges_half_a_turn_apart() -> None:
    """Turning a tool whose beam is along the flange axis is joint 6 alone: two orientations."""
    plan = plan_tool_frame(on_holder("tx90l", 0.0, (0.0, 1.0, 0.0)), "exact", 4)
    assert plan.edge_turns_deg == HALF_TURNS and plan.edge_lines == 8


def test_a_holder_on_a_cell_whose_dh_table_is_identified_scans_half_a_turn_apart() -> None:
    """After the full level the wrist's links are known (``[calibration] dh_std``): half a turn
    measures a holder's tool, as before."""
    identified = on_holder("tx90l", 20.0, (0.0, 1.0, 0.0)).replace(dh_std=np.full((6, 4), 0.002))
    plan = plan_tool_frame(identified, "exact", 4)
    assert plan.edge_turns_deg == HALF_TURNS and not plan.notes


def test_quarter_turns_the_arm_cannot_follow_fall_back_to_half_turns_saying_so(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    edges = tool_plan._plan_edges

    def no_quarter(plate, phi0, notes, turns):
        if len(turns) > 2:
            raise SafetyError("plan edge +e1: the arm cannot follow the edge search")
        return edges(plate, phi0, notes, turns)

    monkeypatch.setattr(tool_plan, "_plan_edges", no_quarter)
    plan = plan_tool_frame(on_holder("tx90l", 20.0, (0.0, 1.0, 0.0)), "exact", 4)
    assert plan.edge_turns_deg == HALF_TURNS
    assert any(
        "two orientations only" in n and "20° off the flange axis" in n for n in plan.notes
    ), plan.notes


def test_a_turned_target_holds_the_tool_centre_and_is_checked_as_planned() -> None:
    """An edge line's correction to normal incidence: the tool turned 6° about its centre
    from the planned orientation, taking joint 5 from 14.5° to 9.3°, within the 10° the plan
    keeps from the singularity; the check is the planned posture's, as the wrist search
    already reached the corrected one."""
    profile = on_holder("tx90l", 20.0, (0.0, 1.0, 0.0))
    plan = plan_tool_frame(profile, "exact", 4)
    point = plan.centre_mm + 60.0 * plan.edges[0].direction
    phi = plan.phi0_deg + 180.0
    turn = Rotation.from_rotvec(np.radians(6.0) * np.array([-1.0, 0.0, 0.0])).as_matrix()
    near = plan.peaks[0].joints_deg
    planned = solve_target(profile, plan.plane, profile.tool_matrix, point, 50.0, phi, near, "e", 0)
    q = solve_target(
        profile, plan.plane, profile.tool_matrix, point, 50.0, phi, near, "e", 0, turn=turn
    )
    assert planned[4] == pytest.approx(14.52, abs=0.01) and q[4] == pytest.approx(9.32, abs=0.01)
    reached = fk(profile.model, q, profile.tool_matrix)
    pose = tcp_pose(plan.plane, point, 50.0, phi)
    assert np.allclose(reached[:3, 3], pose[:3, 3], atol=1e-6)
    assert np.allclose(reached[:3, :3], turn @ pose[:3, :3], atol=1e-9)


def test_a_tool_known_to_5_degrees_is_refused_naming_its_tolerance_and_the_one_that_lifts_it():
    """A tx90xl with a 10° holder known to 10 mm / 5°: the plate centre's postures leave
    joint 5 within the 36° the searches keep (10° the profile's margin, 26° for the tool's
    orientation, three sigma). The refusal names the tool's tolerance and the one that lifts
    it, and that one plans."""
    base = profile_from_data(tomlkit.parse(default_profile_text("tx90xl")), "xl.toml").replace(
        tool_position_mm=np.array([20.0, 0.0, 113.0]),
        tool_rotation_deg=np.array([0.0, 10.0, 0.0]),
        tool_position_std_mm=np.array([10.0, 10.0, 10.0]),
    )
    with pytest.raises(SafetyError) as e:
        plan_tool_frame(base.replace(tool_rotation_std_deg=np.array([5.0, 5.0, 5.0])))
    msg = str(e.value)
    assert "wrist singularity" in msg and "[procedure] singularity_margin_deg" in msg
    assert "26 deg of that from the tool's declared orientation tolerance (±5 deg one sigma)" in msg
    lifted = re.search(
        r"\[tool\] rotation_std_deg: its drawing or a fixture\) to ±([0-9.]+) deg", msg
    )
    assert lifted is not None, msg
    assert "ucal tool-frame" not in msg  # this is tool-frame: the reader states the tool better
    std = float(lifted.group(1))
    assert 1.0 < std < 5.0
    plan_tool_frame(base.replace(tool_rotation_std_deg=np.full(3, std)))
