"""A device fault's one-line message: what to change for a timeout, a device's bytes escaped."""

from __future__ import annotations

from drivers.errors import DeviceTimeout, ProtocolError
from ucal.cli import MAX_MESSAGE_CHARS, _classify
from ucal.errors import EXIT_HARDWARE


def test_a_pulser_timeout_names_the_key_and_where_it_goes() -> None:
    message, code = _classify(
        DeviceTimeout("pulser", "modbus-tcp://127.0.0.1:5020?unit=1", "no answer within 1 s")
    )
    assert code == EXIT_HARDWARE
    assert message.startswith("pulser at modbus-tcp://127.0.0.1:5020?unit=1: no answer within")
    assert "set timeout_s (s, default 1, the link's margin beyond the averaging) in the" in message
    assert "profile's [pulser] table" in message
    assert "add the table if the profile has none" in message


def test_a_controller_timeout_names_its_table() -> None:
    message, _ = _classify(DeviceTimeout("controller", "tcp://127.0.0.1:11000", "no state"))
    assert "the [controller] table's *_timeout_s keys" in message


def test_garbage_from_a_device_is_escaped_and_cut() -> None:
    garbage = "".join(chr(c) for c in range(256)) * 8
    message, code = _classify(ProtocolError("pulser", "ascii:///dev/ttyUSB0", garbage))
    assert code == EXIT_HARDWARE
    assert message.isprintable() and "\n" not in message
    assert len(message) <= MAX_MESSAGE_CHARS and message.endswith(" ...")
    assert "\\x00\\x01" in message
