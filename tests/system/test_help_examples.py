"""Every example in ``ucal --help`` and each command's ``--help`` runs as written.

The examples are read from the help text itself, in a directory holding the files they name
(``cell.toml``, the shipped ``examples/world.toml``, ``scan.csv``); device URLs are those
of a simulated cell on 127.0.0.1. A command that moves the robot runs up to its confirmation,
asked on a terminal and answered "no": its options, files and plan are all checked, and it
must name the cell it would move; nothing moves.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
import pytest
from urdf_files import urdf_text

from ucal.echo import build_reference
from ucal.profile import default_profile_text, load_profile
from ucal.sim.ascan import Digitiser, TransducerPulse, echo_shape, gate_around, synthesise
from ucal.sim.serve import SimulatedCellServer

from doubles import terminal_typed

pytestmark = pytest.mark.system

RunMain = Callable[[list[str]], tuple[int, str, str]]
Examples = Callable[[list[str]], list[tuple[dict[str, str], list[str]]]]

COMMANDS = [
    ["profile"],
    ["profile", "init"],
    ["fk"],
    ["ik"],
    ["path"],
    ["export"],
    ["export", "val3"],
    ["status"],
    ["calibrate"],
    ["tool-frame"],
    ["verify"],
    ["check"],
    ["echo"],
    ["report"],
]
MOVING = {"calibrate", "tool-frame", "verify", "check"}
#: The world file shipped with the sources, which the examples name as ``examples/world.toml``.
EXAMPLE_WORLD = Path(__file__).resolve().parents[2] / "examples" / "world.toml"


@pytest.fixture(scope="module")
def cell(tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict[str, str]]:
    """A simulated cell: the URLs that stand for the examples' real addresses."""
    path = tmp_path_factory.mktemp("cell") / "cell.toml"
    path.write_text(default_profile_text("tx90l"), encoding="utf-8")
    with SimulatedCellServer(None, load_profile(path), time_scale=0.0) as server:
        yield server.urls


def local(word: str, urls: dict[str, str]) -> str:
    """A device URL of an example → the simulated cell's; anything else as written."""
    if word.startswith("tcp://"):
        return urls["controller"]
    if word.startswith("modbus-tcp://"):
        return urls["pulser"]
    return word


@pytest.fixture
def workdir(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    for name in ("UCAL_SIM", "UCAL_CONTROLLER", "UCAL_PULSER"):
        monkeypatch.delenv(name, raising=False)
    monkeypatch.chdir(tmp_path)
    return tmp_path


def add_files(d: Path) -> None:
    """The files the examples name (``run.jsonl``, a recorded run, is
    ``test_record_replay_cli``'s)."""
    (d / "cell.toml").write_text(default_profile_text("tx90l"), encoding="utf-8")
    for world in ("world.toml", "truth.toml"):
        (d / world).write_text("[noise]\ntof_ns = 0.02\nseed = 3\n", encoding="utf-8")
    (d / "examples").mkdir(exist_ok=True)
    for shipped in EXAMPLE_WORLD.parent.glob("*.toml"):  # the shipped example worlds
        shutil.copy(shipped, d / "examples" / shipped.name)
    (d / "scan.csv").write_text(
        "X,Y,Z,RX,RY,RZ\n600,300,100,180,0,0\n610,300,100,180,0,0\n", encoding="utf-8"
    )
    # A-scans and a reference echo (``ucal echo``): a 10 MHz echo at 100 MS/s, 40 dB
    shape = echo_shape(TransducerPulse(10.0), Digitiser(100.0))
    t0, n = gate_around(shape, 67_000.0, noise_samples=64)
    records = synthesise(
        shape,
        np.random.default_rng(0),
        t0_ns=t0,
        n_samples=n,
        arrival_ns=[67_000.0, 67_000.4, 67_001.9],
        amplitude=0.5,
        noise_rms=0.005,
    )
    ref = build_reference(records[:1])
    for name, t_ns, columns in (
        ("scans.csv", records[0].t_ns, [r.samples for r in records]),
        ("ref.csv", ref.t0_ns + ref.dt_ns * np.arange(ref.n), [ref.samples]),
    ):
        rows = np.column_stack([t_ns, *columns])
        header = ",".join(["t_ns", *(f"a{i}" for i in range(len(columns)))])
        np.savetxt(d / name, rows, delimiter=",", header=header, comments="", fmt="%.6f")


@pytest.mark.parametrize("command", COMMANDS, ids=lambda c: " ".join(c) or "ucal")
def test_help_examples_run_as_written(
    command: list[str],
    workdir: Path,
    cell: dict[str, str],
    run_main: RunMain,
    help_examples: Examples,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    if command[0] != "profile":
        add_files(workdir)
    (workdir / "tx90l.urdf").write_text(urdf_text(), encoding="utf-8")  # init --from-urdf
    for env, args in help_examples(command):
        if "--replay" in args:
            continue  # solves a recorded run: test_record_replay_cli runs it beside its record
        for name, value in env.items():
            monkeypatch.setenv(name, local(value, cell))
        args = [local(a, cell) for a in args]
        shown = " ".join(args)
        if args[0] in MOVING:
            before = (workdir / "cell.toml").read_bytes()
            with monkeypatch.context() as m, terminal_typed("n\n") as tty:
                m.setattr(sys, "stdin", tty)
                code, out, err = run_main([a for a in args if a != "--yes"])
            where = (
                "the simulated cell" if "--sim" in args else f"the robot at {cell['controller']}"
            )
            assert code == 4 and f"Move {where} now?" in err, (shown, err)
            assert err.split(f"Move {where} now?")[0].strip(), err  # the plan was shown first
            assert "not confirmed: nothing moved, nothing written" in err
            assert (workdir / "cell.toml").read_bytes() == before, shown
            continue
        code, out, err = run_main(args)
        assert code == 0, (shown, err)
        if "--json" in args:
            assert isinstance(json.loads(out), dict), shown
        for name in env:
            monkeypatch.delenv(name)


def test_the_overview_examples_are_commands_examples(help_examples: Examples) -> None:
    """``ucal --help`` shows examples that each command's own help shows (and runs above)."""
    for env, args in help_examples([]):
        command = args[:2] if args[0] == "sim" else args[:1]
        assert (env, args) in help_examples(command), args


def test_sim_serve_examples_serve_until_interrupted(
    workdir: Path, run_main: RunMain, help_examples: Examples
) -> None:
    """Each serves (its first stdout line gives the URLs) and ends at SIGINT with exit 0."""
    add_files(workdir)
    for _, args in help_examples(["sim", "serve"]):
        interrupter = threading.Thread(target=interrupt_once_serving, daemon=True)
        interrupter.start()
        code, out, err = run_main(args)
        interrupter.join()
        assert code == 0, (args, err)
        urls = json.loads(out.splitlines()[0])
        digitizer = {"digitizer"} if {"ascii-scpi", "manual"} & set(args) else set()
        assert set(urls) == {"controller", "pulser", *digitizer}, args
        assert "127.0.0.1" in urls["controller"]
    assert (workdir / "motions.jsonl").exists()


def interrupt_once_serving() -> None:
    """Send SIGINT once ``sim serve`` has installed its handler (it then stops serving)."""
    while (
        getattr(signal.getsignal(signal.SIGINT), "__qualname__", "") != "serve.<locals>._on_signal"
    ):
        time.sleep(0.01)
    os.kill(os.getpid(), signal.SIGINT)
