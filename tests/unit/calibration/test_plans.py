"""The offsets level's, the full level's and the region check's plans on cells the template
does not lay out: a block declared 2σ off, the README's step on the XY face, a block out of
reach, offsets not yet calibrated (no processes).

Each found plan is checked as the run checks it: every posture inside the joint ranges with
the wrist search's room and the declared tolerances' (``tolerance_margins``), and — for the
full level — still inside them when the block really stands 3σ off its declared pose.
"""

from __future__ import annotations

import itertools
from types import SimpleNamespace

import numpy as np
import pytest
import tomlkit

from ucal.cell import CellProfile, Step
from ucal.errors import SafetyError
from ucal.kinematics.dh import fk, fk_frames
from ucal.kinematics.ik import ik
from ucal.kinematics.rotations import rpy_to_matrix
from ucal.measure.postures import retarget
from ucal.model.geometry import CellGeometry, Configuration, Face, beam_and_tcp
from ucal.model.postures import Posture, order_postures, plan_full
from ucal.model.safety import (
    EDGE_MARGIN_MM,
    MIN_WATER_PATH_MM,
    SEARCH_MARGIN_DEG,
    check_joints,
    face_hit,
    offsets_margins_mm,
    step_blocked,
    tolerance_margins,
)
from ucal.model.targets import calibration_pose, geometry, plan_calibration
from ucal.model.wrist import aim_wrist
from ucal.profile import default_profile_text, profile_from_data
from ucal.verify.region import plan_region

#: The README's example step (docs/method/full-calibration.md).
README_STEP = Step(50.0, np.array([250.0, 250.0]), 60.0, 0.002)


def template(model: str) -> CellProfile:
    """The profile ``ucal profile init MODEL`` writes."""
    return profile_from_data(tomlkit.parse(default_profile_text(model)), f"{model}.toml")


def at_two_sigma(profile: CellProfile) -> CellProfile:
    """The block declared 2σ off the template's pose: lower, turned about every axis."""
    pos2 = 2.0 * profile.sample_position_std_mm
    return profile.replace(
        sample_position_mm=profile.sample_position_mm + pos2 * np.array([1.0, 1.0, -1.0]),
        sample_rotation_deg=2.0 * profile.sample_rotation_std_deg,
    )


def test_the_tolerance_margins_are_three_sigma_of_the_declared_tolerances() -> None:
    profile = template("tx90l")  # block 5 mm, 0.5° per axis; tool 1 mm, 0.5° per axis
    margins = tolerance_margins(profile)
    assert margins.wrist_deg == pytest.approx(3.0 * np.sqrt(0.75 + 0.75))
    tilt = 250.0 * np.radians(0.5)  # the block's tilt over half a 500 mm face
    assert margins.block_mm == pytest.approx(3.0 * np.sqrt(25.0 + 1.0 + tilt**2))
    doweled = profile.replace(
        sample_position_std_mm=np.full(3, 0.5), sample_rotation_std_deg=np.full(3, 0.01)
    )
    assert tolerance_margins(doweled).block_mm < 3.5


def test_the_full_plan_of_a_tx90xl_with_its_block_at_two_sigma_keeps_the_run_in_range() -> None:
    profile = at_two_sigma(template("tx90xl"))
    plan = plan_full(profile)
    margins = tolerance_margins(profile)
    assert len(plan.postures) >= 12
    off = profile.joint_offsets_deg
    # the block really 3σ further off in every direction the plan's margins must cover
    sigma3 = 3.0 * profile.sample_rotation_std_deg
    for signs in ([1, 1, 1], [-1, -1, -1], [1, -1, 1], [-1, 1, -1]):
        rot = rpy_to_matrix(profile.sample_rotation_deg + np.array(signs) * sigma3)
        truth = CellGeometry(profile.model, profile.tool_matrix, rot)
        for p in plan.postures:
            check_joints(profile, p.joints_deg, p.label, tolerance_deg=margins.wrist_deg)
            # as the run predicts it before moving there (ucal.measure.running.check_prediction)
            q = aim_wrist(truth, p.joints_deg, -truth.normal(p.face), off)
            check_joints(profile, q, p.label, SEARCH_MARGIN_DEG)
            assert p.water_path_mm >= MIN_WATER_PATH_MM + margins.block_mm


