"""The check's measurements: calibrate's face measurements of its postures, then the echo chain.

The faces are measured by calibrate's own run (``ucal.measure.sequence.run_calibration``)
over the check's postures: the same search, prediction, final approach and peak refit, so a
check and the commissioning it is compared with measure alike. Then the echo chain at the
postures of ``CheckPlan.echo_labels``: back at the measured normal-incidence posture, the gate
narrowed to a window around the echo, the gain levelled, one averaged reading and the A-scan it
leaves (``read_ascan_trace`` of the Modbus pulser, else the interface's ``read_ascan``); the
gate and gain are restored after. The A-scan's echo gives the centre frequency and the −6 dB
bandwidth (``ucal.echo.estimate_echo``, envelope method: no reference echo is needed for the
band). Last, the scans across the XY face's far edges (``ucal.check.edges.scan_edge``).
"""

from __future__ import annotations

import logging
from dataclasses import asdict, dataclass, field, replace
from typing import Any

import numpy as np

from ucal.acoustics import tof_ns
from ucal.cell import CellProfile
from ucal.check.edges import EdgeReading, scan_edge
from ucal.check.plan import ASCAN_AVERAGES, ASCAN_WINDOW_US, CheckPlan
from ucal.devices.rig import Rig
from ucal.echo import AScan, EchoEstimate, NoEcho, estimate_echo
from ucal.measure.approach import FinalApproachRig
from ucal.measure.sequence import run_calibration
from ucal.model.fit import measurement_label
from ucal.model.geometry import FaceMeasurement
from ucal.model.readings import number
from ucal.progress import MeasureStep, Report

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class EchoReading:
    """The echo chain at one normal-incidence posture.

    ``amplitude_db``: the echo's peak brought to 0 dB gain, dB of full screen height;
    ``snr_db``: that peak over the open-water noise floor (the gate's); the A-scan's figures
    (MHz) are None where no A-scan was read.
    """

    label: str
    tof_ns: float
    tof_std_ns: float
    amplitude_db: float
    snr_db: float
    centre_frequency_mhz: float | None = None
    bandwidth_mhz: float | None = None

    def to_json(self) -> dict[str, Any]:
        """The reading as JSON (a figure it could not give is null)."""
        return {
            "label": self.label,
            "tof_ns": number(self.tof_ns),
            "tof_std_ns": number(self.tof_std_ns),
            "amplitude_db": number(self.amplitude_db),
            "snr_db": number(self.snr_db),
            "centre_frequency_mhz": number(self.centre_frequency_mhz),
            "bandwidth_mhz": number(self.bandwidth_mhz),
        }

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> EchoReading:
        """A reading as a history entry keeps it (a figure it could not give is null)."""

        def number(key: str) -> float:
            v = data.get(key)
            return float("nan") if v is None else float(v)

        def optional(key: str) -> float | None:
            v = data.get(key)
            return None if v is None else float(v)

        return cls(
            str(data["label"]),
            number("tof_ns"),
            number("tof_std_ns"),
            number("amplitude_db"),
            number("snr_db"),
            optional("centre_frequency_mhz"),
            optional("bandwidth_mhz"),
        )


@dataclass
class CheckRun:
    """What a check measured."""

    faces: list[FaceMeasurement]
    echoes: list[EchoReading]
    floor_per_gain: float | None  # open-water noise floor at 0 dB gain (FSH)
    moves: int
    reads: int
    #: the crossings of the XY face's far edges (a record of a check without them: none)
    edges: list[EdgeReading] = field(default_factory=list)


