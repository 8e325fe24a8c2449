"""What scripts rely on: the JSON error object, the cell from the environment, ``-v``/``-q``
anywhere, and usage errors refused before any plan or prompt (SPEC.md)."""

from __future__ import annotations

import contextlib
import json
import logging
import sys
from collections.abc import Callable
from pathlib import Path

import click
import pytest

from ucal.cli import main

from doubles import terminal_typed

CONTROLLER = "tcp://192.0.2.7:11000"
PULSER = "modbus-tcp://192.0.2.8:502"

RunMain = Callable[[list[str]], tuple[int, str, str]]


def one_error(err: str) -> str:
    """The single ``error:`` line of stderr (no plan, no prompt, no traceback)."""
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: "), err
    return lines[0].removeprefix("error: ")


@pytest.mark.parametrize("command", ["calibrate", "tool-frame", "verify", "check"])
def test_no_cell_is_a_usage_error_before_any_plan(
    profile: Path, command: str, run_main: RunMain
) -> None:
    before = profile.read_bytes()
    code, out, err = run_main([command, str(profile), "--json"])
    message = one_error(err)
    assert code == 2 and message.startswith("no cell given: use --sim [WORLD]")
    assert json.loads(out) == {"error": message, "exit_code": 2}
    assert profile.read_bytes() == before


@pytest.mark.parametrize(
    "args, words",
    [
        (
            ["tool-frame", "--controller", CONTROLLER, "--pulser", PULSER, "--dry-run"],
            "--dry-run runs against the simulator: it cannot be combined with "
            "--controller/--pulser",
        ),
        (
            ["calibrate", "--dry-run", "--controller", CONTROLLER],
            "--dry-run runs against the simulator: it cannot be combined with --controller",
        ),
        (
            ["calibrate", "--sim", "--controller", CONTROLLER],
            "--sim cannot be combined with --controller",
        ),
        (["verify", "--controller", CONTROLLER], "--controller given without --pulser URL"),
        (
            ["verify", "--controller", "10.0.0.5", "--pulser", PULSER],
            "--controller: not a controller URL: '10.0.0.5'",
        ),
        (["calibrate", "--sim", "no-such-world.toml"], "no-such-world.toml: world file not found"),
        (["calibrate", "--sim"], "refusing to move the simulated cell without confirmation"),
        (
            ["calibrate", "--sim", "--yes", "--record", "no-such-dir/run.jsonl"],
            "no-such-dir/run.jsonl: cannot write: directory no-such-dir does not exist",
        ),
    ],
)
def test_usage_errors_name_what_was_typed(
    profile: Path, args: list[str], words: str, run_main: RunMain
) -> None:
    code, out, err = run_main([args[0], str(profile), *args[1:]])
    assert code == 2 and one_error(err).startswith(words), err
    assert out == ""  # no --json: nothing on stdout


@pytest.mark.parametrize("command", ["calibrate", "tool-frame", "verify", "check"])
def test_a_missing_profile_is_named_before_the_missing_yes(
    profile: Path, command: str, run_main: RunMain
) -> None:
    """Files are checked before whether the run could ask: the user fixes the file first."""
    missing = profile.with_name("typo.toml")
    code, _, err = run_main([command, str(missing), "--controller", CONTROLLER, "--pulser", PULSER])
    assert code == 2 and one_error(err).startswith(f"{missing}: cannot read"), err
    assert not missing.exists()


def test_calibrate_creates_no_profile_for_a_run_that_cannot_ask(
    profile: Path, run_main: RunMain
) -> None:
    new = profile.with_name("new.toml")
    code, _, err = run_main(["calibrate", str(new), "--sim"])
    assert code == 2 and one_error(err).startswith("refusing to move the simulated cell ")
    assert not new.exists()


