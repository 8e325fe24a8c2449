"""The profile's ``[calibration]`` table as a typed record: what ``calibrate`` wrote, read back
by the commands that build on it.

``calibrate`` writes the offsets, their one-sigma and the joints the data could not determine
(which every command's kinematics uses, ``ucal.profile.read``), and beside them what a later
command takes over: how J1 was gauged (``gauge``: "block", relative to the block as placed, or
"base"), the sound speed the fit found in the tank (``sound_speed_m_s``), what the DH
quantities no posture identifies leave in the tool centre over the scanning region
(``unidentified_tcp_mm``: mean, max, one sigma), and when (``date``). Each key is checked
where the profile is read (``read_calibration``, called by ``profile_from_data``): a value of
the wrong type or out of range stops every command before anything moves, with the file and
the key named (exit 2), instead of being taken as absent by the command that needed it.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path
from typing import Any, Literal

from ucal.profile.validation import Reader, read_toml

#: How J1 was calibrated (``ucal.model.gauge``).
GAUGES = ("block", "base")


@dataclass(frozen=True)
class CalibrationRecord:
    """What a later command reads of ``[calibration]`` besides the offsets; None: not written."""

    gauge: Literal["block", "base"] | None = None
    sound_speed_m_s: float | None = None
    unidentified_tcp_mm: tuple[float, float] | None = None
    date: str | None = None


def written_stds(values: Sequence[float]) -> list[float]:
    """Stds as the profile holds them: rounded, −1 where not determined (NaN)."""
    return [round(float(v), 6) if math.isfinite(v) else -1.0 for v in values]


@dataclass(frozen=True)
class WrittenCalibration:
    """The ``[calibration]`` table one ``calibrate`` run writes (SPEC.md), in the profile's
    units and roundings: the offsets and their one-sigma (NaN: not determined, written −1),
    the joints the data could not determine (1-based), relative to the block as placed where
    ``gauge`` says so, the sound speed and its drift, each joint's lost motion (NaN: not
    measured), the fit, and the level's own keys (the offsets level's condition number, the
    full level's identified table and its stds)."""

    level: Literal["offsets", "full"]
    joint_offsets_deg: Sequence[float]
    std_deg: Sequence[float]
    unobservable_joints: Sequence[int]
    method: str
    approach: str
    sound_speed_m_s: float
    fit_verdict: str
    chi2_reduced: float
    date: str
    gauge: str | None = None
    gauge_note: str | None = None
    std_block_deg: Sequence[float] | None = None
    backlash_deg: Sequence[float] | None = None
    backlash_std_deg: Sequence[float] | None = None
    sound_speed_drift_m_s_per_min: float | None = None
    sound_speed_drift_m_s_per_min_std: float | None = None
    condition_number: float | None = None
    dh: Sequence[Mapping[str, float]] | None = None
    dh_std: Sequence[Mapping[str, float]] | None = None
    unidentified_tcp_mm: tuple[float, float] | None = None
    #: The readings whose gravity load the offsets hold (``ucal.profile.arm_load``).
    load_posture_deg: Sequence[float] | None = None
    #: Each joint's stiffness the full level identified and its one sigma (N·m/rad, −1 where
    #: not determined: ``ucal.model.stiffness.written_stiffness``).
    stiffness: tuple[Sequence[float], Sequence[float]] | None = None

    def table(self) -> dict[str, Any]:
        """The table's keys and values, in the order a new profile shows them."""
        keys: dict[str, Any] = {
            "joint_offsets_deg": [round(float(v), 6) for v in self.joint_offsets_deg],
            "unobservable_joints": [int(j) for j in self.unobservable_joints],
            "method": self.method,
            "std_deg": written_stds(self.std_deg),
            "approach": self.approach,
        }
        if self.gauge is not None and self.std_block_deg is not None:
            keys |= {
                "std_block_deg": written_stds(self.std_block_deg),
                "gauge": self.gauge,
                "gauge_note": self.gauge_note,
            }
        if self.backlash_deg is not None and self.backlash_std_deg is not None:
            assert self.sound_speed_drift_m_s_per_min is not None
            assert self.sound_speed_drift_m_s_per_min_std is not None
            keys |= {
                "backlash_deg": written_stds(self.backlash_deg),
                "backlash_std_deg": written_stds(self.backlash_std_deg),
                "sound_speed_drift_m_s_per_min": round(self.sound_speed_drift_m_s_per_min, 5),
                "sound_speed_drift_m_s_per_min_std": round(
                    self.sound_speed_drift_m_s_per_min_std, 5
                ),
            }
        keys |= {
            "sound_speed_m_s": round(float(self.sound_speed_m_s), 3),
            "fit_verdict": self.fit_verdict,
            "chi2_reduced": round(float(self.chi2_reduced), 4),
            "date": self.date,
            "level": self.level,
        }
        if self.condition_number is not None:
            keys["condition_number"] = round(float(self.condition_number), 3)
        if self.dh is not None:
            keys["dh"] = [dict(row) for row in self.dh]
        if self.dh_std is not None:
            keys["dh_std"] = [dict(row) for row in self.dh_std]
        if self.unidentified_tcp_mm is not None:
            mean, most = self.unidentified_tcp_mm
            keys["unidentified_tcp_mm"] = [round(mean, 4), round(most, 4)]
        if self.load_posture_deg is not None:
            keys["load_posture_deg"] = [round(float(v), 6) for v in self.load_posture_deg]
        if self.stiffness is not None:
            k, std = self.stiffness
            keys["stiffness_nm_per_rad"] = [float(v) for v in k]
            keys["stiffness_std_nm_per_rad"] = [float(v) for v in std]
        return keys


def read_calibration(r: Reader, cal: Mapping[str, Any] | None) -> CalibrationRecord:
    """The record of the ``[calibration]`` table ``cal`` (None: no table), every key checked."""
    if cal is None:
        return CalibrationRecord()
    gauge: Literal["block", "base"] | None = None
    v = r.get(cal, "calibration.gauge")
    if v is not None:
        if v not in GAUGES:
            raise r.error("calibration.gauge", f'must be "block" or "base", got {v!r}')
        gauge = "block" if v == "block" else "base"
    speed = None
    v = r.get(cal, "calibration.sound_speed_m_s")
    if v is not None:
        speed = r.number("calibration.sound_speed_m_s", v, lo=1300.0, hi=1700.0, unit="m/s")
    budget = None
    v = r.get(cal, "calibration.unidentified_tcp_mm")
    if v is not None:
        mean, most = (
            r.number("calibration.unidentified_tcp_mm", x, lo=0.0, unit="mm")
            for x in r.array("calibration.unidentified_tcp_mm", v, 2)
        )
        budget = (mean, most)
    date = None
    v = r.get(cal, "calibration.date")
    if v is not None:
        date = str(v.isoformat() if isinstance(v, datetime) else r.string("calibration.date", v))
        try:
            datetime.fromisoformat(date)
        except ValueError:
            raise r.error("calibration.date", f"must be an ISO 8601 time, got {v!r}") from None
    return CalibrationRecord(gauge, speed, budget, date)


def calibration_record(path: str | Path) -> CalibrationRecord:
    """The ``[calibration]`` record of the profile at ``path`` (``ProfileError``, exit 2,
    naming the file and key where the file or a key is bad)."""
    r = Reader(path, read_toml(path).unwrap())
    return read_calibration(r, r.table("calibration"))
