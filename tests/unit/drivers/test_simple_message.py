"""Simple Message framing from exact bytes, and controller URL parsing.

The REP-I0006 appendix prints its examples as big-endian 32-bit words; the VAL3 server sends
every field little-endian, so each example here is the appendix's word list with every word
byte-reversed (``_le``).
"""

from __future__ import annotations

import struct
import tracemalloc

import pytest
from hypothesis import given
from hypothesis import strategies as st

from drivers.controller.simple_message import (
    MAX_LENGTH,
    CommType,
    FrameReader,
    JointFeedback,
    JointPosition,
    JointTrajPt,
    JointTrajPtReply,
    MsgType,
    OtherMessage,
    ReplyCode,
    SpecialSeq,
    Status,
    parse,
)
from drivers.errors import ProtocolError
from drivers.urls import ControllerAddress, UrlError, parse_controller_url


def _le(words: str) -> bytes:
    """Big-endian hex words as printed in REP-I0006 → the little-endian bytes on the wire."""
    return b"".join(bytes.fromhex(w)[::-1] for w in words.split())


# REP-I0006, Appendix A, "Example: STATUS" (drives powered, e-stop unknown, auto, idle).
REP_STATUS = _le(
    "00000028 0000000D 00000001 00000000 00000001 FFFFFFFF 00000000 00000000 "
    "00000000 00000002 00000001"
)
# REP-I0006, Appendix A, "Example: JOINT_TRAJ_PT" (sequence 1, velocity 0.1, duration 5 s).
REP_TRAJ_PT = _le(
    "00000040 0000000B 00000002 00000000 00000001 A7600000 3EA7CDE8 BF5D9E57 "
    "C0490FDB 3F34815F C0490FDB 00000000 00000000 00000000 00000000 3DCCCCCD "
    "40A00000"
)
# REP-I0006, Appendix A, "Example: JOINT_POSITION" (six joints close to zero).
REP_JOINT_POSITION = _le(
    "00000038 0000000A 00000001 00000000 00000000 B81AD9FA B6836312 "
    "B7C043F5 B8B81516 B865D055 B8B6365E 00000000 00000000 00000000 "
    "00000000"
)


def _f32(x: float) -> float:
    return struct.unpack("<f", struct.pack("<f", x))[0]


def test_status_example_bytes_written_out():
    # The first bytes spelled out: length 40, type 13, TOPIC, reply INVALID, drives on, e-stop -1.
    assert REP_STATUS[:24] == bytes(
        [
            0x28,
            0,
            0,
            0,
            0x0D,
            0,
            0,
            0,
            0x01,
            0,
            0,
            0,
            0,
            0,
            0,
            0,
            0x01,
            0,
            0,
            0,
            0xFF,
            0xFF,
            0xFF,
            0xFF,
        ]
    )
    assert len(REP_STATUS) == 44


def test_status_rep_example_parses_and_packs():
    msg = parse(REP_STATUS)
    assert msg == Status(
        drives_powered=1,
        e_stopped=-1,
        error_code=0,
        in_error=0,
        in_motion=0,
        mode=2,
        motion_possible=1,
    )
    assert msg.comm_type == CommType.TOPIC and msg.reply_code == ReplyCode.INVALID
    assert msg.pack() == REP_STATUS


def test_joint_traj_pt_rep_example_parses_and_packs():
    msg = parse(REP_TRAJ_PT)
    assert isinstance(msg, JointTrajPt)
    assert msg.sequence == 1
    assert msg.comm_type == CommType.SERVICE_REQUEST
    assert msg.joints_rad[1] == pytest.approx(0.327742815)
    assert msg.joints_rad[2] == pytest.approx(-0.865697324)
    assert msg.joints_rad[3] == pytest.approx(-3.141592741)
    assert msg.joints_rad[4] == pytest.approx(0.705099046)
    assert msg.joints_rad[6:] == (0.0,) * 4
    assert msg.velocity == _f32(0.1)
    assert msg.duration == 5.0
    assert msg.pack() == REP_TRAJ_PT
    built = JointTrajPt(1, msg.joints_rad[:6], 0.1, 5.0)
    assert built.pack() == REP_TRAJ_PT


def test_joint_position_rep_example_parses_and_packs():
    msg = parse(REP_JOINT_POSITION)
    assert isinstance(msg, JointPosition)
    assert msg.sequence == 0
    assert msg.joints_rad[0] == pytest.approx(-0.000036919, abs=1e-9)
    assert msg.joints_rad[5] == pytest.approx(-0.000086886, abs=1e-9)
    assert msg.pack() == REP_JOINT_POSITION


