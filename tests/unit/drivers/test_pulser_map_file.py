"""Register map files: the shipped file is the register table ucal's pulser always had, another
device's file encodes what it says, and a bad file is refused naming the file and the key."""

from __future__ import annotations

import math
import tomllib
from pathlib import Path

import pytest

from drivers.pulser import registers as reg
from drivers.pulser.base import PulserSettings
from drivers.pulser.map_file import (
    SHIPPED_MAP_PATH,
    RegisterMapError,
    load_register_map,
    register_map_from_data,
    shipped_map,
)

SHIFTED_MAP_PATH = Path(__file__).resolve().parents[2] / "data" / "shifted_pulser_map.toml"

#: The table of ``drivers/pulser/registers.py`` before the map became a file:
#: name → table, address, type, words, counts per ucal unit, minimum, maximum (ucal units),
#: access, min_version.
OLD_TABLE = {
    "gain": ("holding", 0x0000, "uint16", 1, 10.0, 0.0, 80.0, "read-write", None),
    "prf": ("holding", 0x0001, "uint16", 1, 1.0, 1.0, 20000.0, "read-write", None),
    "gate_start": ("holding", 0x0002, "uint32", 2, 1000.0, 0.0, 1000.0, "read-write", None),
    "gate_width": ("holding", 0x0004, "uint32", 2, 1000.0, 0.1, 1000.0, "read-write", None),
    "averages": ("holding", 0x0006, "uint16", 1, 1.0, 1.0, 1024.0, "read-write", None),
    "threshold": ("holding", 0x0007, "uint16", 1, 1000.0, 0.0, 1.0, "read-write", None),
    "command": ("holding", 0x0008, "uint16", 1, 1.0, None, None, "write", None),
    "pulse_voltage": ("holding", 0x0009, "uint16", 1, 1.0, 10.0, 500.0, "read-write", 2),
    "damping": ("holding", 0x000A, "uint16", 1, 1.0, 10.0, 2000.0, "read-write", 2),
    "high_pass": ("holding", 0x000B, "uint16", 1, 100.0, 0.0, 100.0, "read-write", 2),
    "low_pass": ("holding", 0x000C, "uint16", 1, 100.0, 0.1, 500.0, "read-write", 2),
    "magic": ("input", 0x0000, "uint16", 1, 1.0, None, None, "read", None),
    "map_version": ("input", 0x0001, "uint16", 1, 1.0, None, None, "read", None),
    "model": ("input", 0x0002, "string", 8, 1.0, None, None, "read", 2),
    "firmware_major": ("input", 0x000A, "uint16", 1, 1.0, None, None, "read", 2),
    "firmware_minor": ("input", 0x000B, "uint16", 1, 1.0, None, None, "read", 2),
    "serial": ("input", 0x000C, "uint32", 2, 1.0, None, None, "read", 2),
    "counter": ("input", 0x0010, "uint32", 2, 1.0, None, None, "read", None),
    "device_time": ("input", 0x0012, "uint32", 2, 1.0, None, None, "read", None),
    "status": ("input", 0x0014, "uint16", 1, 1.0, None, None, "read", None),
    "amplitude": ("input", 0x0016, "float32", 2, 1.0, None, None, "read", None),
    "tof": ("input", 0x0018, "float32", 2, 1.0, None, None, "read", None),
    "ascan_counter": ("input", 0x0100, "uint32", 2, 1.0, None, None, "read", None),
    "ascan_length": ("input", 0x0102, "uint16", 1, 1.0, None, None, "read", None),
    "ascan_rate": ("input", 0x0104, "float32", 2, 1.0, None, None, "read", None),
    "ascan_start": ("input", 0x0106, "uint32", 2, 1.0, None, None, "read", None),
    "ascan_samples": ("input", 0x0200, "int16", 32768, 1.0, None, None, "read", None),
}


# --- the shipped map ----------------------------------------------------------------------------
def test_the_shipped_file_is_the_register_table_ucal_always_had() -> None:
    m = shipped_map()
    assert SHIPPED_MAP_PATH.is_file() and m.source == str(SHIPPED_MAP_PATH)
    table = {
        n: (
            r.table,
            r.address,
            r.type,
            r.words,
            r.counts_per_unit,
            r.minimum,
            r.maximum,
            r.access,
            r.min_version,
        )
        for n, r in m.registers.items()
    }
    assert table == OLD_TABLE
    assert {r.word_order for r in m.registers.values()} == {"big"}
    assert m.reserved == (("input", 0x0015, 1), ("input", 0x0103, 1))
    assert m["magic"].values == (0x5550,) and m.versions == (1, 2)
    assert dict(m["command"].names) == {"none": 0, "trigger": 1, "clear_counter": 2}
    assert dict(m["status"].names) == {"echo": 0, "saturated": 1, "gate_error": 2}
    assert m["ascan_samples"].full_scale == reg.ASCAN_FULL_SCALE


