"""The published message: its fields, the calibration-target fields and the shipped schema."""

from __future__ import annotations

import json
import math
from datetime import UTC, datetime, timedelta

import numpy as np
import pytest
from jsonschema import Draft202012Validator

from ucal import __version__
from ucal.fleet.message import (
    QUALITY_OK,
    QUALITY_OUT,
    QUALITY_UNKNOWN,
    RECENT,
    SCHEMA_VERSION,
    CellState,
    Finished,
    build_message,
    encode,
    quality_of,
    schema,
)
from ucal.profile.cell import CellSettings

T0 = datetime(2025, 3, 1, 8, 0, 0, tzinfo=UTC)
SHA = "ab" * 32
VALIDATOR = Draft202012Validator(schema())


def done(
    command: str = "check", code: int = 0, written: bool = True, out: bool = False
) -> Finished:
    result = {"verdict": "ok", "std_deg": [0.01, float("nan"), np.float64(0.02)], "moves": 12}
    return Finished(command, code, "out of tolerance" if out else "", result, written, out, True)


def test_the_schema_is_a_valid_json_schema_of_version_1() -> None:
    Draft202012Validator.check_schema(schema())
    assert schema()["properties"]["schema_version"] == {"const": SCHEMA_VERSION}


def test_a_message_carries_the_cell_the_hash_the_version_the_time_and_the_result() -> None:
    message, after = build_message(done(), CellSettings("line-3"), SHA, CellState(), T0)
    assert VALIDATOR.is_valid(message), list(VALIDATOR.iter_errors(message))
    assert message["schema_version"] == SCHEMA_VERSION
    assert message["cell"] == "line-3" and message["profile_sha256"] == SHA
    assert message["ucal_version"] == __version__
    assert message["time"] == "2025-03-01T08:00:00.000Z"
    assert message["command"] == "check" and message["exit_code"] == 0
    assert message["sequence"] == 1 and after.sequence == 1
    assert message["result"]["moves"] == 12
    assert message["result"]["std_deg"] == [0.01, None, 0.02]  # no NaN in a payload
    assert len(message["message_id"]) == 32


def test_every_message_has_its_own_id_and_the_next_number() -> None:
    state = CellState()
    ids = []
    for k in range(3):
        message, state = build_message(done(), CellSettings("c"), SHA, state, T0)
        ids.append(message["message_id"])
        assert message["sequence"] == k + 1
    assert len(set(ids)) == 3


@pytest.mark.parametrize(
    ("finished", "quality"),
    [
        (done("check"), QUALITY_OK),
        (done("verify", written=False), QUALITY_OK),
        (done("calibrate"), QUALITY_OK),
        (done("tool-frame", written=False), QUALITY_UNKNOWN),
        (done("check", 1, written=False, out=True), QUALITY_OUT),
        (done("calibrate", 1, written=True, out=True), QUALITY_OUT),  # a --force'd misfit
        (done("verify", 130, written=False), QUALITY_OK),
    ],
)
def test_the_quality_is_the_verdict_of_the_result(finished: Finished, quality: str) -> None:
    assert quality_of(finished) == quality


def test_the_next_validation_is_the_last_ok_one_plus_the_declared_interval() -> None:
    cell = CellSettings("c", validation_interval_days=30)
    ok, state = build_message(done(), cell, SHA, CellState(), T0)
    target = ok["calibration_target"]
    assert target["last_validation"] == "2025-03-01T08:00:00.000Z"
    assert target["next_validation"] == "2025-03-31T08:00:00.000Z"
    assert target["quality"] == QUALITY_OK
    # a check out of tolerance a week later: the last validation stays, the quality says so
    bad, state = build_message(
        done("check", 1, False, True), cell, SHA, state, T0 + timedelta(days=7)
    )
    target = bad["calibration_target"]
    assert target["last_validation"] == "2025-03-01T08:00:00.000Z"
    assert target["next_validation"] == "2025-03-31T08:00:00.000Z"
    assert target["quality"] == QUALITY_OUT
    assert VALIDATOR.is_valid(bad)


def test_without_an_interval_or_a_validation_there_is_no_next_date() -> None:
    message, _ = build_message(done(), CellSettings("c"), SHA, CellState(), T0)
    assert message["calibration_target"]["next_validation"] is None
    cell = CellSettings("c", validation_interval_days=7)
    message, _ = build_message(done("tool-frame", written=False), cell, SHA, CellState(), T0)
    assert message["calibration_target"]["last_validation"] is None
    assert message["calibration_target"]["next_validation"] is None
    assert VALIDATOR.is_valid(message)


def test_recent_holds_the_latest_results_oldest_first() -> None:
    state = CellState()
    for k in range(RECENT + 3):
        code = 1 if k % 4 == 3 else 0
        message, state = build_message(
            done("check", code, out=code == 1), CellSettings("c"), SHA, state, T0
        )
    recent = message["recent"]
    assert len(recent) == RECENT
    assert [r["sequence"] for r in recent] == list(range(4, RECENT + 4))
    assert recent[-1]["sequence"] == message["sequence"]
    assert [r["quality"] for r in recent].count(QUALITY_OUT) == 3
    assert CellState.from_json(json.loads(json.dumps(state.to_json()))) == state


def test_the_payload_is_compact_json_without_non_finite_numbers() -> None:
    message, _ = build_message(done(), CellSettings("c"), SHA, CellState(), T0)
    message["result"]["extra"] = {"a": np.array([1.0, np.inf]), "b": math.nan}
    data = encode(message)
    parsed = json.loads(data)
    assert parsed["result"]["extra"] == {"a": [1.0, None], "b": None}
    assert b" " not in data.split(b'"result"')[0].replace(b'"message":""', b"")


def test_a_message_that_breaks_the_schema_is_caught_by_it() -> None:
    message, _ = build_message(done(), CellSettings("c"), SHA, CellState(), T0)
    for key, value in (("cell", "a/b"), ("exit_code", 3), ("profile_sha256", "xyz")):
        broken = {**message, key: value}
        assert not VALIDATOR.is_valid(broken), key
    broken = {**message, "calibration_target": {**message["calibration_target"], "quality": "?"}}
    assert not VALIDATOR.is_valid(broken)
