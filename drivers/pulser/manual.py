"""A pulser-receiver set by hand: no remote interface, a digitiser beside it (``manual://``).

The commonest immersion cell: a pulser-receiver such as an Olympus 5077PR set on its front
panel (gain, pulse frequency, PRF, voltage, damping, filters), its RF output recorded by an
oscilloscope over SCPI/VISA triggered by its sync output, and the time of flight and amplitude
computed on the host from the record (``drivers.pulser.digitised``). ucal cannot set it: its
settings are what the cell's profile declares (``declared``), and ucal checks them against
what the records show before the first motion (``ucal.echo.by_hand``).

``configure`` sets what the digitiser does (the gate is its record window, ``averages`` its
average count) and, of the receiver, only the gain a procedure asks beyond the front panel's:
``host_gain_db`` = asked − declared, applied to the record on the host (samples, rails and
step alike: an echo the digitiser clipped stays clipped, and a gain on the host adds no
resolution). Every other knob is the front panel's: ``settings`` reports the declared values
(the PRF sets the acquisition's wait), with the gain in effect, and ``settings_applied`` what
was asked and what holds.
"""

from __future__ import annotations

import logging
import math
from dataclasses import asdict, replace
from typing import Any

from drivers.digitizer.base import Digitizer, EchoTimer
from drivers.pulser.base import PulserSettings
from drivers.pulser.digitised import DEFAULT_TIMEOUT_S, DigitisedPulser
from drivers.urls import UrlError

log = logging.getLogger(__name__)

SCHEME = "manual"
#: The one URL of a pulser set by hand: nothing to address.
URL = f"{SCHEME}://"
#: The knobs of the front panel, which ucal does not set (the gain aside).
PANEL = ("prf_hz", "pulse_voltage_v", "damping_ohm", "high_pass_mhz", "low_pass_mhz")


def parse_manual_url(url: str) -> str:
    """``manual://`` (the scheme in any case); ``UrlError`` for anything after it."""
    if not isinstance(url, str) or "://" not in url:
        raise UrlError(f"not a pulser URL: {url!r} (expected {URL})")
    scheme, rest = url.strip().split("://", 1)
    if scheme.lower() != SCHEME:
        raise UrlError(f"not a pulser set by hand: {url!r} (expected {URL})")
    if rest:
        raise UrlError(
            f"{url!r}: a pulser set by hand has no address ({URL}): its settings are the "
            "profile's [pulser]"
        )
    return URL


