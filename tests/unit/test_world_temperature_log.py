"""World ``[water] temperature_log``: the tank thermometer's readings over the run, read from a
CSV file beside the world file, in place of ``temperature_c`` and ``drift_c_per_min``."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from ucal.cell import CellProfile, WorldTruth
from ucal.errors import ProfileError
from ucal.profile import default_profile_text, load_profile
from ucal.world import load_world


@pytest.fixture
def tx90l(tmp_path: Path) -> CellProfile:
    (tmp_path / "tx90l.toml").write_text(default_profile_text("tx90l"))
    return load_profile(tmp_path / "tx90l.toml")


def logged_world(folder: Path, csv_text: str, water: str = "") -> Path:
    """A world file in ``folder/worlds`` naming ``logs/t.csv`` beside it, holding ``csv_text``."""
    (folder / "worlds" / "logs").mkdir(parents=True, exist_ok=True)
    (folder / "worlds" / "logs" / "t.csv").write_text(csv_text)
    world_path = folder / "worlds" / "w.toml"
    world_path.write_text(f'[water]\ntemperature_log = "logs/t.csv"\n{water}')
    return world_path


def test_the_log_is_read_relative_to_the_world_file(tx90l: CellProfile, tmp_path: Path) -> None:
    text = "time_min,temperature_c\n# the Pt100, every two minutes\n-2,19.5\n\n2, 20.5\n6,20.25\n"
    w: WorldTruth = load_world(logged_world(tmp_path, text), tx90l)
    log = w.water_temperature_log
    assert log is not None
    assert log.path == tmp_path / "worlds" / "logs" / "t.csv"
    np.testing.assert_array_equal(log.time_min, [-2.0, 2.0, 6.0])
    np.testing.assert_array_equal(log.temperature_c, [19.5, 20.5, 20.25])
    # the world's temperature is the log's at the start; no linear drift on top
    assert (w.water_temperature_c, w.water_drift_c_per_min) == (20.0, 0.0)


def test_the_water_follows_the_log_between_readings_and_holds_outside(
    tx90l: CellProfile, tmp_path: Path
) -> None:
    log = load_world(logged_world(tmp_path, "0,20\n1,22\n3,21\n"), tx90l).water_temperature_log
    assert log is not None
    times = [-5.0, 0.0, 0.25, 1.0, 2.0, 2.5, 3.0, 60.0]
    expected = [20.0, 20.0, 20.5, 22.0, 21.5, 21.25, 21.0, 21.0]
    assert [log.at(t) for t in times] == pytest.approx(expected, abs=1e-12)
    one = load_world(logged_world(tmp_path, "time_min,temperature_c\n4,23.5\n"), tx90l)
    assert one.water_temperature_log is not None
    assert [one.water_temperature_log.at(t) for t in (0.0, 4.0, 9.0)] == [23.5] * 3


#: A log's faults: the CSV's text, the row named (None: the file) and words of the message.
BAD_LOGS = [
    # past the first row, no header is offered
    ("0,20\n1,twenty\n", "row 2", "minutes and °C, got '1,twenty' (water.temperature_log in"),
    ("minutes,celsius\n0,20\n", "row 1", "'minutes,celsius' (a header is time_min,temperature_c)"),
    ("0,20,1\n", "row 1", "expected two numbers"),
    ("0,20\n2,21\n2,22\n", "row 3", "times must increase: 2 min after 2 min"),
    ("0,20\n2,21\n1,22\n", "row 3", "times must increase: 1 min after 2 min"),
    ("0,20\ninf,21\n", "row 2", "expected a finite time"),
    ("0,20\n1,61\n", "row 2", "0-60 °C"),
    ("time_min,temperature_c\n# nothing yet\n", None, "no readings"),
    ("", None, "no readings"),
]


@pytest.mark.parametrize("text, row, words", BAD_LOGS)
def test_a_bad_log_names_its_file_row_and_the_world_key(
    text: str, row: str | None, words: str, tx90l: CellProfile, tmp_path: Path
) -> None:
    world_path = logged_world(tmp_path, text)
    with pytest.raises(ProfileError) as err:
        load_world(world_path, tx90l)
    csv_path = tmp_path / "worlds" / "logs" / "t.csv"
    where = f"{csv_path}: {row}" if row else f"{csv_path}"
    assert str(err.value).startswith(f"{where}: ")
    assert words in str(err.value)
    assert str(err.value).endswith(f"(water.temperature_log in {world_path})")
    assert err.value.exit_code == 2  # SPEC.md: an invalid world file


def test_a_missing_log_names_the_file_and_the_key(tx90l: CellProfile, tmp_path: Path) -> None:
    world_path = tmp_path / "w.toml"
    world_path.write_text('[water]\ntemperature_log = "nowhere.csv"\n')
    with pytest.raises(ProfileError) as err:
        load_world(world_path, tx90l)
    message = str(err.value)
    assert message.startswith(f"{tmp_path / 'nowhere.csv'}: cannot read: ")
    assert message.endswith(f"(water.temperature_log in {world_path})")
    assert err.value.exit_code == 2


@pytest.mark.parametrize("key", ["temperature_c = 21.0", "drift_c_per_min = 0.1"])
def test_the_log_replaces_the_temperature_and_its_drift(
    key: str, tx90l: CellProfile, tmp_path: Path
) -> None:
    world_path = logged_world(tmp_path, "0,20\n", water=key + "\n")
    with pytest.raises(ProfileError) as err:
        load_world(world_path, tx90l)
    name = "water." + key.split(" ")[0]
    assert str(err.value) == (
        f"{world_path}: {name}: not with water.temperature_log: the log gives the water's "
        "temperature over the run"
    )
    assert err.value.exit_code == 2
