"""The tank's sound speed within verify's run, from calibrate's readings read again (pure
functions).

``calibrate`` keeps the readings its fit received (``ucal.model.readings``): each water
path, where (joints), from which side and when it was read, and the sound speed the fit found
at that time. Verify reads one of them per face again, where it was read, at the start of its
run and at its end (``ucal.verify.measure``). The arm repeats a posture reached from the same
side to about 0.02 mm (``REPEAT_STD_MM``): the water path is the same, and the ratio of the
times of flight is the ratio of the sound speeds (``speed_from_repeats``). The start and the
end give the drift within the run; each verify reading's time places it on that line
(``TankEstimate.speed_at``), and its water path is converted with that speed
(``ucal.verify.measure.tank_corrected``).

A block that moved since changes the paths too, but not alike: a translation δ moves face k's
path by −n_k·δ, whatever its length, a sound speed change moves every path in proportion to
its length. The readings are fitted with one speed; a misfit beyond their noise
(``MOVED_P``) is not the water's: the set says so (``TankSet.moved``) and verify keeps the
promise of the speed's age (``ucal.verify.inputs.sound_speed_for_verify``). A translation
whose changes happen to be in proportion to the paths cannot be told from the water's; one
within the readings' noise moves each reading by no more than the arm's repeatability.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.special import chdtrc

from ucal.acoustics import sound_speed_m_s, temperature_for_speed_c
from ucal.cell import CellProfile
from ucal.model.geometry import FaceMeasurement
from ucal.model.readings import CalibrationReadings

#: One sigma of a water path read again at the same joints, each joint reached from the same
#: side (mm): the arm's repeatability, about 0.02 mm, taken as two sigma.
REPEAT_STD_MM = 0.01
#: Readings whose misfit to one sound speed is less likely than this (χ², n − 1 degrees of
#: freedom) changed otherwise than the water does: the block or the arm moved.
MOVED_P = 1e-3
#: The two moments of verify's run the readings are read at, in the order of its readings.
MOMENTS = ("start", "end")


@dataclass(frozen=True)
class TankSet:
    """What one set of calibrate's readings read again says (at verify's start or end).

    ``m_s``: the sound speed (m/s) the paths' ratio gives, one for every reading;
    ``std_m_s``: its one sigma from the readings' noise and the arm's repeatability (not the
    calibration's own std of the speed, common to both sets: ``TankEstimate``);
    ``misfit_mm``: each path's change that one speed does not explain.
    """

    time_min: float
    m_s: float
    std_m_s: float
    chi2: float
    dof: int
    misfit_mm: tuple[float, ...]

    @property
    def moved(self) -> bool:
        """The paths changed otherwise than one sound speed changes them (``MOVED_P``)."""
        # chdtrc(dof, x) is scipy.stats' chi2.sf(x, dof), without importing scipy.stats
        return self.dof > 0 and float(chdtrc(self.dof, self.chi2)) < MOVED_P

    def to_json(self) -> dict[str, Any]:
        return {
            "time_min": self.time_min,
            "sound_speed_m_s": self.m_s,
            "sound_speed_std_m_s": self.std_m_s,
            "chi2": self.chi2,
            "dof": self.dof,
            "misfit_mm": list(self.misfit_mm),
            "moved": self.moved,
        }


def speed_from_repeats(
    paths_then_mm: np.ndarray,
    paths_now_mm: np.ndarray,
    stds_mm: np.ndarray,
    conversion_m_s: float,
    time_min: float,
) -> TankSet:
    """The sound speed now from water paths read again where they were read.

    ``paths_then_mm`` (n,): the true paths (at the calibration's sound speed of their time);
    ``paths_now_mm`` (n,): the same paths read now, converted with ``conversion_m_s``, each of
    one sigma ``stds_mm`` (the arm's ``REPEAT_STD_MM`` is added). Converted at c_v, a path L
    read at the speed c reads ``L·c_v/c``: the weighted least squares of ``now = r·then`` gives
    ``r`` and ``c = c_v/r``, its misfit the χ² on n − 1 degrees of freedom.
    """
    then = np.asarray(paths_then_mm, float)
    now = np.asarray(paths_now_mm, float)
    var = np.asarray(stds_mm, float) ** 2 + REPEAT_STD_MM**2
    info = float(np.sum(then**2 / var))
    ratio = float(np.sum(then * now / var)) / info
    misfit = now - ratio * then
    c = conversion_m_s / ratio
    return TankSet(
        float(time_min),
        c,
        c / ratio / np.sqrt(info),  # |dc/dr|·σ_r = (c_v/r²)/√info
        float(np.sum(misfit**2 / var)),
        len(then) - 1,
        tuple(float(v) for v in misfit),
    )


def tank_set(
    reference: CalibrationReadings,
    again: tuple[FaceMeasurement, ...] | list[FaceMeasurement],
    conversion_m_s: float,
) -> TankSet:
    """What ``reference.faces`` read ``again`` (in their order, converted with
    ``conversion_m_s``) say of the tank's sound speed."""
    times = [m.time_min for m in again if m.time_min is not None]
    return speed_from_repeats(
        np.array([reference.path_mm(m) for m in reference.faces]),
        np.array([m.distance_mm for m in again]),
        np.array([m.distance_std_mm for m in again]),
        conversion_m_s,
        float(np.mean(times)) if times else 0.0,
    )


def start_speed(
    reference: CalibrationReadings, start: list[FaceMeasurement], profile: CellProfile
) -> tuple[float, float] | None:
    """The tank's sound speed (m/s) the start's readings give, and Marczak's temperature for
    it (°C): what the points' water paths are converted at (their paths read at the
    profile's ``[water] temperature_c``); None where they changed unlike the water."""
    conversion = float(sound_speed_m_s(profile.water_temperature_c))
    found = tank_set(reference, start, conversion)
    temperature = temperature_for_speed_c(found.m_s)
    return None if found.moved or temperature is None else (found.m_s, temperature)


@dataclass(frozen=True)
class TankEstimate:
    """The tank's sound speed over verify's run: the readings at its start and end, what the
    calibration's own speed leaves uncertain in both alike, and what a drift that is not
    steady may leave between them.

    ``common_std_m_s``: what the calibration's fitted drift leaves uncertain of its speed at
    the readings' times, carried to the speed now (both sets alike);
    ``calibration_std_m_s``: the calibration's std of its speed itself, carried to the speed
    now: in the speed's own std (``std_m_s``), not in what the water did since
    (``change_std_m_s``, verify's promise: a run right after the calibration has that std in
    ``MEASURED_WITHIN_MM``, set on such runs); ``curvature_std_m_s``: the drift turning by
    the profile's drift tolerance over the run
    (``ucal.model.least_squares.curvature_std_m_s_per_min2``: at most an eighth of the
    declared drift over the run from the line between the ends).
    """

    source: str
    readings: int  # calibrate's readings read again per set
    start: TankSet
    end: TankSet | None
    common_std_m_s: float
    curvature_std_m_s: float = 0.0
    calibration_std_m_s: float = 0.0
    #: the calibration's speed at its readings' mean time (m/s), and that time (min, its run's
    #: clock): the speed the paths' ratio is relative to
    then_m_s: float = float("nan")
    then_time_min: float | None = None

    @property
    def sets(self) -> tuple[TankSet, ...]:
        return (self.start,) if self.end is None else (self.start, self.end)

    @property
    def used(self) -> bool:
        """Every set is the water's: the paths are converted with it."""
        return not any(s.moved for s in self.sets)

    @property
    def seen(self) -> str:
        """What the readings read again saw, in words (``"sound speed"``: a change of the
        water's, or none; ``"moved"``: the paths changed unlike one)."""
        return "sound speed" if self.used else "moved"

    @property
    def extra_moves(self) -> int:
        """The moves verify added to read them."""
        return self.readings * len(self.sets)

    @property
    def drift_m_s_per_min(self) -> float:
        """The sound speed's drift within the run (m/s per min; 0 with one set)."""
        end = self.end
        if end is None or end.time_min <= self.start.time_min:
            return 0.0
        return (end.m_s - self.start.m_s) / (end.time_min - self.start.time_min)

    @property
    def drift_std_m_s_per_min(self) -> float | None:
        """One sigma of ``drift_m_s_per_min`` (None with one set)."""
        end = self.end
        if end is None or end.time_min <= self.start.time_min:
            return None
        return float(np.hypot(self.start.std_m_s, end.std_m_s)) / (
            end.time_min - self.start.time_min
        )

    def speed_at(self, time_min: float | None) -> float:
        """The tank's sound speed (m/s) at a reading's time (verify's run clock, min; the
        start's where unknown), on the line between the two sets."""
        if time_min is None:
            return self.start.m_s
        return self.start.m_s + self.drift_m_s_per_min * (time_min - self.start.time_min)

    @property
    def change_std_m_s(self) -> float:
        """One sigma of ``speed_at`` over the run about the calibration's speed carried by the
        paths' ratio: the sets' noise (the larger), the calibration's drift and the drift's
        curvature. What verify's promise adds for the water (``path_std_mm``)."""
        noise = max(s.std_m_s for s in self.sets)
        return float(np.sqrt(noise**2 + self.common_std_m_s**2 + self.curvature_std_m_s**2))

    @property
    def std_m_s(self) -> float:
        """One sigma of ``speed_at`` as a sound speed: ``change_std_m_s`` and the
        calibration's std of its own speed."""
        return float(np.hypot(self.change_std_m_s, self.calibration_std_m_s))

    @property
    def m_s(self) -> float:
        """The sound speed at the run's start (m/s)."""
        return self.start.m_s

    def path_std_mm(self, path_mm: float) -> float:
        """One sigma of a water path of ``path_mm`` from what the water did since the
        calibration (``change_std_m_s``; mm)."""
        return path_mm * self.change_std_m_s / self.m_s

    def to_json(self) -> dict[str, Any]:
        return {
            "source": self.source,
            "seen": self.seen,
            "used": self.used,
            "readings": self.readings,
            "extra_moves": self.extra_moves,
            "sound_speed_m_s": self.m_s,
            "sound_speed_std_m_s": self.std_m_s,
            "change_std_m_s": self.change_std_m_s,
            "calibrate_sound_speed_m_s": self.then_m_s,
            "calibrate_time_min": self.then_time_min,
            "drift_m_s_per_min": self.drift_m_s_per_min,
            "drift_std_m_s_per_min": self.drift_std_m_s_per_min,
            **{k: s.to_json() for k, s in zip(MOMENTS, self.sets, strict=False)},
        }


def estimate_tank(
    reference: CalibrationReadings,
    again: tuple[FaceMeasurement, ...],
    conversion_m_s: float,
    drift_tolerance_m_s_per_min: float = 0.0,
) -> TankEstimate:
    """The tank's sound speed over verify's run from ``again``: ``reference.faces`` read again
    at the start, then (if read) at the end, converted with ``conversion_m_s``;
    ``drift_tolerance_m_s_per_min``: the profile's (``[water] drift_std_c_per_min`` as m/s)."""
    n = len(reference.faces)
    sets = [
        tank_set(reference, again[k * n : (k + 1) * n], conversion_m_s)
        for k in range(len(again) // n)
    ]
    start = sets[0]
    end = sets[1] if len(sets) > 1 else None
    # what the calibration's drift leaves of its speed at the readings' times
    worst = max(
        reference.drift_std_at(m.time_min) / reference.speed_at(m.time_min) for m in reference.faces
    )
    span = 0.0 if end is None else end.time_min - start.time_min
    own = reference.sound_speed_std_m_s / reference.sound_speed_m_s
    stamps = [m.time_min for m in reference.faces if m.time_min is not None]
    then_time = float(np.mean(stamps)) if stamps else None
    return TankEstimate(
        reference.source,
        n,
        start,
        end,
        start.m_s * worst,
        drift_tolerance_m_s_per_min * span / 8.0,
        start.m_s * own if np.isfinite(own) else 0.0,
        reference.speed_at(then_time),
        then_time,
    )
