"""``[pulser] kind = "manual"``: a profile declares the front panel of a pulser set by hand, and
the world of such a cell serves the digitiser alone with the panel's true gain."""

from __future__ import annotations

from pathlib import Path

import pytest

from ucal.errors import ProfileError
from ucal.profile import default_profile_text, load_profile, profile_to_dict
from ucal.world import load_world

PANEL = 'kind = "manual"\ngain_db = 30.0\nprf_hz = 500.0\npulse_voltage_v = 200.0\n'


def profile(tmp_path: Path, pulser: str):
    path = tmp_path / "cell.toml"
    path.write_text(default_profile_text("tx90l") + "\n[pulser]\n" + pulser)
    return load_profile(path)


def test_the_front_panel_is_read_and_shown_and_timing_is_the_ascans(tmp_path: Path) -> None:
    cell = profile(tmp_path, PANEL)
    assert cell.pulser.set_by_hand and cell.pulser.timing == "ascan"
    by_hand = cell.pulser.by_hand
    assert by_hand is not None
    panel = by_hand.panel
    assert (panel.gain_db, panel.prf_hz, panel.pulse_voltage_v) == (30.0, 500.0, 200.0)
    assert (panel.damping_ohm, panel.high_pass_mhz, panel.low_pass_mhz) == (50.0, 1.0, 50.0)
    assert by_hand.input_noise_uv == 2.2
    shown = profile_to_dict(cell)["pulser"]
    assert shown["kind"] == "manual" and shown["gain_db"] == 30.0 and shown["prf_hz"] == 500.0


def test_a_remote_pulser_has_no_panel(tmp_path: Path) -> None:
    cell = profile(tmp_path, 'timing = "gate"\n')
    assert not cell.pulser.set_by_hand
    assert "kind" not in profile_to_dict(cell)["pulser"]


@pytest.mark.parametrize(
    "text, key, says",
    [
        ('kind = "manual"\n', "pulser.gain_db", "declares its gain"),
        ("gain_db = 30.0\n", "pulser.gain_db", 'add kind = "manual"'),
        ('kind = "hand"\n', "pulser.kind", "must be one of"),
        (PANEL.replace("prf_hz = 500.0", "prf_hz = 0.0"), "pulser.prf_hz", ">= 1"),
        (PANEL + "high_pass_mhz = 60.0\n", "pulser.low_pass_mhz", "empty filter band"),
        (PANEL + 'timing = "gate"\n', "pulser.timing", "no gate"),
        (PANEL + "input_noise_uv = 0\n", "pulser.input_noise_uv", "> 0"),
    ],
)
def test_a_bad_panel_names_the_file_and_the_key(
    tmp_path: Path, text: str, key: str, says: str
) -> None:
    with pytest.raises(ProfileError, match=rf"cell\.toml: {key}: .*{says}"):
        profile(tmp_path, text)


def test_the_world_of_a_cell_set_by_hand_is_manual_with_the_declared_gain(tmp_path: Path) -> None:
    cell = profile(tmp_path, PANEL)
    world = tmp_path / "world.toml"
    world.write_text("")
    truth = load_world(world, cell).pulser
    assert (truth.kind, truth.gain_db) == ("manual", 30.0)
    world.write_text("[pulser]\ngain_db = 50.0\nbits = 8\n")
    truth = load_world(world, cell).pulser
    assert (truth.kind, truth.gain_db, truth.bits) == ("manual", 50.0, 8)
    world.write_text("[pulser]\ngain_db = 500.0\n")
    with pytest.raises(ProfileError, match=r"world\.toml: pulser\.gain_db"):
        load_world(world, cell)
    world.write_text('[pulser]\nkind = "modbus"\ngain_db = 30.0\n')
    with pytest.raises(ProfileError, match=r"pulser\.gain_db: is the front panel's gain"):
        load_world(world, cell)


def test_profile_show_lists_the_panel(tmp_path: Path, run_main) -> None:
    profile(tmp_path, PANEL)
    code, out, _ = run_main(["profile", "show", str(tmp_path / "cell.toml")])
    assert code == 0
    rows = {
        line.split("│")[1].strip(): line.split("│")[2].strip()
        for line in out.splitlines()
        if line.count("│") == 3
    }
    assert rows["pulser.kind"] == "manual" and rows["pulser.gain_db"] == "30"
    assert rows["pulser.prf_hz"] == "500" and rows["pulser.input_noise_uv"] == "2.2"
