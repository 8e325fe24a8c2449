"""Profile writes under faults: symbolic links, a full disk, leftovers of interrupted writes."""

from __future__ import annotations

import errno
import os
from pathlib import Path

import pytest

from ucal.errors import EXIT_USAGE, ProfileError
from ucal.profile import (
    default_profile_text,
    history_dir,
    profile_history,
    undo_profile,
    write_profile,
)

UPDATE = {"calibration": {"joint_offsets_deg": [0.1, -0.2, 0.3, 0.0, 0.05, 0.0]}}


@pytest.fixture
def cell(tmp_path: Path) -> Path:
    p = tmp_path / "cell.toml"
    p.write_text(default_profile_text("tx90l"), encoding="utf-8")
    return p


def _leftovers(directory: Path) -> list[str]:
    return sorted(f.name for f in directory.iterdir() if f.name.endswith(".tmp"))


# --- symbolic links -----------------------------------------------------------------------------
def test_symlinked_profile_is_written_through_the_link(tmp_path: Path) -> None:
    real_dir, link_dir = tmp_path / "profiles", tmp_path / "cells"
    real_dir.mkdir()
    link_dir.mkdir()
    real = real_dir / "tx90l-cell-3.toml"
    real.write_text(default_profile_text("tx90l"), encoding="utf-8")
    link = link_dir / "cell.toml"
    link.symlink_to(real)
    before = real.read_bytes()

    write_profile(link, UPDATE, reason="calibrate")

    assert link.is_symlink() and link.resolve() == real.resolve()
    assert "0.1, -0.2, 0.3" in real.read_text(encoding="utf-8")
    assert history_dir(link) == real_dir / "tx90l-cell-3.toml.history"
    assert (real_dir / "tx90l-cell-3.toml.history" / "0001-before.toml").read_bytes() == before
    assert not (link_dir / "cell.toml.history").exists()
    assert [e.reason for e in profile_history(link)] == ["calibrate"]

    undo_profile(link)
    assert link.is_symlink() and real.read_bytes() == before


# --- a full disk --------------------------------------------------------------------------------
def _full_disk(monkeypatch: pytest.MonkeyPatch, fail_from_call: int = 1) -> list[int]:
    """Make every fsync from the ``fail_from_call``-th one raise ENOSPC, as a full disk does."""
    calls = [0]
    real_fsync = os.fsync

    def fsync(fd: int) -> None:
        calls[0] += 1
        if calls[0] >= fail_from_call:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        real_fsync(fd)

    monkeypatch.setattr(os, "fsync", fsync)
    return calls


@pytest.mark.parametrize("fail_from_call", [1, 2, 3], ids=["history-copy", "index", "profile"])
def test_full_disk_leaves_the_profile_and_history_as_they_were(
    cell: Path, monkeypatch: pytest.MonkeyPatch, fail_from_call: int
) -> None:
    write_profile(cell, {"water": {"temperature_c": 21.0}}, reason="first")  # history exists
    before = cell.read_bytes()
    hdir = history_dir(cell)
    files_before = sorted(f.name for f in hdir.iterdir())
    index_before = (hdir / "history.json").read_bytes()

    with monkeypatch.context() as m:
        _full_disk(m, fail_from_call)
        with pytest.raises(ProfileError, match="No space left on device") as err:
            write_profile(cell, UPDATE, reason="calibrate")
    assert err.value.exit_code == EXIT_USAGE
    assert str(err.value).count("\n") == 0
    assert cell.read_bytes() == before
    assert sorted(f.name for f in hdir.iterdir()) == files_before
    assert (hdir / "history.json").read_bytes() == index_before
    assert _leftovers(cell.parent) == [] and _leftovers(hdir) == []

    # the disk has room again: the next write works and takes the next number
    write_profile(cell, UPDATE, reason="calibrate")
    assert [e.before for e in profile_history(cell)] == ["0001-before.toml", "0002-before.toml"]


def test_failed_history_copy_does_not_block_later_writes(
    cell: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    before = cell.read_bytes()
    with monkeypatch.context() as m:
        _full_disk(m)
        for _ in range(3):
            with pytest.raises(ProfileError, match="cannot write history copy"):
                write_profile(cell, UPDATE, reason="calibrate")
    assert cell.read_bytes() == before
    assert list(history_dir(cell).iterdir()) == []  # no empty 0001-before.toml left
    write_profile(cell, UPDATE, reason="calibrate")
    assert [e.id for e in profile_history(cell)] == [1]


def test_a_copy_left_by_an_older_interrupted_write_is_skipped(cell: Path) -> None:
    hdir = history_dir(cell)
    hdir.mkdir()
    (hdir / "0001-before.toml").write_bytes(b"")  # empty, not in the index
    write_profile(cell, UPDATE, reason="calibrate")
    entries = profile_history(cell)
    assert [(e.id, e.before) for e in entries] == [(2, "0002-before.toml")]
    undo_profile(cell)
    assert "0.1, -0.2, 0.3" not in cell.read_text(encoding="utf-8")


def test_undo_on_a_full_disk_leaves_everything_as_it_was(
    cell: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    write_profile(cell, UPDATE, reason="calibrate")
    after = cell.read_bytes()
    hdir = history_dir(cell)
    files = sorted(f.name for f in hdir.iterdir())
    with monkeypatch.context() as m:
        _full_disk(m, fail_from_call=2)  # the after-copy is written, the index is not
        with pytest.raises(ProfileError, match="No space left"):
            undo_profile(cell)
    assert cell.read_bytes() == after
    assert sorted(f.name for f in hdir.iterdir()) == files
    assert not profile_history(cell)[0].undone


def test_a_failed_final_rename_withdraws_the_history_entry(
    cell: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    before = cell.read_bytes()
    real_replace = os.replace

    def replace(src: str | Path, dst: str | Path) -> None:
        if Path(dst) == cell:
            raise OSError(errno.EIO, os.strerror(errno.EIO))
        real_replace(src, dst)

    with monkeypatch.context() as m:
        m.setattr(os, "replace", replace)
        with pytest.raises(ProfileError, match=r"cell.toml: cannot write: Input/output error"):
            write_profile(cell, UPDATE, reason="calibrate")
    assert cell.read_bytes() == before
    assert profile_history(cell) == []
    assert sorted(f.name for f in history_dir(cell).iterdir()) == ["history.json"]
    assert _leftovers(cell.parent) == []