def test_the_cell_comes_from_the_environment(
    profile: Path, monkeypatch: pytest.MonkeyPatch, run_main: RunMain
) -> None:
    monkeypatch.setenv("UCAL_CONTROLLER", CONTROLLER)
    monkeypatch.setenv("UCAL_PULSER", PULSER)
    code, _, err = run_main(["calibrate", str(profile)])
    assert code == 2 and one_error(err).startswith(f"refusing to move the robot at {CONTROLLER} ")
    # an option typed on the command line wins over the environment
    code, _, err = run_main(["verify", str(profile), "--sim"])
    assert code == 2 and one_error(err).startswith("refusing to move the simulated cell ")
    code, _, err = run_main(["calibrate", str(profile), "--dry-run"])
    assert code == 2 and one_error(err).startswith("refusing to move the simulated cell ")
    monkeypatch.setenv("UCAL_SIM", "1")
    code, _, err = run_main(["tool-frame", str(profile)])
    assert code == 2 and one_error(err).startswith(
        "UCAL_SIM cannot be combined with UCAL_CONTROLLER/UCAL_PULSER"
    )
    monkeypatch.delenv("UCAL_CONTROLLER")
    code, _, err = run_main(["tool-frame", str(profile)])
    assert code == 2 and one_error(err).startswith("UCAL_SIM cannot be combined with UCAL_PULSER")
    code, _, err = run_main(["tool-frame", str(profile), "--controller", CONTROLLER])
    assert code == 2 and one_error(err).startswith(f"refusing to move the robot at {CONTROLLER} ")


def test_sim_from_the_environment(
    profile: Path, monkeypatch: pytest.MonkeyPatch, run_main: RunMain
) -> None:
    monkeypatch.setenv("UCAL_SIM", str(profile.with_name("truth.toml")))
    code, _, err = run_main(["verify", str(profile)])
    assert code == 2 and one_error(err) == (
        f"{profile.with_name('truth.toml')}: world file not found (UCAL_SIM)"
    )
    monkeypatch.setenv("UCAL_SIM", "0")
    code, _, err = run_main(["verify", str(profile)])
    assert code == 2 and one_error(err).startswith("no cell given")


@pytest.mark.parametrize(
    "args",
    [
        ["fk", "{p}", "--joints", "1,2,3", "--json"],  # a bad option value (click)
        ["fk", "{p}", "--bogus", "--json"],  # an unknown option (click)
        ["ik", "{p}", "--pose", "5000,0,0,0,0,0", "--json"],  # unreachable: exit 4
        ["profile", "show", "{p}.missing", "--json"],  # an unreadable file
        ["status", "--json"],  # no controller
    ],
)
def test_every_failure_prints_the_error_object(
    profile: Path, args: list[str], run_main: RunMain
) -> None:
    code, out, err = run_main([a.format(p=profile) for a in args])
    assert code in (2, 4) and "Traceback" not in err
    obj = json.loads(out)
    assert obj == {"error": obj["error"], "exit_code": code} and obj["error"] in err


@pytest.mark.parametrize(
    "args",
    [
        ["-q", "profile", "init", "tx90", "{d}/a.toml"],
        ["profile", "init", "tx90", "{d}/a.toml", "-q"],
        ["profile", "-q", "init", "tx90", "{d}/a.toml"],
    ],
)
def test_quiet_anywhere(tmp_path: Path, args: list[str], run_main: RunMain) -> None:
    code, out, err = run_main([a.format(d=tmp_path) for a in args])
    assert (code, out, err) == (0, "", "")
    code, _, err = run_main(["profile", "init", "tx90", f"{tmp_path}/b.toml"])
    assert code == 0 and err.startswith(f"wrote {tmp_path}/b.toml (tx90)")
    # errors still print with -q
    code, _, err = run_main(["profile", "init", "tx90", f"{tmp_path}/a.toml", "-q"])
    assert code == 2 and one_error(err).endswith(
        "already exists (use --force to replace it; the old file is kept in the history)"
    )


def test_verbose_after_the_subcommand(profile: Path, run_main: RunMain) -> None:
    code, out, _ = run_main(["fk", str(profile), "--joints", "0,0,90,0,90,0", "--json", "-vv"])
    assert code == 0 and set(json.loads(out)) == {"joints_deg", "pose"}


