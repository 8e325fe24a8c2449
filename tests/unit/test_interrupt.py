"""A SIGINT or SIGTERM is acted on however it lands (``ucal.interrupt``): held until the command
line arms the handler, raised from then on, and raised again at the run's boundaries where the
``KeyboardInterrupt`` it raised was swallowed.

The signals are delivered in this process at the exact point (``signal.raise_signal``), inside
a ``contextlib.suppress(BaseException)``: what Cython's module initialisation does around its
``collections.abc.Sequence.register`` calls, where a SIGTERM to a run that was importing scipy
was taken and the run went on to write the profile.
"""

from __future__ import annotations

import contextlib
import json
import signal
import threading
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import click
import pytest

import ucal.procedure as procedure_module
from ucal import interrupt
from ucal.cli import LazyGroup
from ucal.profile import create_profile, profile_history, write_profile


@pytest.fixture(autouse=True)
def own_signals(monkeypatch: pytest.MonkeyPatch) -> Iterator[None]:
    """Nothing received, the handler not armed; the test process's handlers put back after."""
    previous = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    monkeypatch.setattr(interrupt, "received", [])
    monkeypatch.setattr(interrupt, "_armed", False)
    yield
    for s, handler in previous.items():
        signal.signal(s, handler)


def swallow(signum: int) -> None:
    """Deliver ``signum`` here and lose the ``KeyboardInterrupt`` it raises."""
    with contextlib.suppress(BaseException):
        signal.raise_signal(signum)


def test_a_signal_before_the_command_line_takes_over_is_held_then_raised() -> None:
    interrupt.install()
    signal.raise_signal(signal.SIGTERM)  # the imports go on: nothing is raised in them
    signal.raise_signal(signal.SIGINT)
    assert interrupt.received == [signal.SIGTERM, signal.SIGINT]
    with pytest.raises(KeyboardInterrupt, match="signal 15"):
        interrupt.arm()


def test_a_swallowed_interrupt_is_raised_again_by_check() -> None:
    interrupt.arm()
    interrupt.check()  # nothing received: nothing raised
    with pytest.raises(KeyboardInterrupt, match="signal 2"):
        signal.raise_signal(signal.SIGINT)  # armed: raised where it lands
    swallow(signal.SIGTERM)
    with pytest.raises(KeyboardInterrupt, match="signal 2"):
        interrupt.check()
    assert interrupt.received == [signal.SIGINT, signal.SIGTERM]


@pytest.fixture
def profile(tmp_path: Path) -> Path:
    return create_profile(tmp_path / "cell.toml", "tx90")


def interrupted_while_loading(
    monkeypatch: pytest.MonkeyPatch, then: Callable[[], None] = lambda: None
) -> list[Any]:
    """A signal lands while the command's module is being imported (after the command line
    armed the handler) and its interrupt is swallowed there; ``then`` runs next (e.g. raises
    what an extension's initialisation makes of it). Returns the cells opened."""
    get_command = LazyGroup.get_command

    def loading(self: LazyGroup, ctx: click.Context, name: str) -> click.Command | None:
        if not interrupt.received:
            swallow(signal.SIGTERM)
            then()
        return get_command(self, ctx, name)

    opened: list[Any] = []

    def open_cell(*args: Any, **kwargs: Any) -> Any:
        opened.append(args)
        raise AssertionError("the cell was opened after the signal")

    monkeypatch.setattr(LazyGroup, "get_command", loading)
    monkeypatch.setattr(procedure_module, "open_cell", open_cell)
    return opened


def test_a_signal_swallowed_while_the_command_loads_stops_the_run_before_the_cell_opens(
    profile: Path,
    monkeypatch: pytest.MonkeyPatch,
    run_main: Callable[[list[str]], tuple[int, str, str]],
) -> None:
    before = profile.read_bytes()
    opened = interrupted_while_loading(monkeypatch)
    code, out, err = run_main(["calibrate", str(profile), "--sim", "--yes"])
    assert (code, out) == (130, "")
    assert err.strip().splitlines()[-1].startswith("error: interrupted;")
    assert opened == [] and profile.read_bytes() == before
    assert interrupt.received == [signal.SIGTERM]


def test_an_interrupt_turned_into_another_error_is_still_an_interruption(
    profile: Path,
    monkeypatch: pytest.MonkeyPatch,
    run_main: Callable[[list[str]], tuple[int, str, str]],
) -> None:
    def pybind11_init() -> None:
        raise ImportError("initialization failed")

    opened = interrupted_while_loading(monkeypatch, pybind11_init)
    code, out, err = run_main(["calibrate", str(profile), "--sim", "--yes", "--json"])
    assert code == 130 and opened == []
    assert err.strip() == "error: interrupted; the robot was told to stop"
    assert '"exit_code": 130' in out


