"""World ``[pulser] kind``, ``sample_rate_mhz``, ``bits`` and ``scope``: the back-end a simulated
cell speaks, its digitiser and that oscilloscope's family."""

from __future__ import annotations

from pathlib import Path

import pytest

from ucal.errors import ProfileError
from ucal.profile import default_profile_text, load_profile
from ucal.world import load_world


def world(tmp_path: Path, text: str):
    profile_path = tmp_path / "cell.toml"
    profile_path.write_text(default_profile_text("tx90l"))
    path = tmp_path / "world.toml"
    path.write_text(text)
    return load_world(path, load_profile(profile_path))


def test_the_default_cell_speaks_modbus(tmp_path: Path) -> None:
    pulser = world(tmp_path, "").pulser
    assert (pulser.kind, pulser.sample_rate_mhz, pulser.bits) == ("modbus", 200.0, 12)
    assert pulser.scope == "keysight"


def test_the_oscilloscope_of_an_ascii_scpi_cell_may_be_a_rigol(tmp_path: Path) -> None:
    pulser = world(tmp_path, '[pulser]\nkind = "ascii-scpi"\nscope = "rigol"\n').pulser
    assert (pulser.kind, pulser.scope) == ("ascii-scpi", "rigol")


def test_an_ascii_scpi_cell_and_its_digitiser(tmp_path: Path) -> None:
    text = '[pulser]\nkind = "ascii-scpi"\nsample_rate_mhz = 100.0\nbits = 8\n'
    pulser = world(tmp_path, text).pulser
    assert (pulser.kind, pulser.sample_rate_mhz, pulser.bits) == ("ascii-scpi", 100.0, 8)


@pytest.mark.parametrize(
    "text, key",
    [
        ('kind = "gpib"', "pulser.kind"),
        ("sample_rate_mhz = 1.0", "pulser.sample_rate_mhz"),
        ("bits = 24", "pulser.bits"),
        ('scope = "tektronix"', "pulser.scope"),
    ],
)
def test_a_bad_value_names_the_file_and_the_key(tmp_path: Path, text: str, key: str) -> None:
    with pytest.raises(ProfileError, match=rf"world.toml.*{key}"):
        world(tmp_path, f"[pulser]\n{text}\n")
