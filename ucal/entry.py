"""The console script's entry point: interruptible from its first instant.

A run started in the background by a non-interactive shell inherits SIGINT as *ignored*, and
Python installs its own Ctrl-C handler only where SIGINT was not ignored. Importing the command
line (click, numpy, the drivers) takes a few hundred milliseconds on a loaded machine, and a
SIGINT or SIGTERM that arrived in that time was lost: the run went on to move the robot. So the
first thing the process does, before any import of weight, is to take both signals with the one
handler of the whole run (``ucal.interrupt``), which records them; the command line arms it and
acts on one that arrived meanwhile before anything connects or moves (``ucal.cli.main``).
A signal that comes before this first line (while the interpreter itself starts) meets the
disposition the process inherited: SIGTERM's default ends it, an ignored SIGINT is discarded by
the kernel before ucal can see it.

An interrupted run exits with 130 itself. Left to the interpreter's shutdown, a
KeyboardInterrupt that struck while the interpreter ran generated code (a dataclass being built
during an import) makes CPython end the process by SIGINT instead of with the exit code it was
given, so a script saw "killed by a signal" rather than 130.
"""

from __future__ import annotations

import contextlib
import os
import sys

from ucal import interrupt


def main() -> None:
    """Run ``ucal`` with SIGINT and SIGTERM taken from the first line (``ucal.interrupt``)."""
    interrupt.install()
    from ucal.cli import main as cli_main
    from ucal.errors import EXIT_INTERRUPTED

    try:
        cli_main()
    except SystemExit as e:
        if e.code != EXIT_INTERRUPTED:
            raise
        # The robot was told to stop and every resource released while the interrupt
        # unwound the run; nothing is left for the interpreter's shutdown to do.
        for stream in (sys.stdout, sys.stderr):
            with contextlib.suppress(OSError, ValueError):
                stream.flush()
        os._exit(EXIT_INTERRUPTED)
