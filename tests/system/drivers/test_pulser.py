"""The Modbus pulser client against the simulated pulser on 127.0.0.1, over Modbus TCP and over
Modbus RTU framing on a TCP socket (pyserial ``socket://``)."""

from __future__ import annotations

import math
import re
import socket
import threading
import time
from collections.abc import Callable, Iterator

import numpy as np
import pytest
from pymodbus.client import ModbusTcpClient
from scipy.signal import hilbert

from drivers.errors import ConnectionLost, DeviceError, DeviceTimeout, ProtocolError
from drivers.pulser import registers as reg
from drivers.pulser.base import PulserSettings
from drivers.pulser.modbus import ModbusPulser
from drivers.pulser.simulator import SimulatedPulser, gaussian_pulse

pytestmark = pytest.mark.system

TIMEOUT_S = 0.3


class EchoModel:
    """A settable echo ``(amplitude, tof_ns)`` that records the settings of every call."""

    def __init__(self, amplitude: float = 0.5, tof_ns: float = 40_000.0):
        self.amplitude = amplitude
        self.tof_ns = tof_ns
        self.calls: list[PulserSettings] = []
        self._lock = threading.Lock()

    def __call__(self, settings: PulserSettings) -> tuple[float, float]:
        with self._lock:
            self.calls.append(settings)
            return self.amplitude, self.tof_ns


@pytest.fixture(params=["tcp", "rtu"])
def framing(request: pytest.FixtureRequest) -> str:
    return request.param


@pytest.fixture
def model() -> EchoModel:
    return EchoModel()


@pytest.fixture
def sim(model: EchoModel, framing: str) -> Iterator[SimulatedPulser]:
    with SimulatedPulser(model, framing=framing) as simulator:
        yield simulator


@pytest.fixture
def make_pulser() -> Iterator[Callable[..., ModbusPulser]]:
    pulsers: list[ModbusPulser] = []

    def make(url: str, timeout_s: float = TIMEOUT_S, connect: bool = True) -> ModbusPulser:
        pulser = ModbusPulser.from_url(url, timeout_s=timeout_s)
        pulsers.append(pulser)
        if connect:
            pulser.connect()
        return pulser

    yield make
    for pulser in pulsers:
        pulser.close()


@pytest.fixture
def pulser(sim: SimulatedPulser, make_pulser: Callable[..., ModbusPulser]) -> ModbusPulser:
    return make_pulser(sim.url)


def f32(value: float) -> float:
    return float(np.float32(value))


# --- URLs and settings --------------------------------------------------------------------------
def test_url_names_framing_and_loopback_port(sim: SimulatedPulser, framing: str) -> None:
    prefix = {"tcp": "modbus-tcp://127.0.0.1:", "rtu": "modbus-rtu://socket://127.0.0.1:"}
    assert sim.url == f"{prefix[framing]}{sim.port}?unit=1"
    assert sim.port > 0


def test_settings_round_trip(pulser: ModbusPulser, sim: SimulatedPulser) -> None:
    assert pulser.settings() == PulserSettings()  # power-on defaults
    wanted = PulserSettings(
        gain_db=32.5, prf_hz=2000.0, gate_start_us=12.345, gate_width_us=150.0, averages=16
    )
    pulser.configure(wanted)
    assert pulser.settings() == wanted
    assert sim.settings == wanted
    pulser.set_gate_threshold(0.125)
    assert pulser.gate_threshold() == 0.125
    assert sim.gate_threshold == 0.125


def test_invalid_settings_raise_and_write_nothing(
    pulser: ModbusPulser, sim: SimulatedPulser
) -> None:
    with pytest.raises(ValueError, match="prf_hz"):
        pulser.configure(PulserSettings(prf_hz=50_000.0))
    with pytest.raises(ValueError, match="gate_width_us"):  # gate longer than the PRF period
        pulser.configure(PulserSettings(prf_hz=10_000.0, gate_start_us=5.0, gate_width_us=200.0))
    with pytest.raises(ValueError, match="gate_threshold"):
        pulser.set_gate_threshold(1.5)
    assert sim.settings == PulserSettings()
    assert sim.gate_threshold == reg.DEFAULT_THRESHOLD


def test_model_sees_the_configured_settings(pulser: ModbusPulser, model: EchoModel) -> None:
    wanted = PulserSettings(
        gain_db=40.0, prf_hz=500.0, gate_start_us=10.0, gate_width_us=100.0, averages=8
    )
    pulser.configure(wanted)
    pulser.read_gate()
    assert model.calls[-1] == wanted


