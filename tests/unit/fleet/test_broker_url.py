"""The broker URL ``mqtt://HOST[:PORT]/PREFIX`` and the topics under it."""

from __future__ import annotations

import pytest

from ucal.fleet.url import DEFAULT_PORT, BrokerUrl, parse_broker_url


@pytest.mark.parametrize(
    ("text", "host", "port", "prefix"),
    [
        ("mqtt://broker.plant:1884/plant/ucal", "broker.plant", 1884, "plant/ucal"),
        ("mqtt://10.0.0.5/cells", "10.0.0.5", DEFAULT_PORT, "cells"),
        ("mqtt://127.0.0.1:1883", "127.0.0.1", 1883, "ucal"),
        ("mqtt://127.0.0.1:1883/", "127.0.0.1", 1883, "ucal"),
        ("mqtt://[::1]:1883/a/b/", "::1", 1883, "a/b"),
    ],
)
def test_a_broker_url_gives_host_port_and_prefix(
    text: str, host: str, port: int, prefix: str
) -> None:
    assert parse_broker_url(text) == BrokerUrl(host, port, prefix)


@pytest.mark.parametrize(
    ("text", "says"),
    [
        ("mqtts://broker:8883/ucal", "mqtt://"),
        ("tcp://broker:1883/ucal", "mqtt://"),
        ("broker:1883", "mqtt://"),
        ("mqtt://user:pw@broker/ucal", "user name"),
        ("mqtt://broker/ucal?qos=2", "query"),
        ("mqtt://broker:99999/ucal", "port"),
        ("mqtt://broker:0/ucal", "port"),
        ("mqtt://broker:x/ucal", "port"),
        ("mqtt:///ucal", "host"),
        ("mqtt://broker/plant//ucal", "empty level"),
        ("mqtt://broker/plant/+", "'+'"),
        ("mqtt://broker/#", "'#'"),
        ("mqtt://broker/$SYS", "'$'"),
    ],
)
def test_a_url_ucal_cannot_use_is_refused_saying_why(text: str, says: str) -> None:
    with pytest.raises(ValueError) as e:
        parse_broker_url(text)
    assert says in str(e.value)


def test_a_cells_topics_are_under_the_prefix() -> None:
    url = parse_broker_url("mqtt://127.0.0.1:1883/plant/ucal")
    assert url.result_topic("line-3") == "plant/ucal/line-3/result"
    assert url.state_topic("line-3") == "plant/ucal/line-3/state"
    assert url.states_filter() == "plant/ucal/+/state"
    assert url.cell_of("plant/ucal/line-3/state") == "line-3"
    assert url.cell_of("plant/ucal/line-3/result") == "line-3"
    assert url.cell_of("plant/ucal/_fleet/abc/def") is None
    assert url.cell_of("other/line-3/state") is None
    assert str(url) == "mqtt://127.0.0.1:1883/plant/ucal"