def test_the_offsets_plan_keeps_every_beam_off_the_readme_step() -> None:
    """The template's calibration pose aims its XY beam at the step's edge (a run then times
    the step's top as the face and walks off hundreds of moves later): the plan takes a pose
    whose beams all pass the step clear, with the tolerances' room."""
    profile = template("tx90l").replace(step=README_STEP)
    plan = plan_calibration(profile)
    assert not np.allclose(plan.pose_deg, calibration_pose(profile))  # the profile's fails
    geom = geometry(profile)
    margins = tolerance_margins(profile)
    corner = profile.sample_position_mm
    assert {t.config for t in plan.targets} >= {
        Configuration.BASE,
        Configuration.J2,
        Configuration.J3,
    }
    for t in plan.targets:
        check_joints(profile, t.joints_deg, t.label, tolerance_deg=margins.wrist_deg)
        beam, tcp = beam_and_tcp(geom, t.joints_deg, profile.joint_offsets_deg)
        local = geom.block_rotation.T @ (tcp - corner)
        blocked = step_blocked(
            README_STEP,
            local[None],
            (geom.block_rotation.T @ beam)[None],
            np.array([t.face]),
            margins.block_mm,
        )
        assert not blocked[0], t.label
        path, edge = face_hit(geom, t.joints_deg, profile.joint_offsets_deg, corner, t.face, 500.0)
        assert path >= MIN_WATER_PATH_MM + margins.block_mm
        assert edge >= EDGE_MARGIN_MM + margins.block_mm


def test_a_block_out_of_reach_is_refused_naming_how_far_to_move_it() -> None:
    profile = template("tx90l")
    corner = profile.sample_position_mm
    outward = np.array([corner[0], corner[1], 0.0]) / np.hypot(corner[0], corner[1])
    far = profile.replace(sample_position_mm=corner + 300.0 * outward)
    with pytest.raises(SafetyError) as e:
        plan_calibration(far)
    words = str(e.value)
    assert "calibration poses tried passes either: move the block about" in words
    shift = float(words.split("move the block about ")[1].split(" mm")[0])
    assert 100.0 <= shift <= 300.0 and words.endswith("mm towards the robot")


def test_the_offsets_margin_is_three_sigma_of_each_joints_lever_arm() -> None:
    """Only J2 unknown (1°): the tool centre moves by its distance from J2's axis per radian,
    three sigma of it; a calibrated profile's offsets leave hundredths of a millimetre."""
    profile = template("tx90xl")
    q = calibration_pose(profile)
    only_j2 = profile.replace(joint_offsets_std_deg=np.array([1e-9, 1.0, 1e-9, 1e-9, 1e-9, 1e-9]))
    frames = fk_frames(profile.model, q, profile.joint_offsets_deg)
    tcp = (frames[6] @ profile.tool_matrix)[:3, 3]
    axis, origin = frames[1, :3, 2], frames[1, :3, 3]  # joint 2 turns about frame 1's z
    lever = np.linalg.norm(np.cross(axis, tcp - origin))
    margin = offsets_margins_mm(only_j2, q[None])[0]
    assert np.linalg.norm(margin) == pytest.approx(3.0 * np.radians(1.0) * lever, rel=1e-5)
    assert np.linalg.norm(margin) > 30.0  # a TX90XL's reach: 0.76 m from J2, 13 mm a degree
    fresh = offsets_margins_mm(profile, q[None])[0]  # never calibrated: a degree each
    assert np.all(fresh > np.abs(margin) - 1e-9)
    calibrated = profile.replace(joint_offsets_std_deg=np.full(6, 0.003))
    assert np.all(offsets_margins_mm(calibrated, q[None]) < 0.2)


