"""Readings of many averages against the simulated cell served on the host clock, as ``ucal sim
serve`` serves it: its instruments take the time a real one takes (averages at the PRF, scaled
by the time scale), and each back-end's deadline follows what it asked of them, the link's
``timeout_s`` on top. Outcomes and lower bounds of durations are asserted (a sleep never ends
early), not how fast the machine is."""

from __future__ import annotations

import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest

from drivers.digitizer.base import AScanRecord, EchoTiming
from drivers.errors import DeviceTimeout
from drivers.pulser.ascii import AsciiScpiPulser
from drivers.pulser.base import PulserSettings
from drivers.pulser.modbus import ModbusPulser
from ucal.cell import CellProfile
from ucal.cli import _classify
from ucal.profile import default_profile_text, load_profile
from ucal.sim.serve import SimulatedCellServer

pytestmark = pytest.mark.system

#: (world ``[pulser] kind``, Modbus framing) of each back-end.
BACK_ENDS = [("modbus", "tcp"), ("modbus", "rtu"), ("ascii-scpi", "tcp")]


def peak_timer(record: AScanRecord, gate: tuple[float, float]) -> EchoTiming:
    """The largest sample: the ASCII back-end needs a timer, what it finds does not matter."""
    k = int(np.argmax(np.abs(record.samples)))
    return EchoTiming(float(abs(record.samples[k])), record.t0_ns + k * record.dt_ns, 0.0, "peak")


@pytest.fixture(scope="module")
def profile(tmp_path_factory: pytest.TempPathFactory) -> CellProfile:
    path: Path = tmp_path_factory.mktemp("reading_time") / "cell.toml"
    path.write_text(default_profile_text("tx90"), encoding="utf-8")
    return load_profile(path)


@contextmanager
def served_pulser(
    profile: CellProfile, kind: str, framing: str, time_scale: float, timeout_s: float
) -> Iterator[ModbusPulser | AsciiScpiPulser]:
    """The back-end of ``kind`` connected to the demo cell served with ``time_scale``."""
    with SimulatedCellServer(
        None, profile, time_scale=time_scale, pulser_framing=framing, pulser_kind=kind
    ) as cell:
        urls = cell.urls
        pulser: ModbusPulser | AsciiScpiPulser
        if kind == "modbus":
            pulser = ModbusPulser.from_url(urls["pulser"], timeout_s=timeout_s)
        else:
            pulser = AsciiScpiPulser.from_url(
                urls["pulser"], timeout_s, digitizer=urls["digitizer"], echo_timer=peak_timer
            )
        with pulser:
            yield pulser


@pytest.mark.parametrize(("kind", "framing"), BACK_ENDS)
def test_a_thousand_averages_at_1_khz_outlast_the_link_timeout_and_succeed(
    profile: CellProfile, kind: str, framing: str
) -> None:
    """1,000 averages at 1 kHz: 1 s of averaging, 0.2 s at time scale 0.2; the link's
    ``timeout_s`` of 0.1 s alone, once the whole wait, would have cut every reading."""
    settings = PulserSettings(prf_hz=1000.0, averages=1000)
    with served_pulser(profile, kind, framing, time_scale=0.2, timeout_s=0.1) as pulser:
        pulser.configure(settings)
        wait = pulser.reading_wait()
        assert wait.acquisition_s == pytest.approx(1.0)
        assert wait.total_s == pytest.approx(1.1 + wait.transfer_s)
        for _ in range(2):
            start = time.monotonic()
            pulser.read_gate(fresh=True)
            assert time.monotonic() - start >= 0.2  # the simulated instrument averaged


@pytest.mark.parametrize(("kind", "framing"), BACK_ENDS)
def test_an_instrument_slower_than_its_averaging_is_a_timeout_naming_it_and_the_key(
    profile: CellProfile, kind: str, framing: str
) -> None:
    """100 averages at 1 kHz take 0.5 s at time scale 5: past the 0.1 s of averaging and the
    link's 0.05 s, a timeout that says so; the CLI adds the profile key."""
    with served_pulser(profile, kind, framing, time_scale=5.0, timeout_s=0.05) as pulser:
        pulser.configure(PulserSettings(prf_hz=1000.0, averages=100))
        with pytest.raises(DeviceTimeout) as info:
            pulser.read_gate(fresh=True)
    message = str(info.value)
    if kind == "modbus":
        assert info.value.device == "pulser"
        assert "read gate: no answer within " in message
        assert "(0.1 s averaging 100 pulses at 1000 Hz" in message
    else:
        assert info.value.device == "digitizer"
        assert "acquire: no record within 0.15 s (0.1 s of it for the acquisition of 100" in message
        assert "no trigger on EXT rising through 1.4 V (sweep NORM)?" in message
    assert "then timeout_s = 0.05 s for the link)" in message
    shown, code = _classify(info.value)
    assert code == 3
    assert "set timeout_s (s, default 1, the link's margin" in shown
    assert "in the profile's [pulser] table" in shown
