"""``[pulser] register_map`` in a profile and in a world file: the path relative to the file that
names it, the map read and validated with it, a bad map an exit 2 naming the map and its key."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from drivers.pulser.map_file import shipped_map
from ucal.cli import main
from ucal.errors import ProfileError
from ucal.profile import (
    default_profile_text,
    load_profile,
    profile_to_dict,
    profile_warnings,
    write_profile,
)
from ucal.sim.serve import SimulatedCellServer
from ucal.world import load_world

SHIFTED_MAP_PATH = Path(__file__).resolve().parents[1] / "data" / "shifted_pulser_map.toml"


def _profile(directory: Path, pulser: str = "") -> Path:
    directory.mkdir(parents=True, exist_ok=True)
    path = directory / "cell.toml"
    path.write_text(default_profile_text("tx90l") + pulser, encoding="utf-8")
    return path


def test_without_the_key_the_shipped_map_is_used(tmp_path: Path) -> None:
    profile = load_profile(_profile(tmp_path))
    assert profile.pulser.register_map is None and profile.pulser.register_map_path is None
    assert profile_to_dict(profile)["pulser"] == {
        "register_map": None,
        "timeout_s": 1.0,
        "retries": 1,
        "timing": "gate",
        "reference_echo": None,
    }
    server = SimulatedCellServer(None, profile)
    assert server.register_map is None  # the simulated pulser's default: ucal's own map


def test_the_pulser_timeout_and_retries_are_read_and_checked(tmp_path: Path) -> None:
    path = _profile(tmp_path)
    text = path.read_text(encoding="utf-8")
    path.write_text(text + "\n[pulser]\ntimeout_s = 2.5\nretries = 3\n", encoding="utf-8")
    profile = load_profile(path)
    assert (profile.pulser.timeout_s, profile.pulser.retries) == (2.5, 3)
    path.write_text(text + "\n[pulser]\ntimeout_s = 0\n", encoding="utf-8")
    with pytest.raises(ProfileError, match=r"pulser\.timeout_s"):
        load_profile(path)


def test_a_relative_map_is_read_next_to_the_profile(tmp_path: Path) -> None:
    (tmp_path / "cell" / "maps").mkdir(parents=True)
    shutil.copy(SHIFTED_MAP_PATH, tmp_path / "cell" / "maps" / "my_pulser.toml")
    path = _profile(tmp_path / "cell", '\n[pulser]\nregister_map = "maps/my_pulser.toml"\n')
    profile = load_profile(path)
    assert profile.pulser.register_map_path == tmp_path / "cell" / "maps" / "my_pulser.toml"
    assert profile.pulser.register_map is not None
    assert profile.pulser.register_map.name == "shifted test pulser"
    assert profile_warnings(path) == []  # a key ucal knows
    shown = profile_to_dict(profile)["pulser"]["register_map"]
    assert shown == str(tmp_path / "cell" / "maps" / "my_pulser.toml")
    # the profile's map is the simulated pulser's too, unless the world says otherwise
    assert SimulatedCellServer(None, profile).register_map is profile.pulser.register_map


def test_a_written_profile_keeps_its_map(tmp_path: Path) -> None:
    shutil.copy(SHIFTED_MAP_PATH, tmp_path / "my_pulser.toml")
    path = _profile(tmp_path, '\n[pulser]\nregister_map = "my_pulser.toml"\n')
    write_profile(path, {"water": {"temperature_c": 21.0}}, "test")
    assert 'register_map = "my_pulser.toml"' in path.read_text()
    assert load_profile(path).pulser.register_map is not None


def test_a_bad_map_is_an_exit_2_naming_the_map_file_and_its_key(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bad = tmp_path / "my_pulser.toml"
    bad.write_text(SHIFTED_MAP_PATH.read_text().replace("scale = 0.1  #", "scale = -0.1  #"))
    path = _profile(tmp_path, '\n[pulser]\nregister_map = "my_pulser.toml"\n')
    with pytest.raises(ProfileError) as err:
        load_profile(path)
    assert err.value.path == str(bad) and err.value.key == "registers.tof.scale"
    for args in (
        ["profile", "validate", str(path)],
        ["calibrate", str(path), "--sim", "--dry-run"],
    ):
        with pytest.raises(SystemExit) as exc:
            main(args)
        assert exc.value.code == 2
        out = capsys.readouterr()
        lines = out.err.strip().splitlines()
        assert len(lines) == 1, out.err
        assert lines[0].startswith(f"error: {bad}: registers.tof.scale: must be > 0"), lines[0]
        assert f"(pulser.register_map in {path})" in lines[0]


@pytest.mark.parametrize(
    ("value", "key", "message"),
    [
        ('"missing.toml"', "missing.toml", "cannot read"),
        ("3", "pulser.register_map", "must be a non-empty string"),
        ('""', "pulser.register_map", "must be a non-empty string"),
    ],
)
def test_a_missing_or_malformed_key_names_it(
    tmp_path: Path, value: str, key: str, message: str
) -> None:
    path = _profile(tmp_path, f"\n[pulser]\nregister_map = {value}\n")
    with pytest.raises(ProfileError, match=message) as err:
        load_profile(path)
    if key.endswith(".toml"):  # an unreadable map names the map, then the profile's key
        assert err.value.path == str(tmp_path / key)
        assert "(pulser.register_map in" in str(err.value)
    else:
        assert err.value.path == str(path) and err.value.key == key


def test_the_world_chooses_the_simulated_pulsers_map(tmp_path: Path) -> None:
    shutil.copy(SHIFTED_MAP_PATH, tmp_path / "other.toml")
    profile = load_profile(_profile(tmp_path / "cell"))
    world_path = tmp_path / "world.toml"
    world_path.write_text('[pulser]\nregister_map = "other.toml"\namplitude_bits = 12\n')
    world = load_world(world_path, profile)
    assert world.pulser.register_map_path == tmp_path / "other.toml"
    assert world.pulser.amplitude_bits == 12
    server = SimulatedCellServer(world, profile)
    assert server.register_map is world.pulser.register_map
    assert server.register_map is not None and server.register_map != shipped_map()
    world_path.write_text('[pulser]\nregister_map = "nowhere.toml"\n')
    with pytest.raises(ProfileError, match=r"nowhere.toml: cannot read.*pulser.register_map in"):
        load_world(world_path, profile)
