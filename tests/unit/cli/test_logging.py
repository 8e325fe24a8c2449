"""One log format: rich's handler on stderr, a line per record in the command line's words."""

from __future__ import annotations

import logging
from collections.abc import Callable
from pathlib import Path

import pytest

from ucal.cli.options import LOG_PREFIX
from ucal.profile import create_profile


@pytest.fixture
def profile(tmp_path: Path) -> Path:
    return create_profile(tmp_path / "cell.toml", "tx90l")


#: A warning longer than any terminal, with text that rich would read as markup.
LONG = "STOP not confirmed: controller at tcp://127.0.0.1:1:" + " [bold]x[/bold]" * 40


def logged(
    run_main: Callable[[list[str]], tuple[int, str, str]],
    capsys: pytest.CaptureFixture[str],
    args: list[str],
) -> str:
    """What a warning prints once ``ucal ARGS`` configured the logging (the root logger's
    level is put back after the run, its handler stays)."""
    code, _, _ = run_main(args)
    assert code == 0
    log = logging.getLogger("drivers.controller.client")
    log.warning("%s", LONG)
    return capsys.readouterr().err


def test_a_log_line_reads_as_the_command_lines_own_and_is_never_wrapped(
    profile: Path,
    run_main: Callable[[list[str]], tuple[int, str, str]],
    capsys: pytest.CaptureFixture[str],
) -> None:
    err = logged(run_main, capsys, ["-v", "profile", "validate", str(profile), "-v"])
    lines = err.splitlines()
    # one line each, the markup-like text of a device as it is, no time stamp or padding
    assert lines == [f"warning: {LONG}"]
    # -v before and after the command: one handler, not two
    assert len([h for h in logging.getLogger().handlers if type(h).__name__ == "_StderrLog"]) == 1


def test_without_v_only_warnings_print_and_debug_names_the_logger(
    profile: Path,
    run_main: Callable[[list[str]], tuple[int, str, str]],
    capsys: pytest.CaptureFixture[str],
) -> None:
    assert logged(run_main, capsys, ["profile", "validate", str(profile)]) == f"warning: {LONG}\n"
    err = logged(run_main, capsys, ["--debug", "profile", "validate", str(profile)])
    assert err.splitlines()[0].startswith("warning: drivers.controller.client: STOP not")
    assert LOG_PREFIX[logging.WARNING] == "warning: "