def test_each_write_reaches_the_next_acquisition(pulser: ModbusPulser, model: EchoModel) -> None:
    # the simulator decodes the holding registers once per write, not once per acquisition
    assert pulser.read_gate().has_echo
    assert model.calls[-1] == PulserSettings()
    wanted = PulserSettings(gain_db=40.0, gate_start_us=10.0, gate_width_us=100.0, averages=8)
    pulser.configure(wanted)
    pulser.set_gate_threshold(0.6)  # above the model's echo of 0.5
    weak = pulser.read_gate()
    assert model.calls[-1] == wanted
    assert not weak.has_echo and weak.amplitude == 0.5
    pulser.set_gate_threshold(0.4)
    assert pulser.read_gate().has_echo
    assert model.calls[-1] == wanted


# --- readings -----------------------------------------------------------------------------------
def test_reading_counter_advances_once_per_fresh_reading(
    pulser: ModbusPulser, sim: SimulatedPulser, model: EchoModel
) -> None:
    first = pulser.read_gate()
    readings = [pulser.read_gate(fresh=True) for _ in range(5)]
    counters = [first.counter] + [r.counter for r in readings]
    assert counters == list(range(first.counter, first.counter + 6))
    assert sim.counter == counters[-1]
    assert len(model.calls) == sim.acquisitions == counters[-1]  # one model call per reading
    host_times = [first.host_time_s] + [r.host_time_s for r in readings]
    device_times = [first.device_time_s] + [r.device_time_s for r in readings]
    assert host_times == sorted(host_times) and host_times[0] < host_times[-1]
    assert device_times == sorted(device_times)


def test_known_echo_reads_back_exactly_at_float32_precision(
    pulser: ModbusPulser, model: EchoModel
) -> None:
    model.amplitude, model.tof_ns = 0.734, 133_457.123
    reading = pulser.read_gate()
    assert reading.has_echo
    assert reading.amplitude == f32(0.734)
    assert reading.tof_ns == f32(133_457.123)
    assert abs(reading.tof_ns - 133_457.123) < 0.01


def test_echo_outside_the_gate_is_no_echo(pulser: ModbusPulser, model: EchoModel) -> None:
    pulser.configure(PulserSettings(gate_start_us=50.0, gate_width_us=20.0))
    model.tof_ns = 45_000.0  # before the gate
    before = pulser.read_gate()
    model.tof_ns = 70_001.0  # 1 ns after the gate end
    after = pulser.read_gate()
    model.tof_ns = 70_000.0  # on the gate end
    inside = pulser.read_gate()
    for reading in (before, after):
        assert not reading.has_echo and math.isnan(reading.tof_ns)
        assert reading.amplitude == 0.0
    assert inside.has_echo and inside.tof_ns == 70_000.0


def test_echo_below_threshold_is_no_echo_but_keeps_amplitude(
    pulser: ModbusPulser, model: EchoModel
) -> None:
    pulser.set_gate_threshold(0.2)
    model.amplitude = 0.15
    weak = pulser.read_gate()
    assert not weak.has_echo and weak.amplitude == f32(0.15)
    model.amplitude = 0.25
    assert pulser.read_gate().has_echo


def test_model_without_echo_gives_no_echo(pulser: ModbusPulser, model: EchoModel) -> None:
    model.amplitude, model.tof_ns = 0.004, float("nan")
    reading = pulser.read_gate()
    assert not reading.has_echo
    assert reading.amplitude == f32(0.004)


def test_saturated_echo_reads_full_screen(pulser: ModbusPulser, model: EchoModel) -> None:
    model.amplitude = 1.7
    reading = pulser.read_gate()
    assert reading.amplitude == 1.0 and reading.has_echo
    assert reg.Status.SATURATED in pulser.last_status


def test_clear_counter_and_trigger(pulser: ModbusPulser, sim: SimulatedPulser) -> None:
    pulser.read_gate()
    pulser.read_gate()
    pulser.clear_counter()
    assert sim.counter == 0
    pulser.trigger()
    assert sim.counter == 1
    assert pulser.read_gate().counter == 2


