"""The tank's thermometer as a measurement of how the water changed during a run.

A tank with a logging thermometer gives its log to ``calibrate`` and ``tool-frame``
(``--thermometer FILE``, ``UCAL_THERMOMETER``). The file is the logger's CSV: a header, then one
reading a row, times strictly increasing, 0–60 °C (the sound speed's range); blank lines and
``#`` comments are skipped. The header names the time base:

* ``time,temperature_c``: wall-clock times, ISO 8601, as a logger writes them
  (``2026-11-26T07:31:02Z``, ``2026-11-26 08:31:02+01:00``; without a zone, the host's local
  time). A real cell's log. Its last line, until the logger has ended it, is a row still being
  written (cut off, ``20.1`` of ``20.13`` or ``2`` of ``21.40``): it is left out, and read when
  the log is read again.
* ``time_min,temperature_c``: minutes of the simulated cell's clock since it started, the time
  base of a world file's ``[water] temperature_log``: a rehearsal's thermometer on
  ``--sim WORLD`` (that clock is not the wall clock).

The file is read and checked before anything moves (a bad row, a time base that is not the
cell's, or a logger's log that is not being written by the host's clock, ``check_time_base``,
exits 2 naming the file), and read again when the run is solved (``again``): the logger
writes on during the run. A logger's is read again once it has logged half the smoothing
window past the run's last reading (``awaited``, a quarter of a minute after the robot stopped):
read at once, it would end at the run's last paths, and its course there would be extrapolated
from the readings before them: a heater's turn misread where the drift is read best
(``docs/benchmarks.md``).

What a thermometer measures is the tank's *change*, and what the water paths cannot see for
themselves is how that change turns during a run. The solvers fit the sound speed at the
middle of the run and a steady drift from the paths (a face read again, the steps, the wrist's
postures); a real tank does not drift steadily (it approaches the room's temperature, a heater
cycles), and without a log they can only carry that turn as an uncertainty
(``ucal.model.least_squares.curvature_std_m_s_per_min2``: a turn of the declared drift
tolerance over the run). The log measures it. Its absolute reading is off by its calibration
(``[water] temperature_std_c``, which the sound speed's prior keeps) and its probe sits
elsewhere in the tank than the beam, so only its departure from a straight line is taken.
The log's *course* is the log smoothed over ``SMOOTHING_MIN`` (a quadratic about each reading,
Savitzky–Golay: a heater's turn kept, the readings' noise and the logger's steps averaged);
with ``c_M`` Marczak's, ``T`` the course interpolated at a path's time ``t``, and ``a + b·(t −
t_ref)`` the straight line fitted to ``c_M(T(t_i))`` over the run's paths (``t_ref`` the time
the solvers give the sound speed at, the mean of the face readings' times),

    n(t) = c_M(T(t)) − a − b·(t − t_ref),     d' = d·(1 + n(t)/c_M(T(t)))

is the path ``d`` (read with the profile's speed) as the tank on that straight line would have
given it (``Thermometer.corrected``). The solvers then fit the sound speed and the steady drift
as before, with the declared drift tolerance as the drift's prior (the reported drift is the
tank's), and the turn they carry is what the thermometer leaves: a departure of ``σ_th`` =
``[water] thermometer_std_c`` (one sigma: its resolution, its lag, where its probe sits), a
curvature of 8·|dc/dT|·σ_th/D² over a run of D minutes where that is less than the declared
tolerance's (``CellProfile.tank_logged``, ``CellPrior.logged_departure_std_c``).

The course is taken out only where it sees a turn: where it departs from the straight line
by more than three times its own noise (``Thermometer.turns``; the noise from the log's second
differences, at least its resolution, through the smoothing). On a shorter or steadier run the
paths see the drift better than the log would, and correcting by the log would add its noise.
Where it is taken out, each path's std gains what the course's noise leaves in it.

A log that does not cover the run's readings (it starts after the first or ends before the last,
by more than ``EDGE_SLACK_MIN``) is not used: a warning names the file and the gap, and the run
is solved as without a thermometer (the readings are not lost for a late logger).
"""

