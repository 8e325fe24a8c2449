"""Output files that cannot be written are input errors (exit 2) naming the file."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from ucal.errors import EXIT_USAGE
from ucal.profile import default_profile_text

from doubles import exit_code


@pytest.fixture
def inputs(tmp_path: Path) -> tuple[Path, Path]:
    profile = tmp_path / "cell.toml"
    profile.write_text(default_profile_text("tx90l"), encoding="utf-8")
    poses = tmp_path / "scan.csv"
    poses.write_text("X,Y,Z,RX,RY,RZ\n600,0,300,180,0,0\n610,0,300,180,0,0\n", encoding="utf-8")
    return profile, poses


def _one_error_line(err: str) -> str:
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


def test_path_output_into_a_missing_directory(
    inputs: tuple[Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    profile, poses = inputs
    out = tmp_path / "no-such-dir" / "joints.csv"
    assert exit_code(["path", str(profile), str(poses), "-o", str(out)]) == EXIT_USAGE
    line = _one_error_line(capsys.readouterr().err)
    assert line.startswith(f"error: {out}: cannot write") and "does not exist" in line
    assert not out.parent.exists()


def test_path_output_into_an_unwritable_directory(
    inputs: tuple[Path, Path],
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    profile, poses = inputs
    locked = tmp_path / "read-only"
    locked.mkdir()
    out = locked / "joints.csv"
    real_access = os.access
    monkeypatch.setattr(
        os, "access", lambda p, mode: False if Path(p) == locked else real_access(p, mode)
    )
    assert exit_code(["path", str(profile), str(poses), "-o", str(out)]) == EXIT_USAGE
    line = _one_error_line(capsys.readouterr().err)
    assert line.startswith(f"error: {out}: cannot write") and "not writable" in line


def test_path_output_failing_while_written_names_the_file(
    inputs: tuple[Path, Path],
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    import errno

    profile, poses = inputs
    out = tmp_path / "joints.csv"

    def full(*args: object, **kwargs: object) -> None:  # a full disk fails the fsync
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(os, "fsync", full)
    assert exit_code(["path", str(profile), str(poses), "-o", str(out)]) == EXIT_USAGE
    line = _one_error_line(capsys.readouterr().err)
    assert line == f"error: {out}: cannot write: No space left on device"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cell.toml", "scan.csv"]


def test_path_output_still_written(inputs: tuple[Path, Path], tmp_path: Path) -> None:
    profile, poses = inputs
    out = tmp_path / "joints.csv"
    assert exit_code(["path", str(profile), str(poses), "-o", str(out)]) == 0
    header = out.read_text(encoding="utf-8").splitlines()[0]
    assert header == "J1,J2,J3,J4,J5,J6,shoulder,elbow,wrist"


def test_sim_serve_log_into_a_missing_directory(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    log = tmp_path / "missing" / "motions.jsonl"
    assert exit_code(["sim", "serve", "--log", str(log)]) == EXIT_USAGE
    captured = capsys.readouterr()
    line = _one_error_line(captured.err)
    assert line.startswith(f"error: {log}: cannot write the motion log")
    assert captured.out == ""  # nothing served, no URL line


def test_sim_serve_log_that_is_a_directory(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert exit_code(["sim", "serve", "--log", str(tmp_path)]) == EXIT_USAGE
    err = capsys.readouterr().err
    assert str(tmp_path) in err and "is a directory" in err and "Traceback" not in err
