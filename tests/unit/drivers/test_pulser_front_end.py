"""Front-end settings (pulse voltage, damping, filters) and device information: the settings'
validators, the register map (version 2) and the client's frames against v1 and v2 devices."""

from __future__ import annotations

import pytest

from drivers.pulser import registers as reg
from drivers.pulser.base import PulserSettings
from drivers.pulser.map_file import shipped_map
from drivers.pulser.modbus import ModbusPulser

from doubles import ScriptedPort, crc16_modbus

h = bytes.fromhex
MAP = shipped_map()


def encode_front_end(settings: PulserSettings) -> list[int]:
    ((address, words),) = MAP.write_requests(MAP.encode_settings(settings, reg.FRONT_END))
    assert address == 9
    return words


IDENTIFY = h("01 04 00 00 00 02 71 CB")
IDENTIFY_V1 = h("01 04 04 55 50 00 01 2B 99")
IDENTIFY_V2 = h("01 04 04 55 50 00 02 6B 98")
WRITE_SETTINGS = h("01 10 00 00 00 07 0E 00 C8 03 E8 00 00 13 88 00 03 0D 40 00 01 AD 28")
WRITE_SETTINGS_REPLY = h("01 10 00 00 00 07 81 CB")
# 100 V, 50 ohm, high-pass 1.00 MHz, low-pass 50.00 MHz
WRITE_FRONT_END = h("01 10 00 09 00 04 08 00 64 00 32 00 64 13 88 FA ED")
WRITE_FRONT_END_REPLY = h("01 10 00 09 00 04 11 C8")
READ_ALL_HOLDING = h("01 03 00 00 00 0D 84 0F")
# defaults, threshold 2 %, command 0, then 200 V, 100 ohm, 5.00 MHz, 35.50 MHz
ALL_HOLDING_REPLY = h(
    "01 03 1A 00 C8 03 E8 00 00 13 88 00 03 0D 40 00 01 00 14 00 00 00 C8 00 64 01 F4 0D DE 43 5B"
)
READ_DEVICE_INFO = h("01 04 00 02 00 0C 51 CF")
# "UP-1000", firmware 2.3, serial 4242
DEVICE_INFO_REPLY = h(
    "01 04 18 55 50 2D 31 30 30 30 00 00 00 00 00 00 00 00 00 00 02 00 03 00 00 10 92 5E 45"
)

FRAMES = [
    IDENTIFY_V2,
    WRITE_FRONT_END,
    WRITE_FRONT_END_REPLY,
    READ_ALL_HOLDING,
    ALL_HOLDING_REPLY,
    READ_DEVICE_INFO,
    DEVICE_INFO_REPLY,
]


def scripted(
    identity: bytes, dialogue: list[tuple[bytes, bytes]]
) -> tuple[ModbusPulser, ScriptedPort]:
    port = ScriptedPort([(IDENTIFY, identity), *dialogue])
    return ModbusPulser("modbus-rtu:///dev/ttyPULSER0?unit=1", timeout_s=0.2, port=port), port


# --- settings -----------------------------------------------------------------------------------
def test_defaults_are_those_of_a_broadband_contact_setup() -> None:
    s = PulserSettings()
    assert (s.pulse_voltage_v, s.damping_ohm, s.high_pass_mhz, s.low_pass_mhz) == (
        100.0,
        50.0,
        1.0,
        50.0,
    )


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("pulse_voltage_v", 0.0),
        ("pulse_voltage_v", -100.0),
        ("damping_ohm", 0.0),
        ("high_pass_mhz", -1.0),
        ("low_pass_mhz", float("nan")),
        ("pulse_voltage_v", "100"),
        ("damping_ohm", float("inf")),
        ("averages", 0),
        ("averages", 1.5),
    ],
)
def test_meaningless_settings_raise_naming_the_field(field: str, value: object) -> None:
    with pytest.raises(ValueError, match=field):
        PulserSettings(**{field: value})  # type: ignore[arg-type]


def test_an_empty_filter_band_raises() -> None:
    with pytest.raises(ValueError, match=r"low_pass_mhz = 5.*above high_pass_mhz = 10"):
        PulserSettings(high_pass_mhz=10.0, low_pass_mhz=5.0)


