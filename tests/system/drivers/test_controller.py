"""The Simple Message client against the simulated controller and raw fake servers (127.0.0.1)."""

from __future__ import annotations

import logging
import socket
import struct
import threading
import time

import numpy as np
import pytest

from drivers.controller.client import SimpleMessageController
from drivers.controller.simple_message import (
    FrameReader,
    JointPosition,
    JointTrajPt,
    JointTrajPtReply,
    MsgType,
    ReplyCode,
    SpecialSeq,
    Status,
)
from drivers.errors import (
    ConnectionLost,
    DeviceError,
    DeviceTimeout,
    MotionRejected,
    ProtocolError,
)

pytestmark = pytest.mark.system

HOME = np.zeros(6)
TARGET = np.array([10.0, -20.0, 30.0, -40.0, 50.0, -60.0])


def _wait_until(predicate, timeout_s=2.0):
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(0.005)
    return predicate()


def test_move_and_read_back(make_sim_controller, make_controller_client):
    records = []
    sim = make_sim_controller(on_motion=records.append)
    client = make_controller_client(sim.url)
    np.testing.assert_allclose(client.read_joints(), HOME, atol=1e-6)
    t0 = time.monotonic()

    settled = client.move_joints(TARGET, speed=0.5, timeout_s=5.0, tol_deg=1e-3)

    np.testing.assert_allclose(settled, TARGET, atol=1e-3)
    np.testing.assert_allclose(client.read_joints(), TARGET, atol=1e-3)
    np.testing.assert_allclose(sim.joints_deg(), TARGET, atol=1e-3)
    assert client.status().in_motion is False
    assert sim.moves_executed == 1
    assert len(records) == 1
    record = records[0]
    assert record["stopped"] is False
    np.testing.assert_allclose(record["target_deg"], TARGET, atol=1e-3)
    np.testing.assert_allclose(record["start_deg"], HOME)
    # Joint-interpolated trapezoid: J5 sets the path's speed (50 deg at 0.5 · 400 deg/s: 4 /s),
    # J3 its acceleration (30 deg at 1000 deg/s²: 33.3 /s²): 1/4 + 4/33.3 = 0.37 s, times the
    # fixture's time_scale 0.01.
    assert record["duration_s"] == pytest.approx(0.37 * 0.01, rel=1e-3)

    samples = client.joint_samples(t0)
    assert samples and all(s.t_s >= t0 for s in samples)
    assert [s.t_s for s in samples] == sorted(s.t_s for s in samples)
    np.testing.assert_allclose(samples[-1].joints_deg, TARGET, atol=1e-3)
    assert client.joint_samples(time.monotonic() + 10) == []


def test_motion_takes_the_time_the_speed_implies(make_sim_controller, make_controller_client):
    sim = make_sim_controller(time_scale=1.0)
    client = make_controller_client(sim.url)
    target = np.array([25.0, 0, 0, 0, 0, 0])  # J1 at 0.5 · 250 deg/s: 0.2 s
    t0 = time.monotonic()
    client.move_joints(target, speed=0.5, timeout_s=3.0)
    elapsed = time.monotonic() - t0
    assert elapsed >= 0.19  # the motion's own time (an overrun would be the 3 s timeout's error)
    # The streamed samples show the arm part-way, strictly between start and target.
    middle = [s.joints_deg[0] for s in client.joint_samples(t0) if 2.0 < s.joints_deg[0] < 23.0]
    assert middle


def test_target_outside_joint_range_is_rejected(sim_controller, controller_client):
    bad = np.array([0.0, 150.0, 0.0, 0.0, 0.0, 0.0])  # J2 max is 147.5
    with pytest.raises(MotionRejected) as info:
        controller_client.start_move(bad, speed=0.5)
    assert info.value.device == "controller"
    assert info.value.endpoint == sim_controller.url
    assert "refused" in str(info.value)
    time.sleep(0.05)
    assert sim_controller.moves_executed == 0
    np.testing.assert_allclose(sim_controller.joints_deg(), HOME)
    # The link is still usable.
    controller_client.move_joints(TARGET, timeout_s=5.0)


def test_target_on_the_joint_limit_is_accepted(sim_controller, controller_client):
    edge = np.array([180.0, 147.5, -145.0, 270.0, -115.0, -270.0])
    settled = controller_client.move_joints(edge, speed=1.0, timeout_s=5.0, tol_deg=1e-3)
    np.testing.assert_allclose(settled, edge, atol=1e-3)


