"""Every script in ``benchmarks/`` runs in its ``--quick`` mode and prints its figures.

Marked ``bench``: the suite (``pytest -q``) leaves these out, as they cost a minute and a half
of CPU between them; CI runs them as a step of their own (``pytest -q -m bench``). Each runs
as a user runs it, ``python benchmarks/NAME.py --quick``, in a process of its own (one
test per script, so the workers share them out): a benchmark that no longer imports, or no
longer fits the code it measures, fails here instead of on its next long run. Its temporary
files go to the test's directory (``TMPDIR``). A baseline library that is not installed is
said on stderr and skipped.
"""

from __future__ import annotations

import importlib.util
import os
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.system

BENCHMARKS = Path(__file__).resolve().parents[2] / "benchmarks"
SCRIPTS = sorted(p for p in BENCHMARKS.glob("*.py") if not p.name.startswith("_"))
#: Below the suite's per-test timeout, so that a hung benchmark is reported with its output.
TIMEOUT_S = 100


def test_the_benchmarks_are_found() -> None:
    assert len(SCRIPTS) >= 8, SCRIPTS


@pytest.mark.bench
@pytest.mark.parametrize("script", SCRIPTS, ids=lambda p: p.stem)
def test_quick_mode_runs_and_prints_figures(script: Path, tmp_path: Path) -> None:
    try:
        done = subprocess.run(
            [sys.executable, str(script), "--quick"],
            cwd=tmp_path,
            env={**os.environ, "TMPDIR": str(tmp_path)},
            stdin=subprocess.DEVNULL,
            capture_output=True,
            text=True,
            timeout=TIMEOUT_S,
        )
    except subprocess.TimeoutExpired as e:
        pytest.fail(f"{script.name} --quick ran over {TIMEOUT_S} s; stderr: {e.stderr!r}")
    assert done.returncode == 0, done.stderr[-3000:]
    assert done.stdout.strip(), f"{script.name} --quick printed no figures: {done.stderr[-3000:]}"


def test_a_missing_baseline_library_is_said_and_skipped(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.syspath_prepend(str(BENCHMARKS))  # its siblings, as a script run there has
    spec = importlib.util.spec_from_file_location("benchmark_ik", BENCHMARKS / "ik.py")
    assert spec is not None and spec.loader is not None
    ik = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(ik)
    monkeypatch.setitem(sys.modules, "roboticstoolbox", None)  # import raises ImportError

    assert ik.main(["--quick"]) == 0
    out, err = capsys.readouterr()
    assert "closed form (all 8): 1000 poses" in out
    assert "baseline roboticstoolbox-python not installed: skipped" in err