def test_the_shipped_map_groups_requests_as_the_protocol_document_says() -> None:
    m = shipped_map()
    settings = m.present(reg.SETTINGS + reg.FRONT_END, version=2)
    assert m.read_requests(settings) == [("holding", 0, 13)]
    assert m.read_requests(m.present(reg.SETTINGS + reg.FRONT_END, version=1)) == [
        ("holding", 0, 7)
    ]
    assert m.read_requests(m.present(("magic", "map_version"))) == [("input", 0, 2)]
    assert m.read_requests(m.present(reg.DEVICE_INFO)) == [("input", 2, 12)]
    assert m.read_requests(m.present(reg.MEASUREMENT)) == [("input", 0x10, 10)]
    assert m.read_requests(m.present(reg.ASCAN_HEADER)) == [("input", 0x100, 8)]
    assert [a for a, _ in m.write_requests(m.encode_settings(PulserSettings(), reg.SETTINGS))] == [
        0
    ]
    assert m.measurement_trigger.name == "counter"
    assert m.ascan_trigger is not None and m.ascan_trigger.name == "ascan_counter"


def test_the_shipped_map_ships_with_the_package() -> None:
    root = Path(__file__).resolve().parents[3]
    config = tomllib.loads((root / "pyproject.toml").read_text())["tool"]["setuptools"]
    assert "maps/*.toml" in config["package-data"]["drivers.pulser"]
    assert SHIPPED_MAP_PATH.parent.name == "maps"


# --- another device's map -----------------------------------------------------------------------
def test_another_map_encodes_what_it_says() -> None:
    m = load_register_map(SHIFTED_MAP_PATH)
    assert min(r.address for r in m.registers.values()) >= 100
    # the gate in 10 ns counts, least significant word first
    assert m["gate_start"].encode_value(5.0) == [500, 0]
    assert m["gate_width"].encode_value(700.0) == [70000 - 0x10000, 1]
    # PRF in kHz with 1 Hz resolution; the gain as a float32
    assert m["prf"].encode_value(1500.0) == [1500]
    assert m["gain"].encode_value(20.0) == list(reg.encode_float32(20.0, "little"))
    # TOF in 0.1 ns int32, amplitude in 0.01 % of full screen
    tof = m["tof"]
    assert tof.counts_per_unit == 10.0
    assert tof.decode_value(tof.encode(tof.device_raw(67_456.789))) == pytest.approx(67_456.8)
    assert m["amplitude"].decode_value(m["amplitude"].encode(m["amplitude"].device_raw(0.5))) == 0.5
    # the status register puts each flag on its own bit
    assert m["status"].encode_status(reg.Status.ECHO | reg.Status.GATE_ERROR) == 0b1000_1000
    assert m["status"].decode_status(0b0010_0000) == reg.Status.SATURATED
    # discrete values are refused between them, never rounded to one
    with pytest.raises(ValueError, match=r"averages = 3 is not one the device takes \(1, 2, 4"):
        m["averages"].to_raw(3)
    with pytest.raises(ValueError, match=r"damping_ohm = 60.0 Ω is not one"):
        m.encode_settings(PulserSettings(damping_ohm=60.0), reg.FRONT_END)


def test_another_map_round_trips_a_reading_without_nan() -> None:
    m = load_register_map(SHIFTED_MAP_PATH)
    no_echo = reg.Measurement(70_000, 1234.0, reg.Status(0), 0.0123, math.nan)
    words = {r.name: w for r, w in m.encode_measurement(no_echo)}
    back = m.decode_measurement(words)
    assert back.counter == 70_000 - 65_536  # a uint16 counter wraps
    assert back.device_time_ms == 1234.0 and back.status == reg.Status(0)
    assert back.tof_ns == 0.0  # an int32 has no NaN: the status says there is no echo
    assert back.amplitude == pytest.approx(0.0123)
    assert m.read_requests(m.present(reg.MEASUREMENT)) == [("input", 140, 7)]
    # the A-scan header spans an address the map does not declare: two requests
    assert m.read_requests(m.present(reg.ASCAN_HEADER)) == [("input", 147, 1), ("input", 150, 4)]


def test_a_setting_without_a_register_keeps_its_default() -> None:
    text = SHIFTED_MAP_PATH.read_text()
    cut = text.index("[registers.pulse_voltage]")
    text = text[:cut] + text[text.index("[registers.damping]") :]
    path = SHIFTED_MAP_PATH.parent / "unused"  # named in messages only
    m = register_map_from_data(tomllib.loads(text), path)
    m.encode_settings(PulserSettings(), reg.FRONT_END)
    with pytest.raises(
        ValueError, match=r"pulse_voltage_v = 300.0 cannot be set.*no pulse_voltage"
    ):
        m.encode_settings(PulserSettings(pulse_voltage_v=300.0), reg.FRONT_END)


# --- bad files ----------------------------------------------------------------------------------
def _shifted_with(old: str, new: str) -> str:
    text = SHIFTED_MAP_PATH.read_text()
    assert old in text, old
    return text.replace(old, new, 1)


