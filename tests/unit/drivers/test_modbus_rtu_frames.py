"""Modbus RTU frames of the pulser, byte for byte (CRC included), without sockets or processes.

The client runs against a scripted serial port in the style of pymeasure's
``expected_protocol``: every write must equal the next expected request, its reply then becomes
readable, and the test fails if a pair is left unused or bytes are left unread.
"""

from __future__ import annotations

import math
import time

import pytest
from pymodbus.framer import FramerRTU
from pymodbus.pdu import DecodePDU, ExceptionResponse
from pymodbus.pdu.register_message import (
    ReadHoldingRegistersRequest,
    WriteMultipleRegistersRequest,
)

from drivers.errors import DeviceError, DeviceTimeout, ProtocolError
from drivers.pulser.base import PulserSettings
from drivers.pulser.modbus import ModbusPulser
from drivers.pulser.modbus_words import rtu_read_line_s

from doubles import ScriptedPort, crc16_modbus


def h(text: str) -> bytes:
    return bytes.fromhex(text)


# Hand-written frames, CRC included (low byte first).
READ_HR_0_2 = h("01 03 00 00 00 02 C4 0B")  # the classic example: unit 1, address 0, count 2
EXC_READ_HR_ILLEGAL_ADDRESS = h("01 83 02 C0 F1")
IDENTIFY = h("01 04 00 00 00 02 71 CB")
IDENTIFY_REPLY = h("01 04 04 55 50 00 01 2B 99")  # magic "UP", map version 1
READ_SETTINGS = h("01 03 00 00 00 07 04 08")
# gain 200 (20.0 dB), PRF 1000 Hz, gate start 5000 ns, gate width 200000 ns, averages 1
SETTINGS_REPLY = h("01 03 0E 00 C8 03 E8 00 00 13 88 00 03 0D 40 00 01 47 52")
WRITE_SETTINGS = h("01 10 00 00 00 07 0E 00 C8 03 E8 00 00 13 88 00 03 0D 40 00 01 AD 28")
WRITE_SETTINGS_REPLY = h("01 10 00 00 00 07 81 CB")
READ_GATE = h("01 04 00 10 00 0A 71 C8")
# counter 7, device time 1234 ms, status ECHO, reserved, amplitude 0.5, tof 40000.0 ns
GATE_REPLY = h("01 04 14 00 00 00 07 00 00 04 D2 00 01 00 00 3F 00 00 00 47 1C 40 00 B9 BD")
EXC_READ_INPUT_ILLEGAL_ADDRESS = h("01 84 02 C2 C1")
WRITE_THRESHOLD_5PCT = h("01 10 00 07 00 01 02 00 32 26 32")
WRITE_THRESHOLD_REPLY = h("01 10 00 07 00 01 B0 08")
WRITE_TRIGGER = h("01 10 00 08 00 01 02 00 01 66 D8")
WRITE_TRIGGER_REPLY = h("01 10 00 08 00 01 80 0B")


URL = "modbus-rtu:///dev/ttyPULSER0?unit=1&baud=115200"


def scripted(
    dialogue: list[tuple[bytes, bytes | None]], timeout_s: float = 0.2
) -> tuple[ModbusPulser, ScriptedPort]:
    port = ScriptedPort([(IDENTIFY, IDENTIFY_REPLY), *dialogue])
    return ModbusPulser(URL, timeout_s=timeout_s, port=port), port


# --- the CRC and pymodbus's framer against hand-written bytes ----------------------------------
@pytest.mark.parametrize(
    "frame",
    [
        READ_HR_0_2,
        EXC_READ_HR_ILLEGAL_ADDRESS,
        IDENTIFY,
        IDENTIFY_REPLY,
        READ_SETTINGS,
        SETTINGS_REPLY,
        WRITE_SETTINGS,
        WRITE_SETTINGS_REPLY,
        READ_GATE,
        GATE_REPLY,
        EXC_READ_INPUT_ILLEGAL_ADDRESS,
        WRITE_THRESHOLD_5PCT,
        WRITE_THRESHOLD_REPLY,
        WRITE_TRIGGER,
        WRITE_TRIGGER_REPLY,
    ],
)
def test_hand_written_frames_carry_the_crc16_modbus(frame: bytes) -> None:
    assert crc16_modbus(frame[:-2]) == frame[-2:]


def test_crc_of_a_frame_including_its_crc_is_zero() -> None:
    assert crc16_modbus(READ_HR_0_2) == b"\x00\x00"


