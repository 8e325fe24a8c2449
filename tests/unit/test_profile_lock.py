"""One run per profile (``profile_lock``) and the write preflight (``check_writable``)."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
from pathlib import Path

import pytest

from ucal.errors import EXIT_USAGE, InputError, ProfileError
from ucal.profile import (
    check_writable,
    default_profile_text,
    history_dir,
    lock_path,
    profile_lock,
)

from doubles import exit_code

REPO = Path(__file__).resolve().parents[2]

HOLD = """
import sys
from ucal.profile import profile_lock
with profile_lock(sys.argv[1], command="ucal calibrate cell.toml --yes"):
    print("locked", flush=True)
    if sys.argv[2] == "crash":
        import os, signal
        os.kill(os.getpid(), signal.SIGKILL)
    sys.stdin.read()
"""


@pytest.fixture
def cell(tmp_path: Path) -> Path:
    p = tmp_path / "cell.toml"
    p.write_text(default_profile_text("tx90l"), encoding="utf-8")
    return p


def _hold(cell: Path, mode: str = "hold") -> subprocess.Popen[str]:
    """Another process holding the profile (it says so before returning)."""
    proc = subprocess.Popen(
        [sys.executable, "-c", HOLD, str(cell), mode],
        cwd=REPO,
        text=True,
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
    )
    assert proc.stdout is not None
    assert proc.stdout.readline().strip() == "locked"
    return proc


def test_a_second_holder_is_refused_naming_the_first(cell: Path) -> None:
    proc = _hold(cell)
    try:
        with pytest.raises(InputError) as err, profile_lock(cell):
            pass
    finally:
        proc.communicate("")
    message = str(err.value)
    assert err.value.exit_code == EXIT_USAGE
    assert f"pid {proc.pid} on {socket.gethostname()}" in message
    assert "ucal calibrate cell.toml --yes" in message
    assert str(cell) in message and "\n" not in message
    # released: the profile can be taken again, and the lock file is gone
    with profile_lock(cell) as me:
        assert me.pid == os.getpid()
    assert not lock_path(cell).exists()


def test_the_same_process_cannot_take_it_twice(cell: Path) -> None:
    with (
        profile_lock(cell, command="first"),
        pytest.raises(InputError, match="first"),
        profile_lock(cell),
    ):
        pass


def test_a_crashed_run_leaves_no_lock_that_blocks(cell: Path) -> None:
    proc = _hold(cell, "crash")
    assert proc.wait() == -signal.SIGKILL
    assert lock_path(cell).exists()  # the file is left behind, the lock is not
    with profile_lock(cell):
        pass


def test_links_to_one_profile_share_its_lock(cell: Path, tmp_path: Path) -> None:
    link = tmp_path / "other-name.toml"
    link.symlink_to(cell)
    assert lock_path(link) == lock_path(cell) == cell.with_name("cell.toml.lock")
    with (
        profile_lock(cell),
        pytest.raises(InputError, match="in use by another run"),
        profile_lock(link),
    ):
        pass


def test_calibrate_refuses_a_profile_in_use_before_any_motion(
    cell: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    before = cell.read_bytes()
    proc = _hold(cell)
    try:
        code = exit_code(["calibrate", str(cell), "--sim", "--yes"])
        code_tf = exit_code(["tool-frame", str(cell), "--sim", "--yes"])
    finally:
        proc.communicate("")
    err = capsys.readouterr().err
    assert code == code_tf == EXIT_USAGE
    lines = [ln for ln in err.splitlines() if ln.startswith("error:")]
    assert len(lines) == 2 and all(f"pid {proc.pid}" in ln for ln in lines)
    assert "Traceback" not in err
    assert cell.read_bytes() == before


def test_no_command_replaces_or_undoes_a_profile_in_use(
    cell: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # A held profile receives the run's results at its end: a profile replaced under it
    # (init --force) or rolled back (undo) would receive offsets measured on another cell.
    assert exit_code(["calibrate", str(cell), "--sim", "--yes", "-q"]) == 0
    before = cell.read_bytes()
    proc = _hold(cell)
    try:
        code_init = exit_code(["profile", "init", "tx90", str(cell), "--force"])
        code_undo = exit_code(["profile", "undo", str(cell)])
    finally:
        proc.communicate("")
    err = capsys.readouterr().err
    assert code_init == code_undo == EXIT_USAGE
    lines = [ln for ln in err.splitlines() if ln.startswith("error:")]
    assert len(lines) == 2 and all(f"pid {proc.pid}" in ln for ln in lines), err
    assert cell.read_bytes() == before
    # released, both go through
    assert exit_code(["profile", "undo", str(cell)]) == 0
    assert exit_code(["profile", "init", "tx90", str(cell), "--force"]) == 0


# --- preflight ----------------------------------------------------------------------------------
def test_writable_directory_with_room_passes(cell: Path) -> None:
    check_writable(cell)


def test_unwritable_profile_directory_is_named(cell: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    real_access = os.access
    monkeypatch.setattr(
        os,
        "access",
        lambda p, mode: False if Path(p) == cell.parent else real_access(p, mode),
    )
    with pytest.raises(
        ProfileError,
        match=rf"^{cell.parent}: profile directory is not "
        "writable",
    ) as err:
        check_writable(cell)
    assert err.value.exit_code == EXIT_USAGE


def test_unwritable_history_directory_is_named(cell: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    hdir = cell.with_name("cell.toml.history")
    hdir.mkdir()
    real_access = os.access
    monkeypatch.setattr(
        os, "access", lambda p, mode: False if Path(p) == hdir else real_access(p, mode)
    )
    with pytest.raises(ProfileError, match=rf"^{hdir}: history directory is not writable"):
        check_writable(cell)


def test_full_disk_is_refused_before_the_run(
    cell: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    import shutil

    usage = shutil.disk_usage(cell.parent)
    monkeypatch.setattr(shutil, "disk_usage", lambda p: usage._replace(free=4096))
    before = cell.read_bytes()
    with pytest.raises(ProfileError, match=r"4096 bytes free"):
        check_writable(cell)
    code = exit_code(["calibrate", str(cell), "--sim", "--yes"])
    err = capsys.readouterr().err.strip()
    assert code == EXIT_USAGE
    assert err.startswith(f"error: {cell.parent}: profile directory has 4096 bytes free")
    assert "\n" not in err
    assert cell.read_bytes() == before
    assert not lock_path(cell).exists()


KILLED_WRITE = """
import os, signal, sys
import ucal.profile.history as history
from ucal.profile import write_profile

def killed(tmp, path):  # both files staged, neither renamed: the process dies here
    os.kill(os.getpid(), signal.SIGKILL)

history.commit = killed
write_profile(sys.argv[1], {"calibration": {"method": "exact"}}, "calibrate")
"""


def test_the_next_run_removes_what_a_killed_write_left(cell: Path) -> None:
    """A write killed between staging and renaming leaves its staged profile and index beside
    the real ones; the next holder of the profile removes them, and nothing else."""
    before = cell.read_bytes()
    proc = subprocess.run([sys.executable, "-c", KILLED_WRITE, str(cell)], cwd=REPO)
    assert proc.returncode == -signal.SIGKILL
    hdir = history_dir(cell)
    left = [p.name for p in [*cell.parent.iterdir(), *hdir.iterdir()] if p.suffix == ".tmp"]
    assert len(left) == 2 and cell.read_bytes() == before
    others = [cell.parent / ".cell.toml.notes.tmp", hdir / "mine.tmp"]
    for other in others:
        other.write_text("not ucal's")
    with profile_lock(cell):
        now = [p for p in [*cell.parent.iterdir(), *hdir.iterdir()] if p.suffix == ".tmp"]
    assert sorted(now) == sorted(others)
    assert cell.read_bytes() == before
