"""Verify's plan on cells the paper's layout does not fit: a tool on a 20° holder, a long
tool, the README's step (no processes). Every commanded and face posture is checked as the
run checks it, with the declared tolerances' room."""

from __future__ import annotations

import numpy as np
import pytest
import tomlkit
from scipy.spatial.transform import Rotation

from ucal.cell import CellProfile, Step
from ucal.kinematics.rotations import matrix_to_rpy
from ucal.model.geometry import beam_and_tcp
from ucal.model.safety import check_joints, step_blocked, tolerance_margins
from ucal.model.targets import geometry
from ucal.profile import default_profile_text, profile_from_data
from ucal.verify.plan import VERIFY_HEIGHT_MM, plan_verify

README_STEP = Step(50.0, np.array([250.0, 250.0]), 60.0, 0.002)


def profile_with(model: str, holder_deg: float = 0.0, length_mm: float = 80.0) -> CellProfile:
    """The template's profile with a tool ``length_mm`` long on a holder turning the beam
    ``holder_deg`` about the flange's x axis."""
    profile = profile_from_data(tomlkit.parse(default_profile_text(model)), f"{model}.toml")
    turn = Rotation.from_rotvec(np.radians(holder_deg) * np.array([1.0, 0.0, 0.0])).as_matrix()
    return profile.replace(
        tool_rotation_deg=matrix_to_rpy(turn), tool_position_mm=np.array([0.0, 0.0, length_mm])
    )


def assert_in_range(profile: CellProfile, plan) -> None:
    margins = tolerance_margins(profile)
    for t in plan.targets:
        check_joints(profile, t.joints_deg, t.label, tolerance_deg=margins.wrist_deg)
        for q in t.face_joints_deg:
            check_joints(profile, q, t.label, tolerance_deg=margins.wrist_deg)


@pytest.mark.parametrize(("model", "holder"), [("tx90l", 20.0), ("tx90xl", 20.0)])
def test_a_twenty_degree_holder_is_verified_from_points_raised_for_it(model, holder) -> None:
    """Main refused it: at the paper's 30 mm the holder's tool, turning about the wrist
    centre, would come within 20 mm of the face."""
    profile = profile_with(model, holder)
    plan = plan_verify(profile, 6)
    assert plan.height_mm > VERIFY_HEIGHT_MM
    assert_in_range(profile, plan)


def test_verify_points_stay_beside_the_step() -> None:
    profile = profile_with("tx90l").replace(step=README_STEP)
    plan = plan_verify(profile, 6)
    assert_in_range(profile, plan)
    geom = geometry(profile)
    margins = tolerance_margins(profile)
    s_mat = profile.sample_matrix
    for t in plan.targets:
        for face, q in enumerate(t.face_joints_deg):
            beam, tcp = beam_and_tcp(geom, q, plan.offsets_deg[t.pass_name])
            local = s_mat[:3, :3].T @ (tcp - s_mat[:3, 3])
            blocked = step_blocked(
                README_STEP, local[None], (s_mat[:3, :3].T @ beam)[None], np.array([face]), 0.0
            )
            assert not blocked[0], t.label
    # and the tool check's scans run from the points to the far edges away from it
    corner = README_STEP.centre_mm + 0.5 * README_STEP.size_mm + margins.block_mm
    side = [axis for axis in (0, 1) if np.all(plan.nominal_mm[:, axis] >= corner[axis])]
    assert side