def test_a_fresh_full_plan_measures_the_offsets_first_then_postures_with_room_for_them() -> None:
    """A profile whose offsets were never calibrated: the run first measures the offsets
    level's faces (its plan's targets; the tank read by the postures after them), its first
    face reached before anything is measured with the tool 20 mm from the face and the beam
    on it under true offsets of 3° on J1-J3 (a fresh cell's 3σ), so that every posture after
    them is placed with measured offsets; the postures keep that 3σ on J1-J3 inside their
    ranges (the re-placed arm stays on its branch); a calibrated profile goes straight to its
    postures."""
    profile = at_two_sigma(template("tx90xl")).replace(step=README_STEP)
    plan = plan_full(profile)
    assert plan.first is not None and not plan.first.path_again
    offsets = plan_calibration(profile)
    assert [t.label for t in plan.first.targets] == [t.label for t in offsets.targets]
    first = plan.first.targets[0]
    path, edge = offsets_box_hits(profile, first.joints_deg, first.face)
    assert path >= MIN_WATER_PATH_MM and edge >= EDGE_MARGIN_MM
    arm = np.array([p.joints_deg[:3] for p in plan.postures])
    assert np.all(arm >= profile.model.joint_min_deg[:3] + 3.0)
    assert np.all(arm <= profile.model.joint_max_deg[:3] - 3.0)
    assert any(p.step for p in plan.postures) and not plan.postures[0].step
    assert plan_full(profile.replace(joint_offsets_std_deg=np.full(6, 0.003))).first is None


def test_a_posture_whose_branch_the_measured_offsets_leave_is_kept_as_planned() -> None:
    """J3 0.9° from its limit and measured offsets that need 1.3° more: the nearest solution
    in range is the other shoulder (J1 163° away, the arm swung over the base); the run keeps
    the plan's readings instead."""
    profile = template("tx90l")
    planned = np.array([15.31, -2.65, 144.13, -173.89, -58.01, 11.18])
    offsets = np.array([-1.6, -1.8, -1.34, 0.77, -0.6, 1.2])
    geom = geometry(profile)
    running = SimpleNamespace(
        offsets_deg=offsets, corner_mm=profile.sample_position_mm, geometry=geom
    )
    q = retarget(profile, running, Posture("p20", Face.XY, planned, 140.0))
    np.testing.assert_array_equal(q, planned)
    target = fk(profile.model, planned, geom.tool_matrix, profile.joint_offsets_deg)
    nearest = ik(geom.model, target, geom.tool_matrix, offsets, planned)
    assert abs(nearest[0] - planned[0]) > 150.0  # what the arm would have been sent to


def test_a_calibrated_profile_keeps_its_plan_in_travel_order() -> None:
    """Offsets known to thousandths of a degree need no room: the chosen postures in the
    nearest-next order, no lead-in."""
    profile = template("tx90xl").replace(step=README_STEP, joint_offsets_std_deg=np.full(6, 0.003))
    plan = plan_full(profile)
    again = order_postures(list(plan.postures))
    assert [p.label for p in again] == [p.label for p in plan.postures]


def test_offsets_too_uncertain_for_any_posture_are_refused_naming_the_cure() -> None:
    profile = template("tx90xl").replace(joint_offsets_std_deg=np.full(6, 5.0))
    with pytest.raises(SafetyError) as e:
        plan_full(profile)
    words = str(e.value)
    assert "joint offsets known to ±15°" in words
    assert "calibrate the offsets first (`ucal calibrate PROFILE`)" in words
    assert "the block" in words


def test_a_posture_is_retargeted_onto_the_cell_as_measured() -> None:
    """Offsets of a degree and a block 5 mm off, as the run has measured them: the retargeted
    readings, the wrist aimed as the run aims it, put the tool centre where the plan put it
    relative to that block, beam along the same normal, joint 6 as planned."""
    profile = template("tx90xl")
    plan = plan_full(profile.replace(joint_offsets_std_deg=np.full(6, 0.003)), max_postures=3)
    offsets = np.array([0.5, -1.0, 1.0, 0.3, -0.4, 0.0])
    corner = profile.sample_position_mm + np.array([5.0, -3.0, 2.0])
    geom = geometry(profile)
    running = SimpleNamespace(offsets_deg=offsets, corner_mm=corner, geometry=geom)
    for p in plan.postures:
        q = aim_wrist(geom, retarget(profile, running, p), -geom.normal(p.face), offsets)
        planned = fk(profile.model, p.joints_deg, profile.tool_matrix)
        there = fk(profile.model, q, profile.tool_matrix, offsets)
        np.testing.assert_allclose(
            there[:3, 3] - corner, planned[:3, 3] - profile.sample_position_mm, atol=1e-6
        )
        np.testing.assert_allclose(there[:3, 2], planned[:3, 2], atol=1e-9)
        assert q[5] == p.joints_deg[5]
        assert np.max(np.abs(q[:3] - p.joints_deg[:3])) > 0.3  # the arm moved, not the wrist


