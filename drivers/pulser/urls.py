"""Pulser URLs: ``modbus-tcp://HOST:PORT[?unit=N]``, ``modbus-rtu://DEVICE[?baud=N&unit=N]`` and
``ascii://DEVICE[?baud=N]``.

``DEVICE`` is a serial device path (``/dev/ttyUSB0``, written ``modbus-rtu:///dev/ttyUSB0``;
``COM3``) or a pyserial URL such as ``socket://127.0.0.1:5021`` (RTU framing over a TCP
stream, e.g. a serial-to-Ethernet converter). The pulser's options are the query after the
*last* ``?``; pyserial URL options therefore cannot be combined with them.

Defaults: TCP port 502; unit 1; serial line 19200 baud, 8 data bits, even parity, 1 stop bit
(the Modbus serial-line default; ``parity=N|E|O`` overrides it). An ``ascii`` pulser (the
CompactPulser's ASCII command set, ``drivers.pulser.ascii``) speaks 9600 baud 8N1 unless
``baud`` says otherwise.
"""

from __future__ import annotations

from dataclasses import dataclass
from urllib.parse import parse_qsl

from drivers.urls import UrlError

TCP_SCHEME = "modbus-tcp"
RTU_SCHEME = "modbus-rtu"
ASCII_SCHEME = "ascii"
DEFAULT_ASCII_BAUD = 9600
DEFAULT_TCP_PORT = 502
DEFAULT_UNIT = 1
DEFAULT_BAUD = 19200
DEFAULT_PARITY = "E"

_TCP_KEYS = frozenset({"unit"})
_RTU_KEYS = frozenset({"unit", "baud", "parity"})


@dataclass(frozen=True)
class PulserUrl:
    """A parsed pulser URL.

    ``framing`` is ``"tcp"`` (Modbus TCP, MBAP header) or ``"rtu"`` (Modbus RTU, CRC-16).
    For TCP ``host``/``port`` are set; for RTU ``device`` (serial path or pyserial URL),
    ``baud`` (bit/s) and ``parity``. ``unit`` is the Modbus unit (device) id, 1 … 247.
    """

    framing: str
    unit: int = DEFAULT_UNIT
    host: str | None = None
    port: int | None = None
    device: str | None = None
    baud: int = DEFAULT_BAUD
    parity: str = DEFAULT_PARITY

    def __str__(self) -> str:
        if self.framing == "tcp":
            return format_tcp_url(self.host or "", self.port or DEFAULT_TCP_PORT, self.unit)
        return format_rtu_url(self.device or "", self.unit, self.baud, self.parity)


def format_tcp_url(host: str, port: int, unit: int = DEFAULT_UNIT) -> str:
    """Return ``modbus-tcp://HOST:PORT?unit=N``."""
    return f"{TCP_SCHEME}://{host}:{int(port)}?unit={int(unit)}"


def format_rtu_url(
    device: str, unit: int = DEFAULT_UNIT, baud: int | None = None, parity: str | None = None
) -> str:
    """Return ``modbus-rtu://DEVICE?unit=N`` (``baud``/``parity`` added when not default)."""
    query = [f"unit={int(unit)}"]
    if baud is not None and int(baud) != DEFAULT_BAUD:
        query.append(f"baud={int(baud)}")
    if parity is not None and parity != DEFAULT_PARITY:
        query.append(f"parity={parity}")
    return f"{RTU_SCHEME}://{device}?{'&'.join(query)}"


def parse_pulser_url(url: str) -> PulserUrl:
    """Parse a pulser URL; raise ``UrlError`` (a ``ValueError``) naming the problem and the URL."""
    scheme, target, query = _split(
        url, "a pulser URL", {TCP_SCHEME: "HOST:PORT", RTU_SCHEME: "DEVICE"}
    )
    options = _parse_query(query, _TCP_KEYS if scheme == TCP_SCHEME else _RTU_KEYS, url)
    unit = _int_option(options, "unit", DEFAULT_UNIT, 1, 247, url)
    if scheme == TCP_SCHEME:
        host, port = _split_host_port(target, url)
        return PulserUrl("tcp", unit=unit, host=host, port=port)
    if not target:
        raise UrlError(f"missing serial device in {url!r}")
    baud = _int_option(options, "baud", DEFAULT_BAUD, 50, 4_000_000, url)
    parity = options.get("parity", DEFAULT_PARITY).upper()
    if parity not in ("N", "E", "O"):
        raise UrlError(f"parity must be N, E or O in {url!r}, got {options['parity']!r}")
    return PulserUrl("rtu", unit=unit, device=target, baud=baud, parity=parity)


