"""Digitiser URLs: ``visa://RESOURCE``, RESOURCE a VISA resource string.

Examples: ``visa://TCPIP::192.168.0.7::5025::SOCKET`` (raw SCPI socket, the port most LAN
oscilloscopes listen on), ``visa://TCPIP0::192.168.0.7::inst0::INSTR`` (VXI-11),
``visa://USB0::0x0957::0x1796::MY12345678::INSTR`` (USBTMC). The resource string is checked by
PyVISA's own parser; which VISA library opens it is the digitiser's business
(``drivers.digitizer.visa``: pyvisa-py by default).
"""

from __future__ import annotations

from dataclasses import dataclass

from drivers.urls import UrlError

SCHEME = "visa"


@dataclass(frozen=True)
class DigitizerUrl:
    """A parsed digitiser URL: the VISA resource string, as PyVISA normalises it."""

    resource: str

    def __str__(self) -> str:
        return format_digitizer_url(self.resource)


def format_digitizer_url(resource: str) -> str:
    """Return ``visa://RESOURCE``."""
    return f"{SCHEME}://{resource}"


def socket_resource(host: str, port: int) -> str:
    """The raw-socket resource string of ``host:port``: ``TCPIP::HOST::PORT::SOCKET``."""
    return f"TCPIP::{host}::{int(port)}::SOCKET"


def parse_digitizer_url(url: str) -> DigitizerUrl:
    """Parse ``visa://RESOURCE``; ``UrlError`` (a ``ValueError``) names the problem and the URL."""
    if not isinstance(url, str) or "://" not in url:
        raise UrlError(f"not a digitiser URL: {url!r} (expected {SCHEME}://RESOURCE)")
    scheme, resource = url.split("://", 1)
    if scheme.strip().lower() != SCHEME:
        raise UrlError(f"unknown digitiser URL scheme {scheme!r} in {url!r} (expected {SCHEME})")
    resource = resource.strip()
    if not resource:
        raise UrlError(f"missing VISA resource in {url!r}")
    from pyvisa import rname  # PyVISA loads in a tenth of a second: only when a URL is parsed

    try:
        rname.parse_resource_name(resource)
    except rname.InvalidResourceName as e:
        raise UrlError(f"{url!r}: not a VISA resource string: {e}") from None
    return DigitizerUrl(resource)
