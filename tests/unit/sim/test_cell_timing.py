"""The real cell's time in the simulated cell (world ``[timing]``): frames that arrive late and
unevenly, frames that are lost, readings whose acquisition the client does not see."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from drivers.clock import SimClock
from drivers.controller.client import SimpleMessageController
from drivers.controller.motion import JointMove, joint_move
from drivers.controller.simulator import SimulatedController
from ucal.cell import CellTiming
from ucal.errors import ProfileError
from ucal.profile import default_profile_text, load_profile
from ucal.world import load_world

TARGET = np.array([10.0, -20.0, 30.0, -40.0, 50.0, -60.0])
LIMITS = (np.full(6, -170.0), np.full(6, 170.0))


def _world(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "world.toml"
    path.write_text(text, encoding="utf-8")
    return path


def test_timing_keys_are_read_in_ms_and_default_to_a_val3_server_on_a_lan(
    tmp_path: Path,
) -> None:
    (tmp_path / "cell.toml").write_text(default_profile_text("tx90"), encoding="utf-8")
    profile = load_profile(tmp_path / "cell.toml")
    default = load_world(_world(tmp_path, "[noise]\nseed = 1\n"), profile).timing
    assert default == CellTiming()
    assert (default.state_latency_s, default.state_jitter_s) == (0.002, 0.001)
    assert (default.pulser_latency_s, default.pulser_jitter_s) == (0.001, 0.0005)
    assert default.state_period_s is None  # the server's own: 20 ms for the VAL3 server
    world = load_world(
        _world(
            tmp_path,
            "[timing]\nstate_period_ms = 4\nstate_latency_ms = 30\nstate_jitter_ms = 0\n"
            "missing_state_frames = 0.25\npulser_latency_ms = 5\npulser_jitter_ms = 0\n"
            "acquisition_delay_ms = 12\n",
        ),
        profile,
    )
    assert world.timing == CellTiming(0.004, 0.030, 0.0, 0.25, 0.005, 0.0, 0.012)
    with pytest.raises(ProfileError, match=r"timing\.missing_state_frames"):
        load_world(_world(tmp_path, "[timing]\nmissing_state_frames = 0.9\n"), profile)
    with pytest.raises(ProfileError, match=r"did you mean state_latency_ms"):
        load_world(_world(tmp_path, "[timing]\nstate_latncy_ms = 3\n"), profile)


def _samples_of_a_move(**stream: float) -> tuple[np.ndarray, np.ndarray, float, JointMove]:
    """Move to TARGET on simulated time; the client's samples (arrival time, joint 1), the
    instant the motion started and the move (the motion model's)."""
    clock = SimClock(handoff_timeout_s=5.0)
    sim = SimulatedController(*LIMITS, clock=clock, **stream).start()  # type: ignore[arg-type]
    client = SimpleMessageController.from_url(sim.url)
    client.clock = clock
    try:
        client.connect()
        client.read_joints()
        t0 = clock.now()
        client.move_joints(TARGET, speed=0.5, timeout_s=30.0)
        samples = client.joint_samples(t0)
    finally:
        client.close()
        clock.close()
        sim.stop()
    move = joint_move(np.zeros(6), TARGET, 0.5, sim.max_speed_deg_s, sim.max_accel_deg_s2)
    ts = np.array([s.t_s for s in samples])
    j1 = np.array([s.joints_deg[0] for s in samples])
    return ts, j1, t0, move


def _since_start(move: JointMove, j1: np.ndarray) -> np.ndarray:
    """How long after the move's start joint 1 was at ``j1`` (s): the profile inverted."""
    t = np.linspace(0.0, move.duration_s, 20001)
    path = np.array([move.fraction(x) for x in t]) * TARGET[0]
    return np.interp(j1, path, t)


def test_frames_carry_the_arm_as_it_was_latency_before_they_arrive() -> None:
    ts, j1, _, move = _samples_of_a_move(state_latency_s=0.007, state_jitter_s=0.0)
    moving = (j1 > 1e-6) & (j1 < TARGET[0] - 1e-6)
    assert np.count_nonzero(moving) >= 3
    # the arm started (at most a frame after the move was accepted) and follows its profile:
    # each frame's position is that of 7 ms before it arrived, the same for every frame
    lag = ts[moving] - _since_start(move, j1[moving])
    assert np.ptp(lag) < 1e-5  # float32 radians on the wire, the inverted profile's grid
    ts0, j10, _, _ = _samples_of_a_move(state_latency_s=0.0, state_jitter_s=0.0)
    moving0 = (j10 > 1e-6) & (j10 < TARGET[0] - 1e-6)
    lag0 = ts0[moving0] - _since_start(move, j10[moving0])
    assert float(np.median(lag) - np.median(lag0)) == pytest.approx(0.007, abs=1e-6)


def test_jitter_keeps_the_stream_in_order_and_lost_frames_are_missing() -> None:
    ts, j1, _, _ = _samples_of_a_move(state_jitter_s=0.004, missing_state_frames=0.3, seed=5)
    assert np.all(np.diff(j1) >= -1e-12)  # TCP keeps the order: never an older position later
    gaps = np.diff(ts)
    period = 0.020
    # a share of the periods hold no frame: gaps of two periods and more
    lost = np.count_nonzero(gaps > 1.5 * period) / len(gaps)
    assert 0.1 < lost < 0.6
    again = _samples_of_a_move(state_jitter_s=0.004, missing_state_frames=0.3, seed=5)
    np.testing.assert_array_equal(again[0], ts)  # the same seed, the same stream
    np.testing.assert_array_equal(again[1], j1)


def test_the_stream_refuses_impossible_timing() -> None:
    with pytest.raises(ValueError, match="missing_state_frames"):
        SimulatedController(*LIMITS, missing_state_frames=1.0)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="state_latency_s"):
        SimulatedController(*LIMITS, state_latency_s=-1.0)  # type: ignore[arg-type]