@dataclass(frozen=True)
class AsciiUrl:
    """A parsed ``ascii://DEVICE[?baud=N]``: the serial device (path or pyserial URL) and its
    baud rate."""

    device: str
    baud: int = DEFAULT_ASCII_BAUD

    def __str__(self) -> str:
        return format_ascii_url(self.device, self.baud)


def format_ascii_url(device: str, baud: int | None = None) -> str:
    """Return ``ascii://DEVICE`` (``?baud=N`` when not the default 9600)."""
    query = "" if baud is None or int(baud) == DEFAULT_ASCII_BAUD else f"?baud={int(baud)}"
    return f"{ASCII_SCHEME}://{device}{query}"


def parse_ascii_url(url: str) -> AsciiUrl:
    """Parse ``ascii://DEVICE[?baud=N]``; ``UrlError`` names the problem and the URL."""
    _, target, query = _split(url, "an ascii pulser URL", {ASCII_SCHEME: "DEVICE"})
    options = _parse_query(query, frozenset({"baud"}), url)
    if not target:
        raise UrlError(f"missing serial device in {url!r}")
    baud = _int_option(options, "baud", DEFAULT_ASCII_BAUD, 50, 4_000_000, url)
    return AsciiUrl(target, baud)


def _split(url: str, what: str, forms: dict[str, str]) -> tuple[str, str, str]:
    """The scheme (lower case), target and query of ``url``, whose scheme must be one of
    ``forms`` (scheme → what follows it, for the message); ``what`` names the URL expected."""
    expected = " or ".join(f"{scheme}://{target}" for scheme, target in forms.items())
    if not isinstance(url, str) or "://" not in url:
        raise UrlError(f"not {what}: {url!r} (expected {expected})")
    scheme, rest = url.split("://", 1)
    scheme = scheme.lower()
    if scheme not in forms:
        raise UrlError(
            f"unknown pulser URL scheme {scheme!r} in {url!r} (expected {' or '.join(forms)})"
        )
    target, _, query = rest.rpartition("?") if "?" in rest else (rest, "", "")
    return scheme, target, query


def _parse_query(query: str, allowed: frozenset[str], url: str) -> dict[str, str]:
    if not query:
        return {}
    try:
        pairs = parse_qsl(query, keep_blank_values=True, strict_parsing=True)
    except ValueError as exc:
        raise UrlError(f"bad query {query!r} in {url!r}") from exc
    options: dict[str, str] = {}
    for key, value in pairs:
        if key not in allowed:
            raise UrlError(
                f"unknown option {key!r} in {url!r} (allowed: {', '.join(sorted(allowed))})"
            )
        if key in options:
            raise UrlError(f"option {key!r} given twice in {url!r}")
        options[key] = value
    return options


def _int_option(options: dict[str, str], key: str, default: int, lo: int, hi: int, url: str) -> int:
    if key not in options:
        return default
    text = options[key]
    try:
        value = int(text, 10)
    except ValueError:
        raise UrlError(f"{key} must be an integer in {url!r}, got {text!r}") from None
    if not lo <= value <= hi:
        raise UrlError(f"{key} = {value} is out of range [{lo}, {hi}] in {url!r}")
    return value


def _split_host_port(target: str, url: str) -> tuple[str, int]:
    target = target.rstrip("/")
    if not target:
        raise UrlError(f"missing host in {url!r}")
    if target.startswith("["):  # [IPv6]:port
        host, sep, tail = target[1:].partition("]")
        if not sep:
            raise UrlError(f"unterminated IPv6 address in {url!r}")
        port_text = tail[1:] if tail.startswith(":") else ""
        if tail and not tail.startswith(":"):
            raise UrlError(f"bad host:port {target!r} in {url!r}")
    else:
        host, _, port_text = target.partition(":")
    if not host or "/" in host:
        raise UrlError(f"bad host {host!r} in {url!r}")
    if not port_text:
        return host, DEFAULT_TCP_PORT
    try:
        port = int(port_text, 10)
    except ValueError:
        raise UrlError(f"port must be an integer in {url!r}, got {port_text!r}") from None
    if not 1 <= port <= 65535:
        raise UrlError(f"port {port} is out of range [1, 65535] in {url!r}")
    return host, port