@pytest.mark.parametrize(
    ("field", "value", "message"),
    [
        ("pulse_voltage_v", 501.0, r"pulse_voltage_v = 501.0 V is out of range \[10, 500\] V"),
        ("pulse_voltage_v", 5.0, "pulse_voltage_v"),
        ("damping_ohm", 2001.0, "damping_ohm"),
        ("high_pass_mhz", 100.5, "high_pass_mhz"),
        ("low_pass_mhz", 600.0, r"low_pass_mhz = 600.0 MHz is out of range \[0.1, 500\] MHz"),
    ],
)
def test_register_ranges_raise_and_never_clip(field: str, value: float, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        encode_front_end(PulserSettings(**{field: value}))


def test_a_band_that_rounds_to_nothing_raises() -> None:
    with pytest.raises(ValueError, match="low_pass_mhz"):
        encode_front_end(PulserSettings(high_pass_mhz=10.001, low_pass_mhz=10.004))


# --- register map -------------------------------------------------------------------------------
def test_existing_addresses_are_unchanged_and_new_ones_follow() -> None:
    old = ("gain", "prf", "gate_start", "gate_width", "averages", "threshold", "command")
    assert [MAP[n].address for n in old] == [0, 1, 2, 4, 6, 7, 8]
    assert {MAP[n].min_version for n in old} == {None}
    assert [MAP[n].address for n in reg.FRONT_END] == [9, 10, 11, 12]
    assert {MAP[n].min_version for n in reg.FRONT_END} == {2}
    assert MAP.span("holding") == 13
    assert MAP["model"].address == 2 and MAP["counter"].address == 0x10


def test_front_end_registers_round_trip() -> None:
    wanted = PulserSettings(
        pulse_voltage_v=200.0, damping_ohm=100.0, high_pass_mhz=5.0, low_pass_mhz=35.5
    )
    assert encode_front_end(wanted) == [200, 100, 500, 3550]
    words = {r.name: w for r, w in MAP.power_on() if r.name in reg.SETTINGS}
    words |= {r.name: w for r, w in MAP.encode_settings(wanted, reg.FRONT_END)}
    assert MAP.decode_settings(words) == wanted


def test_a_version_1_read_keeps_the_front_end_defaults() -> None:
    words = {r.name: w for r, w in MAP.power_on() if r in MAP.present(reg.SETTINGS, version=1)}
    assert set(words) == set(reg.SETTINGS)
    assert MAP.decode_settings(words) == PulserSettings()


def test_device_info_round_trips_and_refuses_long_names() -> None:
    info = reg.DeviceInfo("UP-1000", (2, 3), 4242)
    entries = MAP.encode_device_info(info)
    assert MAP.decode_device_info({r.name: w for r, w in entries}) == info
    assert info.firmware_version == "2.3"
    with pytest.raises(ValueError, match="longer than 16"):
        MAP.encode_device_info(reg.DeviceInfo("x" * 17, (1, 0), 1))


@pytest.mark.parametrize("frame", FRAMES)
def test_hand_written_frames_carry_the_crc(frame: bytes) -> None:
    assert crc16_modbus(frame[:-2]) == frame[-2:]


# --- the client against a v2 and a v1 device ----------------------------------------------------
def test_v2_configure_writes_the_front_end_once_per_connection() -> None:
    pulser, port = scripted(
        IDENTIFY_V2,
        [
            (WRITE_SETTINGS, WRITE_SETTINGS_REPLY),
            (WRITE_FRONT_END, WRITE_FRONT_END_REPLY),
            (WRITE_SETTINGS, WRITE_SETTINGS_REPLY),  # same front end: not written again
        ],
    )
    with pulser:
        pulser.configure(PulserSettings())
        pulser.configure(PulserSettings())
    port.assert_done()


def test_v2_settings_and_identity_read_back() -> None:
    pulser, port = scripted(
        IDENTIFY_V2, [(READ_ALL_HOLDING, ALL_HOLDING_REPLY), (READ_DEVICE_INFO, DEVICE_INFO_REPLY)]
    )
    with pulser:
        assert pulser.settings() == PulserSettings(
            pulse_voltage_v=200.0, damping_ohm=100.0, high_pass_mhz=5.0, low_pass_mhz=35.5
        )
        assert pulser.identity() == {
            "register_map_version": 2,
            "model": "UP-1000",
            "firmware": "2.3",
            "serial": 4242,
        }
    port.assert_done()


def test_v1_device_gets_the_version_1_frames_only() -> None:
    pulser, port = scripted(IDENTIFY_V1, [(WRITE_SETTINGS, WRITE_SETTINGS_REPLY)])
    with pulser:
        pulser.configure(PulserSettings())
        assert pulser.identity() == {"register_map_version": 1}
    port.assert_done()


def test_v1_device_refuses_front_end_settings_before_any_byte() -> None:
    pulser, port = scripted(IDENTIFY_V1, [])
    with pulser, pytest.raises(ValueError, match=r"pulse_voltage_v.*version 1"):
        pulser.configure(PulserSettings(pulse_voltage_v=300.0))
    port.assert_done()


def test_out_of_range_front_end_raises_before_any_byte() -> None:
    pulser, port = scripted(IDENTIFY_V2, [])
    with pulser, pytest.raises(ValueError, match="damping_ohm"):
        pulser.configure(PulserSettings(damping_ohm=5.0))
    port.assert_done()
