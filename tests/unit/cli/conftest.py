"""What the command-line tests share: a profile to run a command on."""

from __future__ import annotations

import io
import sys
from pathlib import Path

import pytest

from ucal.profile import default_profile_text


@pytest.fixture
def profile(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A profile in a temporary directory; stdin is not a terminal; no cell in the environment."""
    for name in ("UCAL_SIM", "UCAL_CONTROLLER", "UCAL_PULSER"):
        monkeypatch.delenv(name, raising=False)
    monkeypatch.setattr(sys, "stdin", io.StringIO(""))
    path = tmp_path / "cell.toml"
    path.write_text(default_profile_text("tx90l"), encoding="utf-8")
    return path