# --- A-scan ------------------------------------------------------------------------------------
def test_ascan_peaks_at_the_time_of_flight(pulser: ModbusPulser, model: EchoModel) -> None:
    pulser.configure(PulserSettings(gate_start_us=30.0, gate_width_us=20.0))
    model.amplitude, model.tof_ns = 0.6, 40_123.0
    pulser.read_gate()
    scan = pulser.read_ascan_trace()
    assert scan.sample_rate_hz == 100e6
    assert scan.start_ns == 30_000.0
    assert scan.samples.shape == (2001,)
    envelope = np.abs(hilbert(scan.samples))
    peak = int(np.argmax(envelope))
    assert abs(scan.time_ns[peak] - 40_123.0) <= 10.0  # one sample
    assert envelope[peak] == pytest.approx(0.6, rel=0.05)
    samples, rate = pulser.read_ascan()
    assert rate == 100e6 and samples.shape == (2001,)


def test_gaussian_pulse_bandwidth_is_sixty_percent() -> None:
    fs, fc = 10e9, 25e6  # finely sampled to measure the spectrum
    t_ns = np.arange(-2000.0, 2000.0, 1e9 / fs)
    spectrum = np.abs(np.fft.rfft(gaussian_pulse(t_ns, 0.0, 1.0, fc), n=1 << 20))
    freqs = np.fft.rfftfreq(1 << 20, 1 / fs)
    band = freqs[spectrum >= spectrum.max() / 2]  # −6 dB
    assert (band.max() - band.min()) / fc == pytest.approx(0.6, rel=0.01)
    assert freqs[np.argmax(spectrum)] == pytest.approx(fc, rel=0.01)


# --- faults -------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("code", "name"), [(2, "illegal data address (0x02)"), (4, "server device failure (0x04)")]
)
def test_exception_response_is_device_error(
    pulser: ModbusPulser, sim: SimulatedPulser, code: int, name: str
) -> None:
    sim.set_exception(code)
    with pytest.raises(DeviceError) as info:
        pulser.read_gate()
    assert name in str(info.value)
    assert str(info.value).startswith(f"pulser at {sim.url}: ")
    with pytest.raises(DeviceError, match=re.escape(name)):
        pulser.configure(PulserSettings())
    sim.set_exception(None)
    assert pulser.read_gate().has_echo


def test_silent_pulser_times_out_within_the_timeout(
    pulser: ModbusPulser, sim: SimulatedPulser, make_pulser: Callable[..., ModbusPulser]
) -> None:
    sim.set_silent(True)
    start = time.monotonic()
    with pytest.raises(DeviceTimeout) as info:
        pulser.read_gate(timeout_s=5.0)  # the request timeout (0.3 s) is the shorter bound
    elapsed = time.monotonic() - start
    assert TIMEOUT_S * 0.9 <= elapsed < 5.0  # not the 5 s read timeout
    assert sim.url in str(info.value)
    sim.set_silent(False)
    patient = make_pulser(sim.url, timeout_s=5.0)
    sim.set_silent(True)
    start = time.monotonic()
    with pytest.raises(DeviceTimeout):
        patient.read_gate(timeout_s=0.1)  # a shorter read timeout shortens the request
    assert 0.09 <= time.monotonic() - start < 5.0  # not the pulser's 5 s
    sim.set_silent(False)
    assert pulser.read_gate().has_echo


def test_pulser_that_never_answers_fails_connect(
    sim: SimulatedPulser, make_pulser: Callable[..., ModbusPulser]
) -> None:
    sim.set_silent(True)
    start = time.monotonic()
    with pytest.raises(DeviceTimeout):
        make_pulser(sim.url)
    assert time.monotonic() - start < TIMEOUT_S + 0.5


def test_unknown_unit(
    sim: SimulatedPulser, framing: str, make_pulser: Callable[..., ModbusPulser]
) -> None:
    url = sim.url.replace("unit=1", "unit=2")
    if framing == "tcp":  # a Modbus TCP device answers for a missing unit like a gateway
        with pytest.raises(DeviceError, match="gateway target failed to respond"):
            make_pulser(url)
    else:  # an RTU device ignores frames addressed to another unit
        with pytest.raises(DeviceTimeout):
            make_pulser(url)


def test_nothing_listening_is_connection_lost(
    framing: str, make_pulser: Callable[..., ModbusPulser]
) -> None:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    url = (
        f"modbus-tcp://127.0.0.1:{port}"
        if framing == "tcp"
        else f"modbus-rtu://socket://127.0.0.1:{port}"
    )
    with pytest.raises(ConnectionLost, match=f"pulser at modbus-.*127.0.0.1:{port}"):
        make_pulser(url)


