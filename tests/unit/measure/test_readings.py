"""Readings checked where the procedures take them, a zero noise floor, a bounded acquisition
raster, and a sweep's readings paired with the streamed joints (a reading answered late, while
the arm went on, tied to no posture): a fake pulser and a fake controller, no processes."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import replace

import numpy as np
import pytest

from drivers.controller.base import JointSample
from drivers.pulser.base import GateReading
from ucal.acoustics import piston_directivity
from ucal.devices.rig import READ_TRAVEL_STEPS, ZERO_FLOOR_FSH, Rig
from ucal.errors import EXIT_HARDWARE, HardwareError
from ucal.measure.acquire import BLOCK_FACES, acquire_and_centre, acquisition_gain, open_water
from ucal.measure.approach import FinalApproachRig, approaching
from ucal.measure.face import SearchMode
from ucal.measure.running import BLOCK_TRUST, PLATE_TRUST
from ucal.measure.search import PeakSearch, read_distance
from ucal.profile.models import joint_speeds_deg_s

from doubles import FakeController, QuietPulser

ENDPOINT = "fake-pulser://bench"


class FakePulser(QuietPulser):
    """Answers ``reading(n)`` for the n-th read (amplitude, tof_ns)."""

    def __init__(self, reading: Callable[[int], tuple[float, float]]):
        super().__init__(ENDPOINT)
        self.reading = reading
        self.n = 0

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


def test_empty_gate_reading_zero_at_every_gain_gives_a_usable_floor() -> None:
    rig = rig_with(lambda n: (0.0, float("nan")))  # 8-bit amplitude below one level
    rig.configure(gain_db=20.0)
    rig.measure_floor()
    # below one level even at 80 dB: one level there bounds it
    assert rig.settings.gain_db == 80.0
    assert rig.floor_per_gain == pytest.approx(ZERO_FLOOR_FSH / 1e4)
    assert rig.amplitude_step_fsh == ZERO_FLOOR_FSH
    gain = acquisition_gain(rig, np.zeros(6))
    assert math.isfinite(gain) and 20.0 <= gain <= 80.0
    assert math.isfinite(rig.threshold()) and rig.threshold() > 0


def quantised_floor(rig_ref: list[Rig], floor_at_0db: float, bits: int = 8):
    """An empty gate read through a ``bits``-bit register: the floor scales with the gain and
    is truncated to whole levels; a little noise from read to read (deterministic)."""
    levels = float(1 << bits)

    def reading(n: int) -> tuple[float, float]:
        g = rig_ref[0].settings.gain_db
        true = floor_at_0db * 10 ** (g / 20) * (1.0 + 0.2 * math.sin(n))
        return math.floor(true * levels) / levels, float("nan")

    return reading


def test_a_floor_below_one_level_is_measured_at_a_higher_gain() -> None:
    ref: list[Rig] = []
    true_floor = 2e-4  # FSH at 0 dB: 0.5 level at 20 dB, 2 levels at 32 dB, 8 at 44 dB
    rig = rig_with(quantised_floor(ref, true_floor))
    ref.append(rig)
    rig.configure(gain_db=20.0)
    rig.measure_floor()
    assert rig.settings.gain_db == 32.0
    assert rig.amplitude_step_fsh == pytest.approx(1.0 / 256)  # the level seen at 20 dB
    # measured within the quantisation and the read-to-read spread, not 1 level at 20 dB (5×)
    assert rig.floor_per_gain == pytest.approx(true_floor, rel=0.35)


def test_an_unquantised_floor_is_taken_where_it_is_read() -> None:
    rig = rig_with(lambda n: (1e-3 * (1.0 + 0.01 * math.sin(n)), float("nan")))
    rig.configure(gain_db=20.0)
    rig.measure_floor()
    assert rig.settings.gain_db == 20.0 and rig.amplitude_step_fsh == 0.0
    assert rig.floor_per_gain == pytest.approx(1e-4, rel=0.02)


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
    max_moves = BLOCK_FACES.max_moves
    assert max_moves is not None
    assert max_moves <= rig.counters.moves <= max_moves + 5
    assert rig.controller.moves == rig.counters.moves


def test_a_smaller_budget_is_honoured() -> None:
    rig = rig_with(lambda n: (0.0, float("nan")))
    rig.measure_floor()
    with pytest.raises(HardwareError, match="no echo from face YZ"):
        acquire_and_centre(
            _search(rig), rig, np.zeros(6), "YZ", 8.0, 40.0, replace(BLOCK_FACES, max_moves=10)
        )
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


def _peak_reading(rig_ref: list[Rig], averages_seen: list[int]):
    """A main lobe at joints 4, 5 = (0.3, −0.2) deg (1° of joint = 1° of tilt), 0.6 FSH."""

    def reading(n: int) -> tuple[float, float]:
        rig = rig_ref[0]
        averages_seen.append(rig.settings.averages)
        q = rig.controller.read_joints()
        tilt = math.radians(math.hypot(q[3] - 0.3, q[4] + 0.2))
        amp = 0.6 * abs(float(piston_directivity(300.0 * math.sin(2 * tilt))))
        return amp * 10 ** ((rig.settings.gain_db - 20.0) / 20), 40_000.0

    return reading


@pytest.mark.parametrize(("step", "averages"), [(0.0, 8), (1.0 / 256, 32)])
def test_the_peak_fit_averages_more_once_the_amplitude_shows_levels(
    step: float, averages: int
) -> None:
    ref: list[Rig] = []
    seen: list[int] = []
    rig = rig_with(_peak_reading(ref, seen))
    ref.append(rig)
    rig.amplitude_step_fsh = step
    rig.configure(gain_db=20.0)
    peak = _search(rig).fit(np.array([0.0, 30.0, 100.0, 0.25, -0.15, 0.0]), averages=8)
    assert set(seen) == {averages}
    np.testing.assert_allclose(peak.joints_deg[3:5], [0.3, -0.2], atol=1e-4)
    if step:
        # the levels' variance is in the tilt σ even where the readings fit exactly
        assert peak.tilt_std_deg > 1e-4


def test_no_echo_message_names_the_face_once_for_both_levels() -> None:
    from types import SimpleNamespace

    from ucal.measure.acquire import _no_face_echo

    rig = SimpleNamespace(pulser=SimpleNamespace(endpoint="modbus-tcp://127.0.0.1:5020"))
    offsets = str(_no_face_echo(rig, "j3/XY", 20.0, 5))  # type: ignore[arg-type]
    full = str(_no_face_echo(rig, "face YZ (p7)", 20.0, 5))  # type: ignore[arg-type]
    assert "no echo from face XY (j3) within ±20°" in offsets
    assert "no echo from face YZ (p7) within ±20°" in full and "face face" not in full


class TimedPulser(FakePulser):
    """Stamps the n-th reading's arrival at 30·n s on the host clock."""

    def read_gate(self, fresh: bool = True, timeout_s: float = 1.0) -> GateReading:
        r = super().read_gate(fresh, timeout_s)
        return replace(r, host_time_s=30.0 * r.counter)


