"""The pulser register map: encodings, word order, declared settings and their validators, on
ucal's own map (the shipped map file)."""

from __future__ import annotations

import itertools
import math
import struct

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from pymodbus.client import ModbusTcpClient
from pymodbus.constants import ExcCodes
from pymodbus.datastore import ModbusDeviceContext, ModbusSequentialDataBlock

from drivers.pulser import registers as reg
from drivers.pulser.base import PulserSettings
from drivers.pulser.map_file import shipped_map

float32s = st.floats(width=32, allow_nan=True, allow_infinity=True)
MAP = shipped_map()


def encode_settings(settings: PulserSettings) -> list[int]:
    """The words of the first configure request (gain … averages)."""
    ((address, words),) = MAP.write_requests(MAP.encode_settings(settings, reg.SETTINGS))
    assert address == 0
    return words


def decode_settings(words: list[int]) -> PulserSettings:
    """Settings from holding registers read from address 0."""
    present = MAP.present(reg.SETTINGS + reg.FRONT_END)
    return MAP.decode_settings(
        {r.name: words[r.address : r.end] for r in present if r.end <= len(words)}
    )


def image(entries: list[tuple[reg.Register, list[int]]], start: int, count: int) -> list[int]:
    """The registers ``start … start + count - 1`` holding ``entries`` (0 elsewhere)."""
    out = [0] * count
    for r, words in entries:
        out[r.address - start : r.end - start] = words
    return out


# --- float32 / uint32 pairs ---------------------------------------------------------------------
@given(float32s)
def test_float32_pair_round_trips_bit_exactly(value: float) -> None:
    first, second = reg.encode_float32(value)
    assert 0 <= first <= 0xFFFF and 0 <= second <= 0xFFFF
    back = reg.decode_float32(first, second)
    assert struct.pack(">f", back) == struct.pack(">f", value)


@given(st.floats(allow_nan=False, allow_infinity=False, min_value=-3e38, max_value=3e38))
def test_float32_pair_rounds_a_double_to_the_nearest_float32(value: float) -> None:
    assert reg.decode_float32(*reg.encode_float32(value)) == float(np.float32(value))


@given(float32s)
def test_word_order_agrees_with_pymodbus_big_word_order(value: float) -> None:
    ours = list(reg.encode_float32(value))
    theirs = ModbusTcpClient.convert_to_registers(
        value, ModbusTcpClient.DATATYPE.FLOAT32, word_order="big"
    )
    assert ours == theirs


@pytest.mark.parametrize(
    ("value", "registers"),
    [
        (1.0, (0x3F80, 0x0000)),
        (-2.5, (0xC020, 0x0000)),
        (40000.0, (0x471C, 0x4000)),
        (0.1, (0x3DCC, 0xCCCD)),
    ],
)
def test_float32_most_significant_word_first(value: float, registers: tuple[int, int]) -> None:
    assert reg.WORD_ORDER == "big"
    assert {r.word_order for r in MAP.registers.values() if r.words == 2} == {"big"}
    assert reg.encode_float32(value) == registers
    assert reg.encode_float32(value, "little") == registers[::-1]


def test_float32_nan_survives() -> None:
    assert math.isnan(reg.decode_float32(*reg.encode_float32(float("nan"))))


@given(st.integers(0, 0xFFFF_FFFF))
def test_uint32_pair_round_trips(value: int) -> None:
    hi, lo = reg.encode_uint32(value)
    assert (hi << 16) | lo == value
    assert reg.decode_uint32(hi, lo) == value
    assert reg.encode_uint32(value, "little") == (lo, hi)
    assert reg.decode_uint32(lo, hi, "little") == value


@pytest.mark.parametrize("value", [-1, 0x1_0000_0000])
def test_uint32_out_of_range_raises(value: int) -> None:
    with pytest.raises(ValueError):
        reg.encode_uint32(value)


def test_decode_rejects_a_register_that_is_not_uint16() -> None:
    with pytest.raises(ValueError):
        reg.decode_uint32(0x1_0000, 0)


