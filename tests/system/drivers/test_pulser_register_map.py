"""The simulated pulser serves whatever register map it is given, and the client speaks it: another
device's map over Modbus TCP and RTU, a reading spread over two requests, a minimal map."""

from __future__ import annotations

import math
import threading
import tomllib
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from drivers.errors import DeviceError
from drivers.pulser import registers as reg
from drivers.pulser.base import PulserSettings
from drivers.pulser.map_file import load_register_map, register_map_from_data
from drivers.pulser.modbus import ModbusPulser
from drivers.pulser.simulator import SimulatedPulser

pytestmark = pytest.mark.system

SHIFTED_MAP_PATH = Path(__file__).resolve().parents[2] / "data" / "shifted_pulser_map.toml"


class Echo:
    """A settable echo that counts its calls."""

    def __init__(self, amplitude: float = 0.4321, tof_ns: float = 40_123.456):
        self.amplitude, self.tof_ns, self.calls = amplitude, tof_ns, 0
        self._lock = threading.Lock()

    def __call__(self, settings: PulserSettings) -> tuple[float, float]:
        with self._lock:
            self.calls += 1
            return self.amplitude, self.tof_ns


@pytest.fixture(params=["tcp", "rtu"])
def framing(request: pytest.FixtureRequest) -> str:
    return request.param


def _map_without(names: tuple[str, ...], **moves: int) -> reg.RegisterMap:
    """The shifted map without ``names``, with registers moved to other input addresses."""
    data = tomllib.loads(SHIFTED_MAP_PATH.read_text())
    for n in names:
        del data["registers"][n]
    for n, address in moves.items():
        data["registers"][n]["address"] = address
    return register_map_from_data(data, "test map")


@pytest.fixture
def shifted(framing: str) -> Iterator[tuple[SimulatedPulser, ModbusPulser, Echo]]:
    echo = Echo()
    with (
        SimulatedPulser(echo, framing=framing, register_map=SHIFTED_MAP_PATH) as sim,
        ModbusPulser.from_url(sim.url, 0.5, register_map=SHIFTED_MAP_PATH) as pulser,
    ):
        yield sim, pulser, echo


def test_another_map_round_trips_settings_readings_and_commands(
    shifted: tuple[SimulatedPulser, ModbusPulser, Echo],
) -> None:
    sim, pulser, echo = shifted
    assert pulser.identity() == {"register_map_version": 7, "model": "ucal sim", "serial": 1}
    assert pulser.settings() == PulserSettings()  # power-on defaults in the other encoding
    wanted = PulserSettings(
        gain_db=32.5, prf_hz=2000.0, gate_start_us=30.0, gate_width_us=20.0, averages=16,
        damping_ohm=200.0, high_pass_mhz=2.0, low_pass_mhz=30.0,
    )  # fmt: skip
    pulser.configure(wanted)
    assert pulser.settings() == wanted == sim.settings
    first, second = pulser.read_gate(), pulser.read_gate()
    assert (first.counter, second.counter) == (1, 2) and echo.calls == 2
    assert first.amplitude == 0.4321  # 0.01 % counts
    assert first.tof_ns == pytest.approx(40_123.5)  # 0.1 ns counts
    pulser.set_gate_threshold(0.05)
    assert pulser.gate_threshold() == sim.gate_threshold == 0.05
    echo.amplitude = 0.04  # below the threshold: no echo, and the int32 TOF reads NaN
    weak = pulser.read_gate()
    assert not weak.has_echo and math.isnan(weak.tof_ns) and weak.amplitude == 0.04
    echo.amplitude = 1.5
    assert pulser.read_gate().amplitude == 1.0 and reg.Status.SATURATED in pulser.last_status
    pulser.clear_counter()
    assert sim.counter == 0
    pulser.trigger()
    assert sim.counter == 1
    scan = pulser.read_ascan_trace()  # its header takes two requests; the first freezes it
    assert scan.samples.shape == (2001,) and scan.sample_rate_hz == 100e6
    assert scan.start_ns == 30_000.0 and scan.counter == -1  # this map has no A-scan counter
    assert 0.5 < np.max(np.abs(scan.samples)) <= 1.0


def test_the_device_refuses_what_its_map_refuses(
    shifted: tuple[SimulatedPulser, ModbusPulser, Echo],
) -> None:
    sim, pulser, _ = shifted
    with pytest.raises(ValueError, match=r"averages = 3 is not one the device takes"):
        pulser.configure(PulserSettings(averages=3))
    with pytest.raises(DeviceError, match=r"illegal data value \(0x03\)"):
        pulser._write(107, [3], "raw write")  # 3 averages: not one of its values
    with pytest.raises(DeviceError, match=r"illegal data address \(0x02\)"):
        pulser._write(0, [1], "raw write")  # ucal's own gain address: not in this map
    with pytest.raises(DeviceError, match=r"illegal data address \(0x02\)"):
        pulser._read(reg.FunctionCode.READ_INPUT_REGISTERS, 147, 4, "raw read")  # 148 unmapped
    assert sim.settings == PulserSettings()


def test_a_client_with_another_map_is_refused_at_connect(framing: str) -> None:
    with (
        SimulatedPulser(Echo(), framing=framing, register_map=SHIFTED_MAP_PATH) as sim,
        pytest.raises(DeviceError, match="identify: Modbus exception illegal data address"),
    ):
        ModbusPulser.from_url(sim.url, 0.5).connect()  # ucal's own map


def test_a_reading_over_two_requests_is_one_acquisition(framing: str) -> None:
    m = _map_without((), tof=400)  # the TOF far from the rest of the reading
    assert len(m.read_requests(m.present(reg.MEASUREMENT))) == 2
    echo = Echo()
    with (
        SimulatedPulser(echo, framing=framing, register_map=m) as sim,
        ModbusPulser.from_url(sim.url, 0.5, register_map=m) as pulser,
    ):
        readings = [pulser.read_gate() for _ in range(3)]
        assert [r.counter for r in readings] == [1, 2, 3] and echo.calls == 3
        assert [r.tof_ns for r in readings] == pytest.approx([40_123.5] * 3)


def test_a_minimal_map_reads_gates(framing: str) -> None:
    """Only what every map needs, a float32 TOF: no counter, clock, status, identity, A-scan."""
    optional = [n for n, q in reg.QUANTITIES.items() if not q.required]
    data = tomllib.loads(SHIFTED_MAP_PATH.read_text())
    data["registers"] = {n: v for n, v in data["registers"].items() if n not in optional}
    data["registers"]["tof"] = {"table": "input", "address": 140, "type": "float32", "unit": "ns"}
    data["map"]["reserved"] = []
    m = register_map_from_data(data, "minimal map")
    echo = Echo()
    with (
        SimulatedPulser(echo, framing=framing, register_map=m) as sim,
        ModbusPulser.from_url(sim.url, 0.5, register_map=m) as pulser,
    ):
        assert pulser.identity() == {} and pulser.read_ascan() is None
        pulser.configure(PulserSettings(gain_db=30.0))
        assert pulser.settings() == PulserSettings(gain_db=30.0)
        with pytest.raises(ValueError, match="averages = 16 cannot be set"):
            pulser.configure(PulserSettings(averages=16))
        a, b = pulser.read_gate(), pulser.read_gate(fresh=True)
        assert (a.counter, b.counter) == (0, 1) and echo.calls == 2
        assert a.has_echo and a.device_time_s == a.host_time_s
        echo.tof_ns = math.nan
        assert not pulser.read_gate().has_echo
    assert load_register_map(SHIFTED_MAP_PATH).name == "shifted test pulser"