class ManualPulser(DigitisedPulser):
    """A pulser-receiver set by hand and its digitiser (module docstring).

    ``declared``: the front panel's settings as the profile declares them (None: not declared,
    enough for ``identity``; ``configure`` then refuses). ``digitizer``, ``full_screen_v``,
    ``echo_timer``, ``digitizer_options``: as ``DigitisedPulser``. No I/O before
    :meth:`connect`.
    """

    def __init__(
        self,
        digitizer: str | Digitizer,
        declared: PulserSettings | None = None,
        timeout_s: float = DEFAULT_TIMEOUT_S,
        *,
        full_screen_v: float = 1.0,
        echo_timer: EchoTimer | None = None,
        digitizer_options: dict[str, Any] | None = None,
    ):
        self._attach(digitizer, timeout_s, full_screen_v, echo_timer, digitizer_options)
        self.declared = declared
        #: The gain applied to the record on the host, dB (asked − declared).
        self.host_gain_db = 0.0
        #: What the last ``configure`` asked and what holds, by setting.
        self.settings_applied: dict[str, dict[str, float]] = {}

    @classmethod
    def from_url(
        cls, url: str, digitizer: str | Digitizer | None = None, retries: int = 0, **options: Any
    ) -> ManualPulser:
        """Build the back-end from ``manual://`` and its digitiser (``visa://RESOURCE``).
        ``ValueError`` for another URL or a missing digitiser (it is the one that records the
        echo). Does not connect. ``options``: ``declared``, ``timeout_s`` and those of
        ``ManualPulser``; ``retries`` is taken and not used: nothing is asked of the pulser,
        and the digitiser's requests are its own to bound."""
        parse_manual_url(url)
        if digitizer is None:
            raise ValueError(
                f"{URL}: a pulser set by hand does not digitise: give its digitiser, "
                "--digitizer visa://RESOURCE (or UCAL_DIGITIZER)"
            )
        return cls(digitizer, **options)

    # --- PulserReceiver ---------------------------------------------------------------------
    @property
    def endpoint(self) -> str:
        """``manual://``."""
        return URL

    def connect(self) -> None:
        """Open the digitiser; ``ConnectionLost``/``DeviceTimeout`` if it does not answer."""
        self.digitizer.connect()

    def close(self) -> None:
        """Close the digitiser. Idempotent."""
        self.digitizer.close()

    def _panel(self) -> PulserSettings:
        if self.declared is None:
            raise ValueError(
                f"{URL}: the settings of a pulser set by hand are not declared: "
                '[pulser] kind = "manual" and gain_db in the profile'
            )
        return self.declared

    def _in_effect(self, settings: PulserSettings) -> PulserSettings:
        """``settings`` as the cell holds them: the front panel's knobs, the gain asked."""
        panel = self._panel()
        return replace(settings, **{name: getattr(panel, name) for name in PANEL})

    def check_settings(self, settings: PulserSettings) -> None:
        """Validate the gate and the averages against the PRF and the digitiser, sending
        nothing; ``ValueError`` names the setting."""
        held = self._in_effect(settings)
        start_ns, end_ns = held.gate_ns
        if end_ns * 1e-9 * held.prf_hz > 1.0:
            raise ValueError(
                f"gate {held.gate_start_us:g} + {held.gate_width_us:g} µs ends after the pulse "
                f"repetition period ({1e6 / held.prf_hz:g} µs at the front panel's "
                f"{held.prf_hz:g} Hz)"
            )
        if not math.isfinite(held.gain_db):
            raise ValueError(f"gain_db must be finite, got {held.gain_db!r}")
        self.digitizer.check(start_ns, end_ns - start_ns, int(held.averages))

    def configure(self, settings: PulserSettings) -> dict[str, dict[str, float]] | None:
        """Set the digitiser's window and averages and the host's gain (module docstring);
        ``ValueError`` naming the setting, before anything is sent, for one the cell cannot
        take. Returns what was asked and what holds (kept in ``settings_applied``)."""
        self.check_settings(settings)
        held = self._in_effect(settings)
        start_ns, end_ns = held.gate_ns
        self.connect()
        self.digitizer.configure(start_ns, end_ns - start_ns, int(held.averages))
        self.host_gain_db = float(settings.gain_db) - self._panel().gain_db
        asked, holds = asdict(settings), asdict(held)
        self.settings_applied = {
            name: {"asked": float(asked[name]), "set": float(holds[name])} for name in asked
        }
        self._settings = held
        log.debug(
            "pulser %s: front panel %s, %+.1f dB on the host", URL, self.declared, self.host_gain_db
        )
        return self.settings_applied

    def settings(self) -> PulserSettings:
        """The settings in effect: the front panel's as declared, with the gain, window and
        averages last configured (the declared gain before any)."""
        return self._settings or self._panel()

    def record_scale(self) -> float:
        """The host's gain, as a factor."""
        return float(10.0 ** (self.host_gain_db / 20.0))

    def identity(self) -> dict[str, object]:
        """That the pulser is set by hand, its declared settings, the digitiser's identity and
        how echoes are timed."""
        self.connect()
        return {
            "set_by_hand": True,
            "declared": None if self.declared is None else asdict(self.declared),
            "digitizer": {"endpoint": self.digitizer.endpoint, **self.digitizer.identity()},
            "timing": self.timing_label(),
            "host_gain_db": self.host_gain_db,
        }
