"""The shipped example world (``examples/world.toml``): valid, complete, and what it says it is.

It is the documentation of the world keys the code reads (the README points to it): every key
of ``ucal.world.KNOWN_WORLD_KEYS`` is listed in it, set or commented out, under its table.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from ucal.cell import CellProfile
from ucal.profile import default_profile_text, load_profile
from ucal.sim.demo import demo_world
from ucal.world import KNOWN_WORLD_KEYS, load_world, world_warnings

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "world.toml"


@pytest.fixture
def profile(tmp_path: Path) -> CellProfile:
    path = tmp_path / "cell.toml"
    path.write_text(default_profile_text("tx90l"), encoding="utf-8")
    return load_profile(path)


def listed_keys(text: str) -> set[tuple[str, str]]:
    """(table, key) of every key line, set or commented out (``# key = ...``)."""
    found: set[tuple[str, str]] = set()
    table = ""
    for line in text.splitlines():
        header = re.match(r"^#?\s*\[(\w+)\]", line)
        if header:
            table = header.group(1)
            continue
        key = re.match(r"^#?\s*(\w+)\s*=", line)
        if key:
            found.add((table, key.group(1)))
    return found


def test_every_world_key_is_listed() -> None:
    listed = listed_keys(EXAMPLE.read_text(encoding="utf-8"))
    known = {(t, k) for t, keys in KNOWN_WORLD_KEYS.items() for k in keys or ()}
    missing = sorted(f"[{t}] {k}" if t else k for t, k in known - listed)
    assert not missing, f"add these world keys to examples/world.toml, commented: {missing}"
    unknown = sorted(f"[{t}] {k}" for t, k in listed - known if t in KNOWN_WORLD_KEYS)
    assert not unknown, f"examples/world.toml lists keys the code does not read: {unknown}"


def test_it_loads_over_the_default_profile_without_warnings(profile: CellProfile) -> None:
    assert world_warnings(EXAMPLE) == []
    load_world(EXAMPLE, profile)


def test_it_states_the_demo_errors(profile: CellProfile) -> None:
    """Its header says: the built-in demo cell's errors, a warmer tank, a lower plate."""
    world, demo = load_world(EXAMPLE, profile), demo_world(profile)
    for name in ("joint_offsets_deg", "tool_position_mm", "tool_rotation_deg"):
        np.testing.assert_allclose(getattr(world, name), getattr(demo, name), atol=1e-9)
    np.testing.assert_allclose(world.sample_position_mm, demo.sample_position_mm, atol=1e-9)
    assert world.noise == demo.noise
    assert world.water_temperature_c == profile.water_temperature_c + 1.0
    assert demo.reflector is not None and world.reflector is not None
    assert world.reflector.point_mm[2] < demo.reflector.point_mm[2]
