"""Ctrl-C or SIGTERM at any moment of a run, its first instants included, stops it: exit 130,
nothing moved after it, the profile untouched.

A script that starts ``ucal`` in the background from a non-interactive shell hands it SIGINT
as ignored; the signal must still be acted on, however early it comes once ucal's first line has
run (``ucal.entry``), and even where the ``KeyboardInterrupt`` it raises is swallowed where it
lands (``ucal.interrupt``; the exact points are held in ``tests/unit/test_interrupt.py``).
"""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from ucal.errors import EXIT_INTERRUPTED
from ucal.sim.serve import serving

pytestmark = pytest.mark.system


def _background_shell_child() -> None:
    """What a non-interactive shell does to a job started with ``&``."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def _blocked_mask_child() -> None:
    """A parent that blocks SIGINT and SIGTERM in the mask its child inherits (a supervisor
    that forks between ``sigprocmask`` calls, some job runners)."""
    signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT, signal.SIGTERM})


STARTS = {"script": _background_shell_child, "terminal": None, "blocked": _blocked_mask_child}


def _wait_until_taken_over(pid: int) -> None:
    """Wait until process ``pid`` catches both SIGINT and SIGTERM (``SigCgt`` of
    /proc/PID/status; at once where there is no /proc): ucal's first line has run.

    Before it the interpreter itself starts (past 0.1 s on a loaded machine, site's imports
    included) and a signal meets what the process inherited, beyond any program's reach: an
    ignored SIGINT is discarded by the kernel, SIGTERM's default action ends the process, and a
    terminal's SIGINT during site's imports is a fatal error of the interpreter (exit 1).
    """
    status = Path(f"/proc/{pid}/status")
    wanted = (1 << (signal.SIGINT - 1)) | (1 << (signal.SIGTERM - 1))
    deadline = time.monotonic() + 30.0
    while status.exists() and time.monotonic() < deadline:
        caught = [ln.split()[1] for ln in status.read_text().splitlines() if ln[:7] == "SigCgt:"]
        if caught and int(caught[0], 16) & wanted == wanted:
            return
        time.sleep(0.005)


@pytest.fixture(scope="module")
def served(tmp_path_factory: pytest.TempPathFactory):
    d = tmp_path_factory.mktemp("early")
    profile = d / "cell.toml"
    subprocess.run(
        [sys.executable, "-m", "ucal", "profile", "init", "tx90", str(profile)],
        check=True,
        capture_output=True,
    )
    log = d / "motions.jsonl"
    with serving("--profile", str(profile), "--log", str(log)) as urls:
        yield profile, log, urls


@pytest.mark.parametrize("after_s", [0.1, 0.3, 0.6])
@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
@pytest.mark.parametrize("start", list(STARTS))
def test_an_early_signal_stops_the_run_before_any_motion(
    served: tuple[Path, Path, dict], after_s: float, signum: int, start: str
) -> None:
    profile, log, urls = served
    before = profile.read_bytes()
    moved_before = log.read_text().count("\n") if log.exists() else 0
    proc = subprocess.Popen(
        [sys.executable, "-m", "ucal", "calibrate", str(profile), "--yes"]
        + ["--controller", urls["controller"], "--pulser", urls["pulser"]],
        stdin=subprocess.DEVNULL,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=STARTS[start],
    )
    time.sleep(after_s)
    _wait_until_taken_over(proc.pid)
    sent = time.time()
    proc.send_signal(signum)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode != 0, f"signal {signum} at {after_s} s was taken and the run went on"
    assert proc.returncode == EXIT_INTERRUPTED, err
    assert "Traceback" not in err and "interrupted" in err
    assert profile.read_bytes() == before
    lines = log.read_text().splitlines()[moved_before:] if log.exists() else []
    # nothing moved after the signal (a move ending after it must have been stopped)
    assert all(
        json.loads(ln)["t_wall_s"] <= sent + 0.5 or json.loads(ln)["stopped"] for ln in lines
    ), lines
