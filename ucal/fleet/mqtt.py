"""The broker link: paho-mqtt 2.x (callback API version 2), MQTT 3.1.1 over plain TCP.

``MqttLink`` publishes for one run: a clean session, one message at a time at QoS 1, each
waited for until the broker's PUBACK (so that a message is removed from the queue only once
the broker holds it, and the broker receives a cell's messages in their order); a connection
lost is not re-made (the queue keeps what was not acknowledged for the next run).
``read_states`` subscribes to every cell's retained state and returns what the broker holds.
"""

from __future__ import annotations

import json
import logging
import threading
import uuid
from collections.abc import Callable
from types import TracebackType
from typing import Any, Protocol

from ucal.fleet.url import BrokerUrl

log = logging.getLogger(__name__)

#: How long a broker may take to accept the connection (s): TCP and CONNACK each.
CONNECT_TIMEOUT_S = 5.0
#: How long a broker may take to acknowledge one message (s).
ACK_TIMEOUT_S = 10.0
#: Keep-alive of the connection (s): a run's publishing lasts far less.
KEEPALIVE_S = 30


class BrokerError(Exception):
    """The broker cannot be reached, refused the connection, or did not acknowledge."""


class Link(Protocol):
    """What delivering the queue needs of a broker connection."""

    def send(self, topic: str, payload: bytes, retain: bool) -> None:
        """Publish at QoS 1 and return once acknowledged; ``BrokerError`` otherwise."""
        ...


class _Waiter:
    """What the network thread's callbacks tell the caller, under one condition."""

    def __init__(self) -> None:
        self.cond = threading.Condition()
        self.connack: Any = None
        self.lost: str | None = None
        self.acked: set[int] = set()

    def wait(self, done: Callable[[], bool], timeout_s: float) -> bool:
        with self.cond:
            return self.cond.wait_for(lambda: done() or self.lost is not None, timeout_s)


def _client(waiter: _Waiter, reconnect: bool) -> Any:
    """A paho client whose callbacks report to ``waiter``."""
    import paho.mqtt.client as mqtt  # loaded when something is published or read
    from paho.mqtt.enums import CallbackAPIVersion

    client = mqtt.Client(
        CallbackAPIVersion.VERSION2,
        client_id="",
        clean_session=True,
        protocol=mqtt.MQTTv311,
        reconnect_on_failure=reconnect,
    )
    client.connect_timeout = CONNECT_TIMEOUT_S

    def on_connect(client: Any, userdata: Any, flags: Any, reason: Any, props: Any) -> None:
        with waiter.cond:
            waiter.connack = reason
            waiter.cond.notify_all()

    def on_disconnect(client: Any, userdata: Any, flags: Any, reason: Any, props: Any) -> None:
        with waiter.cond:
            waiter.lost = f"the broker closed the connection ({reason})"
            waiter.cond.notify_all()

    def on_publish(client: Any, userdata: Any, mid: int, reason: Any, props: Any) -> None:
        with waiter.cond:
            waiter.acked.add(mid)
            waiter.cond.notify_all()

    client.on_connect = on_connect
    client.on_disconnect = on_disconnect
    client.on_publish = on_publish
    return client


def _connect(client: Any, waiter: _Waiter, url: BrokerUrl) -> None:
    """Connect and wait for the broker's CONNACK; ``BrokerError`` names what failed."""
    try:
        client.connect(url.host, url.port, keepalive=KEEPALIVE_S)
    except (OSError, ValueError) as e:
        raise BrokerError(f"cannot connect to {url.host}:{url.port}: {_why(e)}") from None
    client.loop_start()
    if not waiter.wait(lambda: waiter.connack is not None, CONNECT_TIMEOUT_S):
        raise BrokerError(
            f"{url.host}:{url.port} did not accept the connection within {CONNECT_TIMEOUT_S:g} s"
        )
    if waiter.connack is None or waiter.connack.is_failure:
        raise BrokerError(
            f"{url.host}:{url.port} refused the connection: {waiter.connack or waiter.lost}"
        )


def _why(e: BaseException) -> str:
    return str(getattr(e, "strerror", None) or e or type(e).__name__)


class MqttLink:
    """One run's connection to the broker at ``url`` (a context manager)."""

    def __init__(self, url: BrokerUrl) -> None:
        self.url = url
        self._waiter = _Waiter()
        self._client: Any = None

    def __enter__(self) -> MqttLink:
        self._client = _client(self._waiter, reconnect=False)
        try:
            _connect(self._client, self._waiter, self.url)
        except BaseException:
            self._close()
            raise
        return self

    def __exit__(
        self,
        kind: type[BaseException] | None,
        error: BaseException | None,
        trace: TracebackType | None,
    ) -> None:
        self._close()

    def send(self, topic: str, payload: bytes, retain: bool) -> None:
        """Publish ``payload`` on ``topic`` at QoS 1 and wait for the broker's PUBACK."""
        waiter = self._waiter
        if waiter.lost is not None:
            raise BrokerError(waiter.lost)
        info = self._client.publish(topic, payload, qos=1, retain=retain)
        if not waiter.wait(lambda: info.mid in waiter.acked, ACK_TIMEOUT_S):
            raise BrokerError(f"no acknowledgement of {topic} within {ACK_TIMEOUT_S:g} s")
        with waiter.cond:
            if info.mid not in waiter.acked:
                raise BrokerError(f"{waiter.lost} before it acknowledged {topic}")
            waiter.acked.discard(info.mid)

    def _close(self) -> None:
        client, self._client = self._client, None
        if client is None:
            return
        try:
            client.disconnect()
        finally:
            client.loop_stop()


def read_states(url: BrokerUrl, timeout_s: float = CONNECT_TIMEOUT_S) -> list[dict[str, Any]]:
    """Every cell's retained state the broker at ``url`` holds, as decoded JSON objects.

    The retained messages come right after the subscription; then a probe message this reader
    publishes to a topic of its own comes back, after them: the broker sends a client its
    messages in order (mosquitto does). A payload that is no JSON object is skipped with a
    warning. ``BrokerError`` if the broker cannot be reached or does not answer in time.
    """
    import paho.mqtt.client as mqtt

    waiter = _Waiter()
    client = _client(waiter, reconnect=False)
    probe = f"{url.prefix}/_fleet/{uuid.uuid4().hex}"
    states: dict[str, dict[str, Any]] = {}
    done = threading.Event()

    def on_subscribe(client: Any, userdata: Any, mid: int, reasons: Any, props: Any) -> None:
        client.publish(probe, b"", qos=1)

    def on_message(client: Any, userdata: Any, message: mqtt.MQTTMessage) -> None:
        if message.topic == probe:
            done.set()
            with waiter.cond:
                waiter.cond.notify_all()
            return
        cell = url.cell_of(message.topic)
        if cell is None or not message.payload:
            return  # a state cleared (an empty retained message) or another topic
        try:
            data = json.loads(message.payload)
        except ValueError:
            data = None
        if not isinstance(data, dict):
            log.warning("%s holds no JSON object: skipped", message.topic)
            return
        states[cell] = data

    client.on_subscribe = on_subscribe
    client.on_message = on_message
    try:
        _connect(client, waiter, url)
        client.subscribe([(url.states_filter(), 1), (probe, 1)])
        if not waiter.wait(done.is_set, timeout_s):
            raise BrokerError(f"{url.host}:{url.port} sent no states within {timeout_s:g} s")
        if not done.is_set():
            raise BrokerError(waiter.lost or "the broker did not answer")
    finally:
        try:
            client.disconnect()
        finally:
            client.loop_stop()
    return [states[c] for c in sorted(states)]
