"""``ucal sim serve`` as a process: the URLs it prints answer on 127.0.0.1 with the real
protocols."""

from __future__ import annotations

import json
import math
import select
import signal
import socket
import struct
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from urllib.parse import parse_qs, urlsplit

import numpy as np
import pytest

pytestmark = pytest.mark.system

# Simple Message (little-endian): int32 length · int32 msg_type, comm_type, reply_code · body
_LEN = struct.Struct("<i")
_HDR = struct.Struct("<3i")
JOINT_POSITION, JOINT_TRAJ_PT, STATUS, JOINT_FEEDBACK = 10, 11, 13, 15
SERVICE_REQUEST, SUCCESS = 2, 1


class Served:
    """A running ``ucal sim serve`` process and the URLs of its first stdout line."""

    def __init__(self, args: list[str]):
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "ucal", "sim", "serve", *args],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        ready, _, _ = select.select([self.proc.stdout], [], [], 20.0)
        if not ready:
            self.proc.kill()
            raise AssertionError("ucal sim serve printed nothing within 20 s")
        self.first_line = self.proc.stdout.readline()
        if not self.first_line:
            _, err = self.proc.communicate(timeout=5)
            raise AssertionError(f"ucal sim serve exited early: {err}")
        self.urls = json.loads(self.first_line)

    def terminate(self, signum: int = signal.SIGTERM) -> tuple[int, float, str]:
        """Send ``signum``; return the exit code, the seconds it took and stderr."""
        t0 = time.monotonic()
        self.proc.send_signal(signum)
        try:
            _, err = self.proc.communicate(timeout=5.0)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.communicate()
            raise AssertionError(f"no exit within 5 s of signal {signum}") from None
        return self.proc.returncode, time.monotonic() - t0, err


@pytest.fixture
def serve_demo(tmp_path: Path) -> Iterator[tuple[Served, Path]]:
    log_path = tmp_path / "motions.jsonl"
    served = Served(["--log", str(log_path), "--time-scale", "0"])
    yield served, log_path
    if served.proc.poll() is None:
        served.proc.kill()
        served.proc.communicate()


def recv_exact(sock: socket.socket, n: int) -> bytes:
    buf = b""
    while len(buf) < n:
        chunk = sock.recv(n - len(buf))
        if not chunk:
            raise AssertionError("connection closed")
        buf += chunk
    return buf


def recv_frame(sock: socket.socket) -> tuple[int, int, int, bytes]:
    (length,) = _LEN.unpack(recv_exact(sock, 4))
    frame = recv_exact(sock, length)
    msg_type, comm_type, reply = _HDR.unpack_from(frame)
    return msg_type, comm_type, reply, frame[_HDR.size :]


def modbus_tcp(sock: socket.socket, tid: int, pdu: bytes, unit: int = 1) -> bytes:
    """One Modbus TCP transaction: MBAP (tid, protocol 0, length, unit) + PDU; returns the PDU."""
    sock.sendall(struct.pack(">HHHB", tid, 0, len(pdu) + 1, unit) + pdu)
    r_tid, proto, length, r_unit = struct.unpack(">HHHB", recv_exact(sock, 7))
    assert (r_tid, proto, r_unit) == (tid, 0, unit)
    return recv_exact(sock, length - 1)


def test_serve_prints_urls_answers_raw_protocols_and_logs_motions(
    serve_demo: tuple[Served, Path],
) -> None:
    served, log_path = serve_demo
    assert set(served.urls) == {"controller", "pulser"}
    ctrl = urlsplit(served.urls["controller"])
    assert ctrl.scheme == "tcp" and ctrl.hostname == "127.0.0.1"
    state_port = int(parse_qs(ctrl.query)["state"][0])
    puls = urlsplit(served.urls["pulser"])
    assert puls.scheme == "modbus-tcp" and puls.hostname == "127.0.0.1"

    # state port: streamed joint state, the demo robot at rest at zero
    with socket.create_connection(("127.0.0.1", state_port), timeout=3.0) as st:
        seen = set()
        for _ in range(10):
            msg_type, _, _, body = recv_frame(st)
            seen.add(msg_type)
            if msg_type == JOINT_POSITION:
                joints_rad = struct.unpack_from("<i10f", body)[1:7]
                np.testing.assert_allclose(joints_rad, 0.0, atol=1e-6)
        assert JOINT_POSITION in seen or JOINT_FEEDBACK in seen

    # pulser: Modbus TCP, FC 4 identity ("UP", map version 2), then one acquisition
    with socket.create_connection(("127.0.0.1", puls.port), timeout=3.0) as mb:
        pdu = modbus_tcp(mb, 1, struct.pack(">BHH", 4, 0x0000, 2))
        assert pdu[:2] == bytes([4, 4])
        assert struct.unpack(">HH", pdu[2:6]) == (0x5550, 2)
        pdu = modbus_tcp(mb, 2, struct.pack(">BHH", 4, 0x0010, 10))
        regs = pdu[2:]
        counter = struct.unpack_from(">I", regs, 0)[0]
        amplitude, tof = struct.unpack_from(">ff", regs, 12)
        assert counter >= 1
        assert math.isnan(tof) and 0.0 <= amplitude < 0.02  # arm straight up: beam to the ceiling

    # motion port: one JOINT_TRAJ_PT, acknowledged, executed, logged
    target_deg = np.array([10.0, -5.0, 20.0, 0.0, 30.0, 0.0])
    rad = np.radians(np.concatenate([target_deg, np.zeros(4)]))
    body = struct.pack("<i12f", 0, *rad, 0.5, 0.0)
    with socket.create_connection(("127.0.0.1", ctrl.port), timeout=3.0) as mo:
        mo.sendall(
            _LEN.pack(_HDR.size + len(body)) + _HDR.pack(JOINT_TRAJ_PT, SERVICE_REQUEST, 0) + body
        )
        msg_type, _, reply, _ = recv_frame(mo)
        assert (msg_type, reply) == (JOINT_TRAJ_PT, SUCCESS)
        deadline = time.monotonic() + 5.0
        lines: list[str] = []
        while time.monotonic() < deadline:
            lines = log_path.read_text().splitlines() if log_path.exists() else []
            if lines:
                break
            time.sleep(0.05)
    assert len(lines) == 1, "one executed motion, one log line"
    record = json.loads(lines[0])
    np.testing.assert_allclose(record["target_deg"], target_deg, atol=1e-4)
    np.testing.assert_allclose(record["end_deg"], target_deg, atol=1e-4)
    assert len(record["true_tcp_pose"]) == 6

    code, seconds, err = served.terminate(signal.SIGTERM)
    assert code == 0 and seconds < 5.0
    assert "Traceback" not in err


