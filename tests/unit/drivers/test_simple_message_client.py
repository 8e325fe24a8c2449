"""The Simple Message client byte for byte, on scripted connections (no sockets, no processes).

In the style of pymeasure's ``expected_protocol``: the motion connection is a dialogue of
(expected request, reply) pairs — every write must equal the next expected request, its reply
then becomes readable, a request without a reply finds nothing to read (the reply timeout runs
out at once), and the test fails if a pair is left unused or a reply left unread. The state
connection hands the client's reader the frames a test pushes.
"""

from __future__ import annotations

import logging
import math
import struct
import threading

import numpy as np
import pytest

from drivers.controller.client import (
    MIN_VELOCITY,
    SimpleMessageController,
    val3_percent,
    velocity_on_wire,
)
from drivers.controller.simple_message import (
    CommType,
    JointPosition,
    JointTrajPt,
    JointTrajPtReply,
    MsgType,
    OtherMessage,
    ReplyCode,
    Status,
)
from drivers.errors import DeviceTimeout, MotionRejected, ProtocolError


def h(text: str) -> bytes:
    return bytes.fromhex(text)


Z12 = "00000000 " * 12
# Frames written out by hand (every field an int32 or float32, little-endian as VAL3 sends).
# JOINT_POSITION, TOPIC: sequence 0, J1 = pi/2 (0x3fc90fdb), the other nine zero.
JOINT_POSITION = h("38000000 0a000000 01000000 00000000 00000000 db0fc93f" + " 00000000" * 9)
# STATUS (REP-I0006 appendix A): powered, e-stop unknown, no error, idle, auto, motion possible.
STATUS = h(
    "28000000 0d000000 01000000 00000000 01000000 ffffffff 00000000 00000000 00000000 "
    "02000000 01000000"
)
# JOINT_TRAJ_PT request, sequence 0, to 90, -45, 45, 0, 90, -180 deg at velocity 0.5.
MOVE = h(
    "40000000 0b000000 02000000 00000000 00000000 db0fc93f db0f49bf db0f493f 00000000 "
    "db0fc93f db0f49c0 00000000 00000000 00000000 00000000 0000003f 00000000"
)
MOVE_TARGET_DEG = np.array([90.0, -45.0, 45.0, 0.0, 90.0, -180.0])
# The VAL3 reply: the request's layout, its sequence echoed, SUCCESS (encTrajPtAck.pgx).
MOVE_OK = h("40000000 0b000000 03000000 01000000 00000000 " + Z12)
# STOP_TRAJECTORY: sequence -4, everything else zero; and its SUCCESS reply.
STOP = h("40000000 0b000000 02000000 00000000 fcffffff " + Z12)
STOP_OK = h("40000000 0b000000 03000000 01000000 fcffffff " + Z12)
HOST = "192.168.0.254"
URL = f"tcp://{HOST}:11000?state=11002"


class ScriptedMotion:
    """The motion connection: (expected request, reply or None) pairs."""

    def __init__(self, dialogue: list[tuple[bytes, bytes | None]]):
        self.dialogue = list(dialogue)
        self.rx = bytearray()
        self.closed = False

    def settimeout(self, value: float | None) -> None:
        pass

    def sendall(self, data: bytes) -> None:
        assert self.dialogue, f"unexpected write {bytes(data).hex(' ')}"
        expected, reply = self.dialogue.pop(0)
        assert bytes(data) == expected, f"sent {bytes(data).hex(' ')}, expected {expected.hex(' ')}"
        self.rx += reply or b""

    def recv(self, size: int) -> bytes:
        if not self.rx:
            raise TimeoutError  # no reply scripted: the reply timeout runs out
        out = bytes(self.rx[:size])
        del self.rx[:size]
        return out

    def shutdown(self, how: int) -> None:
        pass

    def close(self) -> None:
        self.closed = True

    def assert_done(self) -> None:
        assert not self.dialogue, f"unused pairs: {self.dialogue}"
        assert not self.rx, f"unread bytes: {bytes(self.rx).hex(' ')}"


