"""What verify's figure is known to when the DH table is not identified: the physics (a wrist
off its table moves the reconstructed TCP across the beam, not along it), the bound it promises
(``measured_within_mm``), and the verdict, message and notes drawn from that bound."""

from __future__ import annotations

from dataclasses import replace
from datetime import datetime, timedelta

import numpy as np
import pytest
import tomlkit

from ucal.devices.record import decode, encode
from ucal.model.priors import prior_from_profile
from ucal.profile import (
    create_profile,
    default_profile_text,
    load_profile,
    profile_from_data,
    profile_history,
    write_profile,
)
from ucal.verify.inputs import (
    BeforeProfile,
    SoundSpeed,
    sound_speed_for_verify,
    wrist_left_unidentified,
)
from ucal.verify.measure import PointResult, VerifyResult
from ucal.verify.plan import plan_verify
from ucal.verify.result import (
    MEASURED_WITHIN_MM,
    Verification,
    VerifySolved,
    budget_json,
    marginal,
    measured_within_mm,
    table_note,
    tool_notes,
    water_note,
)
from ucal.verify.solve import (
    ToolOffset,
    reconstruction_error_mm,
    unidentified_at_points_mm,
)

#: calibrate's [calibration] unidentified_tcp_mm on a TX90L with the default DH tolerances
#: (0.2 mm, 0.02°): mean and largest one sigma over the scanning region (mm)
UNIDENTIFIED = (0.204, 0.379)


@pytest.fixture(scope="module")
def profile():
    return profile_from_data(tomlkit.parse(default_profile_text("tx90l")), "cell.toml")


def test_a_wrist_off_its_table_moves_the_reached_tcp_across_the_beam(profile) -> None:
    """Row 5's d 0.2 mm off (one sigma of the default tolerance): exact echoes from that
    robot, reconstructed with the profile's table, put the TCP of the points straight down 0.2
    mm off across the beam and nothing along it; the tilted point off along it too."""
    dh = profile.model.dh.copy()
    dh[4, 1] += 0.2
    plan = plan_verify(profile, 3)
    errors = reconstruction_error_mm(profile, replace(profile.model, dh=dh), plan)
    down, turned, tilted = errors
    for e in (down, turned):
        assert abs(e[2]) < 1e-6  # along the beam: the XY face's own water path
        assert np.hypot(e[0], e[1]) == pytest.approx(0.2, abs=0.002)
    assert 0.01 < abs(tilted[2]) < 0.05 and np.hypot(tilted[0], tilted[1]) > 0.15
    # four times what verify promised with the table taken as exact
    assert np.max(np.abs(errors)) > 3.0 * MEASURED_WITHIN_MM


def test_at_its_points_the_promise_holds_what_d5_and_a5_do_there(profile) -> None:
    """After the full level, d5 and a5 at [robot] dh_length_std_mm (0.2 mm): each puts the
    points straight down 0.2 mm off across the beam, at right angles to each other, so 0.2 mm
    on either axis in quadrature; the promise is 0.05 mm and twice that (0.45 mm) where the
    region's figure (0.379 mm max, one sigma) would make it 0.81."""
    plan = plan_verify(profile, 3)
    sigma = unidentified_at_points_mm(profile, plan, ("d5", "a5"))
    assert sigma == pytest.approx(0.2, abs=0.005)
    solved = replace(
        solved_with(profile, 0.6, UNIDENTIFIED),
        unidentified_names=("d5", "a5"),
        unidentified_at_points_mm=sigma,
    )
    assert solved.measured_within_mm == pytest.approx(0.05 + 2.0 * sigma)
    assert solved.table_unidentified and marginal(solved)
    [note] = table_note(solved)
    assert "up to 0.379 mm" in note and f"up to {sigma:.3f} mm off on an axis" in note


def test_measured_within_adds_twice_the_tables_largest_sigma() -> None:
    assert measured_within_mm(None) == MEASURED_WITHIN_MM
    assert measured_within_mm(UNIDENTIFIED) == pytest.approx(0.05 + 2.0 * 0.379)
    assert measured_within_mm((0.005, 0.01)) == pytest.approx(0.07)


def solved_with(profile, after_mm: float, unidentified) -> VerifySolved:
    """A solved run whose one "after" point deviates ``after_mm`` in X, tolerance 0.5 mm."""
    plan = plan_verify(profile, 1)
    points = [
        PointResult(
            t.pass_name,
            t.index,
            plan.nominal_mm[t.index],
            t.joints_deg,
            (),
            plan.nominal_mm[t.index],
            plan.nominal_mm[t.index] + [after_mm if t.pass_name == "after" else 3.0, 0.0, 0.0],
            0.0,
        )
        for t in plan.targets
    ]
    result = VerifyResult(plan, points, moves=0, reads=0)
    return VerifySolved(
        result,
        BeforeProfile(np.zeros(6), "zero"),
        SoundSpeed(1482.0, 20.0, "thermometer"),
        0.5,
        after_mm,
        unidentified_tcp_mm=unidentified,
    )


def verification(solved: VerifySolved) -> Verification:
    return Verification(solved, None, [], None)  # type: ignore[arg-type]


def test_a_verdict_within_the_tables_share_is_marginal_and_names_it(profile) -> None:
    """0.6 mm against 0.5: a plain fail with the table identified (0.1 mm > 0.05); marginal,
    the message and a note naming the unidentified table and its cure, with it not."""
    known = solved_with(profile, 0.6, None)
    assert not known.passed and not marginal(known)
    assert "--level full" not in verification(known).message()
    assert table_note(known) == []

    unknown = solved_with(profile, 0.6, UNIDENTIFIED)
    assert not unknown.passed and marginal(unknown)
    msg = verification(unknown).message()
    assert msg.startswith("verify: a point deviates 0.600 mm after calibration, above")
    assert "±0.81 mm with the DH table not identified" in msg and "--level full" in msg
    [note] = table_note(unknown)
    assert "up to 0.379 mm" in note and "±0.81 mm" in note and "--level full" in note
    # a run far outside both: not marginal, the plain message
    far = solved_with(profile, 1.5, UNIDENTIFIED)
    assert not marginal(far) and "--level full" not in verification(far).message()
    # a full-level table (hundredths): verify's own figure, no note
    assert table_note(solved_with(profile, 0.6, (0.005, 0.01))) == []


