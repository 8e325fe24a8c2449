"""The arm's motion model: joint-interpolated trapezoids, synchronised joints, settling, and a
two-point approach queued on the simulated controller over loopback."""

from __future__ import annotations

import math

import numpy as np
import pytest

from drivers.clock import SimClock
from drivers.controller.client import SimpleMessageController
from drivers.controller.motion import (
    DEFAULT_MAX_ACCEL_DEG_S2,
    joint_move,
    trajectory_s,
)
from drivers.controller.simulator import SimulatedController
from ucal.timing import APPROACH_DEG, move_s

SPEED = np.array([250.0, 200.0, 250.0, 400.0, 400.0, 600.0])
ACCEL = np.asarray(DEFAULT_MAX_ACCEL_DEG_S2)
ZERO = np.zeros(6)


def test_a_long_move_reaches_and_holds_the_speed_limit() -> None:
    target = np.array([90.0, 0, 0, 0, 0, 0])
    move = joint_move(ZERO, target, 1.0, SPEED, ACCEL)
    # 250 deg/s reached in 0.25 s over 31.25 deg, cruise, then the same deceleration
    assert move.accel_time_s == pytest.approx(0.25)
    assert move.duration_s == pytest.approx(90.0 / 250.0 + 250.0 / 1000.0)
    cruise = np.linspace(0.26, move.duration_s - 0.26, 7)
    assert [move.velocity(t)[0] for t in cruise] == pytest.approx([250.0] * 7)
    assert move.at(0.25)[0] == pytest.approx(31.25)
    assert move.at(move.duration_s)[0] == 90.0


def test_a_short_move_is_triangular_and_bound_by_the_acceleration() -> None:
    target = np.array([0.09, 0, 0, 0, 0, 0])
    move = joint_move(ZERO, target, 0.3, SPEED, ACCEL)
    assert move.duration_s == pytest.approx(2.0 * math.sqrt(0.09 / 1000.0))
    peak = move.velocity(move.duration_s / 2)[0]
    assert peak == pytest.approx(math.sqrt(0.09 * 1000.0), rel=1e-9)  # below 0.3 · 250
    assert peak < 0.3 * 250.0
    # the same at any speed fraction: it never reaches the speed
    assert joint_move(ZERO, target, 1.0, SPEED, ACCEL).duration_s == pytest.approx(move.duration_s)


def test_joints_start_and_end_together_on_one_line_the_slowest_setting_the_time() -> None:
    target = np.array([10.0, -20.0, 30.0, -40.0, 50.0, -60.0])
    move = joint_move(ZERO, target, 0.5, SPEED, ACCEL)
    alone = [
        joint_move(ZERO, np.where(np.arange(6) == i, target, 0.0), 0.5, SPEED, ACCEL).duration_s
        for i in range(6)
    ]
    assert move.duration_s >= max(alone) - 1e-12
    # J5 sets the path speed (4 /s), J3 and J6 the acceleration (33.3 /s²): 1/4 + 4/33.3
    assert move.duration_s == pytest.approx(0.25 + 4.0 / (1000.0 / 30.0))
    for t in np.linspace(0.0, move.duration_s, 11):
        f = move.at(t) / target
        assert np.ptp(f) < 1e-12  # every joint the same fraction of its way
        np.testing.assert_array_less(np.abs(move.velocity(t)), SPEED * 0.5 + 1e-9)


def test_settling_depends_on_the_move() -> None:
    long = joint_move(ZERO, np.array([90.0, 0, 0, 0, 0, 0]), 1.0, SPEED, ACCEL)
    leg = joint_move(ZERO, np.full(6, APPROACH_DEG), 1.0, SPEED, ACCEL)
    tiny = joint_move(ZERO, np.full(6, 0.002), 1.0, SPEED, ACCEL)
    assert long.settle_s == pytest.approx(0.05)
    # a 0.05 deg leg's following error is at most the 0.05 deg it moves: ln(50)/(2π·15 Hz)
    assert leg.settle_s == pytest.approx(math.log(50.0) / (2 * math.pi * 15.0))
    assert tiny.settle_s < leg.settle_s < long.settle_s
    assert move_s(ZERO, long.target_deg, 1.0, SPEED) == pytest.approx(long.duration_s + 0.05)


def test_an_approach_through_a_pre_point_settles_once() -> None:
    target = np.array([20.0, 10.0, -5.0, 3.0, 2.0, 1.0])
    pre = target - APPROACH_DEG
    first = joint_move(ZERO, pre, 0.3, SPEED, ACCEL)
    last = joint_move(pre, target, 0.3, SPEED, ACCEL)
    queued = move_s(ZERO, target, 0.3, SPEED, approach_deg=APPROACH_DEG)
    assert queued == pytest.approx(first.duration_s + last.duration_s + last.settle_s)
    stopped = move_s(ZERO, pre, 0.3, SPEED) + move_s(pre, target, 0.3, SPEED)
    assert stopped - queued == pytest.approx(first.settle_s)
    assert trajectory_s([ZERO, ZERO], 0.3, SPEED) == 0.0


def test_two_queued_points_reach_the_target_from_below_without_a_stop_between() -> None:
    clock = SimClock(handoff_timeout_s=5.0)
    records: list[dict[str, object]] = []
    limits = (np.full(6, -170.0), np.full(6, 170.0))
    start = np.array([5.0, 5.0, 5.0, 5.0, 5.0, 5.0])
    sim = SimulatedController(
        *limits, start, clock=clock, settling=True, server="val3", on_motion=records.append
    ).start()  # type: ignore[arg-type]
    client = SimpleMessageController.from_url(sim.url)
    client.clock = clock
    target = np.array([2.0, 8.0, 4.0, 6.0, 1.0, 9.0])  # some joints come down onto it
    pre = target - APPROACH_DEG
    try:
        client.connect()
        client.read_joints()
        t0 = clock.now()
        client.start_move(pre, 0.3)
        client.start_move(target, 0.3)
        settled = client.wait_settled(target, timeout_s=30.0)
        elapsed = clock.now() - t0
        sign = sim.motion_sign()
    finally:
        client.close()
        clock.close()
        sim.stop()
    np.testing.assert_allclose(settled, target, atol=1e-3)
    assert sim.moves_executed == 2
    np.testing.assert_array_equal(sign, np.ones(6))  # the last motion of every joint: upward
    first, last = sorted(records, key=lambda r: float(r["t_start"]))  # type: ignore[arg-type]
    # the last leg began the instant the pre-point was reached: no settling, no frame wait
    assert float(last["t_start"]) == pytest.approx(
        float(first["t_start"]) + float(first["duration_s"]), abs=1e-9
    )
    expected = move_s(start, target, 0.3, sim.max_speed_deg_s, sim.max_accel_deg_s2, APPROACH_DEG)
    # the stream's 20 ms frames: the settled state is seen within a frame or two
    assert expected <= elapsed <= expected + 0.06
