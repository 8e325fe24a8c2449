"""The ``ucal`` command line: a thin click group; one module per command exposing ``cli``.

Commands parse, build objects and call the domain layer. Errors become one line on stderr and
the exit code of SPEC.md; a traceback only with ``--debug``.
"""

from __future__ import annotations

import importlib
import logging
import sys

import click

from ucal.errors import EXIT_HARDWARE, EXIT_INTERRUPTED, EXIT_SAFETY, EXIT_USAGE, UcalError

#: command name → module under ``ucal.cli`` exposing ``cli``
COMMANDS = {
    "profile": "profile",
    "fk": "fk",
    "ik": "ik",
    "path": "path",
    "sim": "sim",
    "calibrate": "calibrate",
    "tool-frame": "tool_frame",
    "verify": "verify",
    "status": "status",
}


class LazyGroup(click.Group):
    """Import a command's module only when the command is used (keeps ``ucal --help`` fast)."""

    def list_commands(self, ctx: click.Context) -> list[str]:
        return list(COMMANDS)

    def get_command(self, ctx: click.Context, name: str) -> click.Command | None:
        module = COMMANDS.get(name)
        if module is None:
            return None
        return importlib.import_module(f"ucal.cli.{module}").cli


@click.group(cls=LazyGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.option("--debug", is_flag=True, help="Show tracebacks and debug logging.")
@click.option("-v", "--verbose", count=True, help="More log output (-v info, -vv debug).")
@click.version_option(package_name="ucal")
@click.pass_context
def cli(ctx: click.Context, debug: bool, verbose: int) -> None:
    """Calibrate a Staubli-class robot with the ultrasonic transducer it carries.

    \b
    Examples:
      ucal profile init tx90l cell.toml
      ucal calibrate cell.toml --sim --yes
      ucal ik cell.toml --pose 600,300,100,180,0,0 --all --json
    """
    ctx.ensure_object(dict)
    ctx.obj["debug"] = debug
    level = logging.DEBUG if (debug or verbose > 1) else logging.INFO if verbose else logging.WARNING
    logging.basicConfig(level=level, stream=sys.stderr,
                        format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    # pymodbus logs its own retries and timeouts; ucal reports faults itself, in one line.
    logging.getLogger("pymodbus").setLevel(logging.DEBUG if debug else logging.CRITICAL)


def _fail(message: str, code: int) -> None:
    click.echo(f"error: {message}", err=True)
    sys.exit(code)


def _terminate(signum: int, frame: object) -> None:
    raise KeyboardInterrupt(f"signal {signum}")


def _interruptible() -> None:
    """Ctrl-C and SIGTERM always interrupt: the robot is stopped and the profile kept.

    A process started in the background by a non-interactive shell inherits SIGINT as ignored;
    a supervisor stops a commissioning script with SIGTERM. Both must still stop the robot.
    (``ucal sim serve`` installs its own handlers.)
    """
    import signal

    signal.signal(signal.SIGINT, signal.default_int_handler)
    signal.signal(signal.SIGTERM, _terminate)


def main(argv: list[str] | None = None) -> None:
    """Entry point of the ``ucal`` console script."""
    from drivers.errors import DriverError, MotionRejected

    _interruptible()
    args = sys.argv[1:] if argv is None else argv
    debug = "--debug" in args
    try:
        cli.main(args=args, prog_name="ucal", standalone_mode=False)
    except click.exceptions.Abort:
        _fail("interrupted; any motion was stopped", EXIT_INTERRUPTED)
    except click.exceptions.Exit as e:
        sys.exit(e.exit_code)
    except click.ClickException as e:
        e.show()
        sys.exit(EXIT_USAGE if e.exit_code in (1, 2) else e.exit_code)
    except KeyboardInterrupt:
        if debug:
            raise
        _fail("interrupted; the robot was told to stop", EXIT_INTERRUPTED)
    except UcalError as e:
        if debug:
            raise
        _fail(str(e), e.exit_code)
    except MotionRejected as e:  # the controller refused a target: a safety refusal
        if debug:
            raise
        _fail(str(e), EXIT_SAFETY)
    except DriverError as e:
        if debug:
            raise
        _fail(str(e), EXIT_HARDWARE)
    except Exception as e:
        if debug:
            raise
        _fail(f"internal error: {type(e).__name__}: {e} (run with --debug for details)", 1)
