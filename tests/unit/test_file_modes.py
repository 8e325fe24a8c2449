"""Every write keeps the user's file modes: a new file follows the umask, a rewritten file keeps
its mode, the history copies of a profile have the profile's mode."""

from __future__ import annotations

import os
import stat
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from ucal.profile import history_dir, undo_profile, write_profile

RunMain = Callable[[list[str]], tuple[int, str, str]]


def mode(path: Path) -> int:
    return stat.S_IMODE(path.stat().st_mode)


@pytest.fixture
def umask() -> Iterator[Callable[[int], None]]:
    old = os.umask(0o022)
    yield os.umask
    os.umask(old)


@pytest.mark.parametrize("mask, expected", [(0o022, 0o644), (0o077, 0o600), (0o002, 0o664)])
def test_a_new_profile_follows_the_umask(
    tmp_path: Path, umask: Callable[[int], None], run_main: RunMain, mask: int, expected: int
) -> None:
    umask(mask)
    path = tmp_path / "cell.toml"
    assert run_main(["profile", "init", "tx90l", str(path), "-q"])[0] == 0
    assert mode(path) == expected


@pytest.mark.parametrize("kept", [0o640, 0o604, 0o600])
def test_rewrites_keep_the_mode_and_history_copies_share_it(
    tmp_path: Path, umask: Callable[[int], None], run_main: RunMain, kept: int
) -> None:
    path = tmp_path / "cell.toml"
    assert run_main(["profile", "init", "tx90l", str(path)])[0] == 0
    path.chmod(kept)
    write_profile(path, {"water": {"temperature_c": 21.0}}, reason="test")
    assert mode(path) == kept
    hdir = history_dir(path)
    assert {f.name: mode(f) for f in hdir.iterdir()} == {
        "0001-before.toml": kept,
        "history.json": kept,
    }
    assert run_main(["profile", "init", "tx90l", str(path), "--force"])[0] == 0
    undo_profile(path)
    assert mode(path) == kept
    assert {mode(f) for f in hdir.iterdir()} == {kept}
    assert sorted(f.name for f in hdir.iterdir()) == [
        "0001-before.toml",
        "0002-after.toml",
        "0002-before.toml",
        "history.json",
    ]


def test_path_output_keeps_its_mode_or_follows_the_umask(
    tmp_path: Path, umask: Callable[[int], None], run_main: RunMain
) -> None:
    profile = tmp_path / "cell.toml"
    assert run_main(["profile", "init", "tx90l", str(profile)])[0] == 0
    poses = tmp_path / "scan.csv"
    poses.write_text("600,0,300,180,0,0\n610,0,300,180,0,0\n", encoding="utf-8")
    umask(0o007)
    out = tmp_path / "joints.csv"
    assert run_main(["path", str(profile), str(poses), "-o", str(out)])[0] == 0
    assert mode(out) == 0o660
    first = out.read_bytes()
    out.chmod(0o600)
    assert run_main(["path", str(profile), str(poses), "-o", str(out)])[0] == 0
    assert mode(out) == 0o600 and out.read_bytes() == first
    assert first.startswith(b"J1,J2,J3,J4,J5,J6,shoulder,elbow,wrist\r\n")