# --- settings -----------------------------------------------------------------------------------
def test_default_settings_registers() -> None:
    # gain 20.0 dB = 200, 1000 Hz, gate start 5000 ns, width 200000 ns = 0x0003_0D40, 1 average
    assert encode_settings(PulserSettings()) == [200, 1000, 0, 5000, 3, 0x0D40, 1]


@given(
    gain=st.integers(0, 800),
    prf=st.integers(1, 20000),
    start=st.integers(0, 1_000_000),
    width=st.integers(100, 1_000_000),
    averages=st.integers(1, 1024),
)
def test_settings_on_the_register_grid_round_trip(
    gain: int, prf: int, start: int, width: int, averages: int
) -> None:
    settings = PulserSettings(
        gain_db=gain / 10,
        prf_hz=float(prf),
        gate_start_us=start / 1000,
        gate_width_us=width / 1000,
        averages=averages,
    )
    try:
        registers = encode_settings(settings)
    except ValueError as exc:
        # only the cross-check of gate end against the pulse period may refuse grid values
        assert "pulse repetition period" in str(exc)
        assert (start + width) / 1000 > 1e6 / prf
        return
    assert decode_settings(registers) == settings


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("gain_db", -0.1),
        ("gain_db", 80.01),
        ("gain_db", float("nan")),
        ("prf_hz", 0.0),
        ("prf_hz", 20001.0),
        ("gate_start_us", -0.001),
        ("gate_start_us", 1000.5),
        ("gate_width_us", 0.05),
        ("gate_width_us", 1001.0),
        ("averages", 0),
        ("averages", 1025),
        ("averages", 2.5),
    ],
)
def test_out_of_range_setting_raises_naming_it(field: str, value: float) -> None:
    values = {"prf_hz": 100.0}  # a long pulse period, so only the tested field can be wrong
    values[field] = value
    with pytest.raises(ValueError, match=field):
        encode_settings(PulserSettings(**values))


def test_validator_does_not_clip() -> None:
    with pytest.raises(ValueError, match=r"gain_db = 80\.01 dB is out of range \[0, 80\] dB"):
        MAP["gain"].to_raw(80.01)
    assert MAP["gain"].to_raw(80.0) == 800


def test_non_number_setting_raises() -> None:
    with pytest.raises(ValueError, match="averages"):
        MAP["averages"].to_raw(True)
    with pytest.raises(ValueError, match="gain_db"):
        MAP["gain"].to_raw("20")  # type: ignore[arg-type]


def test_gate_ending_after_the_pulse_period_raises() -> None:
    settings = PulserSettings(prf_hz=20000, gate_start_us=5.0, gate_width_us=46.0)
    with pytest.raises(ValueError, match=r"gate_width_us.*51 µs.*50 µs"):
        encode_settings(settings)
    encode_settings(PulserSettings(prf_hz=20000, gate_start_us=5.0, gate_width_us=45.0))


def test_values_are_rounded_to_the_register_resolution() -> None:
    assert MAP["gain"].to_raw(20.04) == 200
    assert MAP["gate_start"].to_raw(5.0004) == 5000
    assert MAP["threshold"].to_raw(0.02) == 20


def test_device_side_raw_range_matches_user_range() -> None:
    assert MAP["gain"].raw_ok(800) and not MAP["gain"].raw_ok(801)
    assert MAP["gate_width"].raw_ok(100) and not MAP["gate_width"].raw_ok(99)
    assert MAP["prf"].raw_ok(1) and not MAP["prf"].raw_ok(0)
    command = MAP["command"]
    assert command.raw_ok(command.names["clear_counter"]) and not command.raw_ok(3)


def test_holding_map_is_contiguous_and_without_overlap() -> None:
    used: list[int] = []
    for r in sorted(MAP.registers.values(), key=lambda r: r.address):
        if r.table == "holding":
            used += range(r.address, r.end)
    assert used == list(range(13))


