"""Device back-ends chosen by URL scheme, declared as entry points.

A back-end is a class (or any callable) with a ``from_url(url, **options)`` class method that
returns an unconnected device: a ``PulserReceiver`` for the group ``ucal.pulsers``, a
``RobotController`` for ``ucal.controllers``, a ``Digitizer`` (what records the RF of a pulser
that does not digitise) for ``ucal.digitizers``. A package adds one by declaring, in its
``pyproject.toml``::

    [project.entry-points."ucal.pulsers"]
    my-scheme = "my_package.my_module:MyPulser"

The entry-point name is the URL scheme (``my-scheme://...``). ucal's own back-ends are declared
the same way (``modbus-tcp``, ``modbus-rtu``, ``ascii``, ``manual``, ``tcp``, ``visa``) and are
also known without installed metadata (a source checkout), so the drivers work before ``pip
install``.
"""

from __future__ import annotations

import importlib
import logging
from collections.abc import Callable
from importlib.metadata import entry_points
from typing import Any

from drivers.controller.base import RobotController
from drivers.digitizer.base import Digitizer
from drivers.pulser.base import PulserReceiver

log = logging.getLogger(__name__)

PULSER_GROUP = "ucal.pulsers"
CONTROLLER_GROUP = "ucal.controllers"
DIGITIZER_GROUP = "ucal.digitizers"

#: Back-ends shipped with ucal: group → scheme → "module:attribute".
BUILTIN: dict[str, dict[str, str]] = {
    PULSER_GROUP: {
        "modbus-tcp": "drivers.pulser.modbus:ModbusPulser",
        "modbus-rtu": "drivers.pulser.modbus:ModbusPulser",
        "ascii": "drivers.pulser.ascii:AsciiScpiPulser",
        "manual": "drivers.pulser.manual:ManualPulser",
    },
    CONTROLLER_GROUP: {
        "tcp": "drivers.controller.client:SimpleMessageController",
    },
    DIGITIZER_GROUP: {
        "visa": "drivers.digitizer.visa:ScpiScope",
    },
}


def _scheme(url: str, kind: str) -> str:
    """The scheme of ``url`` in lower case; ``ValueError`` if there is none."""
    if not isinstance(url, str) or "://" not in url:
        raise ValueError(f"not a {kind} URL: {url!r} (expected SCHEME://...)")
    return url.split("://", 1)[0].strip().lower()


def backends(group: str) -> dict[str, str]:
    """Known schemes of ``group`` → ``"module:attribute"`` (installed entry points win)."""
    found = dict(BUILTIN.get(group, {}))
    for ep in entry_points(group=group):
        found[ep.name.lower()] = ep.value
    return found


def _load(target: str) -> Any:
    module, _, attribute = target.partition(":")
    obj: Any = importlib.import_module(module)
    for part in attribute.split("."):
        obj = getattr(obj, part)
    return obj


def _open(group: str, kind: str, url: str, options: dict[str, Any]) -> Any:
    scheme = _scheme(url, kind)
    known = backends(group)
    if scheme not in known:
        raise ValueError(
            f"unknown {kind} URL scheme {scheme!r} in {url!r} (known: "
            f"{', '.join(sorted(known))}; a back-end adds its scheme as an "
            f"entry point in the group {group!r})"
        )
    factory: Any = _load(known[scheme])
    build: Callable[..., Any] = getattr(factory, "from_url", factory)
    log.debug("%s %s: back-end %s", kind, url, known[scheme])
    return build(url, **options)


def open_pulser(url: str, **options: Any) -> PulserReceiver:
    """Build the pulser-receiver for ``url`` with the back-end of its scheme (not connected).

    ``options`` go to the back-end's ``from_url`` (e.g. ``timeout_s``; ``digitizer`` for a
    pulser that does not digitise, ``ascii://`` and ``manual://``). Raises ``ValueError`` for an
    unknown scheme (naming it and the known ones) or a malformed URL.
    """
    device = _open(PULSER_GROUP, "pulser", url, options)
    if not isinstance(device, PulserReceiver):
        raise TypeError(
            f"pulser back-end for {url!r} built a {type(device).__name__}, not a PulserReceiver"
        )
    return device


def open_controller(url: str, **options: Any) -> RobotController:
    """Build the robot controller for ``url`` with the back-end of its scheme (not connected).

    ``options`` go to the back-end's ``from_url`` (e.g. ``reply_timeout_s``). Raises
    ``ValueError`` for an unknown scheme (naming it and the known ones) or a malformed URL.
    """
    device = _open(CONTROLLER_GROUP, "controller", url, options)
    if not isinstance(device, RobotController):
        raise TypeError(
            f"controller back-end for {url!r} built a {type(device).__name__}, "
            "not a RobotController"
        )
    return device


def open_digitizer(url: str, **options: Any) -> Digitizer:
    """Build the digitiser for ``url`` with the back-end of its scheme (not connected).

    ``options`` go to the back-end's ``from_url`` (e.g. ``timeout_s``, ``full_scale_v``).
    Raises ``ValueError`` for an unknown scheme (naming it and the known ones) or a malformed
    URL.
    """
    device = _open(DIGITIZER_GROUP, "digitizer", url, options)
    if not isinstance(device, Digitizer):
        raise TypeError(
            f"digitizer back-end for {url!r} built a {type(device).__name__}, not a Digitizer"
        )
    return device
