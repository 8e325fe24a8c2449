"""Checks in a profile's history: their own index beside the writes, the reference they set."""

from __future__ import annotations

import json
import os
import shutil
import stat
from pathlib import Path

import numpy as np
import pytest

from ucal.check.history import (
    CheckEntry,
    append_check,
    checks_path,
    model_digest,
    read_checks,
    reference_check,
)
from ucal.errors import ProfileError
from ucal.model.fit import (
    BACKLASH,
    DRIFT,
    PARAMETERS,
    ParameterTable,
    data_residuals,
    prior_from_profile,
)
from ucal.model.geometry import FaceMeasurement
from ucal.model.readings import faces_from_json, faces_to_json
from ucal.profile import load_profile, profile_history, undo_profile, write_profile

EXAMPLE = Path(__file__).parents[3] / "profiles" / "example_cell.toml"


@pytest.fixture
def profile_path(tmp_path: Path) -> Path:
    path = tmp_path / "cell.toml"
    shutil.copy(EXAMPLE, path)
    return path


def entry(digest: str, reference: bool, verdict: str = "ok") -> CheckEntry:
    return CheckEntry(0, "", "check", verdict, reference, digest, 21.0, summary="test")


def test_checks_are_numbered_and_kept_apart_from_the_writes(profile_path: Path) -> None:
    before = profile_path.read_bytes()
    digest = model_digest(load_profile(profile_path))
    first = append_check(profile_path, entry(digest, True))
    second = append_check(profile_path, entry(digest, False, "out of tolerance"))
    assert (first.id, second.id) == (1, 2) and first.time
    assert [c.verdict for c in read_checks(profile_path)] == ["ok", "out of tolerance"]
    assert profile_path.read_bytes() == before  # the profile is not written
    assert profile_history(profile_path) == []  # nor is a write recorded: nothing to undo
    with pytest.raises(ProfileError, match="nothing to undo"):
        undo_profile(profile_path)
    assert json.loads(checks_path(profile_path).read_text())["profile"] == "cell.toml"


def test_the_reference_is_the_newest_of_the_profile_as_it_now_is(profile_path: Path) -> None:
    digest = model_digest(load_profile(profile_path))
    assert reference_check(profile_path, digest) is None
    append_check(profile_path, entry(digest, True))
    append_check(profile_path, entry(digest, False))
    assert reference_check(profile_path, digest).id == 1
    # a comment changes nothing the check reads; a calibration does
    profile_path.write_text(profile_path.read_text() + "\n# moved the cable tray\n")
    assert model_digest(load_profile(profile_path)) == digest
    write_profile(profile_path, {"calibration": {"joint_offsets_deg": [0, 0.1, 0, 0, 0, 0]}}, "t")
    changed = model_digest(load_profile(profile_path))
    assert changed != digest and reference_check(profile_path, changed) is None
    # undone, the profile is as it was: its reference counts again
    undo_profile(profile_path, force=True)
    assert reference_check(profile_path, model_digest(load_profile(profile_path))).id == 1


def test_a_new_index_takes_the_profiles_mode(profile_path: Path) -> None:
    os.chmod(profile_path, 0o640)
    append_check(profile_path, entry("x", True))
    assert stat.S_IMODE(checks_path(profile_path).stat().st_mode) == 0o640


def test_an_unreadable_index_names_the_file(profile_path: Path) -> None:
    append_check(profile_path, entry("x", True))
    checks_path(profile_path).write_text("{not json")
    with pytest.raises(ProfileError, match=r"checks\.json: unreadable checks index"):
        read_checks(profile_path)


def test_a_reference_keeps_each_readings_time_and_approach_for_the_solver(
    profile_path: Path,
) -> None:
    rng = np.random.default_rng(4)
    faces = [
        FaceMeasurement(
            "base",
            i % 3,
            rng.normal(size=6) * 30.0,
            100.0 + rng.normal(),
            time_min=1.5 * i,
            approach=np.where(rng.uniform(size=6) < 0.5, -1.0, 1.0),
        )
        for i in range(4)
    ]
    back = faces_from_json(json.loads(json.dumps(faces_to_json(faces), allow_nan=False)))
    assert [m.time_min for m in back] == [0.0, 1.5, 3.0, 4.5]
    assert all(np.array_equal(a.approach, b.approach) for a, b in zip(faces, back, strict=True))
    # the solver sees the drift and the lost motion in the reference as in the run itself
    prior = prior_from_profile(load_profile(profile_path))
    table = ParameterTable(PARAMETERS, prior.values(), prior.stds())
    values = table.values.copy()
    values[table.index(DRIFT[0])] = 0.3  # m/s per min
    values[[table.index(n) for n in BACKLASH]] = 0.02  # deg
    c0 = prior.sound_speed_m_s
    assert np.array_equal(
        data_residuals(table, values, prior.model, back, c0),
        data_residuals(table, values, prior.model, faces, c0),
    )
    # an entry written before they were kept reads as no time, every joint from below
    old = [
        {k: v for k, v in row.items() if k not in ("time_min", "approach")}
        for row in faces_to_json(faces)
    ]
    assert all(m.time_min is None and m.approach is None for m in faces_from_json(old))
    assert not np.array_equal(
        data_residuals(table, values, prior.model, faces_from_json(old), c0),
        data_residuals(table, values, prior.model, faces, c0),
    )
