"""Readings checked where the procedures take them, a zero noise floor, and a bounded
acquisition raster: a fake pulser and a fake controller, no processes."""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import pytest

from drivers.controller.base import ControllerStatus, JointSample, RobotController
from drivers.pulser.base import GateReading, PulserReceiver, PulserSettings
from ucal.calibration.faces import MAX_ACQUISITION_MOVES, acquire_and_centre, acquisition_gain
from ucal.calibration.search import ZERO_FLOOR_FSH, PeakSearch, Rig, read_distance
from ucal.errors import EXIT_HARDWARE, HardwareError

ENDPOINT = "fake-pulser://bench"


class FakeController(RobotController):
    """Moves at once; always at rest, powered, no error."""

    def __init__(self) -> None:
        self.q = np.zeros(6)
        self.moves = 0

    @property
    def endpoint(self) -> str:
        return "fake-controller://bench"

    def connect(self) -> None:
        pass

    def close(self) -> None:
        pass

    def read_joints(self, timeout_s: float = 2.0) -> np.ndarray:
        return self.q.copy()

    def status(self, timeout_s: float = 2.0) -> ControllerStatus:
        return ControllerStatus(True, False, False, False)

    def start_move(self, target_deg: np.ndarray, speed: float = 0.5) -> None:
        self.moves += 1
        self.q = np.asarray(target_deg, float).copy()

    def wait_settled(
        self, target_deg: np.ndarray, timeout_s: float, tol_deg: float = 1e-3
    ) -> np.ndarray:
        return self.q.copy()

    def stop(self) -> None:
        pass

    def joint_samples(self, since_t_s: float = 0.0) -> list[JointSample]:
        return []


class FakePulser(PulserReceiver):
    """Answers ``reading(n)`` for the n-th read (amplitude, tof_ns)."""

    def __init__(self, reading: Callable[[int], tuple[float, float]]):
        self.reading = reading
        self.n = 0

    @property
    def endpoint(self) -> str:
        return ENDPOINT

    def connect(self) -> None:
        pass

    def close(self) -> None:
        pass

    def configure(self, settings: PulserSettings) -> None:
        pass

    def settings(self) -> PulserSettings:
        return PulserSettings()

    def read_gate(self, fresh: bool = True, timeout_s: float = 1.0) -> GateReading:
        self.n += 1
        amplitude, tof_ns = self.reading(self.n)
        return GateReading(amplitude, tof_ns, self.n, 0.0, 0.0)


def rig_with(reading: Callable[[int], tuple[float, float]]) -> Rig:
    lo, hi = np.full(6, -270.0), np.full(6, 270.0)
    return Rig(FakeController(), FakePulser(reading), lo, hi)


BAD = [
    ((float("nan"), 40_000.0), r"amplitude nan"),
    ((-0.01, 40_000.0), r"amplitude -0.01"),
    ((float("inf"), 40_000.0), r"amplitude inf"),
    ((0.5, -12.0), r"time of flight -12.0 ns"),
    ((0.5, float("inf")), r"time of flight inf ns"),
    ((0.5, float("-inf")), r"time of flight -inf ns"),
]


@pytest.mark.parametrize(("reading", "what"), BAD)
def test_impossible_reading_is_a_hardware_fault_naming_the_pulser(
    reading: tuple[float, float], what: str
) -> None:
    rig = rig_with(lambda n: reading)
    for take in (
        rig.read,
        rig.normalised_amplitude,
        rig.measure_floor,
        lambda: read_distance(rig, 20.0, averages=1),
    ):
        with pytest.raises(
            HardwareError,
            match=rf"^pulser at {ENDPOINT}: impossible reading: "
            rf".*{what}",
        ) as err:
            take()
        assert err.value.exit_code == EXIT_HARDWARE
        assert "\n" not in str(err.value)


