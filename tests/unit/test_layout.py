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


#: The procedure packages: one per command that moves the robot (docs/design.md).
PROCEDURES = ("calibration", "toolframe", "verify", "check")


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(REPO).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


KNOWN = {_module_name(p): p for p in MODULES}


def _imports(path: Path) -> set[str]:
    """The ``ucal``/``drivers`` modules ``path`` imports anywhere in it (at the top, inside a
    function or under ``TYPE_CHECKING``): ``from a.b import c`` is module ``a.b.c`` where that
    is a module, else ``a.b``."""
    out: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            out |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            subs = {f"{node.module}.{a.name}" for a in node.names}
            out |= (subs & KNOWN.keys()) or {node.module}
    return {n for n in out if n in KNOWN}


GRAPH = {name: _imports(path) for name, path in KNOWN.items()}


def _package(module: str) -> str | None:
    parts = module.split(".")
    return parts[1] if parts[0] == "ucal" and len(parts) > 2 else None


def test_no_procedure_imports_a_sibling_procedure() -> None:
    found = [
        f"{m} -> {n}"
        for m, deps in GRAPH.items()
        if _package(m) in PROCEDURES
        for n in deps
        if _package(n) in PROCEDURES and _package(n) != _package(m)
    ]
    assert not found, found


@pytest.mark.parametrize("floor", ["measure", "model"])
def test_the_measuring_library_and_the_cell_model_import_no_procedure(floor: str) -> None:
    above = {*PROCEDURES, "cli", "report", "sim"}
    found = [
        f"{m} -> {n}"
        for m, deps in GRAPH.items()
        if _package(m) == floor
        for n in deps
        if _package(n) in above or n in ("ucal.procedure", "ucal.devices.session")
    ]
    assert not found, found


def test_the_cell_model_stands_below_the_measuring_library() -> None:
    found = [
        f"{m} -> {n}"
        for m, deps in GRAPH.items()
        if _package(m) == "model"
        for n in deps
        if _package(n) == "measure"
    ]
    assert not found, found


def test_the_files_readers_stand_below_the_simulated_cell() -> None:
    """The world file and the profile are read below ``ucal/sim/``, which serves what they
    say: a constant the simulator needs of a world's keys lives with the reader."""
    found = [
        f"{m} -> {n}"
        for m, deps in GRAPH.items()
        if m.startswith(("ucal.world", "ucal.profile", "ucal.cell"))
        for n in deps
        if _package(n) == "sim"
    ]
    assert not found, found


def test_no_import_cycle() -> None:
    """Tarjan's strongly connected components of the module graph: every one a single module."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    cycles: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        for w in GRAPH[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while (w := stack.pop()) != v:
                component.append(w)
            if component:
                cycles.append(sorted([v, *component]))

    for v in sorted(GRAPH):
        if v not in index:
            visit(v)
    assert not cycles, cycles
