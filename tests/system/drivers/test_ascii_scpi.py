"""The ASCII pulser and the SCPI scope clients against their simulators on 127.0.0.1: the
pulser through pyserial's ``socket://``, the scope through PyVISA (pyvisa-py, raw socket)."""

from __future__ import annotations

import socket
import threading
from collections.abc import Iterator

import numpy as np
import pytest

from drivers.digitizer.base import AScanRecord, EchoTiming
from drivers.digitizer.scpi_simulator import AcquisitionRequest, SimulatedScope
from drivers.errors import DeviceTimeout
from drivers.pulser import ascii_commands as cmd
from drivers.pulser.ascii import AsciiScpiPulser
from drivers.pulser.ascii_simulator import SimulatedAsciiPulser
from drivers.pulser.base import PulserSettings

pytestmark = pytest.mark.system


class Signal:
    """A settable tone burst at ``arrival_ns`` of ``amplitude_v``; keeps every request."""

    def __init__(self, amplitude_v: float = 0.5, arrival_ns: float = 40_000.0):
        self.amplitude_v = amplitude_v
        self.arrival_ns = arrival_ns
        self.requests: list[AcquisitionRequest] = []
        self._lock = threading.Lock()

    def __call__(self, request: AcquisitionRequest) -> np.ndarray:
        with self._lock:
            self.requests.append(request)
        t = request.t_ns - self.arrival_ns
        return self.amplitude_v * np.exp(-((t / 40.0) ** 2)) * np.cos(2 * np.pi * 0.025 * t)


def peak_timer(record: AScanRecord, gate: tuple[float, float]) -> EchoTiming:
    """The largest sample: enough to see that the record is the one asked for."""
    k = int(np.argmax(np.abs(record.samples)))
    return EchoTiming(
        float(abs(record.samples[k])), record.t0_ns + k * record.dt_ns, 0.0, "peak", record.clipped
    )


@pytest.fixture
def signal() -> Signal:
    return Signal()


@pytest.fixture
def sims(signal: Signal) -> Iterator[tuple[SimulatedAsciiPulser, SimulatedScope]]:
    with SimulatedAsciiPulser() as pulser, SimulatedScope(signal, sample_rate_hz=200e6) as scope:
        yield pulser, scope


@pytest.fixture
def client(sims: tuple[SimulatedAsciiPulser, SimulatedScope]) -> Iterator[AsciiScpiPulser]:
    pulser, scope = sims
    device = AsciiScpiPulser.from_url(
        pulser.url, 0.5, digitizer=scope.url, echo_timer=peak_timer, pulse_width_ns=20.0
    )
    with device:
        yield device


def test_configure_sets_the_pulser_and_the_scopes_window(client, sims, signal) -> None:
    pulser, _ = sims
    settings = PulserSettings(gain_db=41.27, gate_start_us=20.0, gate_width_us=50.0, averages=4)
    client.configure(settings)
    assert pulser.code(cmd.Letter.GAIN) == 413 and pulser.pulse_width_ns == 20.0
    assert client.settings_applied["gain_db"] == {"asked": 41.27, "set": pytest.approx(41.3)}
    assert client.settings().gain_db == pytest.approx(41.3)
    reading = client.read_gate()
    request = signal.requests[-1]
    assert (request.t0_ns, request.averages) == (20_000.0, 4)
    assert request.n == 10_001 and request.dt_ns == pytest.approx(5.0)  # 50 µs at 200 MS/s
    assert reading.tof_ns == pytest.approx(40_000.0, abs=2.5)
    assert reading.amplitude == pytest.approx(0.5, abs=0.01)  # 1 V of RF = full screen
    assert client.read_gate().counter == reading.counter + 1  # every reading acquires


def test_an_echo_beyond_the_scopes_range_is_clipped(client, signal) -> None:
    client.configure(PulserSettings(gate_start_us=20.0, gate_width_us=50.0))
    signal.amplitude_v = 2.0
    record = client.read_ascan_record()
    assert record.clipped and np.max(record.samples) == pytest.approx(record.rails[1])
    assert record.lsb == pytest.approx(2.0 / 4096)  # 12 bits over 8 divisions of 0.25 V


def test_the_pulser_ignores_what_it_cannot_take(sims) -> None:
    pulser, _ = sims
    with socket.create_connection(("127.0.0.1", pulser.port), timeout=1.0) as s:
        s.sendall(b"G900\rX5\rG350\rG?\r")
        assert s.recv(64) == b"G=350\r"
    assert pulser.ignored == 2


def test_the_scope_speaks_long_and_short_forms_and_queues_its_errors(sims) -> None:
    _, scope = sims
    assert scope.execute(":WAVeform:FORMat WORD;:ACQuire:TYPE AVERage;COUNt 16") is None
    assert scope.execute(":WAV:FORM?;:ACQ:COUN?") == b"WORD;16\n"
    scope.execute(":BOGUS 1;:ACQ:COUN 1;:WAV:FORM FLOAT")
    errors = [scope.execute(":SYST:ERR?") for _ in range(4)]
    assert errors == [
        b'-113,"Undefined header"\n',
        b'-222,"Data out of range"\n',
        b'-224,"Illegal parameter value"\n',
        b'+0,"No error"\n',
    ]


@pytest.mark.parametrize("silent", ["pulser", "scope"])
def test_a_silent_instrument_is_a_timeout_naming_it(sims, silent: str) -> None:
    pulser, scope = sims
    device = AsciiScpiPulser.from_url(pulser.url, 0.2, digitizer=scope.url, echo_timer=peak_timer)
    with device:
        (pulser if silent == "pulser" else scope).set_silent()
        name = "pulser at ascii://" if silent == "pulser" else "digitizer at visa://"
        with pytest.raises(DeviceTimeout, match=name):
            if silent == "pulser":
                device.settings()
            else:
                device.digitizer.acquire(timeout_s=0.2)
