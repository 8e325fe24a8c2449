"""The client against the VAL3-faithful simulated controller, on simulated time (127.0.0.1).

Client and simulator share a ``SimClock``: the server's 1 s of start-up silence, its 50 Hz /
250 Hz streams and the halt timeouts pass in simulated time, frame by frame in lock step.
"""

from __future__ import annotations

import socket
import struct
import threading
import time
from collections.abc import Callable, Iterator

import numpy as np
import pytest

from drivers.clock import SimClock
from drivers.controller.client import SimpleMessageController
from drivers.controller.simple_message import (
    CommType,
    FrameReader,
    JointFeedback,
    JointPosition,
    JointTrajPt,
    JointTrajPtReply,
    MsgType,
    OtherMessage,
    ReplyCode,
)
from drivers.errors import ConnectionLost, DeviceError

pytestmark = pytest.mark.system

TARGET = np.array([30.0, 0.0, 0.0, 0.0, 0.0, 0.0])


@pytest.fixture
def cell(make_sim_controller) -> Iterator:
    """``make(server, **sim_options)`` → (clock, simulator, connected client on that clock)."""
    made: list = []

    def make(server: str = "val3", **options: object):
        clock = SimClock(handoff_timeout_s=5.0)
        options = {"time_scale": 1.0, "state_rate_hz": None, **options}
        sim = make_sim_controller(server=server, clock=clock, **options)
        client = SimpleMessageController.from_url(sim.url, clock=clock)
        made.append((clock, sim, client))
        client.connect()
        return clock, sim, client

    yield make
    for clock, _, client in made:
        client.close()
        clock.close()


class RawStateReader:
    """Counts what the state port sends, taking frames in lock step like the client."""

    def __init__(self, url: str, clock: SimClock):
        host, ports = url.removeprefix("tcp://").split(":")
        self.sock = socket.create_connection((host, int(ports.split("=")[1])))
        self.sock.settimeout(0.05)
        self.clock = clock
        self.frames: list[tuple[float, str]] = []
        self.done = threading.Event()
        threading.Thread(target=self._run, daemon=True).start()

    def _run(self) -> None:
        reader = FrameReader()
        while not self.done.is_set():
            try:
                data = self.sock.recv(4096)
            except TimeoutError:
                continue
            except OSError:
                return
            if not data:
                return  # closed by the server
            messages = reader.feed(data)
            now = self.clock.now()
            self.frames += [(now, type(m).__name__) for m in messages]
            self.clock.frames_taken(
                sum(isinstance(m, (JointPosition, JointFeedback)) for m in messages)
            )

    def close(self) -> None:
        self.done.set()
        self.sock.close()


def until(condition: Callable[[], bool], what: str, timeout_s: float = 30.0) -> None:
    """Wait (real time: the server's threads) until ``condition()``; fail naming ``what``."""
    deadline = time.monotonic() + timeout_s
    while not condition():
        assert time.monotonic() < deadline, f"{what}: not within {timeout_s:g} s"
        time.sleep(0.01)


@pytest.mark.parametrize(
    "server, joint_type, rate_hz, first, every",
    [
        ("val3", "JointPosition", 50.0, 6, 5),
        ("val3-feedback", "JointFeedback", 250.0, 21, 20),
    ],
)
def test_stream_silence_rate_and_status_cadence(cell, server, joint_type, rate_hz, first, every):
    clock, sim, client = cell(server)
    # One client per port: make room for the raw reader. connect() returns once the sockets are
    # open, before the server's accept thread has registered the client: wait for that first,
    # or the client could leave before it is registered and then be served instead of the raw
    # reader (which the server would refuse as a second client).
    until(sim._has_state_clients, "the server registers the client")
    client.close()
    until(lambda: not sim._has_state_clients(), "the server sees the client leave")
    raw = RawStateReader(sim.url, clock)
    # sleep() below advances simulated time whether or not anybody listens yet
    mine = "{}:{}".format(*raw.sock.getsockname())
    until(lambda: [c.peer for c in sim._state_clients] == [mine], "the server serves the reader")
    try:
        t0 = clock.now()
        for _ in range(300):
            if raw.frames:
                break
            clock.sleep(0.01)
        clock.sleep(1.0)
    finally:
        raw.close()
    times = [t for t, kind in raw.frames if kind == joint_type]
    kinds = [kind for _, kind in raw.frames]
    assert times[0] - t0 >= 1.0  # recvHeartbeat.pgx: delay(1.0)
    assert np.median(np.diff(times)) == pytest.approx(1.0 / rate_hz)
    assert set(kinds) == {joint_type, "Status"}
    status_after = [kinds[:i].count(joint_type) for i, k in enumerate(kinds) if k == "Status"]
    assert status_after[:3] == [first, first + every, first + 2 * every]


def test_first_state_after_the_silence_then_a_move(cell):
    clock, _, client = cell("val3")
    t0 = clock.now()
    np.testing.assert_allclose(client.read_joints(), np.zeros(6), atol=1e-6)
    assert clock.now() - t0 >= 1.0
    np.testing.assert_allclose(client.move_joints(TARGET, 0.5, 5.0), TARGET, atol=1e-3)