class _Babbler:
    """A peer on 127.0.0.1 that streams bytes that are not Modbus, as fast as it can, to
    every client (a misconfigured port: another instrument, a console, line noise)."""

    def __init__(self) -> None:
        self.server = socket.socket()
        self.server.bind(("127.0.0.1", 0))
        self.server.listen()
        self.port = self.server.getsockname()[1]
        self.stop = threading.Event()
        threading.Thread(target=self._serve, daemon=True).start()

    def _serve(self) -> None:
        rng = np.random.default_rng(7)
        try:
            conn, _ = self.server.accept()
        except OSError:
            return
        with conn:
            while not self.stop.is_set():
                try:
                    conn.sendall(rng.integers(0, 256, 64, dtype=np.uint8).tobytes())
                except OSError:
                    return
                time.sleep(0.005)

    def close(self) -> None:
        self.stop.set()
        self.server.close()


def test_a_peer_streaming_garbage_is_a_protocol_fault_within_the_timeout(
    framing: str, make_pulser: Callable[..., ModbusPulser]
) -> None:
    # pymodbus waits for a valid frame as long as bytes keep coming: the request's deadline
    # must bound that wait too, or the identify step hangs for as long as the peer talks.
    babbler = _Babbler()
    url = (
        f"modbus-tcp://127.0.0.1:{babbler.port}"
        if framing == "tcp"
        else f"modbus-rtu://socket://127.0.0.1:{babbler.port}"
    )
    start = time.monotonic()
    try:
        with pytest.raises(ProtocolError, match=r"pulser at .*no valid Modbus frame"):
            make_pulser(url, timeout_s=0.5)
    finally:
        babbler.close()
    # bounded, not endless: a generous bound (the deadline is 0.5 s a request; a loaded host
    # parsing the stream of garbage takes seconds more), well inside the suite's 120 s timeout
    assert time.monotonic() - start < 60.0


def test_stopped_server_is_connection_lost_then_reconnects(
    model: EchoModel, framing: str, make_pulser: Callable[..., ModbusPulser]
) -> None:
    sim = SimulatedPulser(model, framing=framing).start()
    port, url = sim.port, sim.url
    pulser = make_pulser(url)
    pulser.read_gate()
    start = time.monotonic()
    sim.stop()
    assert time.monotonic() - start < 1.0  # stop is fast, even with a client connected
    with pytest.raises(ConnectionLost, match=re.escape(f"pulser at {url}")):
        pulser.read_gate()
    with SimulatedPulser(model, framing=framing, port=port):
        assert pulser.read_gate().has_echo  # the next call reconnects


def test_device_rejects_raw_out_of_range_writes_and_flags_gate_errors(
    model: EchoModel, make_pulser: Callable[..., ModbusPulser]
) -> None:
    with SimulatedPulser(model, framing="tcp") as sim:
        raw = ModbusTcpClient("127.0.0.1", port=sim.port, timeout=TIMEOUT_S, retries=0)
        try:
            assert raw.connect()
            refused = raw.write_registers(0x0000, [801], device_id=1)  # gain 80.1 dB
            assert refused.isError() and refused.exception_code == 3  # illegal data value
            refused = raw.read_input_registers(0x0010, count=12, device_id=1)  # counter …
            assert refused.isError() and refused.exception_code == 2  # spans past the block
            # each register is valid, but the 205 µs gate outlasts the 50 µs pulse period
            assert not raw.write_registers(0x0001, [20_000], device_id=1).isError()  # PRF
        finally:
            raw.close()
        pulser = make_pulser(sim.url)
        with pytest.raises(DeviceError, match="gate error"):
            pulser.read_gate()
        assert reg.Status.GATE_ERROR in pulser.last_status
        assert sim.settings.gain_db == PulserSettings().gain_db


def test_simulator_serves_loopback_only(model: EchoModel) -> None:
    with pytest.raises(ValueError, match="loopback"):
        SimulatedPulser(model, host="0.0.0.0")
    with pytest.raises(ValueError, match="framing"):
        SimulatedPulser(model, framing="ascii")
    with pytest.raises(ValueError, match="exception code"):
        SimulatedPulser(model).set_exception(0x42)