def test_pymodbus_rtu_framer_builds_read_holding_registers() -> None:
    framer = FramerRTU(DecodePDU(False))
    request = ReadHoldingRegistersRequest(address=0, count=2, dev_id=1)
    assert framer.buildFrame(request) == READ_HR_0_2


def test_pymodbus_rtu_framer_builds_write_multiple_registers() -> None:
    framer = FramerRTU(DecodePDU(False))
    request = WriteMultipleRegistersRequest(
        address=0, registers=[200, 1000, 0, 5000, 3, 0x0D40, 1], dev_id=1
    )
    assert framer.buildFrame(request) == WRITE_SETTINGS


def test_pymodbus_rtu_framer_builds_exception_response() -> None:
    framer = FramerRTU(DecodePDU(True))
    assert framer.buildFrame(ExceptionResponse(3, 2, device_id=1)) == EXC_READ_HR_ILLEGAL_ADDRESS


def test_pymodbus_rtu_framer_rejects_a_bad_crc() -> None:
    framer = FramerRTU(DecodePDU(False))
    bad = READ_HR_0_2[:-1] + bytes([READ_HR_0_2[-1] ^ 0xFF])
    _, pdu = framer.handleFrame(bad, 1, 0)
    assert pdu is None
    _, pdu = framer.handleFrame(IDENTIFY_REPLY, 1, 0)
    assert pdu is not None and pdu.registers == [0x5550, 1]


# --- the client's requests and its decoding of replies -----------------------------------------
def test_connect_checks_identity_then_settings_read_back() -> None:
    pulser, port = scripted([(READ_SETTINGS, SETTINGS_REPLY)])
    with pulser:
        assert pulser.settings() == PulserSettings(
            gain_db=20.0, prf_hz=1000.0, gate_start_us=5.0, gate_width_us=200.0, averages=1
        )
    port.assert_done()
    assert not port.is_open


def test_configure_writes_all_settings_in_one_fc16_frame() -> None:
    pulser, port = scripted([(WRITE_SETTINGS, WRITE_SETTINGS_REPLY)])
    with pulser:
        pulser.configure(
            PulserSettings(
                gain_db=20.0, prf_hz=1000, gate_start_us=5.0, gate_width_us=200.0, averages=1
            )
        )
    port.assert_done()


def test_configure_out_of_range_raises_before_any_byte_is_sent() -> None:
    pulser, port = scripted([])
    with pulser, pytest.raises(ValueError, match="gain_db"):
        pulser.configure(PulserSettings(gain_db=80.5))
    port.assert_done()


def test_read_gate_decodes_the_measurement_block() -> None:
    pulser, port = scripted([(READ_GATE, GATE_REPLY)])
    with pulser:
        before = time.monotonic()
        reading = pulser.read_gate()
        after = time.monotonic()
    port.assert_done()
    assert reading.amplitude == 0.5
    assert reading.tof_ns == 40000.0
    assert reading.counter == 7
    assert reading.device_time_s == pytest.approx(1.234)
    assert before <= reading.host_time_s <= after
    assert reading.has_echo


def test_read_gate_fresh_polls_until_the_counter_advances() -> None:
    newer = bytearray(GATE_REPLY[:-2])
    newer[6] = 8  # counter 7 -> 8
    newer += crc16_modbus(bytes(newer))
    pulser, port = scripted(
        [(READ_GATE, GATE_REPLY), (READ_GATE, GATE_REPLY), (READ_GATE, bytes(newer))]
    )
    with pulser:
        assert pulser.read_gate().counter == 7
        assert pulser.read_gate(fresh=True).counter == 8
    port.assert_done()


@pytest.mark.parametrize(("pulser_timeout_s", "read_timeout_s"), [(0.3, None), (5.0, 0.3)])
def test_a_stale_counter_times_out_after_the_read_or_else_the_pulser_timeout(
    pulser_timeout_s: float, read_timeout_s: float | None
) -> None:
    port = ScriptedPort([(IDENTIFY, IDENTIFY_REPLY)] + [(READ_GATE, GATE_REPLY)] * 100_000)
    pulser = ModbusPulser(URL, timeout_s=pulser_timeout_s, port=port)
    with pulser:
        pulser.read_gate()
        with pytest.raises(
            DeviceTimeout,
            match=r"no new reading within 0\.3\d* s \(counter stays at 7; 0\.001 s averaging 1 "
            r"pulse at 1000 Hz, .* then timeout_s = 0\.3 s for the link\)",
        ):
            pulser.read_gate(fresh=True, timeout_s=read_timeout_s)


