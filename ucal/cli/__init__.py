"""The ``ucal`` command line: a thin click group; one module per command exposing ``cli``.

Commands parse, build objects and call the domain layer. Errors become one line on stderr and
the exit code of SPEC.md (with ``--json`` also the error object on stdout); a traceback only
with ``--debug``. ``-v``, ``-q`` and ``--debug`` are accepted before or after the subcommand.
"""

from __future__ import annotations

import importlib
import sys
from typing import Any

import click

from drivers.errors import DeviceTimeout, DriverError, MotionRejected
from ucal import interrupt
from ucal.cli.options import (
    SuggestingGroup,
    add_common_options,
    common_options,
    configure_logging,
    emit_json,
)
from ucal.errors import (
    EXIT_HARDWARE,
    EXIT_INTERRUPTED,
    EXIT_SAFETY,
    EXIT_USAGE,
    InterruptedAfterResult,
    UcalError,
)

#: command name → module under ``ucal.cli`` exposing ``cli``
COMMANDS = {
    "profile": "profile",
    "fk": "fk",
    "ik": "ik",
    "path": "path",
    "export": "export",
    "sim": "sim",
    "calibrate": "calibrate",
    "tool-frame": "tool_frame",
    "verify": "verify",
    "check": "check",
    "status": "status",
    "echo": "echo",
    "report": "report",
    "fleet": "fleet",
}


#: command name → the first paragraph of its help, for ``ucal --help``'s listing without
#: importing every command's module (numpy, scipy and the drivers: a second of start-up);
#: a test holds it to the commands' own help.
SUMMARIES = {
    "profile": "Cell profiles (TOML): nominal geometry of the cell and calibration results.",
    "fk": "Tool centre point X,Y,Z (mm), RX,RY,RZ (deg, Staubli) in the base frame.",
    "ik": "Joint readings (deg) that put the tool at a pose, with the profile's offsets taken out.",
    "path": "Turn tool poses X,Y,Z,RX,RY,RZ (mm, deg) into a joint path in one arm configuration.",
    "export": "Export the calibrated cell for a robot controller (VAL3) or ROS 2.",
    "sim": "The simulated cell (controller and pulser speaking the real protocols).",
    "calibrate": "Find the six joint zero offsets with the ultrasonic transducer and write them.",
    "tool-frame": "Find the tool centre point and beam direction relative to the flange.",
    "verify": "Measure the positioning error before and after calibration (paper 000, §5.2).",
    "check": "Check the cell against its commissioning in about a minute; name what moved.",
    "status": "Show the joint readings, the controller's status and the pulser's identity.",
    "echo": "Time of flight and amplitude of the echo in each A-scan of FILE.",
    "report": "Write one HTML page of the cell as PROFILE and its history hold it.",
    "fleet": "List the cells that publish to a broker: last results, due dates, trends.",
}


def short_help(name: str, limit: int) -> str:
    """Command ``name``'s line in the listing, cut at ``limit`` characters as click cuts it."""
    return click.Command(name, help=SUMMARIES[name]).get_short_help_str(limit)


class LazyGroup(SuggestingGroup):
    """Import a command's module only when the command is used (keeps ``ucal --help`` fast:
    its listing comes from ``SUMMARIES``)."""

    def list_commands(self, ctx: click.Context) -> list[str]:
        return list(COMMANDS)

    def format_commands(self, ctx: click.Context, formatter: click.HelpFormatter) -> None:
        """The "Commands" section as click draws it, each line cut to fit as click cuts it."""
        limit = formatter.width - 6 - max(map(len, COMMANDS))
        rows = [(name, short_help(name, limit)) for name in COMMANDS]
        with formatter.section("Commands"):
            formatter.write_dl(rows)

    def get_command(self, ctx: click.Context, name: str) -> click.Command | None:
        module = COMMANDS.get(name)
        if module is None:
            return None
        command: click.Command = importlib.import_module(f"ucal.cli.{module}").cli
        return add_common_options(command)


@click.group(cls=LazyGroup, context_settings={"help_option_names": ["-h", "--help"]})
@common_options
@click.version_option(package_name="ucal")
@click.pass_context
def cli(ctx: click.Context) -> None:
    """Calibrate a Staubli-class robot with the ultrasonic transducer it carries.

    \b
    Examples:
      ucal profile init tx90l cell.toml
      ucal calibrate cell.toml --sim --yes
      ucal ik cell.toml --pose 600,300,100,180,0,0 --all --json
    """
    configure_logging(ctx)  # -v/-q/--debug after the subcommand adjust it again


def _report(message: str, code: int, as_json: bool, result: dict[str, Any] | None = None) -> None:
    """The one-line error on stderr; with ``--json`` the SPEC error object on stdout too (the
    full result plus the error fields when the run finished out of tolerance)."""
    click.echo(f"error: {message}", err=True)
    if as_json:
        emit_json({**(result or {}), "error": message, "exit_code": code})


