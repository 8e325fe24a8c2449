"""The cell's reference echo captured at the first distance reading (``ucal.echo.capture``):
the timer times by the envelope before it and against it after, the settings are restored,
and the result says where the reference came from."""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np

from drivers.digitizer.base import AScanRecord
from drivers.pulser.base import GateReading, PulserSettings
from ucal.echo import METHOD_ENVELOPE, METHOD_REFERENCE
from ucal.echo.capture import ReferenceCapture
from ucal.echo.host import HostEchoTimer
from ucal.sim.ascan import Digitiser, TransducerPulse, echo_shape, gate_around, synthesise

SHAPE = echo_shape(TransducerPulse(25.0), Digitiser(sample_rate_mhz=200.0, bits=12))
ARRIVAL_NS = 67_431.37


class _Pulser:
    endpoint = "test://pulser"
    last_record: AScanRecord | None = None


class _Controller:
    def read_joints(self) -> np.ndarray:
        return np.array([10.0, 20.0, 30.0, 0.0, 45.0, 0.0])


class _Rig:
    """A rig whose every reading is a digitised echo near ``ARRIVAL_NS``, timed by ``timer``."""

    def __init__(self, timer: HostEchoTimer):
        self.timer = timer
        self.settings = PulserSettings(gain_db=20.0)
        self.pulser = _Pulser()
        self.controller = _Controller()
        self.rng = np.random.default_rng(7)
        self.reads = 0

    def configure(self, **changes: Any) -> None:
        self.settings = replace(self.settings, **changes)

    def level_gain(self, averages: int = 1) -> None:
        self.configure(gain_db=26.5)

    def read(self, averages: int = 1) -> GateReading:
        self.configure(averages=averages)
        self.reads += 1
        t0, n = gate_around(SHAPE, ARRIVAL_NS, 512)
        arrival = ARRIVAL_NS + 0.3 * self.rng.standard_normal()  # trigger jitter
        (scan,) = synthesise(
            SHAPE,
            self.rng,
            t0_ns=t0,
            n_samples=n,
            arrival_ns=[arrival],
            amplitude=0.6,
            noise_rms=0.004 / np.sqrt(averages),
        )
        record = AScanRecord(
            scan.t0_ns,
            scan.dt_ns,
            scan.samples,
            scan.rails or (-1.0, 1.0),
            SHAPE.digitiser.lsb,
            False,
            averages,
            self.reads,
            0.0,
        )
        self.pulser.last_record = record
        echo = self.timer(record, (5_000.0, 200_000.0))
        return GateReading(echo.amplitude, echo.tof_ns, self.reads, 0.0, 0.0, echo.tof_std_ns)


def test_the_reference_is_captured_once_and_times_what_follows() -> None:
    timer = HostEchoTimer()
    rig = _Rig(timer)
    before = rig.read(1)
    assert timer.timed == {METHOD_ENVELOPE: 1}
    capture = ReferenceCapture(timer, captures=8, averages=64)
    assert capture.as_json()["source"] == "none"
    capture.ensure(rig)  # type: ignore[arg-type]
    assert timer.reference is not None and timer.reference.averages == 8
    assert rig.settings.gain_db == 20.0 and rig.settings.averages == 1  # restored
    reads = rig.reads
    capture.ensure(rig)  # type: ignore[arg-type]
    assert rig.reads == reads  # once only

    after = [rig.read(1) for _ in range(20)]
    assert timer.timed[METHOD_REFERENCE] == 20
    # the captured echo's arrival is the synthesiser's (both the zero-phase twin's maximum),
    # within the jitter averaged over the captures; the envelope's is not
    tofs = np.array([r.tof_ns for r in after])
    assert abs(np.mean(tofs) - ARRIVAL_NS) < 0.5
    assert abs(before.tof_ns - ARRIVAL_NS) > abs(np.mean(tofs) - ARRIVAL_NS)
    # each reading's own std: the record's SNR and bandwidth, a few ps at 43 dB
    assert all(0.0 < r.tof_std_ns < 0.05 for r in after)

    shown = capture.as_json()
    assert shown["source"] == "captured" and shown["captures"] == 8
    assert shown["joints_deg"] == [10.0, 20.0, 30.0, 0.0, 45.0, 0.0]
    assert shown["gain_db"] == 26.5 and shown["dt_ns"] == SHAPE.digitiser.dt_ns
    assert len(shown["samples"]) == timer.reference.n
    assert shown["timed"] == {METHOD_ENVELOPE: 1 + 8, METHOD_REFERENCE: 20}  # captures too


def test_a_reference_from_the_profile_is_not_captured_again() -> None:
    rig = _Rig(HostEchoTimer())
    capture = ReferenceCapture(HostEchoTimer())
    capture.ensure(rig)  # type: ignore[arg-type]
    assert capture.source == "captured"
    given = ReferenceCapture(HostEchoTimer(capture.timer.reference), profile_path="ref.csv")
    given.ensure(rig)  # type: ignore[arg-type]
    assert given.as_json()["source"] == "profile" and given.as_json()["path"] == "ref.csv"
