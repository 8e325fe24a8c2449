"""The profile's ``[cell]`` table: the name a cell publishes under and its validation interval."""

from __future__ import annotations

from pathlib import Path

import pytest

from ucal.errors import InputError, ProfileError
from ucal.profile import default_profile_text, load_profile, profile_warnings
from ucal.profile.cell import CellSettings, cell_settings
from ucal.profile.validation import read_toml


def write(tmp_path: Path, extra: str, name: str = "cell.toml") -> Path:
    path = tmp_path / name
    path.write_text(default_profile_text("tx90l") + extra, encoding="utf-8")
    return path


def test_without_the_table_the_file_name_names_the_cell(tmp_path: Path) -> None:
    path = write(tmp_path, "", "line-4.toml")
    load_profile(path)
    assert cell_settings(path, read_toml(path)) == CellSettings("line-4")


def test_the_table_names_the_cell_and_its_interval(tmp_path: Path) -> None:
    path = write(tmp_path, '\n[cell]\nname = "Hall 2 / cell 4"\n')
    with pytest.raises(ProfileError, match=r"cell\.name: 'Hall 2 / cell 4' holds '/'"):
        load_profile(path)
    path = write(tmp_path, '\n[cell]\nname = "hall2-cell4"\nvalidation_interval_days = 14\n')
    load_profile(path)
    assert profile_warnings(path) == []  # known keys
    assert cell_settings(path, read_toml(path)) == CellSettings("hall2-cell4", 14.0)


@pytest.mark.parametrize(
    ("extra", "key"),
    [
        ('name = ""', "cell.name"),
        ('name = "$SYS"', "cell.name"),
        ('name = "a+b"', "cell.name"),
        (f'name = "{"x" * 65}"', "cell.name"),
        ("name = 3", "cell.name"),
        ("validation_interval_days = 0", "cell.validation_interval_days"),
        ("validation_interval_days = -3", "cell.validation_interval_days"),
        ('validation_interval_days = "30"', "cell.validation_interval_days"),
        ("validation_interval_days = 4000", "cell.validation_interval_days"),
    ],
)
def test_a_bad_cell_key_is_refused_naming_it(tmp_path: Path, extra: str, key: str) -> None:
    path = write(tmp_path, f"\n[cell]\n{extra}\n")
    with pytest.raises(ProfileError, match=key.replace(".", r"\.")) as e:
        load_profile(path)
    assert e.value.exit_code == 2


def test_a_misspelt_cell_key_is_refused(tmp_path: Path) -> None:
    path = write(tmp_path, "\n[cell]\nvalidation_interval_day = 7\n")
    with pytest.raises(ProfileError, match="did you mean validation_interval_days"):
        load_profile(path)


def test_a_file_name_that_is_no_topic_level_asks_for_a_name(tmp_path: Path) -> None:
    path = write(tmp_path, "", "a+b.toml")
    with pytest.raises(InputError, match=r"\[cell\] name"):
        cell_settings(path, read_toml(path))
