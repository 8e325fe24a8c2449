"""Front-end settings and device information through the simulated pulser on 127.0.0.1."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from drivers.pulser import registers as reg
from drivers.pulser.base import PulserSettings
from drivers.pulser.modbus import ModbusPulser
from drivers.pulser.simulator import DEVICE_INFO, SimulatedPulser

pytestmark = pytest.mark.system


@pytest.fixture(params=["tcp", "rtu"])
def sim(request: pytest.FixtureRequest) -> Iterator[SimulatedPulser]:
    with SimulatedPulser(lambda settings: (0.5, 40_000.0), framing=request.param) as simulator:
        yield simulator


@pytest.fixture
def pulser(sim: SimulatedPulser) -> Iterator[ModbusPulser]:
    with ModbusPulser.from_url(sim.url, timeout_s=0.5) as client:
        yield client


def test_front_end_settings_are_stored_and_read_back(
    pulser: ModbusPulser, sim: SimulatedPulser
) -> None:
    assert pulser.settings() == PulserSettings()
    wanted = PulserSettings(
        gain_db=30.0, pulse_voltage_v=250.0, damping_ohm=200.0, high_pass_mhz=2.5, low_pass_mhz=30.0
    )
    pulser.configure(wanted)
    assert pulser.settings() == wanted
    assert sim.settings == wanted
    # the threshold between the two blocks is untouched
    assert sim.gate_threshold == pytest.approx(reg.DEFAULT_THRESHOLD)


def test_device_refuses_an_out_of_range_front_end_register(pulser: ModbusPulser) -> None:
    from drivers.errors import DeviceError

    with pytest.raises(DeviceError, match=r"illegal data value \(0x03\)"):
        pulser._write(0x000A, [5], "raw write")  # damping below 10 ohm
    assert pulser.settings() == PulserSettings()


def test_identity_names_the_simulated_device(pulser: ModbusPulser) -> None:
    assert pulser.identity() == {
        "register_map_version": 2,
        "model": DEVICE_INFO.model,
        "firmware": DEVICE_INFO.firmware_version,
        "serial": DEVICE_INFO.serial,
    }
