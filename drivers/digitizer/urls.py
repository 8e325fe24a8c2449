"""Digitiser URLs: ``visa://RESOURCE[?trigger=SOURCE&level=V]``, RESOURCE a VISA resource string.

Examples: ``visa://TCPIP::192.168.0.7::5025::SOCKET`` (raw SCPI socket, the port most LAN
oscilloscopes listen on), ``visa://TCPIP0::192.168.0.7::inst0::INSTR`` (VXI-11),
``visa://USB0::0x0957::0x1796::MY12345678::INSTR`` (USBTMC). The resource string is checked by
PyVISA's own parser; which VISA library opens it is the digitiser's business
(``drivers.digitizer.visa``: pyvisa-py by default).

The query says how the scope's trigger meets the pulser's sync output, the cell's wiring:
``trigger`` the scope input it is wired to (``EXT``, ``CHAN2`` … ``CHAN4``; long forms
``EXTernal``, ``CHANnel2`` taken; default: the family's, EXT on a Keysight, CHAN2 on a Rigol
DS1000Z, which has no EXT input) and ``level`` the edge trigger's level in volts (default
:data:`DEFAULT_TRIGGER_LEVEL_V`). Whether the scope's family takes that input is known once it
has said who it is (``drivers.digitizer.visa``).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from urllib.parse import parse_qsl

from drivers.urls import UrlError

SCHEME = "visa"
#: The edge trigger's level (V) unless the URL says one: the threshold of a TTL sync pulse.
DEFAULT_TRIGGER_LEVEL_V = 1.4
#: Largest trigger level the URL may ask for (V): beyond any scope input's range.
MAX_TRIGGER_LEVEL_V = 100.0

_KEYS = frozenset({"trigger", "level"})
_SOURCE = re.compile(r"^(EXT(ERNAL)?|CHAN(NEL)?([1-4]))$", re.I)


@dataclass(frozen=True)
class DigitizerUrl:
    """A parsed digitiser URL: the VISA resource string, the trigger input the pulser's sync
    output is wired to (short form, ``EXT`` or ``CHANn``; None: the family's) and the trigger
    level (V)."""

    resource: str
    trigger_source: str | None = None
    trigger_level_v: float = DEFAULT_TRIGGER_LEVEL_V

    def __str__(self) -> str:
        return format_digitizer_url(self.resource, self.trigger_source, self.trigger_level_v)


def format_digitizer_url(
    resource: str, trigger: str | None = None, level_v: float = DEFAULT_TRIGGER_LEVEL_V
) -> str:
    """Return ``visa://RESOURCE``, with ``?trigger=…&level=…`` where they are not the
    defaults."""
    query = []
    if trigger is not None:
        query.append(f"trigger={trigger}")
    if level_v != DEFAULT_TRIGGER_LEVEL_V:
        query.append(f"level={level_v:g}")
    return f"{SCHEME}://{resource}" + (f"?{'&'.join(query)}" if query else "")


def socket_resource(host: str, port: int) -> str:
    """The raw-socket resource string of ``host:port``: ``TCPIP::HOST::PORT::SOCKET``."""
    return f"TCPIP::{host}::{int(port)}::SOCKET"


def trigger_source(text: str) -> str:
    """The short form of a trigger input (``EXTernal`` → ``EXT``, ``CHANnel2`` → ``CHAN2``);
    ``ValueError`` for another."""
    m = _SOURCE.match(text.strip())
    if not m:
        raise ValueError(f"trigger input {text!r} is not EXT or CHAN1 … CHAN4")
    return "EXT" if m.group(4) is None else f"CHAN{m.group(4)}"


def parse_digitizer_url(url: str) -> DigitizerUrl:
    """Parse ``visa://RESOURCE[?trigger=SOURCE&level=V]``; ``UrlError`` (a ``ValueError``)
    names the problem and the URL."""
    if not isinstance(url, str) or "://" not in url:
        raise UrlError(f"not a digitiser URL: {url!r} (expected {SCHEME}://RESOURCE)")
    scheme, rest = url.split("://", 1)
    if scheme.strip().lower() != SCHEME:
        raise UrlError(f"unknown digitiser URL scheme {scheme!r} in {url!r} (expected {SCHEME})")
    resource, _, query = rest.partition("?")
    resource = resource.strip()
    if not resource:
        raise UrlError(f"missing VISA resource in {url!r}")
    from pyvisa import rname  # PyVISA loads in a tenth of a second: only when a URL is parsed

    try:
        rname.parse_resource_name(resource)
    except rname.InvalidResourceName as e:
        raise UrlError(f"{url!r}: not a VISA resource string: {e}") from None
    options: dict[str, str] = {}
    for key, value in parse_qsl(query, keep_blank_values=True):
        if key not in _KEYS:
            raise UrlError(f"{url!r}: unknown option {key!r} (known: {', '.join(sorted(_KEYS))})")
        if key in options:
            raise UrlError(f"{url!r}: option {key!r} given twice")
        options[key] = value
    source = None
    if "trigger" in options:
        try:
            source = trigger_source(options["trigger"])
        except ValueError as e:
            raise UrlError(f"{url!r}: {e}") from None
    level = DEFAULT_TRIGGER_LEVEL_V
    if "level" in options:
        try:
            level = float(options["level"])
        except ValueError:
            level = math.nan
        if not (math.isfinite(level) and abs(level) <= MAX_TRIGGER_LEVEL_V):
            raise UrlError(
                f"{url!r}: level {options['level']!r} is not a trigger level in volts "
                f"(|level| <= {MAX_TRIGGER_LEVEL_V:g})"
            )
    return DigitizerUrl(resource, source, level)
