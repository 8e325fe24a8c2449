"""The tank's thermometer log: read, placed on the run's clock, and taking the tank's turns out
of the water paths (``ucal.thermometer``)."""

from __future__ import annotations

import logging
import time
from datetime import UTC, datetime
from pathlib import Path

import numpy as np
import pytest

from ucal.acoustics import sound_speed_m_s
from ucal.errors import InputError, ProfileError
from ucal.measure.sequence import CalibrationRun
from ucal.model.geometry import FaceMeasurement
from ucal.thermometer import Thermometer, check_time_base, on_run, read_log


def _write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "t.csv"
    path.write_text(text)
    return path


def test_a_logger_file_is_read_on_the_wall_clock(tmp_path: Path) -> None:
    path = _write(
        tmp_path,
        "time,temperature_c\n2026-11-26T07:00:00Z,20.10\n# a comment\n"
        "2026-11-26 08:01:30+01:00,20.15\n",
    )
    log = read_log(path)
    assert log.wall_clock
    start = datetime(2026, 11, 26, 7, 0, tzinfo=UTC).timestamp() / 60.0
    assert log.time_min - start == pytest.approx([0.0, 1.5])
    assert log.temperature_c.tolist() == [20.10, 20.15]


def test_a_logger_without_a_zone_writes_the_hosts_local_time(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """One instant three ways (UTC, an offset, a zone's naive local time on a host in that zone)
    is one time; the run's first reading placed on it is said in UTC."""
    monkeypatch.setenv("TZ", "CET-1")  # POSIX: an hour east of UTC, no summer time
    time.tzset()
    try:
        log = read_log(
            _write(
                tmp_path,
                "time,temperature_c\n2026-11-26T07:00:00Z,20.00\n"
                "2026-11-26T08:00:03+01:00,20.01\n2026-11-26 08:00:06,20.02\n",
            )
        )
    finally:
        monkeypatch.undo()  # the host's zone again
        time.tzset()
    start = datetime(2026, 11, 26, 7, 0, tzinfo=UTC).timestamp() / 60.0
    assert log.time_min - start == pytest.approx([0.0, 0.05, 0.1], abs=1e-6)
    water = on_run(log, 0.02, first_read_min=start + 0.5 / 60.0, span_min=0.05)
    assert water is not None
    run = _tank_run(np.full(2, 20.0), np.array([0.0, 0.05]))
    summary = water.summary(run)
    assert summary["first_reading"] == "2026-11-26T07:00:00.500+00:00"
    assert summary["change_c"] == pytest.approx(0.01)
    assert Thermometer.from_json(water.as_json()).summary(run) == summary  # a record keeps it


@pytest.mark.parametrize(
    ("text", "where", "words"),
    [
        ("2026-11-26T07:00:00Z,20\n", "row 1", "expected the header time_min,temperature_c or"),
        ("time,temperature_c\nnoon,20\n", "row 2", "expected an ISO 8601 time and °C"),
        (
            "time,temperature_c\n2026-11-26T07:00:00Z,20\n2026-11-26T06:59:00Z,20\n",
            "row 3",
            "times must increase",
        ),
        ("time_min,temperature_c\n0,20\n1,75\n", "row 3", "0-60 °C"),
    ],
)
def test_a_bad_log_names_its_file_and_row(tmp_path: Path, text: str, where: str, words: str):
    path = _write(tmp_path, text)
    with pytest.raises(ProfileError) as err:
        read_log(path, "--thermometer")
    assert f"{path}: {where}: " in str(err.value)
    assert words in str(err.value)
    assert str(err.value).endswith("(--thermometer)")
    assert err.value.exit_code == 2


def test_a_world_log_takes_minutes_only(tmp_path: Path) -> None:
    """A world file's log is on the simulated cell's clock: minutes, its header optional."""
    assert read_log(_write(tmp_path, "0,20\n2,21\n"), wall_clock=False).at(1.0) == 20.5
    with pytest.raises(ProfileError, match="expected two numbers, minutes and °C"):
        read_log(_write(tmp_path, "time,temperature_c\n"), wall_clock=False)


def test_a_log_on_another_clock_than_the_cells_is_refused(tmp_path: Path) -> None:
    wall = read_log(_write(tmp_path, "time,temperature_c\n2026-11-26T07:00:00Z,20\n"))
    with pytest.raises(InputError, match="the simulated cell runs on its own clock"):
        check_time_base(wall, simulated=True)
    check_time_base(wall, simulated=False, now_s=lambda: 60.0 * wall.time_min[-1] + 5.0)
    cell = read_log(_write(tmp_path, "time_min,temperature_c\n0,20\n"))
    with pytest.raises(InputError, match="give the logger's times"):
        check_time_base(cell, simulated=False)


@pytest.mark.parametrize(
    ("after_last_s", "words"),
    [
        (-90.0, "its last row is ahead of this host's clock by 1.5 min"),
        (150.0, "its last row is 2.5 min old by this host's clock"),
        (-30.0, None),
        (100.0, None),
    ],
)
def test_a_logger_not_writing_now_is_refused_before_anything_moves(
    tmp_path: Path, after_last_s: float, words: str | None
) -> None:
    """A logger's last row more than a minute ahead of the host's clock (a zone, its clock), or
    more than two minutes old (three of its 3 s intervals are less): the log could not cover the
    run (exit 2)."""
    log = read_log(
        _write(tmp_path, "time,temperature_c\n2026-11-26T07:00:00Z,20\n2026-11-26T07:00:03Z,20\n")
    )
    now = 60.0 * float(log.time_min[-1]) + after_last_s
    if words is None:
        check_time_base(log, simulated=False, now_s=lambda: now)
        return
    with pytest.raises(InputError) as err:
        check_time_base(log, simulated=False, now_s=lambda: now)
    assert str(err.value).startswith(f"{log.path}: {words}: the log must be written during")
    assert "a time without a zone is this host's local time, UTC" in str(err.value)


def test_a_log_is_placed_on_the_runs_clock_or_not_used(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    log = read_log(_write(tmp_path, "time_min,temperature_c\n0,20\n10,21\n20,22\n"))
    water = on_run(log, 0.02, first_read_min=5.0, span_min=4.0)
    assert water is not None
    assert water.at(0.0) == pytest.approx(20.5)  # the run's first reading, 5 min in
    assert water.summary(_tank_run(np.full(2, 20.0), np.array([0.0, 4.0])))[
        "first_reading_min"
    ] == pytest.approx(5.0)
    with caplog.at_level(logging.WARNING):
        assert on_run(log, 0.02, first_read_min=15.0, span_min=8.0) is None
    assert "ends 3.0 min before the run's last reading" in caplog.text


def _tank_run(temps: np.ndarray, times: np.ndarray, path_mm: float = 120.0) -> CalibrationRun:
    """Face readings of one true path at ``times``, each read with 20 °C's sound speed in a
    tank at ``temps``."""
    c0 = float(sound_speed_m_s(20.0))
    faces = [
        FaceMeasurement(
            "base",
            i % 3,
            np.zeros(6),
            path_mm * c0 / float(sound_speed_m_s(temp)),
            time_min=float(t),
        )
        for i, (t, temp) in enumerate(zip(times, temps, strict=True))
    ]
    return CalibrationRun(faces, moves=len(faces), reads=len(faces))


def test_the_log_takes_the_tanks_turn_out_of_every_path() -> None:
    """A heater turning the tank during the run: every corrected path is what the tank on the
    straight line fitted to the log would have given, which the solvers' steady drift fits."""
    log_t = np.arange(0.0, 12.0, 0.05)
    log_c = 20.0 + 0.2 * np.sin(2.0 * np.pi * log_t / 4.0)
    water = Thermometer(log_t, np.round(log_c, 3), 0.02, "t.csv")
    times = np.linspace(1.0, 6.0, 12)
    run = _tank_run(20.0 + 0.2 * np.sin(2.0 * np.pi * times / 4.0), times)
    assert water.turns(run)
    fixed = water.corrected(run)
    c0 = float(sound_speed_m_s(20.0))
    speeds = np.array([m.distance_mm for m in fixed.measurements]) / c0  # ∝ 1/c
    line = np.polyval(np.polyfit(times, 1.0 / speeds, 1), times)
    assert np.max(np.abs(1.0 / speeds - line) / line) < 2e-6  # a straight line: no turn
    raw = np.array([m.distance_mm for m in run.measurements]) / c0
    bent = np.polyval(np.polyfit(times, 1.0 / raw, 1), times)
    assert np.max(np.abs(1.0 / raw - bent) / bent) > 1e-4  # the tank did turn
    assert all(m.distance_std_mm > 0.01 for m in fixed.measurements)  # the log's noise added
    assert fixed.moves == run.moves


def test_a_log_that_sees_no_turn_leaves_the_paths_alone() -> None:
    """A steady drift (the solvers fit it) logged with a 0.01 °C resolution: its departure
    from a straight line is its noise, and correcting by it would only add that noise."""
    log_t = np.arange(0.0, 12.0, 0.05)
    water = Thermometer(log_t, np.round(20.0 + 0.05 * log_t, 2), 0.02, "t.csv")
    times = np.linspace(1.0, 6.0, 12)
    run = _tank_run(20.0 + 0.05 * times, times)
    assert not water.turns(run)
    assert water.corrected(run) is run
    assert water.noise_c(run) == pytest.approx(0.01 / np.sqrt(12.0), rel=0.5)


def test_a_log_of_one_value_never_turns() -> None:
    """A logger that writes the same reading all run (a steady tank), its rows a second apart
    give or take a host's scheduling: the smoothing leaves 10⁻¹³ °C of round-off on the
    course, and the log, without a second value, shows no noise to hold it against; the
    summary says no change, no drift and nothing applied, whatever the rows' spacing."""
    rng = np.random.default_rng(7)
    for _ in range(200):
        rows = int(rng.integers(40, 120))
        log_t = np.cumsum(np.full(rows, 1.0 / 60.0) + rng.normal(0.0, 1e-3 / 60.0, rows)) - 0.3
        water = Thermometer(log_t, np.full(rows, 20.3), 0.05, "live.csv")
        times = np.sort(rng.uniform(0.0, 0.9 * log_t[-1], 13))
        run = _tank_run(np.full(13, 20.3), times)
        summary = water.summary(run)
        assert (summary["change_c"], summary["drift_c_per_min"], summary["applied"]) == (
            0.0,
            0.0,
            False,
        )
        assert water.corrected(run) is run


def test_tool_frames_peaks_are_corrected_as_the_faces_are() -> None:
    """Tool-frame's peaks carry their path as ``distance`` (path, std): the same correction,
    and the peaks' order of the run's lists is the reference time's."""
    from ucal.measure.search import PeakResult

    log_t = np.arange(0.0, 12.0, 0.05)
    water = Thermometer(log_t, 20.0 + 0.2 * np.sin(2.0 * np.pi * log_t / 4.0), 0.02, "t.csv")
    times = np.linspace(1.0, 6.0, 6)
    faces = _tank_run(20.0 + 0.2 * np.sin(2.0 * np.pi * times / 4.0), times)
    peaks = [
        PeakResult(np.zeros(6), 1.0, 0.01, 0.0, (m.distance_mm, 0.01), time_min=m.time_min)
        for m in faces.measurements
    ]
    fixed_faces = water.corrected(faces).measurements
    fixed_peaks = water.corrected(CalibrationRun(peaks, 6, 6)).measurements  # type: ignore[arg-type]
    assert [p.distance[0] for p in fixed_peaks] == pytest.approx(
        [m.distance_mm for m in fixed_faces], abs=1e-12
    )
    assert fixed_peaks[0].distance[1] > 0.01


def test_the_logs_drift_is_the_drifts_prior_mean() -> None:
    """The log measures the tank's drift over the run: every solver's drift prior is centred on
    it (its tolerance the declared one), in m/s per minute through Marczak's slope."""
    from ucal.cell import CellProfile
    from ucal.model.priors import prior_from_profile
    from ucal.profile.models import load_model

    log_t = np.arange(0.0, 12.0, 0.05)
    water = Thermometer(log_t, np.round(20.0 + 0.3 * log_t, 3), 0.02, "t.csv")
    times = np.linspace(1.0, 3.0, 9)
    run = _tank_run(20.0 + 0.3 * times, times)
    profile = water.profile(CellProfile(model=load_model("tx90l")), run)
    assert profile.logged_drift_c_per_min == pytest.approx(0.3, rel=1e-3)
    assert not profile.tank_logged  # a steady drift: nothing to take out
    prior = prior_from_profile(profile)
    assert prior.drift_prior_m_s_per_min == pytest.approx(0.3 * prior.sound_speed_slope_m_s_per_c)
    assert prior.values()[-7] == pytest.approx(prior.drift_prior_m_s_per_min)


def test_the_run_keeps_an_evenly_spaced_stretch_of_the_log() -> None:
    """The run's stretch of the log (a minute and a half either side, one reading more) stays
    evenly spaced, so that it is smoothed: no reading from the log's far end."""
    t = np.arange(0.0, 30.0, 0.05)
    from ucal.cell import TemperatureLog

    water = on_run(TemperatureLog(Path("t.csv"), t, 20.0 + 0.0 * t), 0.02, 5.0, 1.0)
    assert water is not None
    steps = np.diff(water.time_min)
    assert np.allclose(steps, 0.05)
    assert water.time_min[0] < -1.5 and water.time_min[-1] > 2.5
    assert water.time_min[-1] < 3.0


def test_the_log_is_read_again_as_the_logger_wrote_it_during_the_run(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """Read before anything moves, the log is read again when the run is solved: the rows the
    logger wrote since are there; a bad row written since keeps what was read, said."""
    from ucal.thermometer import again

    path = _write(tmp_path, "time,temperature_c\n2026-11-26T07:00:00Z,20.00\n")
    first = read_log(path)
    with path.open("a") as f:
        f.write("2026-11-26T07:00:03Z,20.01\n")
    assert again(first).temperature_c.tolist() == [20.0, 20.01]
    with path.open("a") as f:
        f.write("2026-11-26T07:00:06Z,twenty\n")
    with caplog.at_level(logging.WARNING):
        assert again(first) is first
    assert "row 4: expected an ISO 8601 time and °C" in caplog.text
    assert "the log as read before the run is used" in caplog.text


@pytest.mark.parametrize(
    "cut", ["2026-11-26T07:0", "2026-11-26T07:00:06Z,", "2026-11-26T07:00:06Z,2"]
)
def test_a_row_the_logger_is_still_writing_is_left_out(tmp_path: Path, cut: str) -> None:
    """The last line before its line end is a row being written: cut in its time, before its
    reading or in it (``2`` of ``21.40`` would read 2 °C), it is left out, before the run and
    when read again; once ended, it is read. A minutes log (not a logger's) keeps its last
    line."""
    from ucal.thermometer import again

    path = _write(tmp_path, f"time,temperature_c\n2026-11-26T07:00:00Z,21.38\n{cut}")
    first = read_log(path)
    assert first.temperature_c.tolist() == [21.38]
    with path.open("a") as f:
        f.write("2026-11-26T07:00:06Z,21.40\n"[len(cut) :])
    assert again(first).temperature_c.tolist() == [21.38, 21.40]
    assert read_log(_write(tmp_path, "time_min,temperature_c\n0,20\n1,21")).at(1.0) == 21.0


class _Logger:
    """A logger writing a row every ``every_s`` (``rows`` of them at first; its clock
    ``behind_s`` behind the host's) on a host clock that passes only when slept; ``writing``
    False: it has stopped."""

    def __init__(
        self,
        path: Path,
        rows: int,
        writing: bool = True,
        behind_s: float = 0.0,
        every_s: float = 2.0,
    ) -> None:
        self.path, self.writing, self.behind_s, self.every_s = path, writing, behind_s, every_s
        self.now_s = datetime(2026, 11, 26, 7, 0, tzinfo=UTC).timestamp()
        self.slept: list[float] = []
        path.write_text("time,temperature_c\n")
        for _ in range(rows):
            self.now_s += every_s
            self.row()
        self.next_row_s = self.now_s + every_s

    def row(self) -> None:
        stamp = self.now_s - self.behind_s  # the logger's own clock
        when = datetime.fromtimestamp(stamp, UTC).strftime("%Y-%m-%dT%H:%M:%SZ")
        with self.path.open("a") as f:
            f.write(f"{when},20.00\n")

    def sleep(self, seconds: float) -> None:
        self.slept.append(seconds)
        end_s = self.now_s + seconds
        while self.next_row_s <= end_s + 1e-6:
            self.now_s = self.next_row_s
            if self.writing:
                self.row()
            self.next_row_s += self.every_s
        self.now_s = max(self.now_s, end_s)


def test_a_live_log_is_read_once_it_has_logged_past_the_runs_end(tmp_path: Path) -> None:
    """The run's last reading at the log's last row: the log is read again once it reaches a
    quarter of a minute (half the smoothing window) past it, a row every 2 s."""
    from ucal.thermometer import awaited

    logger = _Logger(tmp_path / "t.csv", rows=6)
    first = read_log(logger.path)
    end_min = float(first.time_min[-1])
    told: list[str] = []
    log = awaited(first, end_min, lambda: logger.now_s, logger.sleep, told.append)
    assert 60.0 * (log.time_min[-1] - end_min) == pytest.approx(16.0)  # 15 s, then its row
    assert logger.slept == pytest.approx([2.0] * 8)  # each a logger's interval
    # the technician is told why the run has not ended, once
    assert len(told) == 1 and told[0].startswith("waiting up to 21 s for ")
    assert told[0].endswith("t.csv to log past the run's last reading (the robot has stopped)")


def test_a_logger_whose_clock_is_behind_the_hosts_is_waited_for(tmp_path: Path) -> None:
    """Its rows stamped 10 s behind the host's clock: the wait is timed on the host's clock,
    so the log still reaches a quarter of a minute past the run's last reading."""
    from ucal.thermometer import awaited

    logger = _Logger(tmp_path / "t.csv", rows=6, behind_s=10.0)
    first = read_log(logger.path)
    end_min = float(first.time_min[-1]) + 10.0 / 60.0  # the last reading, now on the host
    log = awaited(first, end_min, lambda: logger.now_s, logger.sleep)
    assert 60.0 * (log.time_min[-1] - end_min) == pytest.approx(16.0)


def test_a_stopped_logger_or_a_minutes_log_is_not_waited_for(tmp_path: Path) -> None:
    """A logger that has written no row for three of its intervals is not waited for longer,
    nor for more than a minute; a log in minutes of a simulated cell's clock (written before
    the run) not at all."""
    from ucal.thermometer import awaited

    logger = _Logger(tmp_path / "t.csv", rows=2, writing=False)
    first = read_log(logger.path)
    log = awaited(first, float(first.time_min[-1]), lambda: logger.now_s, logger.sleep)
    assert log.time_min.tolist() == first.time_min.tolist()
    slept = sum(logger.slept)
    assert 5.9 < slept < 8.1  # three intervals without a row (to a float's last bits): stopped
    slow = _Logger(tmp_path / "slow.csv", rows=2, writing=False, every_s=30.0)
    first = read_log(slow.path)
    awaited(first, float(first.time_min[-1]), lambda: slow.now_s, slow.sleep)
    assert sum(slow.slept) == pytest.approx(60.0, abs=0.01)  # a minute at most, not 90 s
    minutes = read_log(_write(tmp_path, "time_min,temperature_c\n0,20\n1,20\n"))
    assert awaited(minutes, 1.0, lambda: 0.0, logger.sleep).time_min.tolist() == [0.0, 1.0]
    assert sum(logger.slept) == slept
