"""Ctrl-C and SIGTERM: taken once, at the process's first line, and never lost.

One handler serves the whole run. ``install`` (``ucal.entry``, before any import of weight)
makes it take SIGINT and SIGTERM and record them in ``received``; until the command line
``arm``s it, it raises nothing, so a signal cannot strike inside the imports. Armed, it also
raises ``KeyboardInterrupt`` in the main thread, so a wait or a motion ends at once and the
robot is told to stop while the exception unwinds.

A ``KeyboardInterrupt`` raised from a handler strikes wherever the main thread is, and some code
there swallows it. Cython's module initialisation registers its memoryview types with
``collections.abc.Sequence`` inside a bare ``except: pass`` (the scipy and numpy.random
extensions that load with a command's module): a signal that lands in that ``register`` call
was taken and the run went on to the end, profile written. pybind11 turns it into
``ImportError("initialization failed")``; a finaliser or a weakref callback prints it as
"Exception ignored" and carries on. The record survives all of them: ``check`` raises the
interrupt again wherever a run crosses a boundary (each step of ``ucal.procedure``, each
measuring step, before a profile is replaced), and the command line reports a run that
received a signal as interrupted (exit 130) whatever exception ended it.

Once the robot has stopped and the run has begun to write its result, a signal cuts nothing
(``hold``): the write completes, the result is reported, and the run still ends as interrupted
(exit 130), saying that the result stands. So a script never meets a profile new on disk beside
a run that said it was interrupted and printed nothing of what it wrote.
"""

from __future__ import annotations

import contextlib
import signal
from collections.abc import Iterator
from types import FrameType

#: SIGINT and SIGTERM received by this process since ``install`` (their numbers, in order).
received: list[int] = []

_armed = False
#: The run is past its last motion and writing or reporting its result (``hold``).
_held = False


def _on_signal(signum: int, frame: FrameType | None) -> None:
    received.append(signum)
    if _armed:
        raise KeyboardInterrupt(f"signal {signum}")


def install() -> None:
    """Take SIGINT and SIGTERM (even where SIGINT was inherited as ignored, or both blocked in
    the inherited mask, where they would wait unseen until the run's end): record them. One
    sent while they were blocked is delivered as they are unblocked, and recorded."""
    signal.signal(signal.SIGINT, _on_signal)
    signal.signal(signal.SIGTERM, _on_signal)
    if hasattr(signal, "pthread_sigmask"):  # POSIX
        signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT, signal.SIGTERM})


def arm() -> None:
    """From now on a signal also raises ``KeyboardInterrupt``; one received before raises now.

    Installs the handler when ``install`` was not called (the command line run in-process).
    """
    global _armed, _held
    install()
    _armed, _held = True, False
    check()


def check() -> None:
    """Raise ``KeyboardInterrupt`` if a signal was received, even one whose exception was
    swallowed where it struck; nothing once the run is ``hold``ing its result."""
    if received and not _held:
        raise KeyboardInterrupt(f"signal {received[0]}")


def hold() -> None:
    """From now on a signal is recorded and nothing raised: the robot has stopped and the run
    writes and reports its result, which a signal must not cut between the write and the
    report (a profile new on disk while the run said it was interrupted). The command line
    then reports the result with the interruption (``ucal.cli.main``: exit 130)."""
    global _armed, _held
    _armed = False
    _held = True


@contextlib.contextmanager
def deferred() -> Iterator[None]:
    """Raise nothing while the block runs, a commit that must not be cut in two (a profile and
    its history index replaced together); a signal received meanwhile is raised when it ends,
    the commit whole."""
    global _armed
    was = _armed
    _armed = False
    try:
        yield
    finally:
        _armed = was
    if was:
        check()
