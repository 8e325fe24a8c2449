"""Parse and format controller URLs: ``tcp://HOST:PORT[?state=PORT]``.

``PORT`` is the motion (trajectory relay) port, ``state`` the state relay port of the
ROS-Industrial Simple Message server; the VAL3 server listens on 11000 and 11002.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from urllib.parse import parse_qs, urlsplit

log = logging.getLogger(__name__)

DEFAULT_MOTION_PORT = 11000
DEFAULT_STATE_PORT = 11002


class UrlError(ValueError):
    """A URL that does not follow its documented form; the message quotes the URL."""


@dataclass(frozen=True)
class ControllerAddress:
    """Where a Simple Message controller listens: host, motion port, state port."""

    host: str
    motion_port: int = DEFAULT_MOTION_PORT
    state_port: int = DEFAULT_STATE_PORT

    @property
    def url(self) -> str:
        """The canonical URL, always with the state port spelled out."""
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"tcp://{host}:{self.motion_port}?state={self.state_port}"


def _port(text: str, what: str, url: str) -> int:
    try:
        port = int(text)
    except ValueError:
        raise UrlError(f"{url!r}: {what} {text!r} is not a number") from None
    if not 1 <= port <= 65535:
        raise UrlError(f"{url!r}: {what} {port} outside 1..65535")
    return port


def parse_controller_url(url: str) -> ControllerAddress:
    """Parse ``tcp://HOST[:PORT][?state=PORT]``; missing ports take the VAL3 defaults.

    Raises ``UrlError`` (a ``ValueError``) for another scheme, a missing host, a path,
    unknown query keys or ports that are not integers in 1..65535.
    """
    try:
        parts = urlsplit(url.strip())
    except ValueError as e:
        raise UrlError(f"{url!r}: {e}") from None
    netloc = parts.netloc
    if netloc.startswith("["):  # IPv6 literal: [addr]:port
        host, _, rest = netloc[1:].partition("]")
        port_text = rest.removeprefix(":")
    else:
        host, _, port_text = netloc.partition(":")
    if parts.scheme != "tcp":
        raise UrlError(f"{url!r}: controller URLs have the form tcp://HOST:PORT[?state=PORT]")
    if not host:
        raise UrlError(f"{url!r}: no host")
    if parts.path not in ("", "/") or parts.fragment or "@" in netloc:
        raise UrlError(f"{url!r}: unexpected path, fragment or credentials")
    motion = DEFAULT_MOTION_PORT if not port_text else _port(port_text, "port", url)
    try:
        query = parse_qs(parts.query, keep_blank_values=True, strict_parsing=bool(parts.query))
    except ValueError:
        raise UrlError(f"{url!r}: malformed query {parts.query!r}") from None
    unknown = set(query) - {"state"}
    if unknown:
        raise UrlError(
            f"{url!r}: unknown parameter(s) {', '.join(sorted(unknown))}; "
            "only 'state' is understood"
        )
    state = DEFAULT_STATE_PORT
    if "state" in query:
        if len(query["state"]) != 1:
            raise UrlError(f"{url!r}: 'state' given more than once")
        state = _port(query["state"][0], "state port", url)
    if state == motion:
        raise UrlError(f"{url!r}: motion and state ports must differ")
    return ControllerAddress(host, motion, state)
