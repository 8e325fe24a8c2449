"""What the full level identified is known to what it identified it to: ``[calibration]
dh_std`` written from a full-level solution, read back, and taken as the DH prior by the
offsets level's, the full level's and tool-frame's solvers (no simulator)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import tomlkit

from ucal.calibration.procedure import FullCalibration, write_calibration
from ucal.calibration.result import FullSolved, Verdict
from ucal.errors import ProfileError
from ucal.model.fit import DH, PARAMETERS, CellFit, prior_from_profile
from ucal.model.kinematic import (
    KINEMATIC,
    FullSolution,
    Identifiability,
    IdentifiedParameter,
    full_table,
)
from ucal.model.quality import FitQuality
from ucal.profile import default_profile_text, load_profile
from ucal.profile.calibration import WrittenCalibration
from ucal.toolframe.fit import _Data, _table, plate_prior
from ucal.toolframe.plane import fit_plane

#: Held at nominal by the full level on the example cell (``test_full_identification``).
REDUNDANT = ("dh1_d_mm", "dh3_d_mm", "dh5_d_mm", "dh5_a_mm", "dh6_d_mm", "dh6_a_mm")
#: Two identified parameters correlated ρ = 0.6: the largest eigenvalue of the parameters'
#: correlation matrix is then 1.6, every std written √1.6 times its marginal one.
CORRELATED = {"dh3_a_mm": 0.004, "dh4_a_mm": 0.003}
RHO = 0.6
#: A parameter at 0.9 of its tolerance: inflated, it would pass it (its prior's std is kept).
WEAK = "dh4_d_mm"
QUALITY = FitQuality(1.0, 100, 1e-4, 1e-3, "p01", "ok")


@pytest.fixture
def path(tmp_path: Path) -> Path:
    p = tmp_path / "cell.toml"
    p.write_text(default_profile_text("tx90l"), encoding="utf-8")
    return p


def solution(path: Path) -> FullSolution:
    """A full-level solution of the profile at ``path``: every free unknown at half its prior
    std, uncorrelated, but ``CORRELATED`` and ``WEAK``; ``REDUNDANT`` not identifiable."""
    profile = load_profile(path)
    prior = prior_from_profile(profile)
    table = full_table(prior)
    table.free &= table.prior_stds > 0
    for name in REDUNDANT:
        table.free[table.index(name)] = False
    free = table.free_names
    sd = 0.5 * table.prior_stds[table.free]
    sd[free.index(WEAK)] = 0.9 * table.prior_stds[table.index(WEAK)]
    (a, sa), (b, sb) = CORRELATED.items()
    sd[free.index(a)], sd[free.index(b)] = sa, sb
    cov = np.diag(sd**2)
    cov[free.index(a), free.index(b)] = cov[free.index(b), free.index(a)] = RHO * sa * sb
    std = np.full(len(table.names), np.nan)
    std[table.free] = sd
    cell = CellFit(table, table.values.copy(), cov, std, QUALITY, {}, 1.0)
    params = {
        n: IdentifiedParameter(
            cell.value(n),
            None if n in REDUNDANT else cell.sigma(n),
            cell.value(n),
            "not identifiable" if n in REDUNDANT else "identified",
        )
        for n in KINEMATIC
    }
    ident = Identifiability(40, 50, tuple(n for n in KINEMATIC if n not in REDUNDANT), {}, ())
    reasons = {6: "beam on axis 6"}
    return FullSolution(cell, ident, np.zeros(6), np.full(6, 0.002), reasons, prior.model, params)


def expected_std() -> np.ndarray:
    """``solution``'s stds as written: √1.6 × each, NaN (the tolerance) where not determined."""
    k = np.sqrt(1.0 + RHO)
    std = np.full((6, 4), np.nan)
    for name in KINEMATIC:
        if name in REDUNDANT:
            continue
        if name == WEAK:
            std[3, 0] = 0.2
            continue
        col = ("d_mm", "a_mm", "alpha_deg", "beta_deg").index(name.split("_", 1)[1])
        std[int(name[2]) - 1, col] = k * CORRELATED.get(
            name, 0.5 * (0.02 if "deg" in name else 0.2)
        )
    return std


def test_full_level_writes_each_identified_std_inflated_for_the_correlations(path) -> None:
    FullCalibration(load_profile(path), path).write(
        FullSolved(solution(path), QUALITY, Verdict(True, False, ""), None)
    )
    cal = tomlkit.parse(path.read_text())["calibration"]
    rows = cal["dh_std"]
    assert len(rows) == 6 and set(rows[1]) == {"d_mm", "a_mm", "alpha_deg", "beta_deg"}
    assert rows[0]["d_mm"] == -1.0 and rows[4]["a_mm"] == -1.0  # not identifiable
    assert rows[3]["d_mm"] == 0.2  # WEAK: its tolerance
    assert rows[2]["a_mm"] == pytest.approx(np.sqrt(1.6) * 0.004, rel=2e-3)
    assert rows[2]["a_mm"] >= np.sqrt(1.6) * 0.004  # rounded up, never down
    loaded = load_profile(path)
    assert loaded.dh_std is not None
    np.testing.assert_allclose(loaded.dh_std, expected_std(), rtol=2e-3)
    assert loaded.model.dh_source.endswith("[calibration] dh")


