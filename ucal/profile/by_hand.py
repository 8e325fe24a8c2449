"""``[pulser]`` of a pulser-receiver set by hand: ``kind = "manual"`` and its front panel.

A cell whose pulser-receiver has no remote interface (an Olympus 5077PR set on its front panel,
a digitiser beside it) declares what the panel holds::

    [pulser]
    kind = "manual"          # set by hand: run with --pulser manual:// --digitizer visa://...
    gain_db = 30.0           # the receiver's gain (required)
    prf_hz = 500.0           # pulse repetition frequency (default 1000)
    pulse_voltage_v = 200.0  # pulse energy: the pulser's voltage (default 100)
    damping_ohm = 50.0       # (default 50)
    high_pass_mhz = 1.0      # receiver filters (default 1 and 50)
    low_pass_mhz = 50.0
    input_noise_uv = 2.2     # the receiver's noise referred to its input, µV rms (default 2.2)

The pulse frequency is the transducer's, ``[transducer] frequency_mhz``. Echoes are then timed
from the A-scans (``timing = "ascan"``, the only timing such a cell has). These keys without
``kind = "manual"`` are refused: a pulser ucal sets takes its settings from the procedures.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

from drivers.pulser.base import PulserSettings
from ucal.cell import DEFAULT_INPUT_NOISE_UV, CellProfile, SetByHand
from ucal.profile.validation import Reader

if TYPE_CHECKING:  # the echo code (scipy.signal) loads only where a panel is checked
    from ucal.echo.by_hand import Declared

#: ``[pulser] kind``: a pulser ucal talks to (``"remote"``, the default) or one set by hand.
KINDS = ("remote", "manual")
#: The front panel's keys and their ranges (unit, low, high).
PANEL_KEYS: dict[str, tuple[str, float, float]] = {
    "gain_db": ("dB", -20.0, 100.0),
    "prf_hz": ("Hz", 1.0, 20_000.0),
    "pulse_voltage_v": ("V", 1.0, 1000.0),
    "damping_ohm": ("Ω", 1.0, 10_000.0),
    "high_pass_mhz": ("MHz", 0.0, 100.0),
    "low_pass_mhz": ("MHz", 0.1, 500.0),
}
#: Every key of a pulser set by hand.
KEYS = frozenset({"kind", "input_noise_uv", *PANEL_KEYS})


def read_by_hand(r: Reader, table: Mapping[str, Any] | None) -> SetByHand | None:
    """The front panel of a pulser set by hand (module docstring), None for a pulser ucal
    sets; ``ProfileError`` names the key of a bad value, of ``gain_db`` missing, or of a
    front-panel key without ``kind = "manual"``."""
    kind_raw = r.get(table, "pulser.kind")
    kind = "remote" if kind_raw is None else r.string("pulser.kind", kind_raw)
    if kind not in KINDS:
        raise r.error("pulser.kind", f"must be one of {', '.join(map(repr, KINDS))}, got {kind!r}")
    given = [key for key in KEYS - {"kind"} if r.get(table, f"pulser.{key}") is not None]
    if kind != "manual":
        if given:
            key = sorted(given)[0]
            raise r.error(
                f"pulser.{key}",
                'is a front panel\'s setting: add kind = "manual" for a pulser set by hand, or '
                "leave it out (ucal sets a remote pulser itself)",
            )
        return None
    if r.get(table, "pulser.gain_db") is None:
        raise r.error("pulser.gain_db", "missing: a pulser set by hand declares its gain (dB)")
    values: dict[str, Any] = {}
    for key, (unit, lo, hi) in PANEL_KEYS.items():
        raw = r.get(table, f"pulser.{key}")
        if raw is not None:
            values[key] = r.number(f"pulser.{key}", raw, lo=lo, hi=hi, unit=unit)
    try:
        panel = PulserSettings(**values)
    except ValueError as e:  # the filter band
        raise r.error("pulser.low_pass_mhz", str(e)) from None
    noise = r.get(table, "pulser.input_noise_uv")
    return SetByHand(
        panel,
        DEFAULT_INPUT_NOISE_UV
        if noise is None
        else r.number("pulser.input_noise_uv", noise, lo=0.0, lo_open=True, hi=1e4, unit="µV"),
    )


def by_hand_to_dict(by_hand: SetByHand | None) -> dict[str, Any]:
    """The keys of ``read_by_hand`` as ``profile show`` gives them (none for a remote pulser)."""
    if by_hand is None:
        return {}
    panel = by_hand.panel
    return {
        "kind": "manual",
        **{key: float(getattr(panel, key)) for key in PANEL_KEYS},
        "input_noise_uv": by_hand.input_noise_uv,
    }


def declared_of(profile: CellProfile, full_screen_v: float = 1.0) -> Declared:
    """What ``profile`` (whose pulser is set by hand) declares, for a digitiser whose full
    screen is ``full_screen_v``."""
    from ucal.echo.by_hand import Declared

    by_hand = profile.pulser.by_hand
    if by_hand is None:
        raise ValueError(f"{profile.path}: the pulser is not set by hand")
    return Declared(
        by_hand.panel.gain_db,
        profile.frequency_mhz,
        by_hand.input_noise_uv,
        full_screen_v,
        str(profile.path or "the profile"),
    )