@pytest.mark.parametrize(("reading", "what"), BAD[:1] + BAD[3:4])
def test_impossible_reading_in_a_sweep_is_caught(reading: tuple[float, float], what: str) -> None:
    rig = rig_with(lambda n: (0.1, float("nan")) if n < 3 else reading)
    with pytest.raises(HardwareError, match=what):
        rig.line(np.zeros(6), np.array([0, 0, 0, 1.0, 0, 0]))


def test_no_echo_is_not_an_impossible_reading() -> None:
    rig = rig_with(lambda n: (0.0, float("nan")))
    assert rig.read().amplitude == 0.0
    _, amps, tofs = rig.line(np.zeros(6), np.array([0, 0, 0, 1.0, 0, 0]))
    assert np.all(amps == 0.0) and np.all(np.isnan(tofs))


def test_empty_gate_reading_exactly_zero_gives_a_usable_floor() -> None:
    rig = rig_with(lambda n: (0.0, float("nan")))  # 8-bit amplitude below one level
    rig.configure(gain_db=20.0)
    rig.measure_floor()
    assert rig.floor_per_gain == pytest.approx(ZERO_FLOOR_FSH / 10.0)
    gain = acquisition_gain(rig, np.zeros(6))
    assert math.isfinite(gain) and 20.0 <= gain <= 80.0
    assert math.isfinite(rig.threshold()) and rig.threshold() > 0


def test_mostly_zero_floor_takes_the_quantisation_level_seen() -> None:
    level = 1.0 / 256
    rig = rig_with(lambda n: (level if n % 4 == 0 else 0.0, float("nan")))
    rig.configure(gain_db=20.0)
    rig.measure_floor()
    assert rig.floor_per_gain == pytest.approx(level / 10.0)


def _search(rig: Rig) -> PeakSearch:
    tilt_map = np.radians(np.eye(2))  # 1° of joint tilts the beam by 1°
    return PeakSearch(rig, ka=300.0, joints=(3, 4), tilt_map=tilt_map, temperature_c=20.0)


def test_search_without_any_echo_gives_up_after_a_bounded_number_of_moves() -> None:
    rig = rig_with(lambda n: (0.001, float("nan")))  # noise only: the block is not there
    rig.floor_per_gain = 1e-5
    q_pred = np.array([0.0, 30.0, 100.0, 0.0, 50.0, 0.0])
    with pytest.raises(HardwareError) as err:
        acquire_and_centre(_search(rig), rig, q_pred, "base/XY", 16.0, 40.0)
    message = str(err.value)
    assert message.startswith(f"pulser at {ENDPOINT}: no echo from face XY (base) within ±")
    assert message.endswith(
        f"of the predicted posture ({rig.counters.moves} moves): is the block where [sample] says?"
    )
    assert err.value.exit_code == EXIT_HARDWARE
    # the line in progress is finished: at most one line (a move and four sweeps) over
    assert MAX_ACQUISITION_MOVES <= rig.counters.moves <= MAX_ACQUISITION_MOVES + 5
    assert rig.controller.moves == rig.counters.moves


def test_a_smaller_budget_is_honoured() -> None:
    rig = rig_with(lambda n: (0.0, float("nan")))
    rig.measure_floor()
    with pytest.raises(HardwareError, match="no echo from face YZ"):
        acquire_and_centre(_search(rig), rig, np.zeros(6), "YZ", 8.0, 40.0, max_moves=10)
    assert rig.counters.moves <= 10 + 5


def test_raster_stops_at_the_first_echo() -> None:
    # an echo on the third line of the raster (joint 5 stepped by one line spacing)
    rig = rig_with(lambda n: (0.0, float("nan")))
    rig.floor_per_gain = 1e-5

    def reading(n: int) -> tuple[float, float]:
        q = rig.controller.read_joints()
        return (0.5, 40_000.0) if abs(q[4] - 2.5) < 1e-6 else (0.0, float("nan"))

    rig.pulser.reading = reading
    found = _search(rig).acquire(np.zeros(6), 16.0, 40.0, spacing_tilt_deg=2.5, max_moves=50)
    assert found is not None
    posture, _ = found
    assert posture[4] == pytest.approx(2.5)
    assert rig.counters.moves < 15
