"""The record file: values round-trip exactly, a cut-off file stays readable, replay checks."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from drivers.controller.base import ControllerStatus, JointSample
from drivers.pulser.base import GateReading, PulserSettings
from ucal.devices.record import (
    Record,
    Recorder,
    RecordError,
    RecordingPulser,
    Replay,
    ReplayController,
    ReplayPulser,
    decode,
    encode,
    measured_from_lines,
    measurement_lines,
    read_record,
    sha256_text,
)
from ucal.measure.postures import FullRun
from ucal.measure.sequence import CalibrationRun
from ucal.model.geometry import Face, FaceMeasurement
from ucal.procedure import RunOptions
from ucal.profile import default_profile_text, load_profile, write_profile
from ucal.toolframe.measure import PeakResult
from ucal.verify.procedure import VerifyJob
from ucal.verify.solve import EdgeCheck

PROFILE_TEXT = "schema = 1\n"


@given(st.lists(st.floats(allow_nan=True, allow_infinity=True), max_size=8))
def test_floats_round_trip_bit_for_bit_through_json(values: list[float]) -> None:
    back = decode(json.loads(json.dumps(encode(np.array(values)), allow_nan=False)))
    assert back.shape == (len(values),)
    for a, b in zip(values, back.tolist(), strict=True):
        assert (math.isnan(a) and math.isnan(b)) or a == b


def test_driver_dataclasses_round_trip() -> None:
    values = [
        GateReading(0.5, float("nan"), 7, 1.25, 3.0e-3),
        ControllerStatus(True, False, None, False, 0, 2, True),
        JointSample(0.02, np.array([1.0, 2.0, 3.0, 4.0, 5.0, 6.0])),
        PulserSettings(gain_db=31.5, averages=4),
    ]
    for v in values:
        back = decode(json.loads(json.dumps(encode(v), allow_nan=False)))
        assert type(back) is type(v)
        assert repr(back) == repr(v)


def _write(path: Path, calls: list[tuple[str, tuple, object]], end: dict | None) -> None:
    with Recorder(path) as rec:
        rec.open(
            {
                "command": "calibrate",
                "profile_text": PROFILE_TEXT,
                "profile_sha256": sha256_text(PROFILE_TEXT),
                "cell": "test",
            }
        )
        for name, args, result in calls:
            rec.call(name, args, result)
        if end is not None:
            rec.end(end)


def test_replay_serves_the_recorded_results_in_order(tmp_path: Path) -> None:
    path = tmp_path / "run.jsonl"
    reading = GateReading(0.25, 6.7e4, 1, 0.0, 0.5, tof_std_ns=0.02)
    _write(
        path,
        [
            ("clock.now", (), 0.5),
            ("controller.read_joints", (), np.arange(6.0)),
            ("pulser.read_gate", (), reading),
        ],
        {"joint_offsets_deg": [0.0] * 6},
    )
    record = read_record(path)
    replay = Replay(record)
    controller, pulser = ReplayController(replay, "x"), ReplayPulser(replay, "y")
    assert controller.clock.now() == 0.5
    assert np.array_equal(controller.read_joints(), np.arange(6.0))
    assert pulser.read_gate() == reading
    # a device's own gate gives no std (NaN), which the record keeps
    _write(path, [("pulser.read_gate", (), GateReading(0.25, 6.7e4, 1, 0.0, 0.5))], None)
    gate = ReplayPulser(Replay(read_record(path)), "y").read_gate()
    assert gate.tof_ns == 6.7e4 and math.isnan(gate.tof_std_ns)
    assert record.result == {"joint_offsets_deg": [0.0] * 6}


def test_replay_refuses_a_call_the_recording_does_not_have(tmp_path: Path) -> None:
    path = tmp_path / "run.jsonl"
    _write(path, [("controller.start_move", (np.zeros(6), 0.3), None)], None)
    replay = Replay(read_record(path))
    with pytest.raises(RecordError, match="start_move"):
        ReplayController(replay, "x").start_move(np.ones(6), 0.3)


def test_a_run_cut_off_mid_line_leaves_a_readable_record(tmp_path: Path) -> None:
    path = tmp_path / "run.jsonl"
    _write(path, [("clock.now", (), float(i)) for i in range(5)], None)
    text = path.read_text()
    path.write_text(text[:-7])  # the last line is cut in the middle
    record = read_record(path)
    assert isinstance(record, Record)
    assert [c["result"] for c in record.calls] == [0.0, 1.0, 2.0, 3.0]
    assert record.result is None
    replay = Replay(record)
    for _ in range(4):
        replay.next("clock.now", ())
    with pytest.raises(RecordError, match="ends before"):
        replay.next("clock.now", ())


def test_a_tampered_profile_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "run.jsonl"
    _write(path, [], None)
    lines = path.read_text().splitlines()
    header = json.loads(lines[0])
    header["profile_text"] = "schema = 2\n"
    path.write_text(json.dumps(header) + "\n")
    with pytest.raises(RecordError, match="SHA-256"):
        read_record(path)


def test_a_pulser_that_sets_its_own_steps_leaves_asked_and_set_in_the_record(
    tmp_path: Path,
) -> None:
    class Stepping:
        """A pulser whose gain takes 0.5 dB steps: configure says what it set."""

        def configure(self, settings: PulserSettings) -> dict[str, dict[str, float]]:
            return {"gain_db": {"asked": settings.gain_db, "set": round(settings.gain_db * 2) / 2}}

    path = tmp_path / "run.jsonl"
    with Recorder(path) as recorder:
        recorder.open(
            {
                "command": "calibrate",
                "profile_text": PROFILE_TEXT,
                "profile_sha256": sha256_text(PROFILE_TEXT),
                "cell": "test",
            }
        )
        RecordingPulser(Stepping(), recorder).configure(PulserSettings(gain_db=37.24))
        recorder.end({})
    record = read_record(path)
    (line,) = [c for c in record.calls if c["call"] == "pulser.configure"]
    assert decode(line["result"]) == {"gain_db": {"asked": 37.24, "set": 37.0}}
    # and the replay hands it back as the device said it
    replayed = ReplayPulser(Replay(record), "y").configure(PulserSettings(gain_db=37.24))
    assert replayed == {"gain_db": {"asked": 37.24, "set": 37.0}}


def _face(i: int, **extra: object) -> FaceMeasurement:
    rng = np.random.default_rng(i)
    return FaceMeasurement(
        "base",
        i % 3,
        rng.normal(size=6) * 30.0,
        100.0 + rng.normal(),
        distance_std_mm=1e-4 / 3,
        tilt_std_deg=float(rng.uniform()),
        **extra,  # type: ignore[arg-type]
    )


def _same_face(a: FaceMeasurement, b: FaceMeasurement) -> bool:
    """Every field the solver reads, to the bit."""
    return (
        a.config == b.config
        and type(b.face) is Face
        and a.face == b.face
        and np.array_equal(a.joints_deg, b.joints_deg)
        and a.distance_mm == b.distance_mm
        and a.distance_std_mm == b.distance_std_mm
        and a.tilt_std_deg == b.tilt_std_deg
        and (a.amplitude == b.amplitude or (math.isnan(a.amplitude) and math.isnan(b.amplitude)))
        and (
            a.distance_joints_deg is b.distance_joints_deg is None
            or np.array_equal(a.distance_joints_deg, b.distance_joints_deg)
        )
    )


def _through_json(lines: list[dict]) -> list[dict]:
    return [json.loads(json.dumps(line, allow_nan=False)) for line in lines]


def test_measurements_round_trip_bit_for_bit_without_the_searchs_probes() -> None:
    probes = (np.ones((4, 2)), np.arange(4.0), np.zeros(6))
    faces = [
        _face(0, gain_db=31.5, probes=probes, search_joints=(3, 4)),
        _face(1, distance_joints_deg=np.full(6, 1.0 / 3.0), amplitude=float("nan")),
    ]
    lines = measurement_lines(CalibrationRun(faces, moves=182, reads=1273))
    assert [line["of"] for line in lines] == ["measurements", "measurements", "run"]
    back = measured_from_lines(_through_json(lines))
    assert type(back) is CalibrationRun and (back.moves, back.reads) == (182, 1273)
    assert all(_same_face(a, b) for a, b in zip(faces, back.measurements, strict=True))
    # the probes only served the measure step's re-fit; the rest of the fields are kept
    assert back.measurements[0].probes is None and "probes" not in json.dumps(lines)
    assert (back.measurements[0].gain_db, back.measurements[0].search_joints) == (31.5, (3, 4))
    # a frozen run, an empty list, and a dataclass holding tuples and int arrays
    full = FullRun([faces[1]], [], 3, 4)
    again = measured_from_lines(_through_json(measurement_lines(full)))
    assert again.steps == [] and _same_face(again.measurements[0], faces[1])
    peak = PeakResult(np.arange(6), 0.5, 0.001, 0.0, (101.25, 2e-4), None, probes)
    value = decode(json.loads(json.dumps(encode(peak))))
    assert value.distance == (101.25, 2e-4) and value.joints_deg.dtype == peak.joints_deg.dtype
    assert value.probes[0].shape == (4, 2) and isinstance(value.probes, tuple)
    assert decode(encode(np.zeros((0, 3)))).shape == (0, 3)
    # a field of that name that is part of a measurement's value (a scan's probe count) stays
    check = EdgeCheck(0, 1, 280.0, 280.1, 0.02, 21)
    assert decode(json.loads(json.dumps(encode(check, measurement=True)))) == check


def test_a_record_missing_a_measurement_line_is_refused() -> None:
    lines = measurement_lines(CalibrationRun([_face(0), _face(1)], 1, 2))
    with pytest.raises(RecordError, match=r"1 measurement lines of .measurements.*measured 2"):
        measured_from_lines(lines[1:], "run.jsonl")
    with pytest.raises(RecordError, match="no measurement lines"):
        measured_from_lines([], "run.jsonl")


def test_a_record_rebuilds_only_ucal_dataclasses() -> None:
    with pytest.raises(RecordError, match="no ucal dataclass"):
        decode({"dc": "subprocess:Popen", "v": {}})
    with pytest.raises(RecordError, match="does not have"):
        decode({"dc": "ucal.model.geometry:NoSuchThing", "v": {}})
    # a class that moved to another module since: the one of its name the replay has loaded
    moved = {
        "dc": "ucal.calibration.old_home:PeakResult",
        "v": encode(PeakResult(np.ones(6), 0.5, 0.0, 0.0))["v"],
    }
    assert type(decode(moved)) is PeakResult
    # one recorded before a field without a default was added (or after one was removed)
    with pytest.raises(RecordError, match="FaceMeasurement is not this ucal's"):
        decode({"dc": "ucal.model.geometry:FaceMeasurement", "v": {"config": "base"}})


def test_every_line_has_a_kind_header_first_result_last(tmp_path: Path) -> None:
    path = tmp_path / "run.jsonl"
    with Recorder(path) as rec:
        rec.open({"command": "calibrate", "profile_text": "", "profile_sha256": sha256_text("")})
        rec.call("clock.now", (), 0.5)
        rec.measurements(measurement_lines(CalibrationRun([_face(0)], 1, 2)))
        rec.end({"joint_offsets_deg": np.zeros(6)})
    kinds = [json.loads(line)["kind"] for line in path.read_text().splitlines()]
    assert kinds == ["header", "call", "measurement", "measurement", "result"]
    record = read_record(path)
    assert record.version == 2 and record.measured and len(record.calls) == 1
    assert record.result == {"joint_offsets_deg": [0.0] * 6}


def test_a_version_1_record_is_read_and_replays_its_traffic(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    path = tmp_path / "v1.jsonl"
    header = {"record": "ucal", "version": 1, "command": "calibrate", "cell": "test"}
    header |= {"profile_text": PROFILE_TEXT, "profile_sha256": sha256_text(PROFILE_TEXT)}
    lines = [header, {"n": 0, "call": "clock.now", "args": [], "result": 0.5}, {"end": {"a": 1}}]
    path.write_text("".join(json.dumps(line) + "\n" for line in lines))
    record = read_record(path)
    assert (record.version, record.measured, record.result) == (1, False, {"a": 1})
    assert ReplayController(Replay(record), "x").clock.now() == 0.5
    assert not RunOptions(None, replay=record).replays_measurements()  # it has none
    assert "version 1" in caplog.text and "device traffic" in caplog.text


def test_a_verify_replay_reads_the_profiles_history_as_the_run_did(tmp_path: Path) -> None:
    path = tmp_path / "cell.toml"
    path.write_text(default_profile_text("tx90l"), encoding="utf-8")
    run = VerifyJob(load_profile(path), path)
    run.check(RunOptions(None, dry_run=True))
    inputs = json.loads(json.dumps(run.record_header(None)["inputs"]))
    # a calibration since: the history now gives another "before" and another sound speed
    offsets = [0.1, -0.2, 0.3, 0.0, 0.1, 0.2]
    cal = {"joint_offsets_deg": offsets, "sound_speed_m_s": 1490.0}
    write_profile(path, {"calibration": cal}, reason="calibrate")
    now, replay = (
        VerifyJob(load_profile(path), path),
        VerifyJob(load_profile(path), path, recorded_inputs=inputs),
    )
    for job in (now, replay):
        job.check(RunOptions(None, dry_run=True))
    assert now.before.source != run.before.source and now.sound.m_s != run.sound.m_s
    assert (replay.before.source, replay.sound, replay.gauge) == (
        run.before.source,
        run.sound,
        run.gauge,
    )
    assert np.array_equal(replay.before.offsets_deg, run.before.offsets_deg)


def test_a_replayed_pulser_has_an_a_scan_only_where_the_recorded_one_gave_one(
    tmp_path: Path,
) -> None:
    class Scanning:
        def read_ascan(self) -> tuple[np.ndarray, float]:
            return np.linspace(0.0, 1.0, 5), 1e8

        def read_ascan_trace(self) -> None:
            raise ValueError("the register map has no ascan_samples")

    path = tmp_path / "run.jsonl"
    with Recorder(path) as recorder:
        recorder.open({"command": "check", "profile_text": "", "profile_sha256": sha256_text("")})
        pulser = RecordingPulser(Scanning(), recorder)
        with pytest.raises(ValueError):
            pulser.read_ascan_trace()
        pulser.read_ascan()
    replayed = ReplayPulser(Replay(read_record(path)), "y")
    with pytest.raises(ValueError, match="no ascan_samples"):  # as the back-end refused it
        replayed.read_ascan_trace()
    samples, rate_hz = replayed.read_ascan()
    assert np.array_equal(samples, np.linspace(0.0, 1.0, 5)) and rate_hz == 1e8
    # a record whose pulser was never asked for an A-scan: the replayed pulser has none
    _write(path, [("pulser.read_gate", (), GateReading(0.25, 6.7e4, 1, 0.0, 0.5))], None)
    assert getattr(ReplayPulser(Replay(read_record(path)), "y"), "read_ascan", None) is None