def test_rig_records_each_joints_last_motion_and_the_minutes_since_the_first_reading() -> None:
    rig = rig_with(lambda n: (0.5, 1000.0))
    rig.pulser = TimedPulser(lambda n: (0.5, 1000.0))
    assert rig.minutes() == 0.0  # nothing read yet
    rig.move(np.array([1.0, 2.0, 3.0, 4.0, 5.0, 6.0]))
    rig.read()  # t = 30 s: the run's first reading
    rig.move(np.array([0.5, 2.0, 4.0, 4.0, 5.0, 6.0]))  # J1 down, J3 up, the rest still
    rig.read()
    rig.read()  # t = 90 s
    assert rig.approach.tolist() == [-1.0, 1.0, 1.0, 1.0, 1.0, 1.0]
    assert rig.minutes() == pytest.approx(1.0)
    # the final approach: down to below the target, then up onto it on every joint
    approach = FinalApproachRig(rig)
    approach.move(np.array([0.2, 1.0, 4.0, 4.0, 5.0, 6.0]))
    assert rig.approach.tolist() == [1.0] * 6
    assert rig.controller.read_joints().tolist() == [0.2, 1.0, 4.0, 4.0, 5.0, 6.0]
    assert rig.counters.moves == 3


def test_a_posture_is_reached_from_the_side_asked_even_after_a_sweep_ends_the_other_way() -> None:
    rig = rig_with(lambda n: (0.5, 1000.0))
    controller = rig.controller
    assert isinstance(controller, FakeController)
    below = FinalApproachRig(rig)
    q0 = np.array([1.0, 2.0, 3.0, 4.0, 5.0, 6.0])
    below.move(q0)  # up on every joint: straight there
    assert controller.moves == 1 and rig.approach.tolist() == [1.0] * 6
    # a centring sweep that ends moving J4 down
    swept = q0 - np.array([0.0, 0.0, 0.0, 0.3, 0.0, 0.0])
    rig.sweep(swept)
    assert rig.approach[3] == -1.0
    # a static move that raises J5 only: J4 stays where the sweep left it, approached afresh
    q = swept + np.array([0.0, 0.0, 0.0, 0.0, 0.1, 0.0])
    moves, segments = rig.counters.moves, controller.moves
    below.move(q)
    assert rig.approach.tolist() == [1.0] * 6
    assert (rig.counters.moves, controller.moves) == (moves + 1, segments + 2)
    # from above: every joint ends moving down, the overshoot and the approach one move
    above = approaching(below, -1)
    assert isinstance(above, FinalApproachRig) and above.direction == -1
    above.move(q + 0.01)
    assert rig.approach.tolist() == [-1.0] * 6
    assert np.allclose(controller.read_joints(), q + 0.01)
    assert (rig.counters.moves, controller.moves) == (moves + 2, segments + 4)
    above.move(q)  # down on every joint, already from above: straight there
    assert controller.moves == segments + 5 and rig.approach.tolist() == [-1.0] * 6
    with pytest.raises(ValueError, match="direction"):
        FinalApproachRig(rig, direction=0)


