"""The code's layout as docs/design.md draws it: ``drivers/`` is a layer of its own that never
imports ``ucal``, and no module grows past what a reader can hold (700 lines)."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
#: The longest a module of ``ucal/`` or ``drivers/`` may be (lines).
MAX_LINES = 700
MODULES = sorted(p for top in ("ucal", "drivers") for p in (REPO / top).rglob("*.py"))


def test_the_modules_are_found() -> None:
    assert len(MODULES) > 100


@pytest.mark.parametrize("top", ["ucal", "drivers"])
def test_no_module_is_longer_than_a_reader_can_hold(top: str) -> None:
    long = {
        str(p.relative_to(REPO)): n
        for p in MODULES
        if p.relative_to(REPO).parts[0] == top
        and (n := len(p.read_text(encoding="utf-8").splitlines())) > MAX_LINES
    }
    assert not long, long


def test_the_drivers_never_import_ucal() -> None:
    found = []
    for path in (p for p in MODULES if p.relative_to(REPO).parts[0] == "drivers"):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            names = (
                [a.name for a in node.names]
                if isinstance(node, ast.Import)
                else [node.module or ""]
                if isinstance(node, ast.ImportFrom) and node.level == 0
                else []
            )
            found += [f"{path.relative_to(REPO)}: {n}" for n in names if n.split(".")[0] == "ucal"]
    assert not found, found
