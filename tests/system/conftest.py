"""Fixtures shared by the system tests."""

from __future__ import annotations

import re
import shlex
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from doubles import once_per_run, ucal_here

#: One ``--help`` example: the environment it sets and the arguments after ``ucal``.
Example = tuple[dict[str, str], list[str]]

REPO = Path(__file__).resolve().parents[2]
FAULTY_WORLD = REPO / "examples" / "faulty_world.toml"
#: The first line of the README's rehearsal block, which names it.
REHEARSAL_FIRST = "ucal profile init tx90l cell.toml"


def rehearsal_lines() -> list[list[str]]:
    """The README's rehearsal block: each line's arguments after ``ucal``."""
    text = (REPO / "README.md").read_text(encoding="utf-8")
    block = text[text.index(REHEARSAL_FIRST) :].split("```", 1)[0]
    return [shlex.split(ln)[1:] for ln in block.splitlines() if ln.strip()]


@pytest.fixture(scope="session")
def rehearsal(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[dict[str, Any]]]:
    """The README's rehearsal block run once for the test run (``doubles.once_per_run``):
    ``test_rehearsal.py`` asserts its results, ``test_report_rehearsal.py`` the report of the
    cell it leaves. Each line runs as written in the test's process (``doubles.ucal_here``),
    ``--json`` added to every line after the first, in a directory holding
    ``examples/faulty_world.toml``. Returns the directory (to read; a test that writes copies
    it) and, line by line, its arguments, exit code, stdout and stderr and the profile's text
    after it."""

    def make(directory: Path) -> dict[str, Any]:
        (directory / "examples").mkdir()
        shutil.copy(FAULTY_WORLD, directory / "examples" / FAULTY_WORLD.name)
        steps = []
        for i, line in enumerate(rehearsal_lines()):
            args = line if i == 0 else [*line, "--json"]
            r = ucal_here(*args, cwd=directory)
            profile = directory / "cell.toml"
            steps.append(
                {
                    "args": args,
                    "returncode": r.returncode,
                    "stdout": r.stdout,
                    "stderr": r.stderr,
                    "profile": profile.read_text(encoding="utf-8") if profile.exists() else "",
                }
            )
        return {"steps": steps}

    directory, made = once_per_run(tmp_path_factory, "rehearsal", make)
    return directory, made["steps"]


@pytest.fixture
def help_examples(
    run_main: Callable[[list[str]], tuple[int, str, str]],
) -> Callable[[list[str]], list[Example]]:
    """Read the ``Examples:`` block of ``ucal COMMAND --help``."""

    def read(command: list[str]) -> list[Example]:
        code, out, _ = run_main([*command, "--help"])
        assert code == 0 and "Examples:" in out, out
        block = re.sub(r"\\\n\s*", " ", out.split("Examples:", 1)[1])  # continued lines
        found: list[Example] = []
        for line in block.splitlines():
            if not line.strip():
                if found:
                    break
                continue
            words = shlex.split(line)
            env = {}
            while "=" in words[0]:
                name, value = words.pop(0).split("=", 1)
                env[name] = value
            assert words[0] == "ucal", line
            found.append((env, words[1:]))
        assert found
        return found

    return read
