"""Fixtures shared by the system tests."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest


@pytest.fixture(scope="session")
def recorded(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict]:
    """A recorded ``calibrate --dry-run`` on the demo cell: its directory (``run.jsonl``) and
    its JSON result."""
    d = tmp_path_factory.mktemp("record")
    out = subprocess.run([sys.executable, "-m", "ucal", "calibrate", "cell.toml", "--sim",
                          "--yes", "--json", "--dry-run", "--record", "run.jsonl"],
                         check=False, capture_output=True, text=True, cwd=d,
                         stdin=subprocess.DEVNULL, timeout=300)
    assert out.returncode in (0, 1), out.stderr
    return d, json.loads(out.stdout)