def test_stop_mid_motion_stops_short(make_sim_controller, make_controller_client):
    records = []
    sim = make_sim_controller(time_scale=1.0, on_motion=records.append)
    client = make_controller_client(sim.url)
    target = np.array([90.0, 0, 0, 0, 0, 0])  # 0.72 s at speed 0.5
    client.start_move(target, speed=0.5)
    time.sleep(0.15)
    client.stop()
    assert _wait_until(lambda: client.status().in_motion is False)
    time.sleep(0.05)
    stopped_at = client.read_joints()
    assert 5.0 < stopped_at[0] < 85.0
    time.sleep(0.1)
    np.testing.assert_allclose(client.read_joints(), stopped_at, atol=1e-4)
    with pytest.raises(DeviceTimeout):
        client.wait_settled(target, timeout_s=0.2)
    assert len(records) == 1 and records[0]["stopped"] is True
    assert records[0]["end_deg"][0] == pytest.approx(stopped_at[0], abs=1e-3)


def test_sequence_numbers_increase_and_restart_after_stop(
    make_sim_controller, make_controller_client
):
    records = []
    sim = make_sim_controller(on_motion=records.append)
    client = make_controller_client(sim.url)
    client.move_joints(TARGET, timeout_s=5.0)
    client.move_joints(HOME, timeout_s=5.0)
    client.stop()
    client.move_joints(TARGET, timeout_s=5.0)
    assert [r["seq"] for r in records] == [0, 1, 0]


def test_status_round_trip_and_estop_refusal(sim_controller, controller_client):
    status = controller_client.status()
    assert status.drives_powered is True and status.e_stopped is False
    assert status.motion_possible is True and status.mode == 2

    sim_controller.set_fault(e_stopped=True)
    assert _wait_until(lambda: controller_client.status().e_stopped is True)
    assert controller_client.status().motion_possible is False
    with pytest.raises(MotionRejected, match="e-stop engaged"):
        controller_client.start_move(TARGET)
    assert sim_controller.moves_executed == 0

    sim_controller.set_fault(e_stopped=False, drives_powered=False)
    assert _wait_until(lambda: controller_client.status().drives_powered is False)
    with pytest.raises(MotionRejected):
        controller_client.start_move(TARGET)

    sim_controller.set_fault(drives_powered=True, in_error=True, error_code=42)
    assert _wait_until(lambda: controller_client.status().error_code == 42)
    assert controller_client.status().in_error is True
    with pytest.raises(MotionRejected):
        controller_client.start_move(TARGET)

    sim_controller.set_fault(in_error=False, error_code=0)
    # the cleared fault reaches the client with the next STATUS, as the fault did
    assert _wait_until(lambda: controller_client.status().in_error is False)
    controller_client.move_joints(TARGET, timeout_s=5.0)
    assert sim_controller.moves_executed == 1


def test_estop_during_motion_raises_device_error_promptly(
    make_sim_controller, make_controller_client
):
    sim = make_sim_controller(time_scale=1.0)
    client = make_controller_client(sim.url)
    target = np.array([120.0, 0, 0, 0, 0, 0])  # about 1 s at speed 0.5
    client.start_move(target, speed=0.5)
    threading.Timer(0.1, sim.set_fault, kwargs={"e_stopped": True}).start()
    t0 = time.monotonic()
    with pytest.raises(DeviceError, match="e-stop engaged"):
        client.wait_settled(target, timeout_s=5.0)
    assert time.monotonic() - t0 < 5.0  # the e-stop, not the 5 s settle timeout waited out
    assert not sim.in_motion()


def test_simulator_killed_mid_move(make_sim_controller, make_controller_client):
    sim = make_sim_controller(time_scale=1.0)
    client = make_controller_client(sim.url)
    target = np.array([150.0, 0, 0, 0, 0, 0])
    client.start_move(target, speed=0.5)
    time.sleep(0.05)
    sim.kill()
    t0 = time.monotonic()
    with pytest.raises((ConnectionLost, DeviceTimeout)) as info:
        client.wait_settled(target, timeout_s=5.0)
    assert time.monotonic() - t0 < 5.0  # the dead link is noticed, not the 5 s waited out
    assert info.value.device == "controller"
    assert sim.url in str(info.value)
    client.stop()  # must not raise on a dead link
    with pytest.raises((ConnectionLost, DeviceTimeout)):
        client.start_move(HOME)


