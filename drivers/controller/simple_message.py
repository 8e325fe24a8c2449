"""ROS-Industrial Simple Message framing (REP-I0006) as spoken by the Staubli VAL3 server.

A frame on the wire is ``length`` (int32, the number of bytes that follow it), a three-field
header (``msg_type``, ``comm_type``, ``reply_code``, int32 each) and a message-specific body.
Every field is 4 bytes, **little-endian**: the VAL3 server (ros-industrial/staubli_val3_driver)
encodes integers with ``toBinary(..., "-4l", ...)`` and reals with ``"4.0l"`` (signed 4-byte
little-endian integer, 4-byte little-endian IEEE float); see ``val3/ros_server/decTrajPt.pgx``
and ``val3/ros_server/encPrefixHeader.pgx``. The byte layouts are tabulated in
``docs/protocols/simple_message.md``.

There are no sync bytes in the protocol, so a receiver that loses count can never recover; the
``FrameReader`` therefore validates every header (length within bounds, valid comm type and
reply code, exact body size for a known type) and raises ``ProtocolError`` at the first
inconsistency rather than guessing. A well-formed frame of a type this module does not decode
(PING, JOINT_TRAJ_PT_FULL, a vendor message) is returned as ``OtherMessage`` with its raw body:
REP-I0006 receivers (and industrial_core's) skip messages they do not use, and so do the
clients of this module. Joint values are radians on the wire (REP-103); conversion to degrees is the
client's job.
"""

from __future__ import annotations

import logging
import struct
from collections.abc import Iterable
from dataclasses import dataclass, field
from enum import IntEnum
from typing import ClassVar

from drivers.errors import ProtocolError

log = logging.getLogger(__name__)

# Byte order of every field, as the VAL3 server writes it ("-4l" / "4.0l").
BYTE_ORDER = "<"

LENGTH_SIZE = 4  # int32 prefix
HEADER_SIZE = 12  # int32 msg_type, int32 comm_type, int32 reply_code
MAX_JOINTS = 10  # every joint array on the wire has exactly ten elements
# Largest frame we accept (value of the length field). The largest standard message the VAL3
# server sends is JOINT_FEEDBACK at 144 bytes; anything far beyond that is garbage, and must be
# rejected before a buffer of that size is ever requested.
MAX_LENGTH = 1024

_LENGTH = struct.Struct(BYTE_ORDER + "i")
_HEADER = struct.Struct(BYTE_ORDER + "3i")


class MsgType(IntEnum):
    """Assigned message identifiers (REP-I0004); PING and JOINT_TRAJ_PT_FULL are not decoded."""

    PING = 1
    JOINT_POSITION = 10
    JOINT_TRAJ_PT = 11
    STATUS = 13
    JOINT_TRAJ_PT_FULL = 14
    JOINT_FEEDBACK = 15


class CommType(IntEnum):
    """Communication types (REP-I0006, 'Communication Types'); 0 is reserved/invalid."""

    TOPIC = 1
    SERVICE_REQUEST = 2
    SERVICE_REPLY = 3


class ReplyCode(IntEnum):
    """Reply codes; ``INVALID`` also means 'unused' on TOPIC and SERVICE_REQUEST messages."""

    INVALID = 0
    SUCCESS = 1
    FAILURE = 2


class SpecialSeq(IntEnum):
    """Special values of the JOINT_TRAJ_PT ``sequence`` field."""

    START_TRAJECTORY_DOWNLOAD = -1
    START_TRAJECTORY_STREAMING = -2
    END_TRAJECTORY = -3
    STOP_TRAJECTORY = -4


class TriState(IntEnum):
    """Tri-state STATUS fields."""

    UNKNOWN = -1
    OFF = 0
    ON = 1


class RobotMode(IntEnum):
    """STATUS ``mode`` (ISO 10218-1 modes)."""

    UNKNOWN = -1
    MANUAL = 1
    AUTO = 2


