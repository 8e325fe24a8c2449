"""What verify reads from the profile's files beside its model: the offsets and block pose it had
before its last calibration (its history), the sound speed that calibration measured and the
readings it measured it at (to read the tank again), and how it calibrated J1 (the gauge the
figures are relative to)."""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from ucal.acoustics import sound_speed_m_s, temperature_for_speed_c
from ucal.cell import CellProfile
from ucal.model.geometry import FaceMeasurement
from ucal.model.priors import prior_from_profile
from ucal.model.readings import CalibrationReadings, read_readings
from ucal.profile import HistoryEntry, history_dir, load_profile, profile_history
from ucal.profile.calibration import calibration_record


@dataclass(frozen=True)
class BeforeProfile:
    """The "before" pass: the offsets and the block pose the profile had before its last
    calibration, and where they come from."""

    offsets_deg: np.ndarray
    source: str
    #: the block's corner (mm) and orientation (deg) then, base frame; None: the current ones
    sample_position_mm: np.ndarray | None = None
    sample_rotation_deg: np.ndarray | None = None

    def placed(self, profile: CellProfile) -> CellProfile:
        """``profile`` with the block where it was before the calibration (``calibrate``
        writes the block it measured)."""
        if self.sample_position_mm is None or self.sample_rotation_deg is None:
            return profile
        return profile.replace(
            sample_position_mm=self.sample_position_mm,
            sample_rotation_deg=self.sample_rotation_deg,
        )

    def same_as(self, profile: CellProfile) -> bool:
        """True when "before" is the profile as it is: both passes command the same points."""
        placed = self.placed(profile)
        return bool(
            np.allclose(self.offsets_deg, profile.joint_offsets_deg, rtol=0.0, atol=1e-9)
            and np.allclose(placed.sample_matrix, profile.sample_matrix, rtol=0.0, atol=1e-9)
        )


def offsets_before_calibration(profile_path: str | Path) -> BeforeProfile:
    """The joint offsets and the block pose of the profile as it was before its last
    ``calibrate`` write (its history); zero offsets and the current block when the history
    holds none (a profile calibrated by hand, or never)."""

    entry = last_calibration(profile_path)
    if entry is not None:
        before = history_dir(profile_path) / entry.before
        if before.exists():
            old = load_profile(before, base_dir=Path(profile_path).parent)
            return BeforeProfile(
                np.asarray(old.joint_offsets_deg, float),
                f"history entry {entry.id} ({entry.time}): the profile "
                "before its last calibration (its offsets and block pose)",
                np.asarray(old.sample_position_mm, float),
                np.asarray(old.sample_rotation_deg, float),
            )
    return BeforeProfile(np.zeros(6), "no calibration in the profile's history: zero offsets")


@dataclass(frozen=True)
class SoundSpeed:
    """The sound speed verify converts times of flight with, and where it comes from.

    ``std_m_s``: one sigma of the tank's sound speed now about ``m_s``. The calibration
    measured it ``age_min`` minutes ago; since, the tank may have warmed or cooled by the
    profile's drift tolerance a minute (``[water] drift_std_c_per_min``), at most by its
    thermometer's tolerance (``temperature_std_c``: the water is no further from what the
    profile says than that). A water path of ``d`` mm read with a sound speed off by δc is off
    by ``d·δc/c``: 0.3 mm at a wall's 150 mm for 1 °C. 0: not stated (a record made before).
    """

    m_s: float
    temperature_c: float  # the water temperature Marczak's c(T) gives it at
    source: str
    std_m_s: float = 0.0
    age_min: float | None = None

    def path_std_mm(self, path_mm: float) -> float:
        """One sigma of a water path of ``path_mm`` from ``std_m_s`` (mm)."""
        return path_mm * self.std_m_s / self.m_s if self.m_s > 0.0 else 0.0


@dataclass(frozen=True)
class VerifyGauge:
    """What verify's figures are relative to, and what that leaves known in the robot's base
    frame (``ucal.model.gauge``).

    Every deviation is measured against the block's faces (the water paths and the edges):
    it says where the tool is relative to the block. ``calibrate`` gives J1 relative to the
    block as placed (``[calibration] gauge = "block"``), so in the base frame the points are
    where the profile puts them only to the block's yaw tolerance times their distance from
    the base axis; with a doweled block (``"base"``) that is small.
    """

    j1: str | None  # [calibration] gauge as calibrate wrote it; None: not written
    yaw_std_deg: float  # [sample] rotation_std_deg[2]
    reach_mm: float = 0.0  # the points' largest distance from the base axis

    @property
    def absolute_std_mm(self) -> float | None:
        """One sigma of the points' position in the base frame from the block's yaw (mm);
        None when the profile does not say how J1 was calibrated."""
        if self.j1 is None:
            return None
        return self.reach_mm * math.radians(self.yaw_std_deg)

    def statement(self) -> str:
        """The gauge in words (``gauge_note`` in ``--json``)."""
        text = (
            "positions relative to the block (gauge: block): every deviation is measured "
            "against the block's faces, which is what a scan of a part located from the block "
            "needs"
        )
        absolute = self.absolute_std_mm
        if self.j1 == "block" and absolute is not None:
            text += (
                f"; J1 is calibrated relative to the block as placed, so in the robot's base "
                f"frame the points are where the profile puts them only to ±{absolute:.1f} mm "
                f"(one sigma: the block's yaw as placed, ±{self.yaw_std_deg:g}°, at "
                f"{self.reach_mm:.0f} mm from the base axis); a doweled, levelled block makes "
                "them absolute"
            )
        elif self.j1 == "base" and absolute is not None:
            text += (
                f"; J1 is absolute (the block's yaw declared to ±{self.yaw_std_deg:g}°): in the "
                f"robot's base frame too, to ±{absolute:.2f} mm"
            )
        return text