def test_motion_client_disconnect_stops_motion(make_sim_controller, make_controller_client):
    records = []
    sim = make_sim_controller(time_scale=1.0, on_motion=records.append)
    client = make_controller_client(sim.url)
    client.start_move(np.array([90.0, 0, 0, 0, 0, 0]), speed=0.5)
    time.sleep(0.1)
    client.close()  # no STOP: the simulator must notice the lost connection by itself
    assert _wait_until(lambda: not sim.in_motion(), 1.0)
    assert sim.joints_deg()[0] < 85.0
    assert records and records[-1]["stopped"] is True


def test_context_manager_exit_sends_stop(make_sim_controller, caplog):
    sim = make_sim_controller(time_scale=1.0)
    caplog.set_level(logging.INFO, logger="drivers.controller.simulator")
    with SimpleMessageController.from_url(sim.url, reply_timeout_s=1.0) as client:
        client.start_move(np.array([90.0, 0, 0, 0, 0, 0]), speed=0.5)
        time.sleep(0.05)
    assert not sim.in_motion()
    assert "STOP_TRAJECTORY" in caplog.text


def test_joint_feedback_stream(make_sim_controller, make_controller_client):
    sim = make_sim_controller(joint_message=MsgType.JOINT_FEEDBACK)
    client = make_controller_client(sim.url)
    settled = client.move_joints(TARGET, timeout_s=5.0)
    np.testing.assert_allclose(settled, TARGET, atol=1e-3)


def test_connect_to_closed_port_fails_fast(make_controller_client):
    probe = socket.socket()
    probe.bind(("127.0.0.1", 0))
    port = probe.getsockname()[1]
    probe.close()  # nothing listens on this port any more
    client = make_controller_client(f"tcp://127.0.0.1:{port}?state={port + 1}", connect=False)
    t0 = time.monotonic()
    with pytest.raises(ConnectionLost) as info:
        client.connect()
    assert time.monotonic() - t0 < client.connect_timeout_s  # refused, not waited out
    assert info.value.endpoint == f"tcp://127.0.0.1:{port}?state={port + 1}"
    assert "motion port" in str(info.value)


def test_calls_before_connect_raise_connection_lost(make_controller_client, fake_server):
    client = make_controller_client(fake_server.url, connect=False)
    with pytest.raises(ConnectionLost):
        client.read_joints(timeout_s=0.1)
    with pytest.raises(ConnectionLost):
        client.start_move(HOME)
    client.stop()  # logs, never raises


# -- raw fake servers -----------------------------------------------------------------------


def _healthy_state() -> bytes:
    return JointPosition(()).pack() + Status(1, 0, 0, 0, 0, 2, 1).pack()


@pytest.mark.parametrize(
    "garbage",
    [
        b"\x00garbage bytes that are not a frame at all" * 3,
        b"\xff\xff\xff\x7f" + bytes(12),  # length 0x7fffffff
    ],
)
def test_garbage_on_state_port_is_a_protocol_error(fake_server, make_controller_client, garbage):
    client = make_controller_client(fake_server.url)
    _, state = fake_server.accept()
    state.sendall(_healthy_state() + garbage)
    t0 = time.monotonic()
    with pytest.raises(ProtocolError) as info:
        while time.monotonic() - t0 < 5.0:  # read_joints raises once the garbage is read
            client.read_joints()
            time.sleep(0.005)
    assert info.value.endpoint == fake_server.url
    with pytest.raises(ProtocolError):
        client.status()


def test_garbage_reply_on_motion_port_is_a_protocol_error(fake_server, make_controller_client):
    client = make_controller_client(fake_server.url)
    motion, state = fake_server.accept()
    state.sendall(_healthy_state())
    client.read_joints()
    motion.sendall(struct.pack("<4i", 0x7FFFFFFF, 11, 3, 1))
    with pytest.raises(ProtocolError, match="length field"):
        client.start_move(TARGET)
    with pytest.raises(ProtocolError):  # the motion link stays condemned
        client.start_move(TARGET)
    client.stop()


def test_no_reply_is_a_timeout(fake_server, make_controller_client):
    client = make_controller_client(fake_server.url, reply_timeout_s=0.3, state_timeout_s=5.0)
    _, state = fake_server.accept()
    state.sendall(_healthy_state())
    client.read_joints()
    t0 = time.monotonic()
    with pytest.raises(DeviceTimeout, match="no reply to trajectory point 0"):
        client.start_move(TARGET)
    assert 0.25 < time.monotonic() - t0 < 5.0  # the reply timeout, not the state timeout


