"""Bad profile and world files: exit 2 naming the file, the key and its line, never an internal
error (SPEC.md, exit codes), whatever the edit that broke them."""

from __future__ import annotations

from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from ucal.errors import InputError, ProfileError
from ucal.profile import default_profile_text, load_profile
from ucal.world import load_world

from doubles import exit_code, hand_edited

TEMPLATE = default_profile_text("tx90l")
LINES = TEMPLATE.splitlines(keepends=True)


@pytest.mark.parametrize(
    ("text", "key", "line"),
    [
        ("a = 1\na = 2\n", "a", 2),
        ("[r]\nx = 1\n[s]\n[r]\ny = 2\n", "r", 4),
        ("p = { a = 1, a = 2 }\n", "a", 1),
        ("[[t]]\na = 1\na = 2\n", "a", 3),
        ("a.b = 1\na.b = 2\n", "b", 2),
    ],
)
def test_a_key_defined_twice_is_named_with_its_line(
    tmp_path: Path, text: str, key: str, line: int
) -> None:
    p = tmp_path / "cell.toml"
    p.write_text(text, encoding="utf-8")
    with pytest.raises(ProfileError) as e:
        load_profile(p)
    assert str(e.value) == (
        f"{p}: not valid TOML: '{key}' is defined twice (line {line}): keep one of the two"
    )


def test_a_duplicated_profile_key_is_exit_2_on_every_command(tmp_path: Path) -> None:
    """The defect of 2026-11: a key pasted twice into [robot] was exit 1, "internal error:
    KeyAlreadyPresent"."""
    p = tmp_path / "cell.toml"
    text = TEMPLATE.replace('model = "tx90l"\n', 'model = "tx90l"\nmodel = "tx90"\n', 1)
    p.write_text(text, encoding="utf-8")
    line = text.splitlines().index('model = "tx90"') + 1
    for args in (
        ["profile", "validate", str(p)],
        ["calibrate", str(p), "--sim", "--yes", "--dry-run"],
        ["fk", str(p), "0,0,90,0,0,0"],
    ):
        assert exit_code(args) == 2, args
    with pytest.raises(ProfileError, match=rf"'model' is defined twice \(line {line}\)"):
        load_profile(p)
    assert p.read_text(encoding="utf-8") == text


#: What a hand puts in a profile's value.
TOKENS = ['"x"', "-1", "0", "1e300", "nan", "inf", "[]", "[1, 2]", "{}", "true", "1025", '"']


@settings(max_examples=300, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(text=hand_edited(LINES, TOKENS))
def test_an_edited_profile_is_read_or_refused_by_name(tmp_path: Path, text: str) -> None:
    """Every hand edit of the profile either reads or raises ``ProfileError`` naming the file;
    no other exception (which the command line would call an internal error, exit 1)."""
    p = tmp_path / "cell.toml"
    p.write_text(text, encoding="utf-8")
    try:
        profile = load_profile(p)
    except ProfileError as e:
        assert str(e).startswith(f"{p}: ") and "\n" not in str(e)
        return
    # a profile that reads is a valid one for the world reader too
    world = tmp_path / "world.toml"
    world.write_text(text.split("[robot]", 1)[0], encoding="utf-8")
    try:
        load_world(world, profile)
    except InputError as e:
        assert "\n" not in str(e)


@settings(max_examples=200)
@given(
    text=st.lists(
        st.sampled_from(
            [
                "[joint_offsets_deg]\n",
                "[sample]\n",
                "[tool]\n",
                "[noise]\n",
                "values = [0.1, 0.2, 0.3, 0.4, 0.5, 0.6]\n",
                "values = [0.1, 0.2]\n",
                "position_mm = [1.0, 2.0, 3.0]\n",
                "position_mm = 1e300\n",
                "tof_ns = -1\n",
                "tof_ns = nan\n",
                "a = 1\n",
                "values = 1\n",
                "x = { y = 1, y = 2 }\n",
                "[[t]]\n",
                "= 3\n",
            ]
        ),
        max_size=8,
    ).map("".join)
)
def test_an_edited_world_is_read_or_refused_by_name(text: str) -> None:
    import tempfile

    profile = load_profile_template()
    with tempfile.TemporaryDirectory() as d:
        world = Path(d) / "world.toml"
        world.write_text(text, encoding="utf-8")
        try:
            load_world(world, profile)
        except InputError as e:
            assert "\n" not in str(e) and str(world) in str(e)


def load_profile_template() -> object:
    import tempfile

    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / "cell.toml"
        p.write_text(TEMPLATE, encoding="utf-8")
        return load_profile(p)
