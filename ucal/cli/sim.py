"""``ucal sim serve``: serve the simulated controller and pulser on 127.0.0.1."""

from __future__ import annotations

import json
import signal
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import click

from ucal.cell import CellProfile
from ucal.cli.options import F, SuggestingGroup, file_option
from ucal.errors import InputError
from ucal.profile import default_profile_text, load_profile
from ucal.profile.models import DEFAULT_MODEL
from ucal.sim.serve import SimulatedCellServer
from ucal.world import load_world


@click.group("sim", cls=SuggestingGroup)
def cli() -> None:
    """The simulated cell (controller and pulser speaking the real protocols)."""


def _world_choice(flag: str, choices: list[str], world_key: str, text: str) -> Callable[[F], F]:
    """Decorator: ``flag`` taking one of ``choices``, None when not given: the world's
    ``world_key`` then, else the first of ``choices`` (``text`` and the help say so)."""
    default = f" Default: the world's {world_key}, else {choices[0]}."
    return click.option(flag, type=click.Choice(choices), help=text + default)


@cli.command(
    "serve",
    epilog="""\b
Examples:
  ucal sim serve
  ucal sim serve --profile cell.toml --world examples/world.toml --log motions.jsonl
  ucal sim serve --rtu --time-scale 0.1
  ucal sim serve --server val3
  ucal sim serve --pulser-kind ascii-scpi
  ucal sim serve --pulser-kind ascii-scpi --scope rigol
  ucal sim serve --pulser-kind manual
""",
)
@file_option(
    "--world",
    "world_path",
    "World TOML with the truth (default: the demo truth of the profile; an example with every "
    "key: examples/world.toml in the source tree).",
)
@file_option(
    "--profile",
    "profile_path",
    "Cell profile TOML (default: a new profile of the default model, tx90l).",
)
@file_option("--log", "log_path", "Append one JSON line per executed motion to this file.")
@click.option(
    "--time-scale",
    type=click.FloatRange(min=0.0),
    default=1.0,
    show_default=True,
    help="Multiply the duration of every move and acquisition on the host clock (1 = real "
    "time, 0.1 = ten times faster; 0 = instantaneous moves, an arm faster than the stream "
    "shows: the moving commands read their lines in settled steps, slowly, and a face's "
    "search may not settle: rehearse them at 0.1 or more).",
)
@click.option("--rtu", is_flag=True, help="Pulser speaks Modbus RTU framing over TCP.")
@click.option(
    "--pulser-kind",
    type=click.Choice(["modbus", "ascii-scpi", "manual"]),
    help="The pulser back-end served: modbus (a pulser that gates), ascii-scpi (an ASCII "
    "serial pulser at ascii://socket://… and a SCPI oscilloscope at visa://…, whose "
    'URL the first line adds as "digitizer"), or manual (that oscilloscope alone, beside a '
    'pulser set by hand: "pulser" is manual://, its front panel the profile\'s [pulser] '
    "with the world's gain_db). Default: the world's [pulser] kind, else manual for a "
    'profile whose [pulser] kind = "manual", else modbus.',
)
@_world_choice(
    "--scope",
    ["keysight", "rigol"],
    "[pulser] scope",
    "The oscilloscope's family (ascii-scpi and manual cells), the dialect its SCPI speaks: "
    "keysight (an InfiniiVision X-Series, triggered on EXT) or rigol (a DS1000Z, triggered on "
    "CH2).",
)
@_world_choice(
    "--server",
    ["simple", "val3", "val3-feedback"],
    "[controller] server",
    "Simple Message server the controller behaves as: val3 = the released VAL3 server "
    "(JOINT_POSITION at 50 Hz, STATUS every 5th, 1 s of silence after a client connects, one "
    "client per port), val3-feedback = its JOINT_FEEDBACK pull request (250 Hz, STATUS every "
    "20th), simple = state and STATUS in every frame at once.",
)
def serve(
    world_path: Path | None,
    profile_path: Path | None,
    log_path: Path | None,
    time_scale: float,
    rtu: bool,
    pulser_kind: str | None,
    scope: str | None,
    server: str | None,
) -> None:
    """Serve the simulated cell until SIGINT or SIGTERM.

    Prints one JSON line {"controller": URL, "pulser": URL} on stdout (with
    "digitizer": URL for an ascii-scpi or a manual pulser), then serves.
    """

    if log_path is not None:
        _check_log(log_path)
    profile = _load_profile(profile_path)
    world = None
    if world_path is not None:
        world = load_world(world_path, profile)
    default = "manual" if profile.pulser.set_by_hand else "modbus"
    kind = pulser_kind or (world.pulser.kind if world is not None else default)
    if rtu and kind != "modbus":
        raise InputError(f"--rtu is Modbus RTU framing: the {kind} pulser has its own")
    if scope is not None and kind == "modbus":
        raise InputError(
            f"--scope is the ascii-scpi cell's oscilloscope (or a manual one's): the {kind} "
            "pulser has none"
        )

    # The handler takes no lock: a threading.Event set from a signal handler deadlocks when
    # the signal lands while the main thread holds the event's lock inside wait().
    signals: list[int] = []

    def _on_signal(signum: int, frame: object) -> None:
        signals.append(signum)

    previous = {s: signal.signal(s, _on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        with SimulatedCellServer(
            world,
            profile,
            log_path=log_path,
            time_scale=time_scale,
            pulser_framing="rtu" if rtu else "tcp",
            server=server,
            pulser_kind=kind,
            scope=scope,
        ) as cell:
            sys.stdout.write(json.dumps(cell.urls) + "\n")
            sys.stdout.flush()
            while not signals:
                time.sleep(0.1)
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)


def _check_log(path: Path) -> None:
    """Open the motion log for appending once, so that a missing or unwritable directory is an
    input error (exit 2) naming the file before anything is served."""
    try:
        with open(path, "a", encoding="utf-8"):
            pass
    except OSError as e:
        raise InputError(f"{path}: cannot write the motion log: {e.strerror or e}") from None


def _load_profile(path: Path | None) -> CellProfile:
    """The profile at ``path``, or a new profile of the default model."""

    if path is not None:
        return load_profile(path)

    with tempfile.TemporaryDirectory(prefix="ucal-sim-") as tmp:
        tmp_path = Path(tmp) / f"{DEFAULT_MODEL}.toml"
        tmp_path.write_text(default_profile_text(DEFAULT_MODEL), encoding="utf-8")
        return load_profile(tmp_path).replace(path=None)