def run_check(
    profile: CellProfile, plan: CheckPlan, rig: Rig, progress: Report | None = None
) -> CheckRun:
    """Measure the planned faces (calibrate's run), then the echo chain (module docstring).
    The caller owns the connection, STOP and the profile."""
    echo_labels = plan.echo_labels
    total = len(plan.targets) + len(echo_labels) + len(plan.edges)

    def faces_progress(step: MeasureStep) -> None:
        # calibrate's steps, counted against the whole check; its "solving" comes last
        if progress is not None and step.what != "solving":
            progress(replace(step, total=total))

    run = run_calibration(profile, plan.calibration, rig, progress=faces_progress)
    floor = rig.floor_per_gain
    faces = run.measurements
    ascans: dict[str, EchoEstimate | None] = {}
    by_label = {measurement_label(m): m for m in faces}
    for i, label in enumerate(echo_labels):
        if progress:
            config, _, face = label.partition("/")
            progress(MeasureStep(f"A-scan {label}", len(plan.targets) + i, total, config, face))
        m = by_label.get(label)
        if m is None:  # not measured (a configuration skipped on the way)
            continue
        FinalApproachRig(rig).move(m.joints_deg)  # reached as the faces were
        path_tof_ns = float(tof_ns(m.distance_mm, profile.water_temperature_c))
        try:
            ascans[label] = read_echo_band(rig, path_tof_ns)
        except NoAScan as e:
            log.info("no A-scan (%s): no centre frequency or bandwidth", e)
            break
    edges = []
    done = len(plan.targets) + len(echo_labels)
    for i, line in enumerate(plan.edges):
        if progress:
            progress(MeasureStep(line.label, done + i, total, "base", "XY"))
        normal = by_label.get("base/XY")
        reading = scan_edge(rig, profile, line, None if normal is None else normal.joints_deg)
        if reading is not None:
            edges.append(reading)
    if progress:
        progress(MeasureStep("solving", total, total))
    echoes = [echo_reading(profile, m, floor, ascans.get(measurement_label(m))) for m in faces]
    return CheckRun(faces, echoes, floor, rig.counters.moves, rig.counters.reads, edges)


def echo_reading(
    profile: CellProfile,
    m: FaceMeasurement,
    floor_per_gain: float | None,
    band: EchoEstimate | None,
) -> EchoReading:
    """The echo chain of one face measurement (and its A-scan's figures, if read)."""
    temp = profile.water_temperature_c
    amp0 = m.amplitude / 10 ** ((m.gain_db or 0.0) / 20)
    amplitude_db = 20 * np.log10(amp0) if amp0 > 0 else float("-inf")
    snr_db = (
        20 * np.log10(amp0 / floor_per_gain)
        if floor_per_gain and floor_per_gain > 0 and amp0 > 0
        else float("nan")
    )
    return EchoReading(
        measurement_label(m),
        float(tof_ns(m.distance_mm, temp)),
        float(tof_ns(m.distance_std_mm, temp)),
        float(amplitude_db),
        float(snr_db),
        None if band is None else band.centre_frequency_mhz,
        None if band is None else band.bandwidth_mhz,
    )


class NoAScan(Exception):
    """The pulser gives no A-scan."""


def read_echo_band(rig: Rig, echo_tof_ns: float) -> EchoEstimate | None:
    """The echo in the A-scan at the current posture (None: no echo in it), read in a window of
    ``ASCAN_WINDOW_US`` around ``echo_tof_ns`` at a levelled gain; the gate and gain are
    restored after (the settings as they were). ``NoAScan`` when the pulser gives none."""
    pulser = rig.pulser
    trace = getattr(pulser, "read_ascan_trace", None)
    saved = rig.settings
    start_us = max(echo_tof_ns * 1e-3 - ASCAN_WINDOW_US / 2, 0.0)
    try:
        rig.configure(gate_start_us=start_us, gate_width_us=ASCAN_WINDOW_US)
        rig.level_gain(ASCAN_AVERAGES)
        rig.read(ASCAN_AVERAGES)  # the acquisition the A-scan is frozen from
        if trace is not None:
            try:
                scan = trace()
            except ValueError as e:  # a register map without an A-scan
                raise NoAScan(str(e)) from None
            samples, rate_hz, t0_ns = scan.samples, scan.sample_rate_hz, scan.start_ns
        else:
            read_ascan = getattr(pulser, "read_ascan", None)
            got = None if read_ascan is None else read_ascan()
            if got is None:
                raise NoAScan(f"pulser at {pulser.endpoint} gives no A-scan")
            samples, rate_hz = got
            t0_ns = start_us * 1e3
    finally:
        rig.configure(**asdict(saved))
    samples = np.asarray(samples, float)
    if samples.size < 64 or not np.any(samples):
        log.info("A-scan of %d samples without an echo: no band", samples.size)
        return None
    levels = np.diff(np.unique(samples))
    lsb = float(levels.min()) if levels.size else None
    ascan = AScan(float(t0_ns), 1e9 / float(rate_hz), samples, rails=(-1.0, 1.0), lsb=lsb)
    try:
        estimate = estimate_echo(ascan)
    except NoEcho as e:
        log.info("A-scan of %d samples: %s: no band", samples.size, e)
        return None
    log.info(
        "A-scan: echo at %.1f ns, centre %.2f MHz, -6 dB bandwidth %.2f MHz",
        estimate.tof_ns,
        estimate.centre_frequency_mhz,
        estimate.bandwidth_mhz,
    )
    return estimate