def test_stop_trajectory_bytes():
    frame = JointTrajPt(SpecialSeq.STOP_TRAJECTORY, ()).pack()
    # length 64 · type 11 · SERVICE_REQUEST · INVALID · sequence -4 · 12 zero reals
    assert frame == (bytes.fromhex("40000000 0b000000 02000000 00000000 fcffffff") + bytes(48))


def test_val3_style_reply_echoes_sequence():
    frame = JointTrajPtReply(ReplyCode.SUCCESS, 7).pack()
    assert frame == bytes.fromhex("40000000 0b000000 03000000 01000000 07000000") + bytes(48)
    assert parse(frame) == JointTrajPtReply(ReplyCode.SUCCESS, 7, 52)


@pytest.mark.parametrize("body_size", [0, 40])
def test_short_replies_allowed_by_rep(body_size):
    frame = struct.pack("<4i", 12 + body_size, 11, 3, 2) + bytes(body_size)
    reply = parse(frame)
    assert reply == JointTrajPtReply(ReplyCode.FAILURE, None, body_size)
    assert not reply.success
    assert reply.pack() == frame


def test_joint_feedback_round_trip_keeps_raw_time():
    msg = JointFeedback(
        (0.1, -0.2), (1.0,), (), robot_id=0, valid_fields=7, time_raw=struct.pack("<i", 123456)
    )
    frame = msg.pack()
    assert len(frame) == 148 and frame[:4] == struct.pack("<i", 144)
    back = parse(frame)
    assert back.time_raw == struct.pack("<i", 123456)
    assert back.positions_rad[:2] == (_f32(0.1), _f32(-0.2))
    assert back.velocities_rad_s[0] == 1.0


def test_too_many_joints_refused():
    with pytest.raises(ValueError):
        JointPosition(tuple(range(11)))


# -- FrameReader ----------------------------------------------------------------------------

STREAM = [
    parse(REP_JOINT_POSITION),
    parse(REP_STATUS),
    JointTrajPtReply(ReplyCode.SUCCESS, 3),
    JointFeedback((1.0, 2.0)),
]
STREAM_BYTES = b"".join(m.pack() for m in STREAM)


def test_reader_one_byte_at_a_time():
    reader = FrameReader()
    out = []
    for i in range(len(STREAM_BYTES)):
        out += reader.feed(STREAM_BYTES[i : i + 1])
    assert out == STREAM
    assert reader.buffered == 0


def test_reader_coalesced_chunks():
    reader = FrameReader()
    assert reader.feed(STREAM_BYTES + REP_STATUS[:10]) == STREAM
    assert reader.buffered == 10
    assert reader.feed(REP_STATUS[10:]) == [parse(REP_STATUS)]


@given(st.lists(st.integers(min_value=1, max_value=len(STREAM_BYTES)), max_size=20))
def test_reader_any_split(cuts):
    reader = FrameReader()
    points = sorted(set(cuts)) + [len(STREAM_BYTES)]
    out, start = [], 0
    for p in points:
        out += reader.feed(STREAM_BYTES[start:p])
        start = p
    assert out == STREAM


@pytest.mark.parametrize(
    "garbage, reason",
    [
        (b"GET / HTTP/1.1\r\n\r\n", "length field"),
        (struct.pack("<i", -1) + bytes(12), "length field"),
        (struct.pack("<i", 4) + bytes(12), "length field"),
        (struct.pack("<4i", 40, 99, 0, 0), "invalid comm_type 0 in message type 99"),
        (struct.pack("<4i", 40, 13, 0, 0), "invalid comm_type 0"),
        (struct.pack("<4i", 40, 13, 1, 7), "invalid reply_code 7"),
        (struct.pack("<4i", 44, 13, 1, 0), "32-byte body"),
        (struct.pack("<4i", 65, 11, 3, 1), "53-byte body"),
    ],
)
def test_reader_rejects_garbage_from_the_header(garbage, reason):
    reader = FrameReader("controller", "tcp://127.0.0.1:1?state=2")
    with pytest.raises(ProtocolError, match=reason) as info:
        reader.feed(garbage)
    assert info.value.device == "controller"
    assert info.value.endpoint == "tcp://127.0.0.1:1?state=2"
    # The stream cannot be resynchronised: the reader stays broken.
    with pytest.raises(ProtocolError):
        reader.feed(REP_STATUS)


