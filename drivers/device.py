"""What every device interface shares: a name, an endpoint, a clock, a connection to open and
close, and the context manager built on them.

``drivers.controller.base.RobotController``, ``drivers.pulser.base.PulserReceiver`` and
``drivers.digitizer.base.Digitizer`` derive from :class:`Device` and add what their device
does. :class:`RequestLink` is what a driver over one request/answer link (Modbus, VISA, a
serial line) keeps of it: the endpoint URL and the time one request may wait.
"""

from __future__ import annotations

import abc
import logging
import math
from collections.abc import Callable
from typing import Any, Self, TypeVar

from drivers.clock import HOST_CLOCK, Clock
from drivers.errors import ConnectionLost

log = logging.getLogger(__name__)

_Link = TypeVar("_Link")


class Device(abc.ABC):
    """A device behind a connection. Use as a context manager: enter connects, exit closes."""

    #: What the device is, in every error message ("controller", "pulser", "digitizer").
    device: str
    #: Stamps what the device sends and times the waits on it (``drivers.clock``).
    clock: Clock = HOST_CLOCK

    @property
    @abc.abstractmethod
    def endpoint(self) -> str:
        """Where the device is: its URL (the interface's docstring gives an example)."""

    @abc.abstractmethod
    def connect(self) -> None:
        """Open the connection(s); raise ``ConnectionLost`` or ``DeviceTimeout`` on failure."""

    @abc.abstractmethod
    def close(self) -> None:
        """Close the connection(s). Idempotent."""

    def __enter__(self) -> Self:
        self.connect()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class RequestLink:
    """What a driver that sends one request at a time over one link keeps of it: the endpoint
    URL (``_endpoint``), the time one request may wait (``_timeout_s``, s), and how the link
    is opened and closed."""

    device: str
    _endpoint: str
    _timeout_s: float

    def _link_to(self, endpoint: str, timeout_s: float) -> None:
        """Set the endpoint and the request timeout (s; ``ValueError`` unless positive)."""
        if not (isinstance(timeout_s, (int, float)) and math.isfinite(timeout_s) and timeout_s > 0):
            raise ValueError(f"timeout_s must be a positive number of seconds, got {timeout_s!r}")
        self._endpoint = endpoint
        self._timeout_s = float(timeout_s)

    @property
    def endpoint(self) -> str:
        """The device URL the driver was built from."""
        return self._endpoint

    @property
    def timeout_s(self) -> float:
        """Time one request may wait for its answer, s."""
        return self._timeout_s

    def _open_link(
        self,
        injected: _Link | None,
        open_link: Callable[[], _Link],
        what: str,
        errors: tuple[type[BaseException], ...] = (Exception,),
    ) -> _Link:
        """The injected link (tests) if there is one, else ``open_link()``; ``ConnectionLost``
        naming ``what`` when one of ``errors`` says it cannot be opened."""
        if injected is not None:
            return injected
        try:
            return open_link()
        except errors as exc:
            raise ConnectionLost(self.device, self._endpoint, f"cannot open {what}: {exc}") from exc

    def _close_link(self, link: Any) -> None:
        """Close ``link`` (None: nothing is open); log a failure, as closing a dead link must
        not hide why it died."""
        if link is None:
            return
        try:
            link.close()
        except Exception:
            log.debug("%s %s: close failed", self.device, self._endpoint, exc_info=True)
