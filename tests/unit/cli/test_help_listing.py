"""``ucal --help`` lists every command from ``SUMMARIES`` without importing their modules, in
the words and the cut that click would draw from each command's own help."""

from __future__ import annotations

import importlib
import json
import subprocess
import sys

import pytest

from ucal.cli import COMMANDS, short_help


@pytest.mark.parametrize("name", list(COMMANDS))
@pytest.mark.parametrize("limit", [30, 45, 66, 200])
def test_the_listing_says_what_the_commands_help_says(name: str, limit: int) -> None:
    command = importlib.import_module(f"ucal.cli.{COMMANDS[name]}").cli
    assert short_help(name, limit) == command.get_short_help_str(limit)


def test_the_listing_imports_no_command() -> None:
    probe = (
        "import contextlib, io, json, sys\n"
        "from ucal.cli import main\n"
        "with contextlib.redirect_stdout(io.StringIO()) as out, contextlib.suppress(SystemExit):\n"
        "    main(['--help'])\n"
        "loaded = sorted(m for m in sys.modules if m.startswith('ucal.cli.'))\n"
        "print(json.dumps({'loaded': loaded, 'help': out.getvalue()}))\n"
    )
    done = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True)
    shown = json.loads(done.stdout)
    commands = {f"ucal.cli.{module}" for module in COMMANDS.values()}
    assert not commands & set(shown["loaded"])
    for name in COMMANDS:
        assert f"\n  {name} " in shown["help"]