def _joint_array(values: Iterable[float], name: str) -> tuple[float, ...]:
    """Pad ``values`` with zeros to the ten elements every joint array has on the wire."""
    out = tuple(map(float, values))
    if len(out) > MAX_JOINTS:
        raise ValueError(f"{name}: at most {MAX_JOINTS} joints, got {len(out)}")
    return out + (0.0,) * (MAX_JOINTS - len(out))


def _frame(msg_type: int, comm_type: int, reply_code: int, body: bytes) -> bytes:
    return (
        _LENGTH.pack(HEADER_SIZE + len(body)) + _HEADER.pack(msg_type, comm_type, reply_code) + body
    )


class _Framed:
    """What every message of a decoded type does: its frame is the header and the body it
    packs (``_body``); its joint arrays (``_JOINT_ARRAYS``, by field name) are padded to the
    ten elements every joint array has on the wire."""

    msg_type: ClassVar[int]
    _JOINT_ARRAYS: ClassVar[tuple[str, ...]] = ()
    comm_type: int
    reply_code: int

    def __post_init__(self) -> None:
        for name in self._JOINT_ARRAYS:
            object.__setattr__(self, name, _joint_array(getattr(self, name), name))

    def _body(self) -> bytes:
        raise NotImplementedError

    def pack(self) -> bytes:
        """Serialise to a complete frame (length prefix included)."""
        return _frame(self.msg_type, self.comm_type, self.reply_code, self._body())


@dataclass(frozen=True)
class JointPosition(_Framed):
    """JOINT_POSITION (10): joint state, ``joints_rad`` padded to ten elements (rad).

    Body (44 bytes): int32 sequence (0 when reporting state) · float32[10] joint_data.
    """

    msg_type: ClassVar[int] = MsgType.JOINT_POSITION
    _BODY: ClassVar[struct.Struct] = struct.Struct(BYTE_ORDER + "i10f")
    _JOINT_ARRAYS = ("joints_rad",)

    joints_rad: tuple[float, ...]
    sequence: int = 0
    comm_type: int = CommType.TOPIC
    reply_code: int = ReplyCode.INVALID

    def _body(self) -> bytes:
        return self._BODY.pack(self.sequence, *self.joints_rad)

    @classmethod
    def _from_body(cls, comm_type: int, reply_code: int, body: bytes) -> JointPosition:
        seq, *joints = cls._BODY.unpack(body)
        return cls(tuple(joints), seq, comm_type, reply_code)


@dataclass(frozen=True)
class JointTrajPt(_Framed):
    """JOINT_TRAJ_PT (11) request: enqueue one trajectory point.

    Body (52 bytes): int32 sequence · float32[10] joint_data (rad) · float32 velocity (fraction
    of the maximum joint speed, (0, 1]) · float32 duration (s; ignored by the VAL3 server, which
    executes ``movej`` at ``velocity``).
    """

    msg_type: ClassVar[int] = MsgType.JOINT_TRAJ_PT
    _BODY: ClassVar[struct.Struct] = struct.Struct(BYTE_ORDER + "i12f")
    _JOINT_ARRAYS = ("joints_rad",)

    sequence: int
    joints_rad: tuple[float, ...]
    velocity: float = 0.0
    duration: float = 0.0
    comm_type: int = CommType.SERVICE_REQUEST
    reply_code: int = ReplyCode.INVALID

    def _body(self) -> bytes:
        return self._BODY.pack(self.sequence, *self.joints_rad, self.velocity, self.duration)

    @classmethod
    def _from_body(cls, comm_type: int, reply_code: int, body: bytes) -> JointTrajPt:
        seq, *reals = cls._BODY.unpack(body)
        return cls(seq, tuple(reals[:MAX_JOINTS]), reals[10], reals[11], comm_type, reply_code)