_TEXT = SHIFTED_MAP_PATH.read_text()
#: The whole [registers.tof] section.
TOF = _TEXT[_TEXT.index("[registers.tof]") : _TEXT.index("[registers.amplitude]")]


@pytest.mark.parametrize(
    ("old", "new", "key", "message"),
    [
        ("scale = 0.1  # 0.1 ns", "scale = 0  #", "registers.tof.scale", "must be > 0"),
        ("scale = 0.1  # 0.1 ns", "scael = 0.1  #", "registers.tof.scael", "unknown key"),
        (
            'unit = "ns"\nscale = 0.1',
            'unit = "furlong"\nscale = 0.1',
            "registers.tof.unit",
            "one of",
        ),
        ('unit = "ns"\nscale = 0.1', "scale = 0.1", "registers.tof.unit", "missing key"),
        ("address = 140", "address = 70000", "registers.tof.address", "0 … 65535"),
        ("address = 140", "address = 142", "registers.tof.address", "overlaps registers.amplitude"),
        (
            'type = "int32"\nunit = "ns"',
            'type = "int24"\nunit = "ns"',
            "registers.tof.type",
            "one of",
        ),
        (
            "[registers.tof]",
            "[registers.time_of_flight]",
            "registers.time_of_flight",
            "unknown register",
        ),
        (TOF, "", "registers.tof", "missing (every map needs"),
        ('name = "shifted test pulser"', "", "map.name", "missing key"),
        ('word_order = "little"', 'word_order = "middle"', "map.word_order", "big, little"),
        ("range = [0, 80]", "range = [80, 0]", "registers.gain.range", "above maximum"),
        ("range = [0.001, 20]", "range = [0.001, 70]", "registers.prf.range[1]", "beyond a uint16"),
        ("values = [0x4D59]", "", "registers.magic.values", "missing key"),
        ("echo = 3, ", "", "registers.status.bits.echo", "missing key"),
        ("echo = 3", "echo = 16", "registers.status.bits.echo", "0 … 15"),
        ("trigger = 5", "trigger = 0", "registers.command.values", "share a value"),
        (
            'table = "holding"\naddress = 100',
            'table = "input"\naddress = 100',
            "registers.gain.table",
            "must be holding",
        ),
        ("count = 4096", "count = 40000", "registers.ascan_samples.count", "1 … 32768"),
        (
            'type = "int16"\ncount',
            'type = "uint16"\ncount',
            "registers.ascan_samples.type",
            "int16",
        ),
        ("address = 1000", "address = 65000", "registers.ascan_samples.address", "pass 0xFFFF"),
        (
            "[registers.ascan_length]",
            "[registers.ascan_counter]",
            "registers.ascan_length",
            "an A-scan needs",
        ),
        (
            "address = 149, count = 1",
            "address = 140, count = 1",
            "registers.tof.address",
            "overlaps map.reserved[0]",
        ),
        (
            'type = "uint16"  # wraps',
            'type = "float32"  # wraps',
            "registers.counter.type",
            "whole number",
        ),
        (
            "[registers.status]",
            "[registers.status]\nmin_version = 9",
            "registers.status.min_version",
            "above every",
        ),
        (
            "[registers.gain]",
            "[registers.gain]\nmin_version = 2",
            "registers.gain.min_version",
            "every version",
        ),
        (
            'type = "float32"  # dB',
            'type = "float32"\nword_order = "big"  # dB',
            None,
            None,
        ),  # valid
    ],
)
def test_a_bad_map_names_the_file_and_the_key(
    tmp_path: Path, old: str, new: str, key: str | None, message: str | None
) -> None:
    path = tmp_path / "my_pulser.toml"
    path.write_text(_shifted_with(old, new))
    if key is None:
        load_register_map(path)
        return
    with pytest.raises(RegisterMapError) as info:
        load_register_map(path)
    assert info.value.path == str(path) and info.value.key == key
    assert str(info.value).startswith(f"{path}: {key}: ")
    assert message in str(info.value)


def test_an_integer_tof_needs_a_status_echo_bit(tmp_path: Path) -> None:
    text = SHIFTED_MAP_PATH.read_text()
    start = text.index("[registers.status]")
    path = tmp_path / "m.toml"
    path.write_text(text[:start] + text[text.index("[registers.counter]") :])
    with pytest.raises(RegisterMapError, match=r"registers.status: missing: an integer tof"):
        load_register_map(path)


@pytest.mark.parametrize(
    ("content", "message"),
    [(None, "cannot read"), (b"[map\n", "not valid TOML"), (b"\xff\xfe", "not UTF-8")],
)
def test_an_unreadable_map_names_the_file(
    tmp_path: Path, content: bytes | None, message: str
) -> None:
    path = tmp_path / "m.toml"
    if content is not None:
        path.write_bytes(content)
    with pytest.raises(RegisterMapError, match=message) as info:
        load_register_map(path)
    assert str(info.value).startswith(str(path))