from __future__ import annotations

import csv
import dataclasses
import functools
import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from ucal.acoustics import sound_speed_m_s, sound_speed_slope_m_s_per_c
from ucal.cell import CellProfile, TemperatureLog
from ucal.errors import InputError, ProfileError

log = logging.getLogger(__name__)

#: The headers a log may start with: minutes of a simulated cell's clock, or wall-clock times.
CELL_CLOCK_HEADER = ("time_min", "temperature_c")
WALL_CLOCK_HEADER = ("time", "temperature_c")
#: How far past the log's ends a reading may lie and still take the end's temperature (min).
EDGE_SLACK_MIN = 0.5
#: The log's course is the log smoothed over this window (min): a quadratic fitted about each
#: reading (Savitzky–Golay), which keeps a heater's turn and averages the reading noise.
SMOOTHING_MIN = 0.5
#: A departure from a straight line this small (°C) is no turn of the tank: it is what the
#: smoothing's arithmetic leaves on a log that does not change (10⁻¹³ °C on a log of one
#: value, where the log's noise is as small), far below any logger's resolution.
TURN_FLOOR_C = 1e-6
#: A logger's log is written during the run: before anything moves, its last row must lie no
#: more than this ahead of the host's clock (min), and no more than this (or three of its
#: intervals) behind it.
LIVE_AHEAD_MIN = 1.0
LIVE_AGE_MIN = 2.0
#: The longest wait (s) for a logger's log to pass the run's last reading (``awaited``).
WAIT_MAX_S = 60.0


def read_log(path: Path, context: str = "", wall_clock: bool = True) -> TemperatureLog:
    """A thermometer's log (module docstring); ``ProfileError`` (exit 2) names the file, the row
    and what is wrong, with ``context`` (where the file was named) appended. ``wall_clock``
    False: only minutes (a world file's log, whose first line may be left out)."""
    suffix = f" ({context})" if context else ""

    def bad(where: str | None, message: str) -> ProfileError:
        return ProfileError(path, where, message + suffix)

    try:
        text = path.read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as e:
        raise bad(None, f"cannot read: {getattr(e, 'strerror', None) or e}") from None
    headers = (CELL_CLOCK_HEADER, WALL_CLOCK_HEADER) if wall_clock else (CELL_CLOCK_HEADER,)
    expected = " or ".join(",".join(h) for h in headers)
    header: tuple[str, ...] | None = None if wall_clock else CELL_CLOCK_HEADER
    rows: list[tuple[float, float]] = []
    last = ""
    lines = text.splitlines()
    # a logger's last line without its line end is a row it is still writing
    unfinished = len(lines) if lines and not text.endswith(("\n", "\r")) else 0
    for lineno, fields in enumerate(csv.reader(lines), 1):
        cells = tuple(f.strip() for f in fields)
        if not "".join(cells) or cells[0].startswith("#"):
            continue  # blank lines and comments
        if not rows and cells in headers:
            header = cells
            continue
        if lineno == unfinished and header == WALL_CLOCK_HEADER:
            log.debug("%s: row %d is still being written: left out", path, lineno)
            continue
        if header is None:
            raise bad(f"row {lineno}", f"expected the header {expected}, got {','.join(cells)!r}")
        row = _row(cells, header == WALL_CLOCK_HEADER)
        if row is None:
            hint = f" (a header is {expected})" if not rows else ""
            what = (
                "an ISO 8601 time and °C"
                if header == WALL_CLOCK_HEADER
                else "two numbers, minutes and °C"
            )
            raise bad(f"row {lineno}", f"expected {what}, got {','.join(cells)!r}{hint}")
        t_min, temp_c = row
        if not (math.isfinite(t_min) and 0.0 <= temp_c <= 60.0):
            raise bad(
                f"row {lineno}",
                f"expected a finite time and 0-60 °C (the sound speed's range), got "
                f"{','.join(cells)!r}",
            )
        shown = cells[0] if header == WALL_CLOCK_HEADER else f"{t_min:g} min"
        if rows and not t_min > rows[-1][0]:
            raise bad(f"row {lineno}", f"times must increase: {shown} after {last}")
        rows.append((t_min, temp_c))
        last = shown
    if not rows:
        raise bad(None, f"no readings: expected rows of {expected}")
    table = np.array(rows)
    return TemperatureLog(path, table[:, 0], table[:, 1], header == WALL_CLOCK_HEADER)


