"""Fixtures shared by the system tests."""

from __future__ import annotations

import re
import shlex
from collections.abc import Callable

import pytest

#: One ``--help`` example: the environment it sets and the arguments after ``ucal``.
Example = tuple[dict[str, str], list[str]]


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