def calibration_gauge(profile: CellProfile, profile_path: str | Path) -> VerifyGauge:
    """How the profile's J1 was calibrated (``[calibration] gauge``, written by ``calibrate``)
    and the block's yaw tolerance."""
    yaw = float(np.broadcast_to(profile.sample_rotation_std_deg, 3)[2])
    return VerifyGauge(calibration_record(profile_path).gauge, yaw)


def sound_speed_for_verify(
    profile: CellProfile, profile_path: str | Path, now: datetime | None = None
) -> SoundSpeed:
    """The sound speed ``calibrate`` measured with the offsets (``[calibration]
    sound_speed_m_s``), else Marczak's at the profile's ``[water] temperature_c``, with what
    the tank may have done since (``SoundSpeed.std_m_s``; ``now``: the time of the check).

    The thermometer's tolerance (±2 °C, 6 m/s) is 0.4 % of every water path: 0.6 mm at the
    150 mm of a wall, different at every point; the calibration's fitted speed is known to
    tenths of a m/s when it is measured, and as the tank warms or cools after (0.05 °C a minute,
    the default drift tolerance, is 0.15 m/s a minute: 0.3 mm on a wall within the hour).
    """

    temp = float(profile.water_temperature_c)
    now = datetime.now(UTC) if now is None else now
    measured = calibration_record(profile_path).sound_speed_m_s
    prior = prior_from_profile(profile)
    if measured is not None:
        c = measured
        t_eq = temperature_for_speed_c(c)
        if t_eq is not None:
            age = minutes_since_calibration(profile_path, now)
            warmed_c = (
                profile.water_temperature_std_c
                if age is None
                else min(profile.drift_std_c_per_min * age, profile.water_temperature_std_c)
            )
            since = "" if age is None else f" {age:.0f} min ago"
            return SoundSpeed(
                c,
                t_eq,
                f"[calibration] sound_speed_m_s, measured with the offsets{since} ({c:.2f} m/s)",
                prior.sound_speed_slope_m_s_per_c * warmed_c,
                age,
            )
    c = float(sound_speed_m_s(temp))
    return SoundSpeed(
        c,
        temp,
        f"[water] temperature_c = {temp:g} °C ({c:.2f} m/s, Marczak)",
        prior.sound_speed_std_m_s,
    )


def last_calibration(profile_path: str | Path) -> HistoryEntry | None:
    """The profile's last ``calibrate`` write that was not undone (its history); None."""
    for entry in reversed(profile_history(profile_path)):
        if entry.reason.startswith("calibrate") and not entry.undone:
            return entry
    return None


def minutes_since_calibration(profile_path: str | Path, now: datetime) -> float | None:
    """Minutes from the profile's last ``calibrate`` write to ``now``; None without one."""
    entry = last_calibration(profile_path)
    if entry is None:
        return None
    return max((now - datetime.fromisoformat(entry.time)).total_seconds() / 60.0, 0.0)


def written_budget(profile_path: Path) -> tuple[float, float] | None:
    """``[calibration] unidentified_tcp_mm`` of the profile (mean, max), or None."""
    return calibration_record(profile_path).unidentified_tcp_mm


def wrist_left_unidentified(profile: CellProfile) -> tuple[str, ...]:
    """The wrist's lengths (rows 4 and 5, ``d`` and ``a``) that ``calibrate --level full`` left
    at the [robot] tolerance (``[calibration] dh_std`` not determined), e.g. ``("d5", "a5")``:
    they move the flange across the beam, which no echo at normal incidence shows. Empty
    without an identified table (the offsets level: the whole table is at its tolerance).
    Row 1's and row 3's ``d`` are left too, but the block's height and row 2's ``d`` take
    them up; row 6 is the tool's."""
    if profile.dh_std is None:
        return ()
    return tuple(
        f"{name}{row + 1}"
        for row in (3, 4)
        for col, name in enumerate("da")
        if np.isnan(profile.dh_std[row, col])
    )


def tank_reference(profile_path: str | Path) -> CalibrationReadings | None:
    """The readings of the profile's last ``calibrate`` write that verify reads again
    (``ucal.verify.tank``): one per face (``repeated_faces``); None where that write kept none
    (a calibration from before they were kept, or none)."""
    entry = last_calibration(profile_path)
    readings = None if entry is None else read_readings(profile_path, entry)
    if readings is None:
        return None
    faces = repeated_faces(readings.faces)
    return None if faces is None else replace(readings, faces=faces)


def repeated_faces(
    faces: tuple[FaceMeasurement, ...],
) -> tuple[FaceMeasurement, ...] | None:
    """One reading per face, each reached from below on every joint (as verify reaches its
    postures): the first posture of the arm that read all three (the calibration pose: the
    wrist turns between them), else each face's longest path (the sound speed's ratio best
    read); None where a face has none."""
    below = [m for m in faces if m.approach is None or bool(np.all(np.asarray(m.approach) > 0))]
    for config in dict.fromkeys(m.config for m in below):
        mine = {int(m.face): m for m in reversed(below) if m.config == config}
        if len(mine) == 3:
            return tuple(mine[k] for k in range(3))
    longest = {}
    for m in sorted(below, key=lambda m: m.distance_mm):
        longest[int(m.face)] = m
    return tuple(longest[k] for k in range(3)) if len(longest) == 3 else None