class ScriptedState:
    """The state connection: hands the client's reader what ``push`` was given."""

    def __init__(self) -> None:
        self._cond = threading.Condition()
        self._chunks: list[bytes] = []
        self._timeout = 0.1
        self.closed = False

    def push(self, data: bytes) -> None:
        with self._cond:
            self._chunks.append(data)
            self._cond.notify_all()

    def settimeout(self, value: float | None) -> None:
        self._timeout = value or 0.1

    def recv(self, size: int) -> bytes:
        with self._cond:
            if not self._chunks and not self.closed:
                self._cond.wait(self._timeout)
            if self.closed:
                return b""
            if not self._chunks:
                raise TimeoutError
            return self._chunks.pop(0)

    def sendall(self, data: bytes) -> None:
        raise AssertionError("the client never writes to the state port")

    def shutdown(self, how: int) -> None:
        self.close()

    def close(self) -> None:
        with self._cond:
            self.closed = True
            self._cond.notify_all()


def scripted(
    dialogue: list[tuple[bytes, bytes | None]], **options: float
) -> tuple[SimpleMessageController, ScriptedMotion, ScriptedState, list]:
    """A client connected to scripted connections; the state stream already holds a frame."""
    motion, state, opened = ScriptedMotion(dialogue), ScriptedState(), []

    def connect(host: str, port: int, timeout_s: float):
        opened.append((host, port, timeout_s))
        return {11000: motion, 11002: state}[port]

    client = SimpleMessageController.from_url(URL, connect=connect, **options)
    client.connect()
    state.push(JOINT_POSITION + STATUS)
    return client, motion, state, opened


def request(seq: int, velocity: float = 0.5) -> bytes:
    return JointTrajPt(seq, tuple(np.radians(MOVE_TARGET_DEG)), velocity).pack()


def test_byte_dialogue_connect_state_move_stop():
    client, motion, state, opened = scripted([(MOVE, MOVE_OK), (STOP, STOP_OK)])
    # connect: the motion port first, then the state port, each with the connect timeout
    assert opened == [(HOST, 11000, 2.0), (HOST, 11002, 2.0)]
    # state: J1 = float32(pi/2) rad, the REP example's status
    joints = client.read_joints()
    assert joints[0] == pytest.approx(90.0, abs=3e-6) and not np.any(joints[1:])
    st = client.status()
    assert (
        st.drives_powered,
        st.e_stopped,
        st.in_error,
        st.in_motion,
        st.mode,
        st.motion_possible,
    ) == (True, None, False, False, 2, True)
    # move: the exact request, the VAL3 reply
    client.start_move(MOVE_TARGET_DEG, speed=0.5)
    # stop: sequence -4, acknowledged
    client.stop()
    client.close()
    motion.assert_done()
    assert motion.closed and state.closed


@pytest.mark.parametrize(
    "speed, wire_hex",
    [
        (0.5, "0000003f"),
        (0.1, "cdcccc3d"),  # 0.1 is 10 %: sent as asked
        (0.001, "fa61843a"),  # 0.1 %: VAL3's "smooth last point" trigger, sent as 0.00101
        (0.0010004, "fa61843a"),  # rounds to 0.1 % as well
        (1e-6, "17b7d138"),  # below what the server runs as asked: 1e-4
    ],
)
def test_velocity_on_the_wire(speed, wire_hex):
    req = bytearray(request(0))
    req[60:64] = h(wire_hex)
    client, motion, _, _ = scripted([(bytes(req), MOVE_OK)])
    client.start_move(MOVE_TARGET_DEG, speed=speed)
    motion.assert_done()


def test_val3_velocity_rules():
    assert val3_percent(0.001) == 0.1 and val3_percent(0.1) == 10.0
    assert val3_percent(0.0009994) == 0.0999 and val3_percent(0.0010006) == 0.1001
    for speed in np.geomspace(1e-9, 1.0, 2000):
        wire = velocity_on_wire(float(speed))
        assert wire >= MIN_VELOCITY and val3_percent(wire) != 0.1
        assert wire == speed or speed < MIN_VELOCITY or val3_percent(speed) == 0.1