def test_a_second_client_is_not_served_and_its_leaving_does_not_stop_the_arm(cell):
    clock, sim, client = cell("val3")
    client.start_move(TARGET, 0.5)
    second = SimpleMessageController.from_url(sim.url, clock=clock)
    second.connect()
    with pytest.raises(ConnectionLost, match="one client per port"):
        second.read_joints()
    second.close()
    np.testing.assert_allclose(client.wait_settled(TARGET, 5.0), TARGET, atol=1e-3)
    assert sim.moves_executed == 1


def test_requests_it_does_not_execute_get_a_failure_reply(make_sim_controller):
    sim = make_sim_controller(server="val3")
    motion = socket.create_connection(("127.0.0.1", sim.motion_port), timeout=2.0)
    reader = FrameReader()

    def ask(frame: bytes):
        motion.sendall(frame)
        out: list = []
        while not out:
            out = reader.feed(motion.recv(4096))
        return out[0]

    ping = ask(OtherMessage(MsgType.PING, CommType.SERVICE_REQUEST).pack())
    assert ping == OtherMessage(MsgType.PING, CommType.SERVICE_REPLY, ReplyCode.FAILURE)
    body = struct.pack("<3if", 0, 7, 0x3, 0.0) + bytes(120)
    full = ask(OtherMessage(MsgType.JOINT_TRAJ_PT_FULL, CommType.SERVICE_REQUEST, 0, body).pack())
    assert full == OtherMessage(
        MsgType.JOINT_TRAJ_PT_FULL, CommType.SERVICE_REPLY, ReplyCode.FAILURE, body
    )
    # the connection stays up; no state client: the point is acknowledged and dropped
    assert ask(JointTrajPt(3, (0.1,), 0.5).pack()) == JointTrajPtReply(ReplyCode.SUCCESS, 3)
    motion.close()
    assert sim.moves_executed == 0


@pytest.mark.parametrize("reports_motion", [False, True])
def test_a_halt_is_noticed_within_the_halt_timeout(cell, reports_motion):
    clock, sim, client = cell("val3")
    client.start_move(TARGET, 0.5)
    clock.sleep(0.1)
    sim.hold(in_motion=reports_motion)
    t_halt = clock.now()
    said = "in motion" if reports_motion else "not in motion"
    with pytest.raises(DeviceError, match=f"controller halted the motion .* it reports {said}"):
        for _ in range(500):  # the sweep's loop: joint readings while the arm moves
            client.read_joints()
            clock.sleep(0.02)
        pytest.fail("the halt went unnoticed for 10 s")
    assert client.halt_timeout_s <= clock.now() - t_halt <= client.halt_timeout_s + 0.2


def test_val3_master_takes_a_point_while_e_stopped_and_the_status_says_why(cell):
    clock, sim, client = cell("val3")
    client.read_joints()
    sim.set_fault(e_stopped=True)
    client.start_move(TARGET, 0.5)  # SUCCESS: the released server queues it regardless
    t0 = clock.now()
    with pytest.raises(DeviceError, match="e-stop engaged"):
        client.wait_settled(TARGET, 60.0)
    assert clock.now() - t0 <= 0.2  # the next STATUS, not the settle timeout
    assert sim.moves_executed == 0


def test_the_slowest_sweep_is_not_taken_for_a_halt(cell):
    _, _, client = cell("val3")
    target = np.array([1.5, 0, 0, 0, 0, 0])  # at 0.002 of 250 deg/s: 3 s
    np.testing.assert_allclose(client.move_joints(target, 0.002, 60.0), target, atol=1e-3)


def test_status_of_the_refusing_variant(cell):
    clock, sim, client = cell("val3-feedback")
    client.read_joints()
    sim.set_fault(drives_powered=False)
    clock.sleep(0.2)
    assert client.status().drives_powered is False
    with pytest.raises(Exception, match=r"refused .* drives off"):
        client.start_move(TARGET, 0.5)  # PR #36 pushMotion.pgx: FAILURE when not possible


@pytest.mark.parametrize(
    "server, message, rate_hz, every",
    [
        ("val3", "JOINT_POSITION", 50.0, 5),
        ("val3-feedback", "JOINT_FEEDBACK", 250.0, 20),
        ("simple", "JOINT_POSITION", 50.0, 1),
    ],
)
def test_stream_info_tells_the_servers_apart(cell, server, message, rate_hz, every):
    _, _, client = cell(server)
    info = client.stream_info()
    assert (info["joint_message"], info["joint_rate_hz"], info["status_every"]) == (
        message,
        rate_hz,
        every,
    )
    assert info["first_state_s"] == pytest.approx(
        0.0 if server == "simple" else 1.0, abs=1.0 / rate_hz
    )


def test_stream_info_measures_a_stream_with_a_status_every_millisecond(cell):
    """A STATUS every pass at 1 kHz: 0.2 s of them is 200 marks, more than a short history
    holds (it once kept 64, so that no fast stream was ever measured)."""
    _, _, client = cell("simple", state_rate_hz=1000.0)
    info = client.stream_info()
    assert (info["joint_rate_hz"], info["status_every"]) == (1000.0, 1)