def test_sigint_exits_cleanly() -> None:
    served = Served(["--time-scale", "0"])
    with socket.create_connection(
        ("127.0.0.1", urlsplit(served.urls["controller"]).port), timeout=3.0
    ):
        pass
    code, seconds, err = served.terminate(signal.SIGINT)
    assert code == 0 and seconds < 5.0
    assert "Traceback" not in err


def test_world_and_profile_files_drive_the_echo_through_the_drivers(tmp_path: Path) -> None:
    """With --profile and --world the echo read over the wire is the cell's ideal echo."""
    from drivers.controller.client import SimpleMessageController
    from drivers.pulser.base import PulserSettings
    from drivers.pulser.modbus import ModbusPulser
    from ucal.cell import PAPER_CALIBRATION_POSE_DEG
    from ucal.profile import default_profile_text, load_profile
    from ucal.sim.cell import SimulatedCell
    from ucal.world import load_world

    profile_path = tmp_path / "cell.toml"
    profile_path.write_text(default_profile_text("tx90l"), encoding="utf-8")
    world_path = tmp_path / "truth.toml"
    world_path.write_text(
        "[robot]\njoint_offsets_deg = [0.0, 0.0, 0.0, 0.0, 0.3, 0.0]\n"
        "[noise]\ntof_ns = 0.0\namplitude = 0.0\nseed = 5\n",
        encoding="utf-8",
    )
    cell = SimulatedCell(load_world(world_path, load_profile(profile_path)))
    offset_deg = np.array([0.0, 0.0, 0.0, 0.0, 0.3, 0.0])

    served = Served(
        ["--profile", str(profile_path), "--world", str(world_path), "--rtu", "--time-scale", "0"]
    )
    try:
        assert served.urls["pulser"].startswith("modbus-rtu://socket://127.0.0.1:")
        target = PAPER_CALIBRATION_POSE_DEG - offset_deg  # undoes the hidden joint-5 offset
        with (
            SimpleMessageController.from_url(served.urls["controller"]) as robot,
            ModbusPulser.from_url(served.urls["pulser"]) as pulser,
        ):
            pulser.configure(
                PulserSettings(gain_db=20.0, gate_start_us=5.0, gate_width_us=200.0, averages=1)
            )
            readings = {}
            for name, joints in (("corrected", target), ("nominal", PAPER_CALIBRATION_POSE_DEG)):
                reached = robot.move_joints(joints, speed=1.0, timeout_s=5.0)
                readings[name] = (reached, pulser.read_gate(fresh=True))
        reached, gate = readings["corrected"]
        amp, tof = cell.ideal_echo(reached)
        assert np.isfinite(tof), "the default profile puts the block under the paper pose"
        assert gate.has_echo
        assert gate.tof_ns == pytest.approx(tof, abs=0.05)
        assert gate.amplitude == pytest.approx(amp, rel=1e-4)
        # the uncorrected reading is 0.3° off normal: the echo drops below half
        reached, gate = readings["nominal"]
        assert gate.amplitude < 0.5 * amp
        assert gate.amplitude == pytest.approx(cell.ideal_echo(reached)[0], rel=1e-3, abs=1e-3)
    finally:
        code, seconds, err = served.terminate(signal.SIGTERM)
    assert code == 0 and seconds < 5.0, err
