"""The map that carries the wrist centre and the flange's turn from verify's points to the tool
check's edges keeps its offset corrections within what the profile knows (no processes)."""

from __future__ import annotations

import numpy as np
import tomlkit

from ucal.kinematics.dh import fk_frames
from ucal.model.safety import TOLERANCE_SIGMAS, offsets_std_deg
from ucal.profile import default_profile_text, profile_from_data
from ucal.verify.plan import plan_verify
from ucal.verify.solve import WristMap


def test_three_points_with_the_wrist_offsets_undetermined_carry_the_edges():
    """A tx90 with a 10° holder, joints 2, 4, 5 and 6 left undetermined by calibrate and the
    wrist's truly 2.3°, 1.3° and 1.3° off: over verify's three points the map's joint-2
    correction went to −41° (the flange's turn the unmodelled wrist offsets left it), and the
    tool check's scan was commanded to a posture 12–27 mm from where the robot went. Fitted
    too, they carry the edges to where the robot goes."""
    profile = profile_from_data(tomlkit.parse(default_profile_text("tx90")), "tx90.toml").replace(
        tool_position_mm=np.array([18.9, 0.7, 108.6]),
        tool_rotation_deg=np.array([0.0, 10.0, 0.0]),
        joint_offsets_deg=np.array([-1.099, 0.0, -0.890, 0.0, 0.0, 0.0]),
        joint_offsets_std_deg=np.array([0.5, -1.0, 0.0103, -1.0, -1.0, -1.0]),
    )
    plan = plan_verify(profile, 3)
    after = np.array([t.joints_deg for t in plan.targets if t.pass_name == "after"])
    true = profile.joint_offsets_deg + np.array([0.0, -0.04, 0.0, 2.33, 1.30, 1.32])
    s_mat = profile.sample_matrix

    def true_w(q: np.ndarray) -> np.ndarray:
        w = fk_frames(profile.model, q, true)[..., 4, :3, 3]
        return (w - s_mat[:3, 3]) @ s_mat[:3, :3]

    def true_r(q: np.ndarray) -> np.ndarray:
        return fk_frames(profile.model, q, true)[..., 6, :3, :3]

    wmap = WristMap.fit(profile, after, true_w(after), profile.joint_offsets_deg, true_r(after))
    correction = wmap.offsets_deg - profile.joint_offsets_deg
    assert np.all(np.abs(correction) <= TOLERANCE_SIGMAS * offsets_std_deg(profile) + 1e-3)
    far = after[0] + np.array([-8.0, 17.0, -33.0, 0.0, 0.0, 0.0])  # the scan's far end
    assert np.linalg.norm(wmap(far) - true_w(far)) < 0.05