def again(log_: TemperatureLog) -> TemperatureLog:
    """``log_`` read again from its file, as the logger has written it since (a run is solved
    after it measured; the file was read and checked before anything moved; the row the logger
    is writing is left out, ``read_log``). A file that no longer reads (a bad row written since)
    keeps what was read, with a warning naming it."""
    try:
        return read_log(log_.path, "--thermometer", wall_clock=log_.wall_clock)
    except ProfileError as e:
        log.warning("%s: the log as read before the run is used", e)
        return log_


def awaited(
    log_: TemperatureLog,
    last_read_min: float,
    now_s: Callable[[], float] = time.time,
    sleep: Callable[[float], None] = time.sleep,
    waiting: Callable[[str], None] | None = None,
) -> TemperatureLog:
    """``log_`` read again (``again``) once the logger has written half the smoothing window
    past the run's last reading (``last_read_min``, the log's time base): the log's course at
    the run's last paths is then smoothed about them as elsewhere, not extrapolated from the
    readings before them (a live log read at once ends at the run's last reading). A log on the
    simulated cell's clock, written before the run, is read at once. The wait is timed on the
    host's clock, not by the logger's stamps (its clock may be off the host's): it ends when
    the log has written no row for three of its intervals (stopped), or three intervals after
    the time the log needed to get there, at most ``WAIT_MAX_S``. ``waiting`` is told, in
    words, before a wait (the technician sees why the run has not ended)."""
    log_ = again(log_)
    if not log_.wall_clock or len(log_.time_min) < 2:
        return log_
    wanted = last_read_min + 0.5 * SMOOTHING_MIN
    interval_s = 60.0 * float(np.median(np.diff(log_.time_min)))
    limit_s = min(60.0 * (wanted - float(log_.time_min[-1])) + 3.0 * interval_s, WAIT_MAX_S)
    if log_.time_min[-1] < wanted:
        text = f"waiting up to {limit_s:.0f} s for {log_.path} to log past the run's last reading"
        log.info("%s", text)
        if waiting is not None:
            waiting(text + " (the robot has stopped)")
    started_s = row_s = now_s()
    while log_.time_min[-1] < wanted:
        left_s = limit_s - (now_s() - started_s)
        if now_s() - row_s > 3.0 * interval_s or left_s <= 0.0:
            log.info("%s: not logged past the run's last reading: its course ends there", log_.path)
            break
        sleep(min(interval_s, left_s))
        rows = len(log_.time_min)
        log_ = again(log_)
        if len(log_.time_min) > rows:
            row_s = now_s()
    return log_


def _row(cells: tuple[str, ...], wall_clock: bool) -> tuple[float, float] | None:
    """A row's time (minutes of its time base) and temperature, or None if malformed."""
    if len(cells) != 2:
        return None
    try:
        temp_c = float(cells[1])
        if not wall_clock:
            return float(cells[0]), temp_c
        when = datetime.fromisoformat(cells[0])
    except ValueError:
        return None
    return when.astimezone().timestamp() / 60.0, temp_c


