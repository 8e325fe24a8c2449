"""The stiffness a full level identified, written to ``[calibration]`` and read back as the
next calibration's prior in place of the model table's (``ucal.profile.arm_load``): the
joint's value and its narrower std, the others' prior as it was; a half-written pair stops
every command at load time with the key named."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
import tomlkit

from ucal.errors import ProfileError
from ucal.model.fit import prior_from_profile
from ucal.model.load import PostureLoad, model_bodies
from ucal.model.priors import GRAVITY_M_S2
from ucal.model.stiffness import (
    TOOL_MASS_STD_PCT,
    JointStiffness,
    torque_scale_pct,
    written_stiffness,
)
from ucal.profile import create_profile, load_profile, write_profile
from ucal.profile.arm_load import STIFFNESS_STD_PCT
from ucal.profile.models import model_sheet


@pytest.fixture
def profile(tmp_path: Path) -> Path:
    path = tmp_path / "cell.toml"
    create_profile(path, "tx90l")
    return path


def found(c2: float, std2: float) -> tuple[JointStiffness, ...]:
    """J2 identified at compliance ``c2`` ± ``std2`` % (µrad per N·m), the others not."""
    out = []
    for j in range(1, 7):
        if j == 2:
            out.append(JointStiffness(2, c2, 0.03 * c2, 3.9, 2.5, std2, "identified"))
        else:
            out.append(JointStiffness(j, 4.0, 2.0, 3.9, 2.5, 50.0, "not determined", "its std"))
    return tuple(out)


def test_the_identified_stiffness_is_the_next_calibrations_prior(profile: Path) -> None:
    before = prior_from_profile(load_profile(profile))
    k, std = written_stiffness(found(3.5, 4.8))
    assert k[0] == -1.0 and std[2] == -1.0  # not determined: the [robot] prior stands
    assert k[1] == round(1e6 / 3.5) and std[1] >= 1e6 / 3.5 * 0.048  # rounded up: a promise
    write_profile(
        profile,
        {"calibration": {"stiffness_nm_per_rad": k, "stiffness_std_nm_per_rad": std}},
        "calibrate --level full (test)",
    )
    p = load_profile(profile)
    nominal = model_sheet("tx90l").stiffness_nm_per_rad
    assert nominal is not None
    assert p.stiffness_nm_per_rad[1] == k[1]
    assert p.stiffness_std_pct[1] == pytest.approx(4.8, rel=1e-3)
    others = [0, 2, 3, 4, 5]
    assert np.array_equal(p.stiffness_nm_per_rad[others], nominal[others])
    assert np.all(p.stiffness_std_pct[others] == STIFFNESS_STD_PCT)
    after = prior_from_profile(p)
    # the compliance and its std as the fit found them, 13 times narrower than the table's
    assert after.compliance_urad_per_nm[1] == pytest.approx(3.5, rel=1e-5)
    assert after.compliance_std_urad_per_nm[1] == pytest.approx(3.5 * 0.048, rel=1e-3)
    assert after.compliance_std_urad_per_nm[1] < before.compliance_std_urad_per_nm[1] / 10
    assert np.array_equal(
        after.compliance_std_urad_per_nm[others], before.compliance_std_urad_per_nm[others]
    )


@pytest.mark.parametrize(
    ("keys", "named"),
    [
        ({"stiffness_nm_per_rad": [-1, 3e5, -1, -1, -1, -1]}, "stiffness_std_nm_per_rad"),
        (
            {
                "stiffness_nm_per_rad": [-1, 3e5, -1, -1, -1, -1],
                "stiffness_std_nm_per_rad": [-1, 0.0, -1, -1, -1, -1],
            },
            "stiffness_std_nm_per_rad[1]",
        ),
        (
            {
                "stiffness_nm_per_rad": [-1, 500.0, -1, -1, -1, -1],
                "stiffness_std_nm_per_rad": [-1, 50.0, -1, -1, -1, -1],
            },
            "stiffness_nm_per_rad[1]",
        ),
    ],
)
def test_a_half_written_stiffness_is_refused_with_its_key(
    profile: Path, keys: dict, named: str
) -> None:
    doc = tomlkit.parse(profile.read_text())
    doc["calibration"].update(keys)  # type: ignore[union-attr]
    profile.write_text(tomlkit.dumps(doc))
    with pytest.raises(ProfileError, match=re.escape(f"calibration.{named}")):
        load_profile(profile)


def test_a_tool_alone_scales_the_torque_by_its_own_mass_tolerance(profile: Path) -> None:
    model = load_profile(profile).model
    bodies = model_bodies(model, None, None, 1.5, np.array([0.0, 0.0, 50.0]), GRAVITY_M_S2)
    assert bodies is not None
    load = PostureLoad.of(model, bodies, np.zeros(6), np.array([0.0, 30.0, 100.0, 0, 40, 0]))
    readings = np.array([[0.0, 10.0 * i, 110.0 - 5 * i, 0, 40, 0] for i in range(5)])
    scale = torque_scale_pct(load, readings)
    # the tool is all of J2's and J3's torque: its mass's tolerance, no more, no less
    assert scale[1:3] == pytest.approx([TOOL_MASS_STD_PCT] * 2)
    assert scale[0] == 0.0  # J1 about a vertical axis: no torque, no share


def test_the_stated_stiffness_fraction_is_the_compliances_prior(profile: Path) -> None:
    """SPEC.md's ``[robot] stiffness_std_fraction``: one sigma relative (default 0.5), taken as
    the same fraction of each joint's compliance; a value beyond 2 is refused by its key."""
    default = prior_from_profile(load_profile(profile))
    c = default.compliance_urad_per_nm
    assert STIFFNESS_STD_PCT == 50.0
    assert np.allclose(default.compliance_std_urad_per_nm, 0.5 * c)
    write_profile(profile, {"robot": {"stiffness_std_fraction": 0.3}}, "a tighter prior")
    assert np.allclose(
        prior_from_profile(load_profile(profile)).compliance_std_urad_per_nm, 0.3 * c
    )
    write_profile(profile, {"robot": {"stiffness_std_fraction": 0.2}}, "tighter still")
    text = profile.read_text().replace("stiffness_std_fraction = 0.2", "stiffness_std_fraction = 3")
    profile.write_text(text)
    with pytest.raises(ProfileError, match=r"robot\.stiffness_std_fraction"):
        load_profile(profile)
