"""``ucal calibrate --level full`` on the simulated cell, a short plan (a whole run is the
benchmark's: ``benchmarks/full_calibration.py``); the run recorded and replayed."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import numpy as np
import pytest

from ucal.profile import create_profile, load_profile
from ucal.profile.models import model_sheet

from doubles import ucal_here

pytestmark = pytest.mark.system

WORLD = """
[robot]
joint_offsets_deg = [0.3, -0.2, 0.25, -0.3, 0.2, 0.1]
backlash_deg = [0.015, 0.02, 0.008, 0.018, 0.012, 0.01]
# the arm bends as the model table's nominal stiffness says: the profile's prior, at its mean
stiffness_nm_per_rad = [6.3e5, 2.56e5, 2.56e5, 6.7e4, 5.7e4, 2.2e4]
# the TX90L's links (profiles/tx90l.toml): a world with its own DH table names its masses
link_mass_kg = [16.934564, 14.350897, 7.501506, 6.420429, 0.56876, 0.030977]
link_centre_of_mass_mm = [[19.143, 24.764, -64.596], [49.993, 221.192, 206.856],
  [50.002, 115.008, 503.572], [48.002, 49.992, 860.301], [50.0, 49.931, 1072.823],
  [49.757, 50.0, 1143.707]]
dh = [
  { theta_offset_deg = 0.0, d_mm = 0.0, a_mm = 50.3, alpha_deg = -90.03 },
  { theta_offset_deg = -90.0, d_mm = 50.2, a_mm = 500.4, alpha_deg = 0.02, beta_deg = 0.04 },
  { theta_offset_deg = 90.0, d_mm = 0.0, a_mm = 0.0, alpha_deg = 90.04 },
  { theta_offset_deg = 0.0, d_mm = 549.6, a_mm = 0.0, alpha_deg = -89.96 },
  { theta_offset_deg = 0.0, d_mm = 0.0, a_mm = 0.0, alpha_deg = 90.03 },
  { theta_offset_deg = 0.0, d_mm = 100.0, a_mm = 0.0, alpha_deg = 0.0 },
]
[noise]
tof_ns = 0.5
amplitude = 0.01
seed = 3
"""


def ucal(*args: str) -> subprocess.CompletedProcess:
    """``ucal ARGS`` in this process (``doubles.ucal_here``)."""
    return ucal_here(*args)


def test_full_level_writes_the_identified_table_and_replays(tmp_path: Path) -> None:
    profile = tmp_path / "cell.toml"
    create_profile(profile, "tx90l")
    world = tmp_path / "world.toml"
    world.write_text(WORLD)
    record = tmp_path / "run.jsonl"
    before = profile.read_bytes()
    r = ucal(
        "calibrate",
        str(profile),
        "--sim",
        str(world),
        "--level",
        "full",
        "--postures",
        "5",
        "--yes",
        "--json",
        "--record",
        str(record),
    )
    assert r.returncode == 0, r.stderr[-2000:]
    out = json.loads(r.stdout)
    assert out["level"] == "full" and out["written"] and out["fit"]["verdict"] == "ok"
    assert out["plan"]["postures"] == 5 and "D-optimality" in r.stderr
    ident = out["identification"]
    assert {"dh1_d_mm", "dh3_d_mm", "dh6_d_mm"} <= set(ident["not_identifiable"])
    assert ident["rank"] < ident["unknowns"] and ident["scale"]
    beta = ident["parameters"]["dh2_beta_deg"]
    assert abs(beta["value"] - 0.04) < 3 * beta["std"]
    assert profile.read_bytes() != before
    p = load_profile(profile)
    assert p.model.dh_source == "[calibration] dh"
    assert p.model.beta_deg[1] == pytest.approx(beta["value"], abs=1e-6)
    assert p.model.dh[1, 2] == pytest.approx(ident["parameters"]["dh2_a_mm"]["value"], abs=1e-5)
    # each identified parameter's std beside the table, at least the fit's; not identifiable: none
    assert p.dh_std is not None
    assert p.dh_std[1, 3] == out["dh_std"][1]["beta_deg"] and p.dh_std[1, 3] >= beta["std"]
    assert np.isnan(p.dh_std[0, 0]) and out["dh_std"][0]["d_mm"] is None  # d1: not identifiable
    backlash = [0.015, 0.02, 0.008, 0.018, 0.012, 0.01]
    # the offsets of the positive approach: the link lags the encoder by half the lost motion
    true = [o - b / 2 for o, b in zip([0.3, -0.2, 0.25, -0.3, 0.2, 0.1], backlash, strict=True)]
    for j, (v, sd) in enumerate(zip(out["joint_offsets_deg"], out["std_deg"], strict=True)):
        assert p.joint_offsets_deg[j] == pytest.approx(v, abs=1e-6)
        if sd is not None:  # few postures: some stay unobservable
            assert abs(v - true[j]) < 3 * sd
    # five postures cannot spare one to read from above: the lost motion is not measured
    # (it would pass its prior on to the offsets), and the offsets are the positive approach's
    assert out["backlash_deg"] == [None] * 6 and "From above" not in r.stderr
    # a rigid arm: no compliance to identify, none written (the model table's prior stands)
    assert out["stiffness_nm_per_rad"] == [None] * 6
    assert set(out["stiffness_status"]) == {"not determined"}
    assert np.array_equal(p.stiffness_nm_per_rad, model_sheet("tx90l").stiffness_nm_per_rad)

    # the recorded run solves again offline to the same numbers, and writes nothing
    written = profile.read_bytes()
    r = ucal("calibrate", str(profile), "--replay", str(record), "--json")
    assert r.returncode == 0, r.stderr[-2000:]
    again = json.loads(r.stdout)
    assert again["level"] == "full" and again["written"] is False
    keys = ("joint_offsets_deg", "std_deg", "dh", "dh_std", "identification", "plan", "fit")
    for key in (*keys, "stiffness_nm_per_rad", "stiffness_std_nm_per_rad"):
        assert again[key] == out[key], key
    assert again["pulser_reads"] == out["pulser_reads"] and again["moves"] == out["moves"]
    assert profile.read_bytes() == written
