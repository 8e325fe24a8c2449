"""The torques a fit takes its joints' sag from are those of the links where the offsets put
them: the profile's, or the full level's fitted ones where they stand far from the profile's
(a cell never calibrated: degrees off), which move the torques' differences between postures."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from ucal.model.fit import prior_from_profile
from ucal.model.load import PostureLoad
from ucal.profile import create_profile, load_profile, write_profile


def test_the_torques_are_taken_at_the_load_offsets_where_given(tmp_path: Path) -> None:
    path = tmp_path / "cell.toml"
    create_profile(path, "tx90l")
    write_profile(path, {"tool": {"mass_kg": 1.5}}, "a weighed tool")
    prior = prior_from_profile(load_profile(path))
    assert prior.bodies is not None
    readings = np.array([[30.0, 20.0 + 5 * i, 100.0 - 4 * i, 0.0, 40.0, 0.0] for i in range(6)])
    fitted = prior.offsets_deg + np.array([0.5, 1.0, -1.0, 0.3, 0.8, 0.0])
    posed = [SimpleNamespace(joints_deg=q) for q in readings]  # readings taken at postures
    at_profile = prior.posture_load(posed)
    at_fitted = replace(prior, load_offsets_deg=fitted).posture_load(posed)
    assert at_profile is not None and at_fitted is not None
    want = PostureLoad.of(prior.model, prior.bodies, fitted, readings[0]).relative_nm(readings)
    assert np.allclose(at_fitted.relative_nm(readings), want)
    # a degree on J2 and J3 moves J2's torque differences over the readings by tenths of a N·m
    moved = np.abs(at_fitted.relative_nm(readings) - at_profile.relative_nm(readings))
    assert 0.1 < moved[:, 1:3].max() < 20.0