def test_after_a_reply_timeout_the_sequence_moves_on_and_the_late_reply_is_skipped():
    client, motion, _, _ = scripted(
        [
            (request(0), None),
            (
                request(1),
                JointTrajPtReply(ReplyCode.SUCCESS, 0).pack()  # late, for point 0
                + JointTrajPtReply(ReplyCode.FAILURE, 1).pack(),
            ),
        ]
    )
    with pytest.raises(
        DeviceTimeout,
        match=r"reply timeout ran out \(reply_timeout_s = 2 s\): "
        r"no reply to trajectory point 0",
    ):
        client.start_move(MOVE_TARGET_DEG)
    # point 1's own answer (FAILURE), not the late SUCCESS of point 0
    with pytest.raises(MotionRejected, match=r"trajectory point 1 .* refused"):
        client.start_move(MOVE_TARGET_DEG)
    motion.assert_done()


def test_a_late_reply_without_a_sequence_is_never_taken_for_a_new_point():
    header_only_ok = JointTrajPtReply(ReplyCode.SUCCESS, None, 0).pack()
    client, motion, _, _ = scripted(
        [(request(0), None), (request(1), header_only_ok), (request(2), header_only_ok)]
    )
    with pytest.raises(DeviceTimeout, match="point 0"):
        client.start_move(MOVE_TARGET_DEG)
    with pytest.raises(DeviceTimeout, match="point 1"):  # that reply may be point 0's
        client.start_move(MOVE_TARGET_DEG)
    with pytest.raises(DeviceTimeout, match="point 2"):  # and this one point 1's
        client.start_move(MOVE_TARGET_DEG)
    motion.assert_done()


def test_well_formed_frames_of_other_types_are_skipped_on_both_ports(caplog):
    ping_reply = OtherMessage(MsgType.PING, CommType.SERVICE_REPLY, ReplyCode.SUCCESS).pack()
    vendor_topic = OtherMessage(4242, CommType.TOPIC, ReplyCode.INVALID, b"vendor data!").pack()
    caplog.set_level(logging.WARNING, logger="drivers.controller.client")
    client, motion, state, _ = scripted([(MOVE, ping_reply + vendor_topic + MOVE_OK)])
    state.push(vendor_topic + JointPosition((0.0, 1.0)).pack() + vendor_topic)
    client.start_move(MOVE_TARGET_DEG, speed=0.5)
    assert client.read_joints()[1] == pytest.approx(math.degrees(1.0), rel=1e-6)
    motion.assert_done()
    assert "ignoring OtherMessage (type 4242) on the state port" in caplog.text


@pytest.mark.parametrize(
    "bad",
    [
        b"\x00garbage bytes that are not a frame at all",
        struct.pack("<4i", 0x7FFFFFFF, 11, 3, 1),  # length 0x7fffffff
        struct.pack("<4i", 12, 99, 0, 0),  # unknown type, comm type 0: no frame
    ],
)
def test_stop_is_sent_after_a_bad_frame_on_the_motion_port(bad, caplog):
    caplog.set_level(logging.WARNING, logger="drivers.controller.client")
    client, motion, _, _ = scripted([(MOVE, bad), (STOP, None)])
    with pytest.raises(ProtocolError) as info:
        client.start_move(MOVE_TARGET_DEG, speed=0.5)
    assert info.value.endpoint == URL
    client.stop()  # STOP goes out (the dialogue expects it); the earlier fault is logged
    assert not motion.dialogue
    assert "STOP sent to" in caplog.text and "the motion link failed" in caplog.text
    with pytest.raises(ProtocolError):  # the motion link stays condemned
        client.start_move(MOVE_TARGET_DEG)


def test_a_refused_connection_names_the_port_and_a_silent_one_the_connect_timeout():
    def refuse(host: str, port: int, timeout_s: float):
        raise ConnectionRefusedError(111, "Connection refused")

    client = SimpleMessageController.from_url(URL, connect=refuse)
    with pytest.raises(Exception, match="cannot connect to the motion port 11000"):
        client.connect()

    def hang(host: str, port: int, timeout_s: float):
        raise TimeoutError("timed out")

    client = SimpleMessageController.from_url(URL, connect=hang, connect_timeout_s=3.5)
    with pytest.raises(
        DeviceTimeout,
        match=r"connect timeout ran out \(connect_timeout_s = "
        r"3.5 s\): no answer connecting to the motion port",
    ):
        client.connect()


def test_status_frame_constants_match_the_message_classes():
    assert Status(1, -1, 0, 0, 0, 2, 1).pack() == STATUS
    assert JointTrajPtReply(ReplyCode.SUCCESS, 0).pack() == MOVE_OK