def test_gate_threshold_and_trigger_frames() -> None:
    pulser, port = scripted(
        [(WRITE_THRESHOLD_5PCT, WRITE_THRESHOLD_REPLY), (WRITE_TRIGGER, WRITE_TRIGGER_REPLY)]
    )
    with pulser:
        pulser.set_gate_threshold(0.05)
        pulser.trigger()
    port.assert_done()


def test_exception_response_becomes_device_error_with_a_readable_name() -> None:
    pulser, port = scripted([(READ_GATE, EXC_READ_INPUT_ILLEGAL_ADDRESS)])
    with pulser, pytest.raises(DeviceError) as info:
        pulser.read_gate()
    port.assert_done()
    message = str(info.value)
    assert "illegal data address (0x02)" in message
    assert message.startswith("pulser at modbus-rtu:///dev/ttyPULSER0")
    assert info.value.device == "pulser"


def test_bad_crc_becomes_protocol_error() -> None:
    corrupted = GATE_REPLY[:-1] + bytes([GATE_REPLY[-1] ^ 0x01])
    pulser, port = scripted([(READ_GATE, corrupted)], timeout_s=0.1)
    with pulser, pytest.raises(ProtocolError, match="bad CRC"):
        pulser.read_gate()
    port.assert_done()


def test_reply_from_another_unit_becomes_protocol_error() -> None:
    other = b"\x02" + GATE_REPLY[1:-2]
    other += crc16_modbus(other)
    pulser, port = scripted([(READ_GATE, other)], timeout_s=0.1)
    with pulser, pytest.raises(ProtocolError):
        pulser.read_gate()
    port.assert_done()


def test_no_reply_becomes_device_timeout_within_the_timeout() -> None:
    pulser, port = scripted([(READ_GATE, None)], timeout_s=0.15)
    with pulser:
        start = time.monotonic()
        with pytest.raises(DeviceTimeout, match="no answer"):
            pulser.read_gate()
        elapsed = time.monotonic() - start
    port.assert_done()
    assert 0.1 <= elapsed < 2.0  # the 0.15 s timeout, with slack for a loaded machine


def test_identity_of_another_map_is_refused() -> None:
    wrong = h("01 04 04 12 34 00 01")
    wrong += crc16_modbus(wrong)
    port = ScriptedPort([(IDENTIFY, wrong)])
    pulser = ModbusPulser(URL, timeout_s=0.2, port=port)
    with pytest.raises(ProtocolError, match="0x1234"):
        pulser.connect()
    port.assert_done()


def test_no_echo_reading_has_nan_tof() -> None:
    reply = bytearray(GATE_REPLY[:-2])
    reply[12] = 0x00  # status: no ECHO bit
    reply[19:23] = bytes.fromhex("7F C0 00 00")  # tof NaN
    reply += crc16_modbus(bytes(reply))
    pulser, port = scripted([(READ_GATE, bytes(reply))])
    with pulser:
        reading = pulser.read_gate()
    port.assert_done()
    assert not reading.has_echo and math.isnan(reading.tof_ns)
    assert reading.amplitude == 0.5


def test_a_whole_reply_past_the_deadline_is_a_reply_and_a_stream_is_not() -> None:
    # A loaded host can hand over the last short request's reply a few milliseconds after its
    # deadline: that is a frame; bytes that keep coming past it and form none are a babbler.
    from drivers.pulser.modbus_link import _NoFrame

    pulser = ModbusPulser(URL, timeout_s=0.3, port=ScriptedPort([]))
    pulser._rx_deadline = 0.0  # long past
    assert pulser._trace_packet(False, GATE_REPLY) == GATE_REPLY
    with pytest.raises(_NoFrame):
        pulser._trace_packet(False, GATE_REPLY[:-1] + bytes([GATE_REPLY[-1] ^ 0x01]))
    with pytest.raises(_NoFrame):
        pulser._trace_packet(False, b"\x00garbage")


# --- a reading's deadline: what it asks of the device, then the link's margin ----------------
def write_settings(prf_hz: int, averages: int) -> bytes:
    """The FC 16 frame of the default settings but ``prf_hz`` and ``averages``."""
    body = (
        h("01 10 00 00 00 07 0E 00 C8")
        + prf_hz.to_bytes(2, "big")
        + h("00 00 13 88 00 03 0D 40")
        + averages.to_bytes(2, "big")
    )
    return body + crc16_modbus(body)