def test_a_block_turned_off_the_base_axes_leaves_what_no_beam_sees_unidentifiable() -> None:
    """d5, a5 and link 6's a move the flange across every beam: on a block turned by a
    fraction of a degree their columns are rounding (5e-7), not weak information, and they
    stay held at their values as on a block square to the base."""
    square = plan_full(template("tx90l")).structure
    turned = plan_full(template("tx90l").replace(sample_rotation_deg=np.array([0.8, -0.6, 0.3])))
    assert square is not None and turned.structure is not None
    unseen = {"dh5_d_mm", "dh5_a_mm", "dh6_a_mm"}
    assert unseen <= set(square.redundant) and unseen <= set(turned.structure.redundant)
    assert not unseen & set(turned.structure.weak)
    assert turned.structure.rank == square.rank


def offsets_box_hits(profile: CellProfile, q: np.ndarray, face: int) -> tuple[float, float]:
    """The least water path and distance of the beam's hit from the face's edge (mm) at
    readings ``q``, over true offsets of J1-J3 anywhere on the corners and edges of the box of
    three sigma each (a never-calibrated profile's 1°), the declared block."""
    geom = geometry(profile)
    corner = profile.sample_matrix[:3, 3]
    hits = [
        face_hit(geom, q, 3.0 * np.array([*s, 0.0, 0.0, 0.0]), corner, face, 500.0)
        for s in itertools.product((-1.0, 0.0, 1.0), repeat=3)
    ]
    return min(h[0] for h in hits), min(h[1] for h in hits)


def test_a_fresh_region_plan_starts_where_the_offsets_leave_the_beam_on_the_face() -> None:
    """A never-calibrated TX90: the region's postures in travel order alone (lowest J1 first,
    the old plan) would meet the face with the beam off its edge under offsets of 3° on J1-J3;
    the plan leads with a posture that keeps the water path and the edge's margin there."""
    profile = template("tx90")
    plan = plan_region(profile, 12)
    assert len(plan.postures) == 12
    first = plan.postures[0]
    path, edge = offsets_box_hits(profile, first.joints_deg, first.face)
    assert path >= MIN_WATER_PATH_MM and edge >= EDGE_MARGIN_MM
    old = order_postures(list(plan.postures))[0]
    assert old.label != first.label
    assert offsets_box_hits(profile, old.joints_deg, old.face)[1] < 0.0  # off the face


def test_a_calibrated_region_plan_keeps_its_travel_order() -> None:
    """Offsets known to thousandths of a degree (after ``calibrate``) leave hundredths of a
    millimetre of room to keep: the spread postures in the nearest-next order, no lead-in."""
    profile = template("tx90").replace(joint_offsets_std_deg=np.full(6, 0.003))
    plan = plan_region(profile, 12)
    assert [p.label for p in plan.postures] == [f"r{i + 1:02d}" for i in range(12)]
    again = order_postures(list(plan.postures))
    assert [p.label for p in again] == [p.label for p in plan.postures]
    assert len({tuple(p.joints_deg) for p in plan.postures}) == 12


def test_a_region_plan_without_room_for_the_offsets_is_refused_naming_the_cure() -> None:
    profile = template("tx90xl").replace(joint_offsets_std_deg=np.full(6, 5.0))
    with pytest.raises(SafetyError) as e:
        plan_region(profile, 12)
    words = str(e.value)
    assert words.startswith("plan verify --region: with the joint offsets known to ±15°")
    assert "calibrate the offsets first (`ucal calibrate PROFILE`)" in words


def test_a_region_plan_with_the_block_out_of_reach_is_refused_naming_how_far_to_move_it() -> None:
    profile = template("tx90l")
    corner = profile.sample_position_mm
    outward = np.array([corner[0], corner[1], 0.0]) / np.hypot(corner[0], corner[1])
    with pytest.raises(SafetyError) as e:
        plan_region(profile.replace(sample_position_mm=corner + 1000.0 * outward), 12)
    words = str(e.value)
    assert words.startswith("plan verify --region: no posture normal to a block face passes")
    assert words.endswith("mm towards the robot") and "move the block about " in words