@pytest.mark.parametrize(
    "other",
    [
        OtherMessage(MsgType.PING, CommType.SERVICE_REQUEST),  # header only
        OtherMessage(
            MsgType.JOINT_TRAJ_PT_FULL, CommType.SERVICE_REPLY, ReplyCode.FAILURE, bytes(136)
        ),
        OtherMessage(4242, CommType.TOPIC, ReplyCode.INVALID, b"vendor data!"),
    ],
)
def test_well_formed_frame_of_another_type_is_kept_raw_between_known_ones(other):
    frame = other.pack()
    assert frame[:4] == struct.pack("<i", 12 + len(other.body))
    reader = FrameReader()
    out = reader.feed(REP_STATUS + frame + REP_JOINT_POSITION)
    assert out == [parse(REP_STATUS), other, parse(REP_JOINT_POSITION)]
    assert reader.buffered == 0


def test_wrong_body_size_rejected_before_body_arrives():
    reader = FrameReader()
    # A STATUS header announcing a 100-byte body: rejected as soon as the header is complete.
    with pytest.raises(ProtocolError, match="100-byte body"):
        reader.feed(struct.pack("<4i", 112, 13, 1, 0))


def test_absurd_length_rejected_without_allocation():
    reader = FrameReader()
    tracemalloc.start()
    try:
        with pytest.raises(ProtocolError, match=str(0x7FFFFFFF)):
            reader.feed(b"\xff\xff\xff\x7f")
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < 64 * 1024
    assert reader.buffered == 0


def test_length_bound_is_configurable_and_inclusive():
    frame = parse(REP_STATUS).pack()
    assert FrameReader(max_length=40).feed(frame) == [parse(REP_STATUS)]
    with pytest.raises(ProtocolError):
        FrameReader(max_length=39).feed(frame)
    assert MAX_LENGTH >= 148


def test_parse_requires_exactly_one_frame():
    with pytest.raises(ProtocolError, match="exactly one frame"):
        parse(REP_STATUS + REP_STATUS)
    with pytest.raises(ProtocolError, match="exactly one frame"):
        parse(REP_STATUS[:-1])


float32s = st.floats(width=32, allow_nan=False, allow_infinity=False)


@given(
    seq=st.integers(min_value=-(2**31), max_value=2**31 - 1),
    joints=st.lists(float32s, min_size=0, max_size=10),
    velocity=float32s,
    duration=float32s,
    comm=st.sampled_from([CommType.TOPIC, CommType.SERVICE_REQUEST]),
)
def test_joint_traj_pt_round_trip(seq, joints, velocity, duration, comm):
    msg = JointTrajPt(seq, tuple(joints), velocity, duration, comm)
    frame = msg.pack()
    assert len(frame) == 68
    assert parse(frame) == msg
    assert FrameReader().feed(frame) == [msg]


@given(
    fields=st.lists(st.integers(min_value=-1, max_value=1), min_size=7, max_size=7),
    code=st.integers(min_value=-(2**31), max_value=2**31 - 1),
)
def test_status_round_trip(fields, code):
    fields[2] = code
    msg = Status(*fields)
    assert parse(msg.pack()) == msg


# -- controller URLs (drivers.urls) ---------------------------------------------------------


@pytest.mark.parametrize(
    "url, expected",
    [
        ("tcp://127.0.0.1:11000?state=11002", ControllerAddress("127.0.0.1", 11000, 11002)),
        ("tcp://robot", ControllerAddress("robot", 11000, 11002)),
        ("tcp://10.0.0.5:1234", ControllerAddress("10.0.0.5", 1234, 11002)),
        ("tcp://127.0.0.1:5000?state=5001", ControllerAddress("127.0.0.1", 5000, 5001)),
        ("tcp://[::1]:5?state=6", ControllerAddress("::1", 5, 6)),
    ],
)
def test_parse_controller_url(url, expected):
    address = parse_controller_url(url)
    assert address == expected
    assert parse_controller_url(address.url) == expected


def test_canonical_url_spells_out_state_port():
    assert parse_controller_url("tcp://robot").url == "tcp://robot:11000?state=11002"


@pytest.mark.parametrize(
    "url, message",
    [
        ("udp://robot:1", "tcp://HOST:PORT"),
        ("modbus-tcp://127.0.0.1:502", "tcp://HOST:PORT"),
        ("tcp://:11000", "no host"),
        ("tcp://robot:abc", "not a number"),
        ("tcp://robot:0", "outside 1..65535"),
        ("tcp://robot:70000", "outside 1..65535"),
        ("tcp://robot:1?unit=2", "unknown parameter"),
        ("tcp://robot:1?state=x", "not a number"),
        ("tcp://robot:1?state=3&state=4", "more than once"),
        ("tcp://robot:1?state=1", "must differ"),
        ("tcp://robot:1/x", "unexpected path"),
    ],
)
def test_bad_controller_urls(url, message):
    with pytest.raises(UrlError, match=message) as info:
        parse_controller_url(url)
    assert isinstance(info.value, ValueError)
    assert repr(url) in str(info.value)
