"""The cell's own reference echo, captured on the block at the start of a run.

A run that times echoes on the host (``[pulser] timing = "ascan"``, or a back-end that only
digitises) and whose profile names no ``reference_echo`` times its first readings by their
envelope (the coarse fallback, ``ucal.echo.timing.METHOD_ENVELOPE``). At its first distance
reading (``ucal.measure.search.read_distance``: the first face's normal-incidence
posture, where the echo is the block's and strongest) :meth:`ReferenceCapture.ensure` levels
the gain, takes ``captures`` readings of ``averages`` acquisitions each, averages their records
into the reference (``ucal.echo.reference.build_reference``), restores the settings and hands
the reference to the timer: every reading after it is timed by correlation with it. The run's
result says how each echo was timed (``as_json``).
"""

from __future__ import annotations

import logging
from dataclasses import asdict
from typing import Any, Protocol

import numpy as np

from drivers.controller.base import RobotController
from drivers.pulser.base import GateReading, PulserReceiver, PulserSettings
from ucal.echo.ascan import AScan, ReferenceEcho
from ucal.echo.host import HostEchoTimer
from ucal.echo.reference import build_reference

log = logging.getLogger(__name__)

#: Records averaged into a captured reference, and acquisitions averaged into each.
CAPTURES = 16
CAPTURE_AVERAGES = 64


class CaptureRig(Protocol):
    """What a capture uses of the rig that calls it (``ucal.devices.rig.Rig``): its devices, its
    settings and the reads and gain levelling every measurement goes through."""

    controller: RobotController
    pulser: PulserReceiver
    settings: PulserSettings

    def configure(self, **changes: Any) -> None: ...

    def level_gain(self, averages: int = 1) -> None: ...

    def read(self, averages: int = 1) -> GateReading: ...


class Capture(Protocol):
    """What a session's rig calls at its first distance reading, and what the result says of
    the reference echo: a capture (``ReferenceCapture``) or a recorded one replayed."""

    def ensure(self, rig: CaptureRig) -> None: ...

    def as_json(self) -> dict[str, Any]: ...


class ReferenceCapture:
    """Captures the reference echo of ``timer`` once, where the run first reads a distance
    (module docstring). ``source`` says where the timer's reference came from: ``"profile"``,
    ``"captured"``, or ``"none"`` (not captured yet, or the capture failed)."""

    def __init__(
        self,
        timer: HostEchoTimer,
        captures: int = CAPTURES,
        averages: int = CAPTURE_AVERAGES,
        profile_path: str | None = None,
    ):
        self.timer = timer
        self.captures = int(captures)
        self.averages = int(averages)
        self.source = "profile" if timer.reference is not None else "none"
        self.profile_path = profile_path
        self.joints_deg: np.ndarray | None = None
        self.gain_db: float | None = None
        self._tried = timer.reference is not None

    def ensure(self, rig: CaptureRig) -> None:
        """Capture the reference at the rig's posture unless the timer has one (or a capture
        was tried already)."""
        if self._tried:
            return
        self._tried = True
        saved = rig.settings
        records: list[AScan] = []
        try:
            rig.level_gain(self.averages)
            gain_db = rig.settings.gain_db
            for _ in range(self.captures):
                reading = rig.read(self.averages)
                record = getattr(rig.pulser, "last_record", None)
                if reading.has_echo and record is not None:
                    records.append(
                        AScan(
                            record.t0_ns,
                            record.dt_ns,
                            np.asarray(record.samples, float),
                            rails=tuple(record.rails),
                            lsb=record.lsb if record.lsb > 0 else None,
                        )
                    )
        finally:
            rig.configure(**asdict(saved))
        if len(records) < max(self.captures // 2, 2):
            log.warning(
                "reference echo: %d of %d captures held an echo; echoes stay timed by their "
                "envelope (coarse)",
                len(records),
                self.captures,
            )
            return
        try:
            reference = build_reference(records)
        except ValueError as e:
            log.warning("reference echo: cannot build it (%s); echoes stay coarse", e)
            return
        self.timer.reference = reference
        self.source = "captured"
        self.joints_deg = np.asarray(rig.controller.read_joints(), float)
        self.gain_db = gain_db
        log.info(
            "reference echo captured: %d records of %d averages at %.1f dB, %d samples every "
            "%.3g ns, noise %.2g of its peak; echoes from now on timed against it",
            len(records),
            self.averages,
            gain_db,
            reference.n,
            reference.dt_ns,
            reference.noise_rms,
        )

    def as_json(self) -> dict[str, Any]:
        """Where the reference came from, the captured echo itself (``t0_ns``, ``dt_ns``,
        ``samples``: the CSV of ``[pulser] reference_echo``), and the echoes timed by each
        method."""
        ref: ReferenceEcho | None = self.timer.reference
        out: dict[str, Any] = {"source": self.source}
        if self.source == "profile":
            out["path"] = self.profile_path
        if self.source == "captured":
            assert self.joints_deg is not None
            out.update(
                joints_deg=[round(float(v), 6) for v in self.joints_deg],
                gain_db=self.gain_db,
                captures=self.captures,
                averages=self.averages,
            )
        if ref is not None:
            out.update(
                t0_ns=ref.t0_ns,
                dt_ns=ref.dt_ns,
                rms_bandwidth_mhz=ref.rms_bandwidth_mhz,
                noise_rms=ref.noise_rms,
                samples=[round(float(v), 7) for v in ref.samples],
            )
        out["timed"] = dict(self.timer.timed)
        return out


class ReplayedCapture:
    """The capture of a recorded run, replayed (``ucal.devices.record``): the same device calls in
    the same order — the gain levelled, ``captures`` readings of ``averages`` acquisitions,
    the settings restored, the joints read — so that the replay keeps to the recording; the
    reference itself is the recorded one (the records it was averaged from are not in the
    recording, and the readings after it were timed with it already)."""

    def __init__(self, recorded: dict[str, Any]):
        self.recorded = dict(recorded)
        self.captures = int(recorded.get("captures", CAPTURES))
        self.averages = int(recorded.get("averages", CAPTURE_AVERAGES))
        self._tried = False

    def ensure(self, rig: CaptureRig) -> None:
        """Make the recorded capture's calls once."""
        if self._tried:
            return
        self._tried = True
        saved = rig.settings
        try:
            rig.level_gain(self.averages)
            for _ in range(self.captures):
                rig.read(self.averages)
        finally:
            rig.configure(**asdict(saved))
        rig.controller.read_joints()

    def as_json(self) -> dict[str, Any]:
        """The recorded run's account of its reference echo."""
        return dict(self.recorded)
