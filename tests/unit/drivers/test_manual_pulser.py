"""The pulser set by hand (``drivers.pulser.manual``, ``manual://``): its digitiser records, its
front panel is the declaration, and the gain a procedure asks beyond it is applied to the
record on the host, rails and step alike."""

from __future__ import annotations

import numpy as np
import pytest

from drivers.digitizer.base import AScanRecord, Digitizer, EchoTiming
from drivers.pulser.base import PulserSettings
from drivers.pulser.manual import ManualPulser, parse_manual_url
from drivers.registry import open_pulser
from drivers.urls import UrlError

PANEL = PulserSettings(gain_db=30.0, prf_hz=500.0, pulse_voltage_v=200.0, damping_ohm=25.0)


class RecordingScope(Digitizer):
    """A digitiser that records a 0.1 V echo sample among zeros, on ±1 V rails of 12 bits,
    and remembers what it was told."""

    endpoint = "visa://TCPIP::scope::5025::SOCKET"

    def __init__(self) -> None:
        self.windows: list[tuple[float, float, int]] = []
        self.connected = False
        self.waits: list[tuple[float | None, float]] = []

    def connect(self) -> None:
        self.connected = True

    def close(self) -> None:
        self.connected = False

    def check(self, start_ns: float, width_ns: float, averages: int) -> None:
        if averages > 4096:
            raise ValueError(f"averages {averages}: the scope averages 2 … 4096")

    def configure(self, start_ns: float, width_ns: float, averages: int) -> None:
        self.windows.append((start_ns, width_ns, averages))

    def acquire(self, timeout_s: float | None = None, acquisition_s: float = 0.0) -> AScanRecord:
        self.waits.append((timeout_s, acquisition_s))
        samples = np.zeros(64)
        samples[32] = 0.1
        return AScanRecord(5000.0, 5.0, samples, (-1.0, 1.0), 2.0 / 4096, False, 1, 1, 0.0)

    def identity(self) -> dict[str, object]:
        return {"model": "DSOX3024T"}


def test_the_url_has_no_address() -> None:
    assert parse_manual_url("MANUAL://") == "manual://"
    for bad in ("manual://cell", "manual://?gain=30", "ascii://x"):
        with pytest.raises(UrlError):
            parse_manual_url(bad)


def test_the_registry_knows_it_and_it_needs_its_digitiser() -> None:
    with pytest.raises(ValueError, match=r"does not digitise: give its digitiser, --digitizer"):
        open_pulser("manual://")
    pulser = open_pulser("manual://", digitizer=RecordingScope(), declared=PANEL)
    assert isinstance(pulser, ManualPulser) and pulser.endpoint == "manual://"


def test_the_panel_holds_and_the_gain_beyond_it_is_the_hosts() -> None:
    scope = RecordingScope()
    pulser = ManualPulser(scope, PANEL, echo_timer=lambda r, g: EchoTiming(0, 0, 0, "x"))
    asked = PulserSettings(gain_db=42.0, gate_start_us=5.0, gate_width_us=400.0, averages=16)
    applied = pulser.configure(asked)
    assert applied is not None
    assert scope.windows == [(5000.0, 400_000.0, 16)]
    assert pulser.host_gain_db == pytest.approx(12.0)
    # every other knob is the front panel's
    held = pulser.settings()
    assert (held.gain_db, held.prf_hz, held.pulse_voltage_v, held.damping_ohm) == (
        42.0,
        500.0,
        200.0,
        25.0,
    )
    assert applied["prf_hz"] == {"asked": 1000.0, "set": 500.0}
    assert applied["gain_db"] == {"asked": 42.0, "set": 42.0}
    # the record, its rails and its step are scaled by 12 dB: clipping stays the scope's
    record = pulser.read_ascan_record()
    factor = 10 ** (12.0 / 20)
    assert record.samples[32] == pytest.approx(0.1 * factor)
    assert record.rails == pytest.approx((-factor, factor))
    assert record.lsb == pytest.approx(factor * 2.0 / 4096)
    # the wait is 16 pulses at the panel's 500 Hz, not the 1 kHz asked
    assert scope.waits[-1][1] == pytest.approx(16 / 500.0)


def test_a_gate_beyond_the_panels_period_and_what_the_scope_refuses_are_refused() -> None:
    scope = RecordingScope()
    pulser = ManualPulser(scope, PANEL)
    with pytest.raises(ValueError, match="front panel's 500 Hz"):
        pulser.check_settings(PulserSettings(gate_start_us=5.0, gate_width_us=1999.0))
    with pytest.raises(ValueError, match="averages 8192"):
        pulser.configure(PulserSettings(averages=8192))
    assert scope.windows == []


def test_without_a_declaration_it_identifies_itself_and_sets_nothing() -> None:
    pulser = ManualPulser(RecordingScope())
    identity = pulser.identity()
    assert identity["set_by_hand"] is True and identity["declared"] is None
    assert identity["digitizer"] == {
        "endpoint": "visa://TCPIP::scope::5025::SOCKET",
        "model": "DSOX3024T",
    }
    with pytest.raises(ValueError, match=r'kind = "manual" and gain_db'):
        pulser.configure(PulserSettings())