def test_open_water_turns_the_joint_up_or_down_where_up_leaves_its_range() -> None:
    lo, hi = np.full(6, -140.0), np.full(6, 140.0)
    q = np.array([0.0, 30.0, 100.0, 0.0, 50.0, 0.0])
    assert open_water(q, 4, lo, hi)[4] == pytest.approx(75.0)
    q[4] = 120.0  # 25° up would leave the range: clipped, the beam would turn back
    assert open_water(q, 4, lo, hi)[4] == pytest.approx(95.0)
    assert open_water(q, 4, lo, hi)[[0, 1, 2, 3, 5]].tolist() == [0.0, 30.0, 100.0, 0.0, 0.0]


def test_one_trust_policy_acquires_the_first_face_then_centres_then_fits_at_once() -> None:
    faces = [(0, False, np.inf), (1, False, 2.0), (2, True, 0.6), (3, False, 0.14)]
    modes = [BLOCK_TRUST.mode(n, seen, miss) for n, seen, miss in faces]
    assert modes == [SearchMode.ACQUIRE, SearchMode.QUICK, SearchMode.QUICK, SearchMode.DIRECT]
    # a prediction that landed inside the fit's first grid: fitted at once after one face
    assert BLOCK_TRUST.mode(1, False, 0.01) == SearchMode.DIRECT
    assert BLOCK_TRUST.mode(2, False, 0.1) == SearchMode.QUICK  # on the lobe, not in the grid
    # the same face again after one: its prediction rests on what it measured
    assert BLOCK_TRUST.mode(1, True, 2.0) == SearchMode.QUICK
    # the last prediction missed by more than the main lobe's half-width: centre first
    assert BLOCK_TRUST.mode(5, True, 1.0) == SearchMode.QUICK
    assert (BLOCK_TRUST.radius(0), BLOCK_TRUST.radius(1), BLOCK_TRUST.radius(7)) == (16.0, 8.0, 8.0)
    # the plate: one posture fixes the beam, none is fitted without centring
    plate = [PLATE_TRUST.mode(n, n > 0, 0.0) for n in range(4)]
    assert plate == [SearchMode.ACQUIRE] + [SearchMode.QUICK] * 3


