"""Verification maths: statistics, grid, and the reached TCP from three face measurements."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest
import tomlkit
from scipy.spatial.transform import Rotation

from ucal.acoustics import sound_speed_m_s
from ucal.errors import SafetyError
from ucal.kinematics.dh import fk_frames
from ucal.model.geometry import beam_and_tcp
from ucal.model.safety import MIN_WATER_PATH_MM
from ucal.model.targets import geometry
from ucal.model.wrist import aim_wrist
from ucal.profile import default_profile_text, profile_from_data
from ucal.verify.inputs import sound_speed_for_verify
from ucal.verify.measure import (
    PointResult,
    SkippedPoint,
    VerifyResult,
    line_to_edge,
    predicted_clearance_mm,
)
from ucal.verify.picture import plot_verify
from ucal.verify.plan import (
    grid_shape,
    nominal_points,
    plan_verify,
    tool_clearance_mm,
    tool_lever,
    verify_region,
    wrist_centre_local,
)
from ucal.verify.result import profile_notes
from ucal.verify.solve import (
    WristMap,
    deviation_stats,
    estimate_orientation,
    reached_from_peaks,
    reached_tcp_local,
    wrist_centre_from_distances,
)


@pytest.fixture(scope="module")
def profile():
    return profile_from_data(tomlkit.parse(default_profile_text("tx90l")), "cell.toml")


def test_deviation_stats_exact_numbers() -> None:
    dev = np.array([[1.0, -2.0, 0.5], [-3.0, 2.0, 0.5], [2.0, -2.0, -0.5], [-2.0, 4.0, 1.5]])
    st = deviation_stats(dev)
    # |Δ|: X 1, 3, 2, 2 → mean 2, max 3, std sqrt(0.5); Y 2, 2, 2, 4 → 2.5, 4, sqrt(0.75)
    # Z 0.5, 0.5, 0.5, 1.5 → 0.75, 1.5, sqrt(0.1875)
    assert st["mean"] == pytest.approx([2.0, 2.5, 0.75])
    assert st["max"] == pytest.approx([3.0, 4.0, 1.5])
    assert st["std"] == pytest.approx([np.sqrt(0.5), np.sqrt(0.75), np.sqrt(0.1875)])
    assert st["signed_mean"] == pytest.approx([-0.5, 0.5, 0.5])
    assert st["signed_std"] == pytest.approx([np.sqrt(4.25), np.sqrt(6.75), np.sqrt(0.5)])


def test_notes_name_what_the_profile_does_not_know(profile) -> None:
    """verify says why its 'after' is off when the profile says so itself: never calibrated,
    or J1 kept (a hand-placed block); J6 alone is no note (the tool is measured in its frame)."""
    [never] = profile_notes(profile)
    assert "never calibrated" in never
    std = np.array([np.nan, 0.005, 0.004, 0.004, 0.0006, np.nan])
    [j1] = profile_notes(profile.replace(joint_offsets_std_deg=std, unobservable_joints=(1, 6)))
    assert j1.startswith("J1 not calibrated") and "block's yaw" in j1
    [j3] = profile_notes(profile.replace(joint_offsets_std_deg=std, unobservable_joints=(3,)))
    assert j3.startswith("J3 not calibrated") and "yaw" not in j3
    assert profile_notes(profile.replace(joint_offsets_std_deg=std, unobservable_joints=(6,))) == []


def test_wrist_centre_from_distances_adds_the_lever() -> None:
    w = wrist_centre_from_distances(np.array([70.0, 95.5, 30.0]), 180.0)
    assert w == pytest.approx([250.0, 275.5, 210.0])


@pytest.mark.parametrize(
    "n, shape", [(20, (5, 4)), (4, (2, 2)), (6, (3, 2)), (9, (3, 3)), (7, (7, 1)), (1, (1, 1))]
)
def test_grid_shape(n: int, shape: tuple[int, int]) -> None:
    assert grid_shape(n) == shape


def test_nominal_points_uniform_on_the_30mm_plane(profile) -> None:
    pts = nominal_points(profile, 20)
    lo, hi = verify_region(profile)
    assert pts.shape == (20, 3)
    assert np.all(pts[:, 2] == 30.0)
    assert sorted(set(np.round(pts[:, 0], 6))) == pytest.approx(np.linspace(lo[0], hi[0], 5))
    assert sorted(set(np.round(pts[:, 1], 6))) == pytest.approx(np.linspace(lo[1], hi[1], 4))
    # W (180 mm above the TCP) keeps 50–150 mm of water to each wall
    _, lever = tool_lever(profile)
    assert lever == pytest.approx(180.0)
    assert lo == pytest.approx([230.0, 230.0]) and hi == pytest.approx([330.0, 330.0])


def test_reached_tcp_from_three_exact_face_measurements(profile) -> None:
    """Synthetic measurements on a robot with hidden offsets give back its true TCP."""
    geom = geometry(profile)
    true = np.array([0.8, -1.2, 1.5, -2.0, 1.1, 0.6])
    plan = plan_verify(profile, 4)
    v, lever = tool_lever(profile)
    s_mat = profile.sample_matrix
    for target in plan.targets:
        q_cmd = target.joints_deg
        # the true robot's normal-incidence postures, same arm joints
        peaks = np.array(
            [aim_wrist(geom, target.face_joints_deg[k], -geom.normal(k), true) for k in range(3)]
        )
        assert np.allclose(peaks[:, :3], q_cmd[:3])
        dist = np.array(
            [
                geom.normal(k) @ (beam_and_tcp(geom, peaks[k], true)[1] - s_mat[:3, 3])
                for k in range(3)
            ]
        )
        w = wrist_centre_from_distances(dist, lever)
        orient = estimate_orientation(geom, peaks, plan.offsets_deg[target.pass_name])
        got = reached_tcp_local(geom, w, orient, q_cmd, v)
        tcp_true = beam_and_tcp(geom, q_cmd, true)[1]
        want = s_mat[:3, :3].T @ (tcp_true - s_mat[:3, 3])
        assert got == pytest.approx(want, abs=1e-6)
        # and the robot really is off the nominal point by millimetres
        assert np.max(np.abs(want - plan.nominal_mm[target.index])) > 1.0


def test_reached_tcp_of_a_tool_off_the_flange_axis(profile) -> None:
    """A tool 1.7 mm off the flange axis with its beam 1.2° off it, on a robot whose J1–J5
    offsets differ from the profile's: the reached TCP comes out in the frame of the profile's
    J6 offset (the tool's), to a micrometre, in both passes."""
    prof = profile.replace(
        tool_position_mm=np.array([1.2, -1.2, 80.0]),
        tool_rotation_deg=np.array([0.9, -0.8, 0.0]),
        joint_offsets_deg=np.array([0.3, -0.5, 0.4, 0.2, -0.3, 0.7]),
    )
    geom = geometry(prof)
    true = np.array([1.6, -0.9, 1.1, -1.4, 0.5, 0.7])  # J6 as the profile says: the tool's frame
    plan = plan_verify(prof, 2)
    s_mat = prof.sample_matrix
    for target in plan.targets:
        peaks = np.array(
            [aim_wrist(geom, target.face_joints_deg[k], -geom.normal(k), true) for k in range(3)]
        )
        dist = np.array(
            [
                geom.normal(k) @ (beam_and_tcp(geom, peaks[k], true)[1] - s_mat[:3, 3])
                for k in range(3)
            ]
        )
        _, orient, got = reached_from_peaks(prof, geom, peaks, dist, target.joints_deg)
        want = s_mat[:3, :3].T @ (beam_and_tcp(geom, target.joints_deg, true)[1] - s_mat[:3, 3])
        assert orient.rms_deg < 1e-6
        assert got == pytest.approx(want, abs=1e-3)


def test_orientation_ignores_the_unseen_joint_6(profile) -> None:
    """With the beam on the joint-6 axis a joint-6 offset changes neither beam nor TCP."""
    geom = geometry(profile)
    plan = plan_verify(profile, 1)
    t = plan.targets[0]
    v, _ = tool_lever(profile)
    tcps = []
    for j6 in (0.0, 3.0):
        true = np.array([0.0, 0.0, 0.0, 0.0, 0.0, j6])
        peaks = np.array(
            [aim_wrist(geom, t.face_joints_deg[k], -geom.normal(k), true) for k in range(3)]
        )
        orient = estimate_orientation(geom, peaks, np.zeros(6))
        assert orient.rms_deg < 1e-8
        tcps.append(reached_tcp_local(geom, np.zeros(3), orient, t.joints_deg, v))
    # W at the origin: the TCP is 180 mm straight below it in both cases
    assert tcps[0] == pytest.approx([0.0, 0.0, -180.0], abs=1e-6)
    assert tcps[1] == pytest.approx(tcps[0], abs=1e-6)


def test_plan_refuses_an_unreachable_block(profile) -> None:
    far = profile.replace(sample_position_mm=profile.sample_position_mm + [2000.0, 0.0, 0.0])
    with pytest.raises(SafetyError, match=r"unreachable|range"):
        plan_verify(far, 4)


def test_plan_uses_the_offsets_in_the_after_pass_only(profile) -> None:
    off = np.array([0.4, -0.5, 0.6, -0.7, 0.5, 0.3])
    plan = plan_verify(profile.replace(joint_offsets_deg=off), 4)
    before = [t for t in plan.targets if t.pass_name == "before"]
    after = [t for t in plan.targets if t.pass_name == "after"]
    assert len(before) == len(after) == 4
    for b, a in zip(before, after, strict=True):
        # the commanded readings of "after" put the *offset* model's TCP on the point
        tb = beam_and_tcp(geometry(profile), b.joints_deg, np.zeros(6))[1]
        ta = beam_and_tcp(geometry(profile), a.joints_deg, off)[1]
        assert ta == pytest.approx(tb, abs=1e-6)
        assert not np.allclose(a.joints_deg, b.joints_deg, atol=0.1)


def test_before_is_the_profile_before_its_last_calibration(tmp_path) -> None:
    from ucal.profile import create_profile, write_profile
    from ucal.verify.inputs import offsets_before_calibration
    from ucal.verify.solve import passed

    path = create_profile(tmp_path / "cell.toml", "tx90l")
    assert offsets_before_calibration(path).offsets_deg.tolist() == [0.0] * 6
    first = [0.1, 0.2, 0.3, 0.4, 0.5, 0.6]
    write_profile(path, {"calibration": {"joint_offsets_deg": first}}, "calibrate --method exact")
    write_profile(path, {"tool": {"position_mm": [1.0, 0.0, 80.0]}}, "tool-frame (exact)")
    write_profile(
        path,
        {"calibration": {"joint_offsets_deg": [0.0, 0.0, 0.0, 0.0, 0.0, 1.0]}},
        "calibrate --method exact",
    )
    before = offsets_before_calibration(path)
    assert before.offsets_deg.tolist() == first and "history entry 3" in before.source
    stats = {"max": [0.1, 0.4, 0.2]}
    assert passed(stats, 0.4) and not passed(stats, 0.39)


def test_before_is_commanded_in_the_block_the_profile_had_then(tmp_path) -> None:
    """calibrate writes the block it measured: "before" places its points in the block the
    profile had before that write, "after" in the measured one, and an uncalibrated profile's
    "before" is the profile as it is."""
    from ucal.profile import create_profile, load_profile, write_profile
    from ucal.verify.inputs import offsets_before_calibration

    path = create_profile(tmp_path / "cell.toml", "tx90l")
    fresh = load_profile(path)
    assert offsets_before_calibration(path).same_as(fresh)
    placed = fresh.sample_position_mm
    write_profile(
        path,
        {
            "calibration": {"joint_offsets_deg": [0.8, -1.2, 1.5, -2.0, 1.1, 0.0]},
            "sample": {"position_mm": (placed + [1.5, -1.0, 0.8]).tolist()},
        },
        "calibrate --method exact: fit ok",
    )
    profile = load_profile(path)
    before = offsets_before_calibration(path)
    assert not before.same_as(profile)
    then = before.placed(profile)
    assert then.sample_position_mm == pytest.approx(placed)
    plan = plan_verify(profile, 2, before_offsets_deg=before.offsets_deg, before_placed=then)
    geom_then, geom_now = geometry(then), geometry(profile)
    for target in plan.targets:
        seen, geom, off = (
            (then, geom_then, before.offsets_deg)
            if target.pass_name == "before"
            else (profile, geom_now, profile.joint_offsets_deg)
        )
        tcp = beam_and_tcp(geom, target.joints_deg, off)[1]
        s_mat = seen.sample_matrix
        local = s_mat[:3, :3].T @ (tcp - s_mat[:3, 3])
        assert local == pytest.approx(plan.nominal_mm[target.index], abs=1e-6)


def test_gauge_says_what_is_known_only_relative_to_the_block(tmp_path, profile) -> None:
    """verify's figures are relative to the block; with J1 calibrated relative to the block
    as placed, the points in the base frame are known to the yaw's tolerance at their reach."""
    from ucal.verify.inputs import VerifyGauge, calibration_gauge

    path = tmp_path / "cell.toml"
    doc = tomlkit.parse(default_profile_text("tx90l"))
    path.write_text(tomlkit.dumps(doc), encoding="utf-8")
    none = calibration_gauge(profile, path)
    assert none.j1 is None and none.absolute_std_mm is None
    assert "gauge: block" in none.statement() and "J1" not in none.statement()
    doc["calibration"]["gauge"] = "block"
    path.write_text(tomlkit.dumps(doc), encoding="utf-8")
    hand = calibration_gauge(profile, path)
    assert hand.j1 == "block" and hand.yaw_std_deg == 0.5
    reached = VerifyGauge("block", 0.5, reach_mm=650.0)
    assert reached.absolute_std_mm == pytest.approx(650.0 * np.radians(0.5))
    assert "only to ±5.7 mm" in reached.statement()
    assert "relative to the block as placed" in reached.statement()
    fixture = VerifyGauge("base", 0.01, reach_mm=650.0)
    assert "J1 is absolute" in fixture.statement() and "±0.11 mm" in fixture.statement()


def test_wrist_map_carries_arm_errors_to_the_edges(profile) -> None:
    """Joints 1–3 off by degrees (not calibrated) and the block shifted: fitted over a 2 × 3
    grid of wrist centres, carried 200 mm beyond it to within a micrometre (a single rigid
    motion misses the change of a joint-2 error's axis with joint 1 by tenths of a mm)."""
    plan = plan_verify(profile, 6)
    after = np.array([t.joints_deg for t in plan.targets if t.pass_name == "after"])
    error = np.array([2.0, -1.6, 0.8, 0.0, 0.0, 0.0])
    shift = np.array([0.3, -0.2, 0.05])
    s_mat = profile.sample_matrix

    def true_w(q: np.ndarray) -> np.ndarray:
        w = fk_frames(profile.model, q, error)[..., 4, :3, 3]
        return (w - s_mat[:3, 3]) @ s_mat[:3, :3] + shift

    wmap = WristMap.fit(profile, after, true_w(after), np.zeros(6))
    far = after[0].copy()
    far[0] += 8.0  # joint 1 turned: ~150–200 mm along the block
    far[1] -= 3.0
    assert wmap(far) == pytest.approx(true_w(far), abs=1e-3)
    # one point: the shift only
    one = WristMap.fit(profile, after[:1], true_w(after[:1]), np.zeros(6))
    assert one(after[0]) == pytest.approx(true_w(after[0]), abs=1e-6)
    # with the flange rotations the points measured (here turned as the block's faces are, by
    # a constant 0.1°), the flange's turn is carried there too: to a microradian
    turn = Rotation.from_rotvec([0.0, 0.0, np.radians(0.1)]).as_matrix()

    def true_r(q: np.ndarray) -> np.ndarray:
        return turn @ fk_frames(profile.model, q, error)[..., 6, :3, :3]

    both = WristMap.fit(profile, after, true_w(after), np.zeros(6), true_r(after))
    assert both(far) == pytest.approx(true_w(far), abs=1e-3)
    miss = Rotation.from_matrix(both.rotation(far).T @ true_r(far)).magnitude()
    assert miss < 1e-6
    assert Rotation.from_matrix(wmap.rotation(far).T @ true_r(far)).magnitude() > 1e-3


def test_sound_speed_from_the_calibration_else_the_thermometer(tmp_path, profile) -> None:
    path = tmp_path / "cell.toml"
    path.write_text(default_profile_text("tx90l"), encoding="utf-8")
    s = sound_speed_for_verify(profile, path)
    assert s.m_s == pytest.approx(sound_speed_m_s(profile.water_temperature_c))
    assert "temperature_c" in s.source
    doc = tomlkit.parse(path.read_text(encoding="utf-8"))
    doc["calibration"]["sound_speed_m_s"] = 1486.422
    path.write_text(tomlkit.dumps(doc), encoding="utf-8")
    s = sound_speed_for_verify(profile, path)
    assert s.m_s == 1486.422 and "measured with the offsets" in s.source
    assert sound_speed_m_s(s.temperature_c) == pytest.approx(1486.422, abs=1e-6)


def test_a_before_point_the_measured_points_put_into_the_block_is_skipped(
    profile, tmp_path
) -> None:
    """Offsets before calibration 2° off put the TCP 25 mm below the nominal points, 5 mm above
    the XY face: the next point's clearance comes from the W measured at the last one, and a
    point skipped is reported as such, its pass's statistics over the points measured."""
    plan = plan_verify(profile, 2)
    off = plan.offsets_deg["before"]
    first, second = plan.targets[0], plan.targets[1]
    w_model = wrist_centre_local(profile, first.joints_deg, off)
    low = w_model - np.array([0.0, 0.0, 25.0])  # what the faces measured: 25 mm lower

    def point(pass_name: str, index: int, w: np.ndarray, tcp: np.ndarray) -> PointResult:
        q = plan.targets[index if pass_name == "before" else 2 + index].joints_deg
        return PointResult(pass_name, index, plan.nominal_mm[index], q, (), w, tcp, 0.0)

    measured = point("before", 0, low, plan.nominal_mm[0] - np.array([0.0, 0.0, 25.0]))
    clear = predicted_clearance_mm(profile, measured, second.joints_deg, off)
    w_second = wrist_centre_local(profile, second.joints_deg, off)
    assert clear == pytest.approx(tool_clearance_mm(profile, w_second) - 25.0, abs=1e-9)
    assert clear == pytest.approx(5.0, abs=0.01)  # 30 mm above the face, 25 mm lower
    result = VerifyResult(
        plan,
        [measured] + [point("after", i, w_model, plan.nominal_mm[i] + 0.01) for i in range(2)],
        moves=0,
        reads=0,
        skipped=(SkippedPoint("before", 1, clear),),
    )
    out = result.to_json(0.5)
    assert out["measured_points"] == {"before": [1], "after": [1, 2]}
    assert out["skipped"] == [
        "before point 2 not measured: the tool would come 5.0 mm from a face there (the "
        "points measured before it say), less than the 20 mm kept"
    ]
    assert out["before_mm"]["max"] == pytest.approx([0.0, 0.0, 25.0])
    assert out["after_mm"]["max"] == pytest.approx([0.01, 0.01, 0.01])
    assert out["passed"]
    assert plot_verify(result, tmp_path / "v.png").stat().st_size > 0
    # every "before" point skipped: its statistics null, the verdict the "after" points'
    none = replace(result, points=result.points[1:], skipped=(*result.skipped, result.skipped[0]))
    out = json.loads(json.dumps(none.to_json(0.5), allow_nan=False))
    assert out["before_mm"]["max"] == [None] * 3 and out["measured_points"]["before"] == []
    assert out["after_mm"]["max"] == pytest.approx([0.01, 0.01, 0.01]) and out["passed"]


def test_before_points_the_current_offsets_put_into_the_block_are_flagged(profile) -> None:
    """Before the first motion: a "before" point commanded with offsets 2° off from the
    profile's current ones would put the tool a few mm from the XY face; the plan says so from
    the current offsets (the run skips it without moving there), and not of "after" points."""
    calibrated = profile.replace(joint_offsets_deg=np.array([0.0, 2.0, -1.0, 0.0, 0.0, 0.0]))
    plan = plan_verify(calibrated, 3, before_offsets_deg=np.zeros(6))
    before = [t for t in plan.targets if t.pass_name == "before"]
    after = [t for t in plan.targets if t.pass_name == "after"]
    assert all(t.clearance_mm < MIN_WATER_PATH_MM for t in before[:2])  # 30 mm, beam down
    assert all(t.clearance_mm >= MIN_WATER_PATH_MM for t in after)
    # the same plan with the before offsets right: nothing flagged
    plan = plan_verify(calibrated, 3, before_offsets_deg=calibrated.joint_offsets_deg)
    assert all(t.clearance_mm >= MIN_WATER_PATH_MM for t in plan.targets)


def test_the_edge_scan_line_follows_the_arm_the_points_measured() -> None:
    """A profile whose J1 is 1.8° off: the real TCP moves 0.88 mm per mm the profile's does
    along the line, and starts 17.7 mm beyond the nominal point; the line ends 15 mm of real
    motion beyond the edge (the profile's own offset alone would stop 20 mm short)."""

    def estimate(t: float) -> float:
        return 330.0 + 17.7 + 0.88 * t + 1e-5 * t**2

    t_edge, t_max = line_to_edge(estimate, estimate(0.0), 500.0 - 347.7, 500.0, 15.0)
    assert estimate(t_edge) == pytest.approx(500.0, abs=1e-4)
    assert estimate(t_max) == pytest.approx(515.0, abs=0.05)
    assert estimate(500.0 - 347.7 + 15.0) < 500.0 - 4.0


def test_peak_noise_does_not_turn_the_tool_about_joint_6(profile) -> None:
    """Peaks found to 0.003° (their noise) on a tool 1.7 mm off the flange axis with its beam
    1.2° off it: joint 6 stays the profile's (the tool's frame), so the TCP moves by the
    noise's own hundredth of a mm, not by a J6 fitted from it (0.14 mm here)."""
    prof = profile.replace(
        tool_position_mm=np.array([1.2, -1.2, 80.0]),
        tool_rotation_deg=np.array([0.9, -0.8, 0.0]),
    )
    geom = geometry(prof)
    plan = plan_verify(prof, 2)
    s_mat = prof.sample_matrix
    rng = np.random.default_rng(7)
    worst = 0.0
    for target in plan.targets:
        exact = np.array(
            [
                aim_wrist(geom, target.face_joints_deg[k], -geom.normal(k), np.zeros(6))
                for k in range(3)
            ]
        )
        for _ in range(5):
            peaks = exact.copy()
            peaks[:, 3:5] += rng.normal(0.0, 0.003, (3, 2))
            dist = np.array(
                [
                    geom.normal(k) @ (beam_and_tcp(geom, exact[k], np.zeros(6))[1] - s_mat[:3, 3])
                    for k in range(3)
                ]
            )
            _, _, got = reached_from_peaks(prof, geom, peaks, dist, target.joints_deg)
            tcp = beam_and_tcp(geom, target.joints_deg, np.zeros(6))[1]
            want = s_mat[:3, :3].T @ (tcp - s_mat[:3, 3])
            worst = max(worst, float(np.max(np.abs(got - want))))
    assert worst < 0.03