@pytest.mark.parametrize(
    "flags, level",
    [
        ([], logging.WARNING),
        (["-v"], logging.INFO),
        (["-vv"], logging.DEBUG),
        (["-q"], logging.ERROR),
    ],
)
def test_log_level_from_flags_anywhere(profile: Path, flags: list[str], level: int) -> None:
    root = logging.getLogger()
    before = root.level  # put back after, as run_main does (it would hide the level set)
    try:
        for args in ([*flags, "fk", str(profile)], ["fk", str(profile), *flags]):
            root.setLevel(logging.NOTSET)
            with contextlib.suppress(SystemExit):
                main([*args, "--joints", "0,0,90,0,90,0"])
            assert root.level == level
            # pymodbus reports its own retries; ucal reports faults once, itself
            assert logging.getLogger("pymodbus").level == logging.CRITICAL
    finally:
        root.setLevel(before)


@pytest.mark.parametrize("answer", ["n\n", "\n", "\x04"], ids=["no", "default", "end of input"])
@pytest.mark.parametrize("quiet", [[], ["-q"]], ids=["", "quiet"])
def test_declining_the_confirmation_is_refused_exit_4(
    profile: Path,
    answer: str,
    quiet: list[str],
    run_main: RunMain,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """SPEC.md: saying no before the first motion is a refusal (4), not an interruption
    (130). The plan is shown before the question even with -q: the operator cannot confirm
    what they have not seen."""
    before = profile.read_bytes()
    with terminal_typed(answer) as tty:
        monkeypatch.setattr(sys, "stdin", tty)
        code, out, err = run_main([*quiet, "calibrate", str(profile), "--sim", "--json"])
    assert code == 4, err
    message = "not confirmed: nothing moved, nothing written"
    assert err.rstrip().endswith(f"error: {message}")
    assert json.loads(out) == {"error": message, "exit_code": 4}
    plan, _, _ = err.partition("Move the simulated cell now?")
    assert "Calibration plan for tx90l" in plan and "Estimated time on a real cell" in plan
    assert profile.read_bytes() == before


def test_ctrl_c_at_the_confirmation_is_an_interruption(
    profile: Path, run_main: RunMain, monkeypatch: pytest.MonkeyPatch
) -> None:
    def interrupted(*args: object, **kwargs: object) -> bool:
        try:  # what click.confirm does with Ctrl-C
            raise KeyboardInterrupt
        except KeyboardInterrupt:
            raise click.exceptions.Abort() from None

    monkeypatch.setattr(click, "confirm", interrupted)
    monkeypatch.setattr(sys.stdin, "isatty", lambda: True)
    code, _, err = run_main(["calibrate", str(profile), "--sim"])
    assert code == 130
    assert err.rstrip().splitlines()[-1] == (
        "error: interrupted at the confirmation: nothing moved, nothing written"
    )


def test_a_profile_created_for_a_declined_run_is_removed(
    profile: Path, run_main: RunMain, monkeypatch: pytest.MonkeyPatch
) -> None:
    new = profile.with_name("typo.toml")
    with terminal_typed("n\n") as tty:
        monkeypatch.setattr(sys, "stdin", tty)
        code, _, err = run_main(["-q", "calibrate", str(new), "--sim"])
    assert code == 4
    assert f"warning: {new} did not exist: created it from the default model tx90l" in err
    assert err.rstrip().endswith(
        f"error: not confirmed: nothing moved, nothing written ({new}, created for the run, "
        "removed)"
    )
    assert not new.exists()


@pytest.mark.parametrize(
    "args, message",
    [
        (["calibrat"], "No such command 'calibrat'. Did you mean 'calibrate'?"),
        (["tool_frame"], "No such command 'tool_frame'. Did you mean 'tool-frame'?"),
        (["profile", "shw"], "No such command 'shw'. Did you mean 'show'?"),
        (["sim", "serv"], "No such command 'serv'. Did you mean 'serve'?"),
        (["xyzzy"], "No such command 'xyzzy'."),
    ],
)
def test_a_mistyped_command_names_the_nearest_one(
    args: list[str], message: str, run_main: RunMain
) -> None:
    code, out, err = run_main([*args, "cell.toml"])
    assert code == 2 and out == ""
    assert err.rstrip().splitlines()[-1] == f"Error: {message}"
    code, out, _ = run_main([*args, "cell.toml", "--json"])
    assert code == 2 and json.loads(out) == {"error": message, "exit_code": 2}