# --- measurement and A-scan blocks --------------------------------------------------------------
@given(
    counter=st.integers(0, 0xFFFF_FFFF),
    time_ms=st.integers(0, 0xFFFF_FFFF),
    status=st.sampled_from([0, 1, 2, 3, 4]),
    amplitude=st.floats(0, 1, width=32),
    tof=st.floats(0, 1e6, width=32) | st.just(float("nan")),
)
def test_measurement_block_round_trips(
    counter: int, time_ms: int, status: int, amplitude: float, tof: float
) -> None:
    m = reg.Measurement(counter, time_ms, reg.Status(status), amplitude, tof)
    entries = MAP.encode_measurement(m)
    back = MAP.decode_measurement({r.name: words for r, words in entries})
    assert (back.counter, back.device_time_ms, back.status) == (counter, time_ms, status)
    assert back.amplitude == amplitude
    assert back.tof_ns == tof or (math.isnan(back.tof_ns) and math.isnan(tof))


def test_measurement_layout() -> None:
    m = reg.Measurement(0x0001_0002, 1234, reg.Status.ECHO | reg.Status.SATURATED, 1.0, 40000.0)
    assert MAP.read_requests(MAP.present(reg.MEASUREMENT)) == [("input", 0x10, 10)]
    assert image(MAP.encode_measurement(m), 0x10, 10) == [
        1, 2, 0, 1234, 3, 0, 0x3F80, 0, 0x471C, 0x4000
    ]  # fmt: skip
    assert MAP["tof"].address - MAP["counter"].address == 8
    assert reg.MEASUREMENT_COUNT == 10  # what ucal.timing charges for a reading


def test_ascan_header_round_trips() -> None:
    header = reg.AScanHeader(counter=9, length=2001, sample_rate_hz=100e6, start_ns=30_000)
    entries = MAP.encode_ascan_header(header)
    assert image(entries, 0x100, 8) == [0, 9, 2001, 0, *reg.encode_float32(100e6), 0, 30_000]
    assert MAP.decode_ascan_header({r.name: words for r, words in entries}) == header


def test_samples_are_int16_with_full_scale_32767_and_saturate() -> None:
    registers = reg.encode_samples(np.array([0.0, 1.0, -1.0, 0.5, 2.0, -3.0]))
    assert registers == [0, 0x7FFF, 0x8001, 16384, 0x7FFF, 0x8001]
    assert np.allclose(reg.decode_samples(registers), [0, 1, -1, 16384 / 32767, 1, -1])


def test_input_blocks_do_not_overlap_and_fit_the_image() -> None:
    blocks = sorted(
        MAP.read_requests(MAP.present(names))[0][1:]
        for names in (("magic", "map_version"), reg.DEVICE_INFO, reg.MEASUREMENT, reg.ASCAN_HEADER)
    )
    assert blocks == [(0, 2), (2, 12), (0x10, 10), (0x100, 8)]
    for (a, n), (b, _) in itertools.pairwise(blocks):
        assert a + n <= b
    assert MAP.span("input") == 0x200 + reg.ASCAN_MAX_SAMPLES <= 0x1_0000


def test_exception_names() -> None:
    assert reg.exception_name(2) == "illegal data address (0x02)"
    assert reg.exception_name(4) == "server device failure (0x04)"
    assert reg.exception_name(0x42) == "unknown exception (0x42)"
    assert {int(c) for c in reg.ExceptionCode} == {int(c) for c in ExcCodes}


def test_pymodbus_datastore_serves_protocol_address_n_from_block_address_n_plus_1() -> None:
    # the simulator relies on this: blocks are created at DATASTORE_OFFSET so that protocol
    # address N is values[N]
    block = ModbusSequentialDataBlock(reg.DATASTORE_OFFSET, [10, 11, 12])
    context = ModbusDeviceContext(hr=block)
    assert context.getValues(3, 0, 3) == [10, 11, 12]
    assert context.getValues(3, 2, 1) == [12]
    at_zero = ModbusDeviceContext(hr=ModbusSequentialDataBlock(0, [10, 11, 12]))
    assert at_zero.getValues(3, 0, 1) == [11]  # what a block at 0 would wrongly serve