def test_an_interrupt_swallowed_since_the_last_motion_starts_no_other(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    from ucal import interrupt
    from ucal.measure.approach import FinalApproachRig

    rig = rig_with(lambda n: (0.5, 1000.0))
    rig.move(np.zeros(6))
    monkeypatch.setattr(interrupt, "received", [15])  # taken, its exception lost somewhere
    moved = rig.counters.moves
    for move in (rig.move, FinalApproachRig(rig).move):
        with pytest.raises(KeyboardInterrupt, match="signal 15"):
            move(np.full(6, -1.0))
    assert rig.counters.moves == moved


PERIOD_S = 0.02  # the state stream's
READ_S = 0.002  # a reading's round trip
LATE_S = 0.04  # the one answer a loaded host reads late
LATE_READ = 5


class FakeClock:
    def __init__(self) -> None:
        self.t = 100.0

    def now(self) -> float:
        return self.t

    def sleep(self, seconds: float) -> None:
        self.t += max(seconds, 0.0)


class StreamedArm(FakeController):
    """Moves linearly at the commanded speed; streams its joints every ``PERIOD_S``, each frame
    stamped with the instant it shows."""

    def __init__(self, clock: FakeClock) -> None:
        super().__init__()
        self.clock = clock  # type: ignore[assignment]
        self.motion = (clock.t, clock.t, np.zeros(6), np.zeros(6))

    def at(self, t: float) -> np.ndarray:
        t0, t1, a, b = self.motion
        f = 1.0 if t >= t1 else max(t - t0, 0.0) / (t1 - t0)
        return a + f * (b - a)

    def read_joints(self, timeout_s: float = 2.0) -> np.ndarray:
        return self.at(np.floor(self.clock.t / PERIOD_S) * PERIOD_S)

    def start_move(self, target_deg: np.ndarray, speed: float = 0.5) -> None:
        here, target = self.at(self.clock.t), np.asarray(target_deg, float)
        duration = float(np.max(np.abs(target - here) / (joint_speeds_deg_s(None) * speed)))
        self.motion = (self.clock.t, self.clock.t + duration, here, target)

    def wait_settled(
        self, target_deg: np.ndarray, timeout_s: float, tol_deg: float = 1e-3
    ) -> np.ndarray:
        self.clock.t = max(self.clock.t, self.motion[1] + PERIOD_S)
        return self.at(self.clock.t)

    def joint_samples(self, since_t_s: float = 0.0) -> list[JointSample]:
        k = np.arange(np.ceil(since_t_s / PERIOD_S), np.floor(self.clock.t / PERIOD_S) + 1)
        return [JointSample(float(t), self.at(float(t))) for t in k * PERIOD_S]


class LatePulser(QuietPulser):
    """Each reading takes ``READ_S``, the ``LATE_READ``-th ``LATE_S``; acquired halfway. Its
    amplitude says which reading it was."""

    def __init__(self, clock: FakeClock, arm: StreamedArm) -> None:
        super().__init__("fake-pulser://timed")
        self.clock, self.arm, self.n = clock, arm, 0
        self.acquired: dict[float, np.ndarray] = {}

    def read_gate(self, fresh: bool = True, timeout_s: float = 1.0) -> GateReading:
        self.n += 1
        took = LATE_S if self.n == LATE_READ else READ_S
        self.clock.sleep(0.5 * took)
        amplitude = self.n / 1000.0
        self.acquired[amplitude] = self.arm.at(self.clock.t)
        self.clock.sleep(0.5 * took)
        return GateReading(amplitude, 1000.0, self.n, self.clock.t, self.clock.t)


def test_a_reading_answered_late_in_a_sweep_is_left_out_and_the_others_tied() -> None:
    clock = FakeClock()
    arm = StreamedArm(clock)
    pulser = LatePulser(clock, arm)
    rig = Rig(arm, pulser, np.full(6, -270.0), np.full(6, 270.0))
    target = np.array([0.0, 0.0, 0.0, 1.5, 0.0, 0.0])
    step = 0.06
    q, amps, _ = rig.sweep(target, max_step_deg=step)
    assert pulser.n > 2 * LATE_READ  # the late one is well inside the sweep
    kept = np.round(amps * 1000).astype(int)
    # the late reading spans 20 of the spacings' travel: not where it was acquired
    assert LATE_READ not in kept
    assert len(kept) == pulser.n - 1
    truth = np.array([pulser.acquired[a][3] for a in amps])
    assert np.max(np.abs(q[:, 3] - truth)) <= 0.5 * READ_TRAVEL_STEPS * step