def test_silent_state_stream_is_a_timeout(fake_server, make_controller_client):
    client = make_controller_client(fake_server.url, state_timeout_s=0.3)
    _, state = fake_server.accept()
    state.sendall(_healthy_state())
    client.read_joints()
    time.sleep(0.4)
    with pytest.raises(DeviceTimeout, match=r"state timeout ran out \(state_timeout_s = 0.3 s\)"):
        client.status(timeout_s=5.0)


def test_first_state_waits_out_the_val3_silence_and_no_longer(fake_server, make_controller_client):
    """The VAL3 server is silent for 1 s after connecting; the first-state timeout covers it."""
    client = make_controller_client(fake_server.url, state_timeout_s=0.3, first_state_timeout_s=1.5)
    _, state = fake_server.accept()
    threading.Timer(1.0, state.sendall, args=(_healthy_state(),)).start()
    np.testing.assert_allclose(client.read_joints(timeout_s=0.1), HOME)
    silent = make_controller_client(fake_server.url, first_state_timeout_s=0.4)
    fake_server.accept()
    t0 = time.monotonic()
    with pytest.raises(
        DeviceTimeout,
        match=r"first-state timeout ran out "
        r"\(first_state_timeout_s = 0.4 s\)",
    ) as info:
        silent.read_joints(timeout_s=0.1)
    assert 0.35 < time.monotonic() - t0 < 1.5  # the 0.4 s timeout, not the 1.5 s one
    assert info.value.endpoint == fake_server.url


def test_request_bytes_and_reply_handling(fake_server, make_controller_client):
    """The exact request sent, stale replies skipped, header-only replies understood."""
    client = make_controller_client(fake_server.url)
    motion, state = fake_server.accept()
    state.sendall(_healthy_state())
    client.read_joints()
    errors = []

    def move(target, speed):
        try:
            client.start_move(target, speed)
        except Exception as e:
            errors.append(e)

    worker = threading.Thread(target=move, args=(TARGET, 0.001))
    worker.start()
    reader = FrameReader()
    request = []
    while not request:
        request = reader.feed(motion.recv(4096))
    (req,) = request
    assert isinstance(req, JointTrajPt)
    assert req.sequence == 0
    np.testing.assert_allclose(np.degrees(req.joints_rad[:6]), TARGET, atol=1e-4)
    assert req.joints_rad[6:] == (0.0,) * 4
    # 0.001 (VAL3: 0.1 %, the "smooth last point" trigger of interpolateVel.pgx) goes as 0.00101.
    assert req.velocity == pytest.approx(0.00101, rel=1e-6)
    # A stale reply (sequence 5) is ignored; the matching one completes the request.
    motion.sendall(
        JointTrajPtReply(ReplyCode.SUCCESS, 5).pack()
        + JointTrajPtReply(ReplyCode.SUCCESS, 0).pack()
    )
    worker.join(timeout=2.0)
    assert not worker.is_alive() and not errors

    # A header-only FAILURE reply (REP-I0006 'alternative reply') is a rejection.
    worker = threading.Thread(target=move, args=(HOME, 0.5))
    worker.start()
    request = []
    while not request:
        request = reader.feed(motion.recv(4096))
    assert request[0].sequence == 1 and request[0].velocity == pytest.approx(0.5)
    motion.sendall(JointTrajPtReply(ReplyCode.FAILURE, None, 0).pack())
    worker.join(timeout=2.0)
    assert len(errors) == 1 and isinstance(errors[0], MotionRejected)

    # STOP is sequence -4 and waits for its own reply.
    worker = threading.Thread(target=client.stop)
    worker.start()
    request = []
    while not request:
        request = reader.feed(motion.recv(4096))
    assert request[0].sequence == SpecialSeq.STOP_TRAJECTORY
    motion.sendall(JointTrajPtReply(ReplyCode.SUCCESS, SpecialSeq.STOP_TRAJECTORY).pack())
    worker.join(timeout=2.0)
    assert not worker.is_alive()


def test_frames_logged_as_hex(sim_controller, make_controller_client, caplog):
    caplog.set_level(logging.DEBUG, logger="drivers.controller.client")
    client = make_controller_client(sim_controller.url)
    client.move_joints(TARGET, timeout_s=5.0)
    writes = [r.getMessage() for r in caplog.records if r.getMessage().startswith("WRITE:")]
    reads = [r.getMessage() for r in caplog.records if r.getMessage().startswith("READ:")]
    assert any("40000000" + "0b000000" + "02000000" in w.replace(" ", "") for w in writes)
    assert reads