class AveragingPort(ScriptedPort):
    """A scripted port whose device answers a gate read once it has averaged: ``answer_s``
    after the request."""

    def __init__(self, dialogue: list[tuple[bytes, bytes | None]], answer_s: float):
        super().__init__(dialogue)
        self.answer_s = answer_s
        self._held = b""
        self._due = 0.0

    def write(self, data: bytes) -> int:
        before = len(self.rx)
        sent = super().write(data)
        if bytes(data) == READ_GATE:
            self._held, self._due = bytes(self.rx[before:]), time.monotonic() + self.answer_s
            del self.rx[before:]
        return sent

    def _release(self) -> None:
        if self._held and time.monotonic() >= self._due:
            self.rx += self._held
            self._held = b""

    @property
    def in_waiting(self) -> int:
        self._release()
        return len(self.rx)

    def read(self, size: int = 1) -> bytes:
        self._release()
        return super().read(size)


def test_the_settings_frame_of_the_deadline_tests_is_the_default_one_at_1000_hz() -> None:
    assert write_settings(1000, 1) == WRITE_SETTINGS


@pytest.mark.parametrize(
    ("averages", "prf_hz", "timeout_s", "total_s"),
    [(1, 1000, 0.2, 0.201), (16, 1000, 1.0, 1.016), (1000, 1000, 1.0, 2.0), (1000, 200, 1.0, 6.0)],
)
def test_the_deadline_is_the_averaging_as_configured_the_line_and_the_link(
    averages: int, prf_hz: int, timeout_s: float, total_s: float
) -> None:
    pulser, port = scripted(
        [(write_settings(prf_hz, averages), WRITE_SETTINGS_REPLY)], timeout_s=timeout_s
    )
    line_s = rtu_read_line_s(10, 115200)  # the measurement block at the URL's baud: 3.8 ms
    with pulser:
        assert pulser.reading_wait().total_s == pytest.approx(0.001 + line_s + timeout_s)
        pulser.configure(PulserSettings(prf_hz=prf_hz, averages=averages))
        wait = pulser.reading_wait()
        assert wait.acquisition_s == pytest.approx(averages / prf_hz)
        assert (wait.transfer_s, wait.link_s) == (pytest.approx(line_s), timeout_s)
        assert wait.total_s == pytest.approx(total_s + line_s)
        assert pulser.reading_wait(0.05).total_s == pytest.approx(
            total_s - timeout_s + line_s + 0.05
        )
    port.assert_done()


def test_a_reading_of_many_averages_longer_than_the_link_timeout_succeeds() -> None:
    """60 averages at 200 Hz: the device answers once it has averaged, after 0.3 s, longer
    than the link's 0.2 s (once the whole wait); the reading may take 0.3 s more than that."""
    port = AveragingPort(
        [
            (IDENTIFY, IDENTIFY_REPLY),
            (write_settings(200, 60), WRITE_SETTINGS_REPLY),
            (READ_GATE, GATE_REPLY),
        ],
        answer_s=0.3,
    )
    pulser = ModbusPulser(URL, timeout_s=0.2, port=port)
    with pulser:
        pulser.configure(PulserSettings(prf_hz=200, averages=60))
        assert pulser.reading_wait().total_s == pytest.approx(0.3 + 0.0038 + 0.2, abs=1e-4)
        reading = pulser.read_gate()
    port.assert_done()
    assert (reading.counter, reading.tof_ns) == (7, 40000.0)


def test_a_silent_device_is_still_a_timeout_naming_it_and_its_averaging() -> None:
    port = ScriptedPort(
        [
            (IDENTIFY, IDENTIFY_REPLY),
            (write_settings(200, 20), WRITE_SETTINGS_REPLY),
            (READ_GATE, None),
        ]
    )
    pulser = ModbusPulser(URL, timeout_s=0.05, port=port)
    with pulser:
        pulser.configure(PulserSettings(prf_hz=200, averages=20))
        with pytest.raises(DeviceTimeout) as info:
            pulser.read_gate()
    port.assert_done()
    assert info.value.device == "pulser"
    message = str(info.value)
    assert message.startswith(f"pulser at {URL}: read gate: no answer within 0.1")
    assert message.endswith(
        "(0.1 s averaging 20 pulses at 200 Hz, 0.0038 s on the line, then timeout_s = 0.05 s "
        "for the link)"
    )
