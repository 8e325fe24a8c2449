"""Every command example in README.md runs as written.

The examples are the ``ucal ...`` lines of the README's fenced ``sh`` blocks; a line may start
with ``NAME=VALUE`` settings, and ``export NAME=VALUE ...`` sets them for the lines after it.
Each block runs in a fresh directory, its lines in order as a reader types them. The directory
holds the files the README tells the reader to have: ``cell.toml`` (as ``ucal profile init
tx90l`` writes it) unless the block's first command creates it, the shipped
``examples/world.toml``, ``scan.csv``; device URLs are those of a simulated cell on 127.0.0.1.

* A command on the simulated cell (``--sim``, ``UCAL_SIM``) runs to its end: exit 0, or 1 where
  ``OUT_OF_TOLERANCE`` says why.
* A moving command on a real cell's URLs runs up to its confirmation, asked on a terminal and
  answered "no" (exit 4): its options, files and plan are all checked, and nothing moves.
* ``ucal sim serve`` serves (its first line gives the URLs) until interrupted, exit 0.

A block in ``RUN_ELSEWHERE`` runs in the test named there, its lines as written (with
``--json`` to check each result): the rehearsal, whose last line must exit 1.
"""

from __future__ import annotations

import json
import os
import re
import shlex
import sys
import threading
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import pytest
from test_help_examples import add_files, interrupt_once_serving, local

from ucal.profile import default_profile_text, load_profile
from ucal.sim.serve import SimulatedCellServer

from doubles import terminal_typed

pytestmark = pytest.mark.system

RunMain = Callable[[list[str]], tuple[int, str, str]]

README = Path(__file__).resolve().parents[2] / "README.md"
MOVING = {"calibrate", "tool-frame", "verify"}
#: Programs other than ucal that a README block may name (they are not run here).
OTHER_PROGRAMS = {"pip", "pytest"}
#: README lines that end out of tolerance (exit 1), and why; each must be in the README.
OUT_OF_TOLERANCE: dict[str, str] = {}
#: The README's opening blocks, which CI runs as they are (keep the test command `pytest -q`).
OPENING = [
    ["pip install .", "ucal calibrate cell.toml --sim --yes"],
    ["pip install -e '.[test]'", "pytest -q"],
]
MAX_LINES = 300
ROOT = README.parent
#: The benchmarks page keeps today's figures of each benchmark; their history is in git.
BENCHMARKS_PAGE = ROOT / "docs" / "benchmarks.md"
MAX_BENCHMARKS_LINES = 400


@dataclass
class Command:
    """One README line: the environment it sets, the arguments after ``ucal`` (None for an
    ``export`` line), and the line as written."""

    env: dict[str, str]
    args: list[str] | None
    line: str


@dataclass
class Block:
    """A fenced ``sh`` block of the README."""

    first_line: int
    lines: list[str]
    commands: list[Command] = field(default_factory=list)

    @property
    def id(self) -> str:
        shown = next((c.line for c in self.commands if c.args is not None), "")
        return f"line {self.first_line}: {shown}"


def shell_blocks(text: str) -> list[Block]:
    """The README's fenced ``sh`` blocks, continued lines joined."""
    blocks: list[Block] = []
    current: Block | None = None
    for n, line in enumerate(text.splitlines(), start=1):
        if current is None:
            if re.fullmatch(r"```(sh|shell|bash|console)\s*", line):
                current = Block(n + 1, [])
        elif line.startswith("```"):
            blocks.append(current)
            current = None
        else:
            current.lines.append(line)
    assert current is None, "an unclosed code block in README.md"
    for block in blocks:
        joined = re.sub(r"\\\n\s*", " ", "\n".join(block.lines))
        block.commands = [c for ln in joined.splitlines() if (c := parse(ln)) is not None]
    return blocks


def parse(line: str) -> Command | None:
    """A README line as a command; None for an empty line, a comment or another program."""
    words = shlex.split(line, comments=True)
    if not words:
        return None
    env: dict[str, str] = {}
    export = words[0] == "export"
    if export:
        words.pop(0)
    while words and re.match(r"[A-Z_][A-Z0-9_]*=", words[0]):
        name, value = words.pop(0).split("=", 1)
        env[name] = value
    if export:
        assert env and not words, f"README: an export line sets variables only: {line!r}"
        return Command(env, None, line.strip())
    assert words, f"README: a line that only sets variables: {line!r}"
    if words[0] in OTHER_PROGRAMS:
        return None
    assert words[0] == "ucal", f"README: {words[0]!r} is neither ucal nor a known program: {line!r}"
    return Command(env, words[1:], line.strip())


BLOCKS = [b for b in shell_blocks(README.read_text(encoding="utf-8")) if b.commands]


def creates_profile(block: Block) -> bool:
    """Whether the block's first ucal command creates ``cell.toml``: ``profile init``, or
    ``calibrate --sim`` (which creates a missing profile; a dry run does not)."""
    first = next(c for c in block.commands if c.args is not None)
    args = first.args or []
    return args[:2] == ["profile", "init"] or (
        args[:1] == ["calibrate"] and "--sim" in args and "--dry-run" not in args
    )


@pytest.fixture(scope="module")
def cell(tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict[str, str]]:
    """A simulated cell: the URLs that stand for the README's real addresses."""
    path = tmp_path_factory.mktemp("cell") / "cell.toml"
    path.write_text(default_profile_text("tx90l"), encoding="utf-8")
    with SimulatedCellServer(None, load_profile(path), time_scale=0.0) as server:
        yield server.urls


def test_the_readme_opens_with_the_install_and_test_commands() -> None:
    blocks = shell_blocks(README.read_text(encoding="utf-8"))
    assert [[ln.strip() for ln in b.lines if ln.strip()] for b in blocks[:2]] == OPENING