@dataclass(frozen=True)
class JointTrajPtReply(_Framed):
    """JOINT_TRAJ_PT (11) SERVICE_REPLY: the result of enqueueing one point.

    REP-I0006 allows three body sizes: none (header only), 40 bytes (float32[10] dummy data) and
    the VAL3 form, 52 bytes, laid out like the request with the request's ``sequence`` echoed and
    everything else zero (``setupRosMsgs.pgx``: ack prefix length 64; ``decTrajPt.pgx`` copies
    the sequence). ``sequence`` is ``None`` when the reply does not carry it.
    """

    msg_type: ClassVar[int] = MsgType.JOINT_TRAJ_PT
    BODY_SIZES: ClassVar[tuple[int, ...]] = (0, 40, 52)

    reply_code: int
    sequence: int | None = None
    body_size: int = 52
    comm_type: int = CommType.SERVICE_REPLY

    def __post_init__(self) -> None:
        if self.body_size not in self.BODY_SIZES:
            raise ValueError(f"body_size must be one of {self.BODY_SIZES}, got {self.body_size}")
        if self.body_size != 52 and self.sequence is not None:
            raise ValueError("only the 52-byte reply carries a sequence")

    @property
    def success(self) -> bool:
        return self.reply_code == ReplyCode.SUCCESS

    def _body(self) -> bytes:
        if self.body_size == 52:
            return JointTrajPt._BODY.pack(self.sequence or 0, *([0.0] * 12))
        return bytes(self.body_size)

    @classmethod
    def _from_body(cls, comm_type: int, reply_code: int, body: bytes) -> JointTrajPtReply:
        seq = _LENGTH.unpack_from(body)[0] if len(body) == 52 else None
        return cls(reply_code, seq, len(body), comm_type)


@dataclass(frozen=True)
class Status(_Framed):
    """STATUS (13): controller state; tri-states are -1 unknown, 0 false, 1 true.

    Body (28 bytes): int32 drives_powered · e_stopped · error_code · in_error · in_motion ·
    mode (-1 unknown, 1 manual, 2 auto) · motion_possible.
    """

    msg_type: ClassVar[int] = MsgType.STATUS
    _BODY: ClassVar[struct.Struct] = struct.Struct(BYTE_ORDER + "7i")
    #: The body's fields, in their order on the wire.
    _FIELDS: ClassVar[tuple[str, ...]] = (
        "drives_powered",
        "e_stopped",
        "error_code",
        "in_error",
        "in_motion",
        "mode",
        "motion_possible",
    )

    drives_powered: int = TriState.UNKNOWN
    e_stopped: int = TriState.UNKNOWN
    error_code: int = 0
    in_error: int = TriState.UNKNOWN
    in_motion: int = TriState.UNKNOWN
    mode: int = RobotMode.UNKNOWN
    motion_possible: int = TriState.UNKNOWN
    comm_type: int = CommType.TOPIC
    reply_code: int = ReplyCode.INVALID

    def _body(self) -> bytes:
        return self._BODY.pack(*(getattr(self, name) for name in self._FIELDS))

    @classmethod
    def _from_body(cls, comm_type: int, reply_code: int, body: bytes) -> Status:
        fields = dict(zip(cls._FIELDS, cls._BODY.unpack(body), strict=True))
        return cls(**fields, comm_type=comm_type, reply_code=reply_code)


