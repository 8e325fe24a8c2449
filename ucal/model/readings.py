"""Face readings as the profile's history keeps them, and calibrate's beside its write.

A face measurement (``ucal.model.geometry.FaceMeasurement``) as JSON: its posture, where and
when its water path was read, from which side each joint came (``faces_to_json``,
``faces_from_json``). ``check`` keeps its own in ``checks.json`` (``ucal.check.history``);
``calibrate`` keeps the readings its fit received in ``NNNN-readings.json``, beside the history
copy ``NNNN-before.toml`` of the write they produced (``write_readings``), with the sound speed
the fit found for them (``ucal.calibration.result.calibration_readings``): a later command
that reads a water path again where calibrate read it
(same joints, same side: the arm repeats to hundredths of a mm) learns the tank's sound speed
now from the ratio of the two (``ucal.verify.tank``).

The file is written after the profile, under the run's lock; a file that cannot be written
costs the later commands that comparison, not the calibration (a warning).
"""

from __future__ import annotations

import json
import logging
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ucal import files
from ucal.errors import ProfileError
from ucal.model.geometry import FaceMeasurement
from ucal.profile import HistoryEntry, history_dir

log = logging.getLogger(__name__)

#: The suffix of calibrate's readings beside its history entry (``NNNN`` its id).
READINGS_SUFFIX = "-readings.json"


def number(value: float | None) -> float | None:
    """A JSON number, or null for what is not one (NaN, ±inf)."""
    return None if value is None or not np.isfinite(value) else float(value)


def faces_to_json(faces: Sequence[FaceMeasurement]) -> list[dict[str, Any]]:
    """Face measurements as a history entry keeps them: what the solver receives, with each
    reading's time and approach (the drift and the lost motion the solver sees)."""
    return [
        {
            "config": str(m.config),
            "face": int(m.face),
            "joints_deg": [float(v) for v in m.joints_deg],
            "distance_mm": float(m.distance_mm),
            "distance_std_mm": float(m.distance_std_mm),
            "tilt_std_deg": float(m.tilt_std_deg),
            "amplitude": number(m.amplitude),
            "gain_db": None if m.gain_db is None else float(m.gain_db),
            "distance_joints_deg": (
                None if m.distance_joints_deg is None else [float(v) for v in m.distance_joints_deg]
            ),
            "time_min": None if m.time_min is None else float(m.time_min),
            "approach": None if m.approach is None else [float(v) for v in m.approach],
        }
        for m in faces
    ]


def faces_from_json(rows: list[dict[str, Any]]) -> list[FaceMeasurement]:
    """The face measurements of a history entry."""
    return [
        FaceMeasurement(
            r["config"],
            r["face"],
            np.asarray(r["joints_deg"], float),
            float(r["distance_mm"]),
            float(r["distance_std_mm"]),
            float(r["tilt_std_deg"]),
            float("nan") if r["amplitude"] is None else float(r["amplitude"]),
            None if r["distance_joints_deg"] is None else np.asarray(r["distance_joints_deg"]),
            gain_db=r["gain_db"],
            # an entry written before they were kept: no time (no drift seen), from below
            time_min=None if r.get("time_min") is None else float(r["time_min"]),
            approach=None if r.get("approach") is None else np.asarray(r["approach"], float),
        )
        for r in rows
    ]


@dataclass(frozen=True)
class CalibrationReadings:
    """The readings a calibration's fit received and the sound speed it found for them.

    Each reading's water path was converted with ``conversion_m_s`` (Marczak's at the
    profile's ``[water] temperature_c`` then); the fit's sound speed at a reading's time ``t``
    is ``sound_speed_m_s + drift_m_s_per_min·(t − time_ref_min)``, so its true water path is
    ``distance_mm`` times that over ``conversion_m_s`` (``path_mm``).
    """

    faces: tuple[FaceMeasurement, ...]
    conversion_m_s: float
    sound_speed_m_s: float
    sound_speed_std_m_s: float
    drift_m_s_per_min: float
    drift_std_m_s_per_min: float
    time_ref_min: float
    source: str = ""  # the history entry, in words

    def speed_at(self, time_min: float | None) -> float:
        """The fit's sound speed (m/s) at a reading's time (its reference time if None)."""
        if time_min is None or not np.isfinite(self.drift_m_s_per_min):
            return self.sound_speed_m_s
        return self.sound_speed_m_s + self.drift_m_s_per_min * (time_min - self.time_ref_min)

    def drift_std_at(self, time_min: float | None) -> float:
        """One sigma of ``speed_at`` about the fit's speed at its reference time (m/s): its
        drift's std over the time between."""
        d_std = self.drift_std_m_s_per_min if np.isfinite(self.drift_std_m_s_per_min) else 0.0
        return 0.0 if time_min is None else abs(d_std * (time_min - self.time_ref_min))

    def path_mm(self, m: FaceMeasurement) -> float:
        """The true water path (mm) of reading ``m`` at the fit's sound speed of its time."""
        return m.distance_mm * self.speed_at(m.time_min) / self.conversion_m_s

    def to_json(self) -> dict[str, Any]:
        return {
            "faces": faces_to_json(self.faces),
            "conversion_m_s": self.conversion_m_s,
            "sound_speed_m_s": self.sound_speed_m_s,
            "sound_speed_std_m_s": number(self.sound_speed_std_m_s),
            "drift_m_s_per_min": number(self.drift_m_s_per_min),
            "drift_std_m_s_per_min": number(self.drift_std_m_s_per_min),
            "time_ref_min": self.time_ref_min,
        }

    @classmethod
    def from_json(cls, data: dict[str, Any], source: str = "") -> CalibrationReadings:
        def value(key: str) -> float:
            v = data.get(key)
            return float("nan") if v is None else float(v)

        return cls(
            tuple(faces_from_json(data["faces"])),
            float(data["conversion_m_s"]),
            float(data["sound_speed_m_s"]),
            value("sound_speed_std_m_s"),
            value("drift_m_s_per_min"),
            value("drift_std_m_s_per_min"),
            float(data["time_ref_min"]),
            source,
        )


def readings_path(profile_path: str | Path, entry: HistoryEntry) -> Path:
    """Where the readings of the calibrate write ``entry`` are kept."""
    return history_dir(profile_path) / f"{entry.id:04d}{READINGS_SUFFIX}"


def write_readings(
    profile_path: str | Path, entry: HistoryEntry, readings: CalibrationReadings
) -> None:
    """Keep ``readings`` beside the history entry of the write they produced (atomically; a
    failure is logged, the calibration stands)."""
    path = readings_path(profile_path, entry)
    text = json.dumps(readings.to_json(), indent=1, allow_nan=False) + "\n"
    try:
        files.commit(files.stage(path, text.encode("utf-8")), path)
    except OSError as e:
        log.warning("%s: not written (%s): verify will not read the tank again", path, e)


def read_readings(profile_path: str | Path, entry: HistoryEntry) -> CalibrationReadings | None:
    """The readings of the calibrate write ``entry``; None where it kept none."""
    path = readings_path(profile_path, entry)
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        return None
    except (OSError, ValueError) as e:
        raise ProfileError(path, None, f"unreadable calibration readings: {e}") from None
    try:
        return CalibrationReadings.from_json(data, f"history entry {entry.id} ({entry.time})")
    except (KeyError, TypeError, ValueError) as e:
        raise ProfileError(path, None, f"unreadable calibration readings: {e}") from None
