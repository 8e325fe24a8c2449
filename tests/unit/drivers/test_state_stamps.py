"""State frames dated by their arrival in the kernel, not by when a loaded host's reader thread
got round to them: a reader held back a fixed half second still dates every frame that waited
for it where the controller sent it (a real socket on 127.0.0.1, the simulated controller on
the host clock)."""

from __future__ import annotations

import socket
import sys
import threading
import time

import numpy as np
import pytest

from drivers.controller.client import SimpleMessageController
from drivers.controller.link import Connection, tcp_connect
from drivers.controller.simulator import SimulatedController

pytestmark = pytest.mark.skipif(
    not sys.platform.startswith("linux"), reason="the kernel's receive stamps are Linux's"
)

HOLD_S = 0.5
LIMITS = (np.full(6, -170.0), np.full(6, 170.0))


class HeldReader(socket.socket):
    """A socket whose reads wait until ``released`` is set: the reader thread of a host too
    busy to schedule it, while the controller's frames queue up in the kernel."""

    released = threading.Event()

    def recv(self, *args: int) -> bytes:
        HeldReader.released.wait()
        return super().recv(*args)

    def recvmsg(self, *args: int) -> tuple[bytes, list[tuple[int, int, bytes]], int, object]:
        HeldReader.released.wait()
        return super().recvmsg(*args)


def held(host: str, port: int, timeout_s: float) -> Connection:
    sock = tcp_connect(host, port, timeout_s)
    return HeldReader(sock.family, sock.type, sock.proto, fileno=sock.detach())


def test_frames_that_waited_for_a_late_reader_are_paired_with_when_they_arrived() -> None:
    """One client moves the arm (J1 by 10° in 0.8 s) while another's state reader is held for
    half a second: when let go it reads every frame that waited, at once, and the samples it
    keeps say where the arm was at their times (within the 20 ms a frame's position may be
    old), not where it was half a second before the time they were read at."""
    motions: list[dict] = []
    sim = SimulatedController(*LIMITS, on_motion=motions.append).start()
    mover = SimpleMessageController.from_url(sim.url)
    watcher = SimpleMessageController.from_url(sim.url, connect=held)
    HeldReader.released.clear()
    target = np.array([10.0, 0.0, 0.0, 0.0, 0.0, 0.0])
    speed = 10.0 / (0.8 * float(sim.max_speed_deg_s[0]))
    try:
        mover.connect()
        watcher.connect()
        mover.read_joints()
        mover.start_move(target, speed)
        time.sleep(HOLD_S)
        released = time.monotonic()
        HeldReader.released.set()
        mover.wait_settled(target, 5.0)
        watcher.read_joints()
        samples = watcher.joint_samples()
    finally:
        HeldReader.released.set()
        watcher.close()
        mover.close()
        sim.stop()
    (move,) = motions
    t0, duration = move["t_start"], move["duration_s"]
    ts = np.array([s.t_s for s in samples])
    j1 = np.array([s.joints_deg[0] for s in samples])
    truth = np.clip((ts - t0) / duration, 0.0, 1.0) * target[0]
    waited = (ts < released - 0.05) & (j1 > 0.0) & (j1 < target[0])
    assert np.count_nonzero(waited) >= 1, (ts - released, j1)
    assert np.all(np.diff(ts) > 0.0)
    rate = target[0] / duration
    assert np.max(np.abs(j1 - truth)[waited]) <= rate * 0.02, (ts - t0, j1, truth)