@dataclass(frozen=True)
class JointFeedback(_Framed):
    """JOINT_FEEDBACK (15): joint state with velocities (VAL3 pull request #36 streams it).

    Body (132 bytes): int32 robot_id · int32 valid_fields (bit 0 time, 1 position, 2 velocity,
    3 acceleration) · 4-byte time · float32[10] positions (rad) · float32[10] velocities
    (rad/s) · float32[10] accelerations (rad/s²). REP-I0006 makes ``time`` a float32; the VAL3
    server writes it as an int32 (``encodeJFeedback.pgx``), so it is kept here as the raw 4
    bytes and ``time_s`` decodes it the REP way. Consumers should timestamp on receipt instead.
    """

    msg_type: ClassVar[int] = MsgType.JOINT_FEEDBACK
    _BODY: ClassVar[struct.Struct] = struct.Struct(BYTE_ORDER + "ii4s30f")
    _JOINT_ARRAYS = ("positions_rad", "velocities_rad_s", "accelerations_rad_s2")

    positions_rad: tuple[float, ...]
    velocities_rad_s: tuple[float, ...] = ()
    accelerations_rad_s2: tuple[float, ...] = ()
    robot_id: int = 0
    valid_fields: int = 0x02
    time_raw: bytes = field(default=bytes(4))
    comm_type: int = CommType.TOPIC
    reply_code: int = ReplyCode.INVALID

    def __post_init__(self) -> None:
        super().__post_init__()
        if len(self.time_raw) != 4:
            raise ValueError("time_raw must be 4 bytes")

    @property
    def time_s(self) -> float:
        """The ``time`` field read as REP-I0006 defines it (float32, s)."""
        return float(struct.unpack(BYTE_ORDER + "f", self.time_raw)[0])

    def _body(self) -> bytes:
        return self._BODY.pack(
            self.robot_id,
            self.valid_fields,
            self.time_raw,
            *self.positions_rad,
            *self.velocities_rad_s,
            *self.accelerations_rad_s2,
        )

    @classmethod
    def _from_body(cls, comm_type: int, reply_code: int, body: bytes) -> JointFeedback:
        robot_id, valid, t_raw, *reals = cls._BODY.unpack(body)
        return cls(
            tuple(reals[0:10]),
            tuple(reals[10:20]),
            tuple(reals[20:30]),
            robot_id,
            valid,
            t_raw,
            comm_type,
            reply_code,
        )


@dataclass(frozen=True)
class OtherMessage:
    """A well-formed frame of a type this module does not decode, kept as its raw body."""

    msg_type: int
    comm_type: int = CommType.TOPIC
    reply_code: int = ReplyCode.INVALID
    body: bytes = b""

    def pack(self) -> bytes:
        """Serialise to a complete frame (length prefix included)."""
        return _frame(self.msg_type, self.comm_type, self.reply_code, self.body)


Message = JointPosition | JointTrajPt | JointTrajPtReply | Status | JointFeedback | OtherMessage


_COMM_TYPES = frozenset(int(c) for c in CommType)
_REPLY_CODES = frozenset(int(c) for c in ReplyCode)


def _allowed_body_sizes(msg_type: int, comm_type: int) -> tuple[int, ...] | None:
    """Body sizes a (msg_type, comm_type) pair may have; ``None`` (any) for another type."""
    if msg_type == MsgType.JOINT_POSITION:
        return (44,)
    if msg_type == MsgType.JOINT_TRAJ_PT:
        return JointTrajPtReply.BODY_SIZES if comm_type == CommType.SERVICE_REPLY else (52,)
    if msg_type == MsgType.STATUS:
        return (28,)
    if msg_type == MsgType.JOINT_FEEDBACK:
        return (132,)
    return None


def _check_header(
    length: int, msg_type: int, comm_type: int, reply_code: int, device: str, endpoint: str
) -> None:
    """Raise ``ProtocolError`` unless the header describes a well-formed frame.

    A type this module does not decode passes with any body size the length allows (the
    length itself was checked against ``MAX_LENGTH``); its comm type and reply code must still
    be valid, which rejects most garbage that happens to carry a plausible length.
    """
    sizes = _allowed_body_sizes(msg_type, comm_type)
    if comm_type not in _COMM_TYPES:
        raise ProtocolError(
            device, endpoint, f"invalid comm_type {comm_type} in message type {msg_type}"
        )
    if reply_code not in _REPLY_CODES:
        raise ProtocolError(
            device, endpoint, f"invalid reply_code {reply_code} in message type {msg_type}"
        )
    body_size = length - HEADER_SIZE
    if sizes is not None and body_size not in sizes:
        raise ProtocolError(
            device,
            endpoint,
            f"message type {msg_type} (comm_type {comm_type}) with a "
            f"{body_size}-byte body; expected {' or '.join(map(str, sizes))}",
        )