def test_after_the_full_level_the_note_names_what_it_left_unidentified(profile) -> None:
    """A full-level table: rows 1, 3 (d) and 5 (d, a) not determined in [calibration] dh_std;
    the note, the message and --json name row 5's d5, a5 (row 1's and row 3's d are gauges)
    and send nobody to the full level again."""
    dh_std = np.full((6, 4), 0.01)
    dh_std[[0, 2, 4], 0] = np.nan
    dh_std[4, 1] = np.nan
    dh_std[5] = np.nan
    full = profile.replace(dh_std=dh_std)
    assert wrist_left_unidentified(full) == ("d5", "a5")
    assert wrist_left_unidentified(profile) == ()
    solved = replace(solved_with(full, 0.6, UNIDENTIFIED), unidentified_names=("d5", "a5"))
    assert marginal(solved)
    msg = verification(solved).message()
    assert "±0.81 mm with the DH table's d5, a5 not identified" in msg and "--level" not in msg
    [note] = table_note(solved)
    assert note.startswith("the DH table's d5, a5 are not identified")
    assert "up to 0.379 mm" in note and "±0.81 mm" in note and "scanning region" in note
    assert budget_json(UNIDENTIFIED, ("d5", "a5")) == {
        "mean": 0.204,
        "max": 0.379,
        "quantities": ["d5", "a5"],
    }


def test_the_tables_share_is_not_called_a_tool_error(profile) -> None:
    """The tool check on a cell whose table is off: 0.21 mm 'shorter along the beam' is the
    tool's error beyond its 0.05 mm with the table exact, and within what the unidentified
    table leaves with it."""
    measured = profile.replace(tool_position_std_mm=np.full(3, 0.05))
    tool = ToolOffset(-0.213, np.array([-0.117, -0.044, 0.0]), np.array([0.0, 0.0, 1.0]), True)
    [along] = tool_notes(tool, measured)
    assert "0.213 mm shorter along the beam" in along and "beyond" in along
    assert tool_notes(tool, measured, measured_within_mm(UNIDENTIFIED)) == []


def test_the_budget_verify_used_is_recorded_for_its_replay() -> None:
    inputs = {"unidentified": UNIDENTIFIED, "none": None}
    assert decode(encode(inputs)) == inputs


def test_the_tanks_sound_speed_since_calibrate_is_in_the_promise(tmp_path) -> None:
    """verify reads its water paths with the sound speed calibrate measured: the tank may have
    warmed or cooled since by the profile's drift tolerance a minute, at most its thermometer's
    tolerance; a wall's 150 mm carries that into the promise, in quadrature with the table."""
    path = tmp_path / "cell.toml"
    create_profile(path, "tx90l")
    write_profile(path, {"water": {"drift_std_c_per_min": 0.02}}, "the tank")
    assert sound_speed_for_verify(load_profile(path), path).std_m_s == pytest.approx(
        prior_from_profile(load_profile(path)).sound_speed_std_m_s  # never calibrated: ±2 °C
    )
    write_profile(path, {"calibration": {"sound_speed_m_s": 1482.4}}, "calibrate")
    profile = load_profile(path)
    written = datetime.fromisoformat(profile_history(path)[-1].time)
    slope = prior_from_profile(profile).sound_speed_slope_m_s_per_c
    sounds = {}
    for minutes, warmed_c in ((0.0, 0.0), (10.0, 0.2), (60.0, 1.2), (600.0, 2.0)):
        sound = sound_speed_for_verify(profile, path, written + timedelta(minutes=minutes))
        assert sound.m_s == 1482.4 and sound.age_min == pytest.approx(minutes)
        assert sound.std_m_s == pytest.approx(slope * warmed_c)
        assert f"{minutes:.0f} min ago" in sound.source
        sounds[minutes] = sound
    # an hour after: 1.2 °C, 3.7 m/s, 0.37 mm on a wall's 150 mm
    water = sounds[60.0].path_std_mm(150.0)
    assert water == pytest.approx(150.0 * slope * 1.2 / 1482.4) and 0.35 < water < 0.39
    assert measured_within_mm(UNIDENTIFIED, water) == pytest.approx(
        MEASURED_WITHIN_MM + 2.0 * np.hypot(UNIDENTIFIED[1], water)
    )
    assert measured_within_mm(UNIDENTIFIED, 0.0) == measured_within_mm(UNIDENTIFIED)


def test_a_tank_unknown_since_is_said_in_the_notes_and_makes_a_verdict_marginal(
    profile,
) -> None:
    """0.6 mm against 0.5 with the table identified: a plain fail on a tank measured a minute
    ago; an hour later (3.7 m/s, 0.37 mm on a wall) marginal, the note naming the water."""
    solved = solved_with(profile, 0.6, None)
    assert not marginal(solved) and water_note(solved) == []
    sound = SoundSpeed(1482.4, 20.0, "[calibration] sound_speed_m_s", 3.7, 60.0)
    later = replace(solved, sound=sound)
    assert later.water_unknown and not later.table_unidentified and marginal(later)
    (note,) = water_note(later)
    assert "60 min ago" in note and "±0.37 mm" in note and "`ucal calibrate`" in note