@dataclass(frozen=True)
class Thermometer:
    """A thermometer's log on a run's own clock: what the solvers correct the water paths with.

    ``time_min`` (n,): minutes since the run's first reading (the readings' ``time_min``);
    ``temperature_c`` (n,); ``std_c``: ``[water] thermometer_std_c``; ``source``: the file;
    ``first_read_min``: where the run's first reading met the log, in the log's own time base
    (``TemperatureLog.time_min``: minutes since the Unix epoch where ``wall_clock``, else of
    the simulated cell's clock; None: not known, a record written before it was kept).
    """

    time_min: np.ndarray
    temperature_c: np.ndarray
    std_c: float
    source: str
    first_read_min: float | None = None
    wall_clock: bool = False

    def at(self, t_min: float) -> float:
        return float(np.interp(t_min, self.time_min, self.temperature_c))

    def change_c(self, start_min: float, end_min: float) -> float:
        """How much the log says the tank warmed (°C) from ``start_min`` to ``end_min``."""
        return self.at(end_min) - self.at(start_min)

    def corrected(self, data: Any) -> Any:
        """``data`` (a measure step's dataclass) with every water path taken to the tank on a
        straight line (module docstring), its std widened by what the log's own noise leaves
        in it (``noise_c``): each dataclass within it with a ``time_min`` and a path
        (``distance_mm`` and ``distance_std_mm``, or ``distance`` as (path, std)). Unchanged
        when the log turns no more than three times its noise over the run (``turns``)."""
        t_ref = _reference_time(data)
        if t_ref is None or not self.turns(data):
            return data
        times = _times(data)
        b, a = np.polyfit(times - t_ref, self.speeds_m_s(times), 1)
        noise_m_s = self.slope_m_s_per_c * self.course_noise_c(data)

        def factor(t: float) -> float:
            c = float(self.speeds_m_s(np.array([t]))[0])
            return float(1.0 + (c - a - b * (t - t_ref)) / c)

        return _corrected(data, factor, lambda d: d * noise_m_s / float(a))

    def turns(self, data: Any) -> bool:
        """Whether the log sees the tank turn during ``data``'s run: its course departs from a
        straight line by more than three times the course's own noise (and more than
        ``TURN_FLOOR_C``: a log of one value turns by the round-off of its smoothing, which its
        noise, as small, does not bound)."""
        departure = self.departure_c(data)
        return departure > TURN_FLOOR_C and departure > 3.0 * self.course_noise_c(data)

    def noise_c(self, data: Any) -> float:
        """One sigma of a logged reading about the tank's smooth course over ``data``'s run
        (°C): the scatter of the readings about the course within a minute of the run's paths
        (over √(1 − h), h the smoothing's own weight of a reading: a heater's turn is in the
        course, not in the scatter; a log not smoothed, its second differences' scatter over
        √6), at least the logger's resolution over √12."""
        lo, hi = _span(data)
        inside = (self.time_min >= lo - 1.0) & (self.time_min <= hi + 1.0)
        course, _, own = self._course
        residual = (self.temperature_c - course)[inside]
        if own < 1.0 and residual.size:
            scatter = float(np.sqrt(np.mean(residual**2) / (1.0 - own)))
        else:  # not smoothed: the second differences' scatter over √6
            temps = self.temperature_c[inside]
            scatter = float(np.std(np.diff(temps, 2)) / np.sqrt(6.0)) if temps.size > 3 else 0.0
        steps = np.abs(np.diff(np.unique(self.temperature_c)))
        resolution = float(np.min(steps)) if len(steps) else 0.0
        return float(max(scatter, resolution / np.sqrt(12.0)))

    def course_noise_c(self, data: Any) -> float:
        """One sigma of the log's course (``course_c``) over ``data``'s run (°C): the readings'
        noise through the smoothing."""
        return self.noise_c(data) * self._course[1]

    def course_c(self, t_min: np.ndarray) -> np.ndarray:
        """The tank's temperature (°C) at each of ``t_min`` as the log's course gives it: the
        log smoothed over ``SMOOTHING_MIN`` (as logged where its readings are too few or not
        evenly spaced), interpolated."""
        return np.asarray(np.interp(t_min, self.time_min, self._course[0]))

    @functools.cached_property
    def _course(self) -> tuple[np.ndarray, float, float]:
        """The smoothed log, the smoothing's noise gain and its weight of the reading it is
        centred on (1, 1: not smoothed; the scatter about the course then says nothing)."""
        raw = self.temperature_c
        step = np.diff(self.time_min)
        median = float(np.median(step)) if len(step) else 0.0
        if len(raw) < 5 or np.ptp(step) > 0.2 * median:
            return raw, 1.0, 1.0
        window = round(SMOOTHING_MIN / median) // 2 * 2 + 1
        window = min(window, len(raw) - (1 - len(raw) % 2))
        if window < 5:
            return raw, 1.0, 1.0
        from scipy.signal import savgol_coeffs, savgol_filter  # a second at import: when used

        coeffs = savgol_coeffs(window, 2)
        own = float(coeffs[window // 2])
        return savgol_filter(raw, window, 2), float(np.linalg.norm(coeffs)), own

    @property
    def slope_m_s_per_c(self) -> float:
        """|dc/dT| at the log's middle temperature (m/s per °C, Marczak)."""
        return abs(sound_speed_slope_m_s_per_c(float(np.median(self.temperature_c))))

    def speeds_m_s(self, t_min: np.ndarray) -> np.ndarray:
        """Marczak's sound speed (m/s) at the log's course at each of ``t_min``."""
        return np.asarray(sound_speed_m_s(self.course_c(t_min)))

    def departure_c(self, data: Any) -> float:
        """How far the log's course departs from a straight line over ``data``'s paths (°C,
        largest): the turn of the tank during the run that the log takes out."""
        times = _times(data)
        if len(times) < 2 or np.ptp(times) <= 0.0:
            return 0.0
        temps = self.course_c(times)
        line = np.polyval(np.polyfit(times, temps, 1), times)
        return float(np.max(np.abs(temps - line)))

    def profile(self, profile: CellProfile, data: Any) -> CellProfile:
        """``profile`` for ``data``'s paths once ``corrected``: the drift's prior mean the log's
        (``drift_c_per_min``), and where the log took the tank's turns out of the paths, a
        drift that turns no more than the thermometer allows (``CellProfile.tank_logged``)."""
        return dataclasses.replace(
            profile,
            tank_logged=self.turns(data),
            logged_drift_c_per_min=self.drift_c_per_min(data),
        )

    def drift_c_per_min(self, data: Any) -> float:
        """The tank's drift over ``data``'s paths as the log's course says (°C/min): the slope
        of the straight line through it at the paths' times (0 for paths at one time)."""
        times = _times(data)
        if len(times) < 2 or np.ptp(times) <= 0.0:
            return 0.0
        return float(np.polyfit(times, self.course_c(times), 1)[0])

    def summary(self, data: Any) -> dict[str, Any]:
        """What the log said of the run whose readings are ``data`` (``--json``'s
        ``thermometer``): the file, the tank's change over the readings (°C), its drift
        (``drift_c_per_min``, the drift's prior mean), how far it turned
        from a straight line (``departure_c``) against the log's own noise (``noise_c``),
        whether the paths were corrected (``applied``: ``turns``), the readings' span (min),
        ``std_c``; where the log met the run's first reading, in the log's time
        (``first_reading``: ISO 8601 UTC for a logger's wall-clock times; ``first_reading_min``:
        minutes of a simulated cell's clock)."""
        start, end = _span(data)
        return {
            "file": self.source,
            **self._first_reading(),
            "change_c": round(self.change_c(start, end), 4),
            "drift_c_per_min": round(self.drift_c_per_min(data), 5),
            "departure_c": round(self.departure_c(data), 4),
            "noise_c": round(self.course_noise_c(data), 4),
            "applied": self.turns(data),
            "span_min": round(end - start, 3),
            "std_c": self.std_c,
        }

    def _first_reading(self) -> dict[str, Any]:
        """``summary``'s ``first_reading`` or ``first_reading_min`` (none when not known)."""
        if self.first_read_min is None:
            return {}
        if not self.wall_clock:
            return {"first_reading_min": round(self.first_read_min, 4)}
        when = datetime.fromtimestamp(self.first_read_min * 60.0, UTC)
        return {"first_reading": when.isoformat(timespec="milliseconds")}

    def as_json(self) -> dict[str, Any]:
        """The thermometer as a record's session line holds it."""
        return {
            "time_min": self.time_min.tolist(),
            "temperature_c": self.temperature_c.tolist(),
            "std_c": self.std_c,
            "source": self.source,
            "first_read_min": self.first_read_min,
            "wall_clock": self.wall_clock,
        }

    @classmethod
    def from_json(cls, obj: dict[str, Any]) -> Thermometer:
        first = obj.get("first_read_min")
        return cls(
            np.asarray(obj["time_min"], float),
            np.asarray(obj["temperature_c"], float),
            float(obj["std_c"]),
            str(obj["source"]),
            None if first is None else float(first),
            bool(obj.get("wall_clock", False)),
        )


def on_run(
    log_: TemperatureLog,
    std_c: float,
    first_read_min: float,
    span_min: float,
) -> Thermometer | None:
    """``log_`` on a run's clock: ``first_read_min`` is the run's first reading in the log's
    time base (wall-clock minutes since the epoch, or the simulated cell's minutes since it
    started), ``span_min`` the run's readings' span. None, with a warning naming the file and
    the gap, when the log does not cover the readings (module docstring)."""
    t = log_.time_min - first_read_min
    before = float(t[0])  # > 0: the log starts after the first reading
    after = span_min - float(t[-1])  # > 0: it ends before the last
    if before > EDGE_SLACK_MIN or after > EDGE_SLACK_MIN:
        gap = (
            f"it starts {before:.1f} min after the run's first reading"
            if before > EDGE_SLACK_MIN
            else f"it ends {after:.1f} min before the run's last reading"
        )
        log.warning(
            "%s does not cover the run (%s): the tank's drift is fitted without it",
            log_.path,
            gap,
        )
        return None
    # the readings within a minute and a half of the run, and one more each side to interpolate
    near = np.flatnonzero((t >= -EDGE_SLACK_MIN - 1.0) & (t <= span_min + EDGE_SLACK_MIN + 1.0))
    lo, hi = (max(near[0] - 1, 0), min(near[-1] + 2, len(t))) if near.size else (0, len(t))
    return Thermometer(
        t[lo:hi],
        log_.temperature_c[lo:hi],
        float(std_c),
        str(log_.path),
        float(first_read_min),
        log_.wall_clock,
    )


def check_time_base(
    log_: TemperatureLog, simulated: bool, now_s: Callable[[], float] = time.time
) -> None:
    """Refuse, before anything moves, a log whose time base is not the cell's: a simulated cell
    runs on its own clock (minutes, ``time_min``), a real one on the wall clock (``time``); and
    a logger's log that is not being written now by the host's clock (``now_s``), its last row
    more than ``LIVE_AHEAD_MIN`` ahead of it (a time zone, or the logger's clock) or more than
    ``LIVE_AGE_MIN`` (or three of its intervals) behind it (a logger not writing, or a time
    zone): such a log could not cover the run (``InputError``, exit 2, naming the file)."""
    if log_.wall_clock and not simulated:
        _check_live(log_, now_s() / 60.0)
    if log_.wall_clock == simulated:
        raise InputError(
            f"{log_.path}: "
            + (
                "wall-clock times (column time), but the simulated cell runs on its own clock: "
                "give its log in minutes since the cell started (column time_min)"
                if simulated
                else "minutes of a simulated cell's clock (column time_min), but this cell runs "
                "on the wall clock: give the logger's times (column time, ISO 8601)"
            )
        )


def _check_live(log_: TemperatureLog, now_min: float) -> None:
    """``check_time_base``'s refusal of a logger's log that is not being written at ``now_min``."""
    last = float(log_.time_min[-1])
    steps = np.diff(log_.time_min)
    age_min = max(LIVE_AGE_MIN, 3.0 * float(np.median(steps))) if len(steps) else LIVE_AGE_MIN
    if -LIVE_AHEAD_MIN <= now_min - last <= age_min:
        return
    offset = datetime.now().astimezone().strftime("%z")
    where = (
        f"ahead of this host's clock by {last - now_min:.1f} min"
        if last > now_min
        else f"{now_min - last:.1f} min old by this host's clock"
    )
    raise InputError(
        f"{log_.path}: its last row is {where}: the log must be written during the run "
        f"(is the logger writing, its clock set? a time without a zone is this host's local "
        f"time, UTC{offset[:3]}:{offset[3:]})"
    )


def reading_span_min(data: Any) -> float:
    """The span (min) of the water paths' times within a measure step's ``data``."""
    start, end = _span(data)
    return end - start


def last_reading_min(data: Any) -> float:
    """The last water path's time within ``data`` (min since the run's first reading)."""
    return _span(data)[1]


def _reference_time(data: Any) -> float | None:
    """The time the solvers give the sound speed at (``reference_time_min``): the mean time of
    the first list of water paths in ``data`` (the faces; a full level's steps are referred to
    their time too; tool-frame's peaks); None when no path has a time."""
    if not dataclasses.is_dataclass(data) or isinstance(data, type):
        return None
    for f in dataclasses.fields(data):
        value = getattr(data, f.name)
        if isinstance(value, list | tuple) and value and _is_path_reading(value[0]):
            times = _times(value)
            if times.size:
                return float(np.mean(times))
    return None


def _is_path_reading(data: Any) -> bool:
    """Whether ``data`` is a dataclass instance that holds one water path and its time."""
    if not dataclasses.is_dataclass(data) or isinstance(data, type):
        return False
    names = {f.name for f in dataclasses.fields(data)}
    return "time_min" in names and bool({"distance_mm", "distance"} & names)


def _times(data: Any) -> np.ndarray:
    """The ``time_min`` of every water path within ``data`` that has one (min)."""
    return np.array([t for t in _each_time(data) if t is not None], float)


def _span(data: Any) -> tuple[float, float]:
    """The first and the last water path's time within ``data`` (min; 0, 0 without one)."""
    times = _times(data)
    return (float(times.min()), float(times.max())) if times.size else (0.0, 0.0)


def _each_time(data: Any) -> list[float | None]:
    """Every water path's ``time_min`` within ``data`` (None where it has none)."""
    if isinstance(data, list | tuple):
        return [t for v in data for t in _each_time(v)]
    if _is_path_reading(data):
        return [data.time_min]
    if not dataclasses.is_dataclass(data) or isinstance(data, type):
        return []
    return [t for f in dataclasses.fields(data) for t in _each_time(getattr(data, f.name))]


def _corrected(
    data: Any, factor: Callable[[float], float], std_mm: Callable[[float], float]
) -> Any:
    """``Thermometer.corrected`` below the top: lists, tuples and dataclasses rebuilt, each
    water path ``d`` at ``t`` made ``d·factor(t)``, ``std_mm(d)`` added to its std in
    quadrature."""
    if isinstance(data, list | tuple):
        return type(data)(_corrected(v, factor, std_mm) for v in data)
    if _is_path_reading(data):
        t = data.time_min
        if t is None:
            return data
        k = factor(t)
        if hasattr(data, "distance_mm"):
            d, s = data.distance_mm, data.distance_std_mm
            return dataclasses.replace(
                data, distance_mm=d * k, distance_std_mm=math.hypot(s, std_mm(d))
            )
        if data.distance is None:
            return data
        d, s = data.distance
        return dataclasses.replace(data, distance=(d * k, math.hypot(s, std_mm(d))))
    if not dataclasses.is_dataclass(data) or isinstance(data, type):
        return data
    changes = {
        f.name: _corrected(getattr(data, f.name), factor, std_mm)
        for f in dataclasses.fields(data)
        if f.init
    }
    return dataclasses.replace(data, **changes)