def test_no_profile_is_written_once_a_signal_was_received(profile: Path) -> None:
    before = profile.read_bytes()
    interrupt.install()
    signal.raise_signal(signal.SIGTERM)
    with pytest.raises(KeyboardInterrupt, match="signal 15"):
        write_profile(profile, {"calibration": {"method": "exact"}}, "calibrate")
    assert profile.read_bytes() == before
    assert profile_history(profile) == []
    assert sorted(p.name for p in profile.parent.iterdir()) == ["cell.toml"]


def test_a_signal_during_the_commit_waits_for_the_profile_and_its_history_together(
    profile: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """SIGTERM between the history index's rename and the profile's: both are replaced, then
    the run is interrupted; never an index that names a write that did not happen."""
    import ucal.profile.history as history

    interrupt.arm()
    commit = history.commit
    calls = []

    def signalled_commit(*args, **kwargs):
        result = commit(*args, **kwargs)
        calls.append(args)
        if len(calls) == 1:  # the history index renamed, the profile not yet: the signal
            signal.raise_signal(signal.SIGTERM)
        return result

    monkeypatch.setattr(history, "commit", signalled_commit)
    with pytest.raises(KeyboardInterrupt, match="signal 15"):
        write_profile(profile, {"calibration": {"method": "exact"}}, "calibrate")
    assert len(calls) == 2  # the commit was not cut in two
    entries = profile_history(profile)
    assert len(entries) == 1 and "exact" in profile.read_text()


def signalled_at_commit(monkeypatch: pytest.MonkeyPatch, after_calls: int) -> list[Any]:
    """SIGTERM delivered once ``after_calls`` renames of the profile's write are done (1: the
    history index renamed, the profile not yet; 2: both). Returns the renames made."""
    import ucal.profile.history as history

    commit = history.commit
    calls: list[Any] = []

    def signalled_commit(*args: Any, **kwargs: Any) -> None:
        commit(*args, **kwargs)
        calls.append(args)
        if len(calls) == after_calls:
            signal.raise_signal(signal.SIGTERM)

    monkeypatch.setattr(history, "commit", signalled_commit)
    return calls


@pytest.mark.parametrize("after_calls", [1, 2])
def test_a_signal_once_the_result_is_being_written_ends_the_run_with_that_result(
    profile: Path,
    monkeypatch: pytest.MonkeyPatch,
    run_main: Callable[[list[str]], tuple[int, str, str]],
    after_calls: int,
) -> None:
    """The robot has stopped, the profile is being replaced: the write completes, the result
    is printed with the error's fields (written: true) and the run ends as interrupted."""
    calls = signalled_at_commit(monkeypatch, after_calls)
    code, out, err = run_main(["calibrate", str(profile), "--sim", "--yes", "--json"])
    assert code == 130 and len(calls) == 2
    result = json.loads(out)
    assert result["written"] is True and result["exit_code"] == 130
    assert result["error"].startswith("interrupted as the run ended")
    assert "was written and stands" in result["error"]
    assert err.strip().splitlines()[-1] == f"error: {result['error']}"
    assert len(profile_history(profile)) == 1
    assert "joint_offsets_deg" in profile.read_text()
    assert interrupt.received == [signal.SIGTERM]


def test_a_signal_after_the_result_was_printed_leaves_it_standing(
    profile: Path,
    monkeypatch: pytest.MonkeyPatch,
    run_main: Callable[[list[str]], tuple[int, str, str]],
) -> None:
    """A signal as the printed result leaves the command: one JSON object (the result), the
    run ended as interrupted, said so on stderr."""
    import ucal.cli.procedure as cli_procedure

    emit = cli_procedure.emit_json

    def emit_then_signal(data: Any) -> None:
        emit(data)
        signal.raise_signal(signal.SIGINT)

    monkeypatch.setattr(cli_procedure, "emit_json", emit_then_signal)
    code, out, err = run_main(["calibrate", str(profile), "--sim", "--yes", "--json"])
    assert code == 130
    result = json.loads(out)  # one object: the result as the run printed it
    assert result["written"] is True and "error" not in result
    assert err.strip().splitlines()[-1] == (
        "error: interrupted as the run ended: its result stands as printed"
    )
    assert len(profile_history(profile)) == 1


class SignalledInFinaliser:
    """A signal that lands while a finaliser runs (as an import's weakref callback does)."""

    def __del__(self) -> None:
        signal.raise_signal(signal.SIGTERM)


def test_a_signal_in_a_finaliser_is_acted_on_at_once_and_prints_nothing(
    capsys: pytest.CaptureFixture[str],
) -> None:
    interrupt.arm()
    with pytest.raises(KeyboardInterrupt, match="signal 15"):
        SignalledInFinaliser()  # dropped at once: its finaliser runs here
        threading.Event().wait(60)  # the wait that follows (a motion's): the signal ends it
    assert interrupt.received == [signal.SIGTERM]
    assert "Exception ignored" not in capsys.readouterr().err