def test_the_offsets_level_writing_later_keeps_the_table_and_its_stds(path) -> None:
    FullCalibration(load_profile(path), path).write(
        FullSolved(solution(path), QUALITY, Verdict(True, False, ""), None)
    )
    before = load_profile(path)
    write_calibration(
        path,
        "calibrate --method exact",
        QUALITY,
        Verdict(True, False, ""),
        WrittenCalibration(
            level="offsets",
            joint_offsets_deg=[0.1] * 6,
            std_deg=[0.001] * 6,
            unobservable_joints=[],
            method="exact",
            approach="positive",
            sound_speed_m_s=1482.3,
            fit_verdict="ok",
            chi2_reduced=1.0,
            date="2026-12-06T08:00:00+00:00",
        ),
    )
    after = load_profile(path)
    np.testing.assert_array_equal(after.joint_offsets_deg, np.full(6, 0.1))
    np.testing.assert_array_equal(after.model.dh, before.model.dh)
    assert after.dh_std is not None and before.dh_std is not None
    np.testing.assert_array_equal(after.dh_std, before.dh_std)


def test_solvers_take_the_identified_stds_and_the_tolerance_elsewhere(path) -> None:
    FullCalibration(load_profile(path), path).write(
        FullSolved(solution(path), QUALITY, Verdict(True, False, ""), None)
    )
    profile = load_profile(path)
    prior = prior_from_profile(profile)
    want = np.where(np.isfinite(expected_std()), expected_std(), [0.2, 0.2, 0.02, 0.02])
    # the offsets level's unknowns (and check's, verify's: prior_from_profile)
    table = full_table(prior)
    got = {n: table.prior_stds[table.index(n)] for n in (*DH, "dh2_beta_deg")}
    np.testing.assert_allclose([got[n] for n in DH], want[:, :3].ravel(), rtol=2e-3)
    assert got["dh2_beta_deg"] == pytest.approx(want[1, 3], rel=2e-3)
    stds = prior.stds()
    np.testing.assert_array_equal([stds[PARAMETERS.index(n)] for n in DH], [got[n] for n in DH])
    # tool-frame's
    plane = fit_plane(profile.reflector_points_mm)
    plate = plate_prior(plane, profile.reflector_points_mm, 1.0)
    tf = _table(prior, plate, np.full(6, 10.0), np.zeros(0), _Data(prior, plate, (), (), 0), ())
    np.testing.assert_array_equal([tf.prior_stds[tf.index(n)] for n in DH], [got[n] for n in DH])
    # a profile without the key: the [robot] tolerance everywhere
    fresh = prior_from_profile(load_profile(path).replace(dh_std=None))
    np.testing.assert_array_equal(fresh.dh_prior_stds(), np.tile([0.2, 0.2, 0.02], 6))


def test_dh_std_round_trips_and_is_refused_where_it_describes_no_table(path) -> None:
    dh = load_profile(path).model.dh
    doc = tomlkit.parse(path.read_text())
    rows = [{"d_mm": -1.0, "a_mm": 0.01, "alpha_deg": 0.001} for _ in range(6)]
    rows[1]["beta_deg"] = 0.0005
    del rows[4]["a_mm"]  # left out: not determined, as -1
    doc["calibration"]["dh_std"] = rows
    path.write_text(tomlkit.dumps(doc))
    with pytest.raises(ProfileError) as err:  # no [calibration] dh: nothing to describe
        load_profile(path)
    assert err.value.key == "calibration.dh_std"
    doc["calibration"]["dh"] = [
        {"theta_offset_deg": r[0], "d_mm": r[1], "a_mm": r[2], "alpha_deg": r[3]}
        for r in dh.tolist()
    ]
    path.write_text(tomlkit.dumps(doc))
    std = load_profile(path).dh_std
    assert std is not None
    want = np.tile([np.nan, 0.01, 0.001, np.nan], (6, 1))
    want[1, 3], want[4, 1] = 0.0005, np.nan
    np.testing.assert_array_equal(std, want)
    doc["calibration"]["dh_std"][2]["alpah_deg"] = 0.001
    del doc["calibration"]["dh_std"][2]["alpha_deg"]
    path.write_text(tomlkit.dumps(doc))
    with pytest.raises(ProfileError) as err:
        load_profile(path)
    assert err.value.key == "calibration.dh_std[2].alpah_deg" and "alpha_deg" in str(err.value)
    doc["calibration"]["dh_std"][2] = {"d_mm": 20.0}
    path.write_text(tomlkit.dumps(doc))
    with pytest.raises(ProfileError) as err:
        load_profile(path)
    assert err.value.key == "calibration.dh_std[2].d_mm"
