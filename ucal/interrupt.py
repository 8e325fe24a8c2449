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
``ImportError("initialization failed")``; a finaliser or a weakref callback would print it as
"Exception ignored" and carry on: there the signal is delivered again at once, to strike in the
code that runs next (``_unraisable``), and nothing is printed. The record survives all of them:
``check`` raises the interrupt again wherever a run crosses a boundary (each step of
``ucal.procedure``, each measuring step, each evaluation of a cell fit, before a profile is
replaced), and the command line reports a run that received a signal as interrupted (exit
130) whatever exception ended it.

Once the robot has stopped and the run has begun to write its result, a signal cuts nothing
(``hold``): the write completes, the result is reported, and the run still ends as interrupted
(exit 130), saying that the result stands. So a script never meets a profile new on disk beside
a run that said it was interrupted and printed nothing of what it wrote.
"""

from __future__ import annotations

import contextlib
import signal
import sys
import threading
import time
from collections.abc import Iterator
from types import FrameType

#: SIGINT and SIGTERM received by this process since ``install`` (their numbers, in order).
received: list[int] = []

_armed = False
#: The run is past its last motion and writing or reporting its result (``hold``).
_held = False


#: A signal delivered again by ``_unraisable`` (already in ``received``), this long after.
_again = False
AGAIN_AFTER_S = 0.001


def _on_signal(signum: int, frame: FrameType | None) -> None:
    global _again
    if _again:
        _again = False
    else:
        received.append(signum)
    if _armed:
        raise KeyboardInterrupt(f"signal {signum}")


class _Redelivery:
    """A thread that sends the main thread a signal again, a moment after it is asked to
    (``request``): started with the handler, so that asking starts nothing and waits for
    nothing (a wait there is where a signal would strike again)."""

    def __init__(self) -> None:
        self._wanted = threading.Event()
        self._signum = signal.SIGTERM
        self._thread: threading.Thread | None = None

    def start(self) -> None:
        if self._thread is None or not self._thread.is_alive():
            self._thread = threading.Thread(target=self._run, name="ucal-signal", daemon=True)
            self._thread.start()

    def request(self, signum: int) -> None:
        self._signum = signal.Signals(signum)
        self._wanted.set()

    def _run(self) -> None:
        main = threading.main_thread().ident
        assert main is not None
        while True:
            self._wanted.wait()
            self._wanted.clear()
            time.sleep(AGAIN_AFTER_S)  # the finaliser's hook has returned
            signal.pthread_kill(main, self._signum)  # ends a wait the main thread is in


_redelivery = _Redelivery()


def _unraisable(unraisable: sys.UnraisableHookArgs) -> None:
    """A signal's ``KeyboardInterrupt`` that struck in a finaliser or a weakref callback (an
    import's, the garbage collector's), where Python can only print it as "Exception ignored":
    deliver the signal again, to strike in the code that runs next, which can act on it;
    nothing printed. Anything else goes to the hook that was there."""
    global _again
    if isinstance(unraisable.exc_value, KeyboardInterrupt) and received and _armed:
        _again = True
        _redelivery.request(received[-1])
        return
    _previous_hook(unraisable)


_previous_hook = sys.unraisablehook


def install() -> None:
    """Take SIGINT and SIGTERM (even where SIGINT was inherited as ignored, or both blocked in
    the inherited mask, where they would wait unseen until the run's end): record them. One
    sent while they were blocked is delivered as they are unblocked, and recorded."""
    signal.signal(signal.SIGINT, _on_signal)
    signal.signal(signal.SIGTERM, _on_signal)
    sys.unraisablehook = _unraisable
    if hasattr(signal, "pthread_kill"):  # POSIX
        _redelivery.start()
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
