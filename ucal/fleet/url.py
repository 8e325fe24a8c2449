"""The broker URL ``mqtt://HOST[:PORT]/PREFIX`` and the topics a cell publishes under it.

``PREFIX`` is one or more topic levels (``plant/ucal``; default ``ucal``); a cell named ``CELL``
publishes every result to ``PREFIX/CELL/result`` and its latest state, retained, to
``PREFIX/CELL/state``. Plain TCP only (port 1883 by default): no TLS, no user name or password,
no query: what a broker on the plant's network takes from anonymous clients.
"""

from __future__ import annotations

from dataclasses import dataclass
from urllib.parse import urlsplit

#: The broker's default MQTT port (plain TCP).
DEFAULT_PORT = 1883
#: The topic prefix when the URL names none.
DEFAULT_PREFIX = "ucal"
#: The topic levels under ``PREFIX/CELL/``.
RESULT_LEVEL = "result"
STATE_LEVEL = "state"


@dataclass(frozen=True)
class BrokerUrl:
    """A broker and the topic prefix the cells publish under."""

    host: str
    port: int
    prefix: str

    def __str__(self) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"mqtt://{host}:{self.port}/{self.prefix}"

    def result_topic(self, cell: str) -> str:
        """Every result of ``cell`` (QoS 1, not retained)."""
        return f"{self.prefix}/{cell}/{RESULT_LEVEL}"

    def state_topic(self, cell: str) -> str:
        """The latest result of ``cell`` (QoS 1, retained)."""
        return f"{self.prefix}/{cell}/{STATE_LEVEL}"

    def states_filter(self) -> str:
        """The subscription that receives every cell's retained state."""
        return f"{self.prefix}/+/{STATE_LEVEL}"

    def cell_of(self, topic: str) -> str | None:
        """The cell whose state or result ``topic`` is, None for another topic."""
        head = self.prefix + "/"
        if not topic.startswith(head):
            return None
        parts = topic[len(head) :].split("/")
        if len(parts) != 2 or parts[1] not in (RESULT_LEVEL, STATE_LEVEL) or not parts[0]:
            return None
        return parts[0]


def parse_broker_url(text: str) -> BrokerUrl:
    """Parse ``mqtt://HOST[:PORT][/PREFIX]``; ``ValueError`` says what is wrong."""
    parts = urlsplit(text.strip())
    if parts.scheme != "mqtt":
        shown = f"{parts.scheme}://" if parts.scheme else "no scheme"
        raise ValueError(f"a broker URL is mqtt://HOST[:PORT]/PREFIX (plain TCP), got {shown}")
    if parts.username is not None or parts.password is not None:
        raise ValueError("a broker URL takes no user name or password (anonymous clients only)")
    if "?" in text or "#" in text:
        raise ValueError("a broker URL takes no query and no '#': mqtt://HOST[:PORT]/PREFIX")
    bad_port = f"the broker's port must be a number from 1 to 65535 in {text!r}"
    try:
        port = parts.port
    except ValueError:
        raise ValueError(bad_port) from None
    if port == 0:
        raise ValueError(bad_port)
    if not parts.hostname:
        raise ValueError(f"no broker host in {text!r}: mqtt://HOST[:PORT]/PREFIX")
    prefix = parts.path.strip("/") or DEFAULT_PREFIX
    levels = prefix.split("/")
    if any(not level for level in levels):
        raise ValueError(f"the topic prefix {prefix!r} has an empty level")
    bad = sorted({c for c in prefix if c in "+#\0"})
    if bad:
        raise ValueError(f"the topic prefix {prefix!r} holds {', '.join(map(repr, bad))}")
    if prefix.startswith("$"):
        raise ValueError(f"the topic prefix {prefix!r} starts with '$' (the broker's own topics)")
    return BrokerUrl(parts.hostname, DEFAULT_PORT if port is None else port, prefix)