def test_the_readme_is_short() -> None:
    """A README for users; derivations and benchmarks live in docs/."""
    n = len(README.read_text(encoding="utf-8").splitlines())
    assert n <= MAX_LINES, f"README.md has {n} lines (at most {MAX_LINES}): move detail to docs/"


def heading_anchors(markdown: str) -> set[str]:
    """The anchors GitHub gives the headings (lower case, punctuation dropped, spaces ``-``)."""
    headings = re.findall(r"^#+ (.+)$", markdown, flags=re.MULTILINE)
    return {re.sub(r"[^\w\- ]", "", h.strip().lower()).replace(" ", "-") for h in headings}


def test_the_benchmarks_page_keeps_todays_figures_of_every_benchmark() -> None:
    """docs/benchmarks.md: short, every script of benchmarks/ in it, every link into it lands."""
    text = BENCHMARKS_PAGE.read_text(encoding="utf-8")
    n = len(text.splitlines())
    assert n <= MAX_BENCHMARKS_LINES, (
        f"docs/benchmarks.md has {n} lines (at most {MAX_BENCHMARKS_LINES}): keep today's "
        "figures of each benchmark, their history is in git"
    )
    scripts = sorted(p.name for p in (ROOT / "benchmarks").glob("*.py") if p.name[0] != "_")
    assert [s for s in scripts if f"`{s}`" not in text and f"benchmarks/{s}" not in text] == []
    anchors = heading_anchors(text)
    docs = [README, *sorted((ROOT / "docs").rglob("*.md"))]
    links = {
        (doc.name, anchor)
        for doc in docs
        for anchor in re.findall(r"benchmarks\.md#([\w\-]+)", doc.read_text(encoding="utf-8"))
    }
    assert {link for link in links if link[1] not in anchors} == set()


def test_every_decision_record_states_its_date_status_and_alternatives() -> None:
    decisions = ROOT / "docs" / "decisions"
    index = (decisions / "README.md").read_text(encoding="utf-8")
    for record in sorted(decisions.glob("0*.md")):
        text = record.read_text(encoding="utf-8")
        head = "\n".join(text.splitlines()[1:5])
        assert re.search(r"^(\*\*)?Date[.:]", head, flags=re.MULTILINE), (record.name, "date")
        assert re.search(r"\bStatus[.:]", head), (record.name, "status")
        assert "**Alternatives weighed.**" in text, (record.name, "alternatives")
    linked = re.findall(r"\]\((0\d+-[\w\-]+\.md)\)", index)
    assert linked and [name for name in linked if not (decisions / name).is_file()] == []


def test_every_out_of_tolerance_entry_is_a_readme_line() -> None:
    lines = {c.line for b in BLOCKS for c in b.commands}
    assert set(OUT_OF_TOLERANCE) <= lines, set(OUT_OF_TOLERANCE) - lines


#: Blocks another test runs line by line as written, with ``--json`` to check their results:
#: the rehearsal (``test_rehearsal.py``; running it twice costs the suite 15 s of CPU).
RUN_ELSEWHERE = {"ucal profile init tx90l cell.toml": "test_rehearsal.py"}


def test_blocks_run_elsewhere_are_in_the_readme() -> None:
    firsts = {c.line for b in BLOCKS for c in b.commands[:1]}
    assert set(RUN_ELSEWHERE) <= firsts, set(RUN_ELSEWHERE) - firsts


@pytest.mark.parametrize(
    "block", [b for b in BLOCKS if b.commands[0].line not in RUN_ELSEWHERE], ids=lambda b: b.id
)
def test_readme_block_runs_as_written(
    block: Block,
    tmp_path: Path,
    cell: dict[str, str],
    run_main: RunMain,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    for name in ("UCAL_SIM", "UCAL_CONTROLLER", "UCAL_PULSER"):
        monkeypatch.delenv(name, raising=False)
    monkeypatch.chdir(tmp_path)
    add_files(tmp_path)
    if creates_profile(block):
        (tmp_path / "cell.toml").unlink()
    for command in block.commands:
        for name, value in command.env.items():
            monkeypatch.setenv(name, local(value, cell))
        if command.args is None:
            continue  # an export: the variables stay set for the lines after it
        run(command, [local(a, cell) for a in command.args], cell, run_main, monkeypatch)
        for name in command.env:
            monkeypatch.delenv(name)


def run(
    command: Command,
    args: list[str],
    cell: dict[str, str],
    run_main: RunMain,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Run one README line (module docstring) and check how it ends."""
    shown = command.line
    on_sim = "--sim" in args or os.environ.get("UCAL_SIM", "0") not in ("", "0")
    if args[:2] == ["sim", "serve"]:
        interrupter = threading.Thread(target=interrupt_once_serving, daemon=True)
        interrupter.start()
        code, out, err = run_main(args)
        interrupter.join()
        assert code == 0, (shown, err)
        assert set(json.loads(out.splitlines()[0])) >= {"controller", "pulser"}, shown
        return
    if args[0] in MOVING and not on_sim:
        before = Path("cell.toml").read_bytes()
        with monkeypatch.context() as m, terminal_typed("n\n") as tty:
            m.setattr(sys, "stdin", tty)
            code, out, err = run_main([a for a in args if a != "--yes"])
        asked = f"Move the robot at {cell['controller']} now?"
        assert code == 4 and asked in err, (shown, err)
        assert "not confirmed: nothing moved, nothing written" in err, (shown, err)
        assert Path("cell.toml").read_bytes() == before, shown
        return
    code, out, err = run_main(args)
    assert code == (1 if shown in OUT_OF_TOLERANCE else 0), (shown, code, err[-2000:])
    if "--json" in args:
        assert isinstance(json.loads(out), dict), shown