def _wants_json(args: list[str]) -> bool:
    """Whether ``--json`` is among the options (not after ``--``)."""
    options = args[: args.index("--")] if "--" in args else args
    return "--json" in options


def main(argv: list[str] | None = None) -> None:
    """Run the ``ucal`` command line on ``argv`` (default: the process's arguments).

    Ctrl-C and SIGTERM always interrupt: the robot is stopped and the profile kept. A process
    started in the background by a non-interactive shell inherits SIGINT as ignored; a
    supervisor stops a commissioning script with SIGTERM. Both must still stop the robot. The
    handler is armed first thing (``ucal.interrupt``): a signal that arrived while the command
    line was imported interrupts the run here, before anything is connected; a run that
    received one ends as interrupted (exit 130) even where its ``KeyboardInterrupt`` was
    swallowed or turned into another error on the way. (``ucal sim serve`` installs its own
    handlers.)
    """
    args = sys.argv[1:] if argv is None else argv
    debug = "--debug" in args
    as_json = _wants_json(args)
    try:
        interrupt.arm()
        try:
            cli.main(args=args, prog_name="ucal", standalone_mode=False)
        finally:
            interrupt.hold()  # the reporting below is not cut by a signal: it reports one
        if interrupt.received:  # a signal once the result was printed: it stands
            click.echo(f"error: {LATE_SIGNAL}", err=True)
            sys.exit(EXIT_INTERRUPTED)
    except click.exceptions.Abort as e:
        # click turns Ctrl-C into Abort: during the run (with a cause) or at the confirmation
        # (without; a declined confirmation is NotConfirmed, exit 4)
        _report(
            "interrupted; any motion was stopped"
            if e.__cause__ is not None
            else "interrupted at the confirmation: nothing moved, nothing written",
            EXIT_INTERRUPTED,
            as_json,
        )
        sys.exit(EXIT_INTERRUPTED)
    except click.exceptions.Exit as e:
        sys.exit(e.exit_code)
    except click.ClickException as e:
        e.show()
        code = EXIT_USAGE if e.exit_code in (1, 2) else e.exit_code
        if as_json:
            emit_json({"error": e.format_message(), "exit_code": code})
        sys.exit(code)
    except (KeyboardInterrupt, Exception) as e:
        message, code = _classify(e)
        _report(message, code, as_json, getattr(e, "result", None))
        if debug:
            raise
        sys.exit(code)


def _classify(e: BaseException) -> tuple[str, int]:
    """The one-line message and the SPEC exit code of an error that ended a command."""

    if isinstance(e, InterruptedAfterResult):
        return str(e), e.exit_code
    if isinstance(e, KeyboardInterrupt) or interrupt.received:
        # a signal's KeyboardInterrupt may have become another error where it struck (an
        # ImportError from an extension's initialisation): the run was still interrupted
        return "interrupted; the robot was told to stop", EXIT_INTERRUPTED
    if isinstance(e, UcalError):
        return str(e), e.exit_code
    if isinstance(e, MotionRejected):  # the controller refused a target: a safety refusal
        return one_line(str(e)), EXIT_SAFETY
    if isinstance(e, DeviceTimeout):
        return one_line(str(e)) + TIMEOUT_HINTS.get(e.device, ""), EXIT_HARDWARE
    if isinstance(e, DriverError):
        return one_line(str(e)), EXIT_HARDWARE
    return f"internal error: {type(e).__name__}: {e} (run with --debug for details)", 1


#: What a timeout's message adds by device: the profile key that sets the wait, and where it
#: goes (``ucal profile init`` writes a ``[controller]`` table, no ``[pulser]`` one).
TIMEOUT_HINTS = {
    "pulser": (
        "; if the instrument is on and wired, its link may need longer: set timeout_s (s, "
        "default 1, the link's margin beyond the averaging) in the profile's [pulser] table "
        "(add the table if the profile has none)"
    ),
    "digitizer": (
        "; if the scope is on, triggered and wired, its link may need longer: set timeout_s "
        "(s, default 1, the link's margin beyond the acquisition) in the profile's [pulser] "
        "table (add the table if the profile has none)"
    ),
    "controller": (
        "; if the controller's server is running, it may need longer: the [controller] "
        "table's *_timeout_s keys set each wait"
    ),
}
#: A signal that came once the command had printed its result.
LATE_SIGNAL = "interrupted as the run ended: its result stands as printed"
#: Longest one-line message of a device fault: a device's garbage beyond is cut.
MAX_MESSAGE_CHARS = 400


def one_line(text: str) -> str:
    """A device fault's message on one line: control characters and bytes that are no text
    escaped (a device's garbage pasted into the message), the whole cut at
    ``MAX_MESSAGE_CHARS``."""
    shown = "".join(c if c.isprintable() else repr(c)[1:-1] for c in text)
    if len(shown) > MAX_MESSAGE_CHARS:
        shown = shown[: MAX_MESSAGE_CHARS - 5] + " ..."
    return shown