def _decode(msg_type: int, comm_type: int, reply_code: int, body: bytes) -> Message:
    if msg_type == MsgType.JOINT_POSITION:
        return JointPosition._from_body(comm_type, reply_code, body)
    if msg_type == MsgType.JOINT_TRAJ_PT:
        if comm_type == CommType.SERVICE_REPLY:
            return JointTrajPtReply._from_body(comm_type, reply_code, body)
        return JointTrajPt._from_body(comm_type, reply_code, body)
    if msg_type == MsgType.STATUS:
        return Status._from_body(comm_type, reply_code, body)
    if msg_type == MsgType.JOINT_FEEDBACK:
        return JointFeedback._from_body(comm_type, reply_code, body)
    return OtherMessage(msg_type, comm_type, reply_code, body)


def parse(
    frame: bytes, device: str = "controller", endpoint: str = "simple message frame"
) -> Message:
    """Decode exactly one complete frame (length prefix included).

    Raises ``ProtocolError`` for a bad length, an invalid header field, a wrong body size or
    trailing bytes; a well-formed frame of another type is an ``OtherMessage``.
    """
    reader = FrameReader(device, endpoint)
    messages = reader.feed(frame)
    if len(messages) != 1 or reader.buffered:
        raise ProtocolError(
            device,
            endpoint,
            f"expected exactly one frame in {len(frame)} bytes, found "
            f"{len(messages)} and {reader.buffered} bytes left over",
        )
    return messages[0]


class FrameReader:
    """Split a TCP byte stream into decoded messages.

    Feed it whatever ``recv`` returned; it returns the complete messages and keeps the rest.
    The length prefix is checked as soon as its four bytes arrive (negative, shorter than a
    header or above ``MAX_LENGTH`` → ``ProtocolError``), the header as soon as it arrives
    (invalid comm type or reply code, body size that does not fit a known type), so
    garbage is rejected without waiting for, or allocating, the body it claims to have. After
    an error the reader stays broken: the stream has no sync marker to resume from.
    """

    def __init__(
        self,
        device: str = "controller",
        endpoint: str = "simple message stream",
        max_length: int = MAX_LENGTH,
    ):
        self.device = device
        self.endpoint = endpoint
        self.max_length = max_length
        self._buf = bytearray()
        self._error: ProtocolError | None = None

    @property
    def buffered(self) -> int:
        """Bytes received but not yet part of a complete frame."""
        return len(self._buf)

    @property
    def wanted(self) -> int:
        """Bytes that complete the next frame (its length prefix first): a reader that reads
        no more than this at a time gets one frame per read, never the start of the next."""
        n = len(self._buf)
        if n < LENGTH_SIZE:
            return LENGTH_SIZE - n
        (length,) = _LENGTH.unpack_from(self._buf)
        return int(max(LENGTH_SIZE + length - n, 1))

    def feed(self, data: bytes) -> list[Message]:
        """Append ``data`` and return every message completed by it, in order."""
        if self._error is not None:
            raise self._error
        self._buf += data
        out: list[Message] = []
        try:
            while len(self._buf) >= LENGTH_SIZE:
                (length,) = _LENGTH.unpack_from(self._buf)
                if length < HEADER_SIZE or length > self.max_length:
                    raise ProtocolError(
                        self.device,
                        self.endpoint,
                        f"length field {length} outside "
                        f"[{HEADER_SIZE}, {self.max_length}] "
                        f"(bytes {bytes(self._buf[:16]).hex()})",
                    )
                if len(self._buf) < LENGTH_SIZE + HEADER_SIZE:
                    break
                msg_type, comm_type, reply_code = _HEADER.unpack_from(self._buf, LENGTH_SIZE)
                _check_header(length, msg_type, comm_type, reply_code, self.device, self.endpoint)
                end = LENGTH_SIZE + length
                if len(self._buf) < end:
                    break
                body = bytes(self._buf[LENGTH_SIZE + HEADER_SIZE : end])
                del self._buf[:end]
                out.append(_decode(msg_type, comm_type, reply_code, body))
        except ProtocolError as e:
            self._error = e
            self._buf.clear()
            raise
        return out
