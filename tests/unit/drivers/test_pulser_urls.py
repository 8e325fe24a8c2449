"""Pulser URLs: modbus-tcp://HOST:PORT[?unit=N], modbus-rtu://DEVICE[?baud=N&unit=N]."""

from __future__ import annotations

import pytest

from drivers.pulser.modbus import ModbusPulser
from drivers.pulser.urls import PulserUrl, format_rtu_url, format_tcp_url, parse_pulser_url
from drivers.urls import UrlError


@pytest.mark.parametrize(
    ("url", "expected"),
    [
        ("modbus-tcp://127.0.0.1:5020", PulserUrl("tcp", unit=1, host="127.0.0.1", port=5020)),
        (
            "modbus-tcp://127.0.0.1:5020?unit=7",
            PulserUrl("tcp", unit=7, host="127.0.0.1", port=5020),
        ),
        ("modbus-tcp://pulser.local", PulserUrl("tcp", unit=1, host="pulser.local", port=502)),
        ("modbus-tcp://[::1]:1502?unit=2", PulserUrl("tcp", unit=2, host="::1", port=1502)),
        ("modbus-rtu:///dev/ttyUSB0", PulserUrl("rtu", device="/dev/ttyUSB0")),
        (
            "modbus-rtu:///dev/ttyUSB0?baud=115200&unit=3",
            PulserUrl("rtu", unit=3, device="/dev/ttyUSB0", baud=115200),
        ),
        ("modbus-rtu://COM3?parity=n", PulserUrl("rtu", device="COM3", parity="N")),
        (
            "modbus-rtu://socket://127.0.0.1:5021?unit=1",
            PulserUrl("rtu", unit=1, device="socket://127.0.0.1:5021"),
        ),
        (
            "modbus-rtu://socket://127.0.0.1:5021",
            PulserUrl("rtu", unit=1, device="socket://127.0.0.1:5021"),
        ),
    ],
)
def test_parse(url: str, expected: PulserUrl) -> None:
    assert parse_pulser_url(url) == expected


@pytest.mark.parametrize(
    ("url", "message"),
    [
        ("tcp://127.0.0.1:11000", "scheme"),
        ("127.0.0.1:502", "not a pulser URL"),
        ("modbus-tcp://:502", "host"),
        ("modbus-tcp://127.0.0.1:70000", "port"),
        ("modbus-tcp://127.0.0.1:x", "port"),
        ("modbus-tcp://127.0.0.1:502?unit=0", "unit"),
        ("modbus-tcp://127.0.0.1:502?unit=248", "unit"),
        ("modbus-tcp://127.0.0.1:502?unit=one", "unit"),
        ("modbus-tcp://127.0.0.1:502?baud=9600", "baud"),
        ("modbus-tcp://127.0.0.1:502?unit=1&unit=2", "twice"),
        ("modbus-rtu://?unit=1", "device"),
        ("modbus-rtu:///dev/ttyUSB0?baud=fast", "baud"),
        ("modbus-rtu:///dev/ttyUSB0?parity=X", "parity"),
        ("modbus-rtu:///dev/ttyUSB0?speed=9600", "speed"),
    ],
)
def test_bad_urls_raise_naming_the_problem(url: str, message: str) -> None:
    with pytest.raises(UrlError, match=message):
        parse_pulser_url(url)


@pytest.mark.parametrize(
    "url",
    [
        "modbus-tcp://127.0.0.1:5020?unit=1",
        "modbus-rtu://socket://127.0.0.1:5021?unit=1",
        "modbus-rtu:///dev/ttyUSB0?unit=4&baud=9600&parity=N",
    ],
)
def test_format_round_trips(url: str) -> None:
    parsed = parse_pulser_url(url)
    assert parse_pulser_url(str(parsed)) == parsed


def test_format_helpers() -> None:
    assert format_tcp_url("127.0.0.1", 5020) == "modbus-tcp://127.0.0.1:5020?unit=1"
    assert (
        format_rtu_url("socket://127.0.0.1:5021", 1)
        == "modbus-rtu://socket://127.0.0.1:5021?unit=1"
    )


def test_from_url_does_no_io_and_validates() -> None:
    pulser = ModbusPulser.from_url("modbus-tcp://127.0.0.1:1?unit=5", timeout_s=0.5)
    assert pulser.endpoint == "modbus-tcp://127.0.0.1:1?unit=5"
    assert pulser.timeout_s == 0.5
    pulser.close()  # idempotent without a connection
    with pytest.raises(ValueError, match="timeout_s"):
        ModbusPulser.from_url("modbus-tcp://127.0.0.1:1", timeout_s=0)
    with pytest.raises(ValueError, match="scheme"):
        ModbusPulser.from_url("http://127.0.0.1:1")
