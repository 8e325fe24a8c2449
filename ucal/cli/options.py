"""Options shared by several commands, defined once, and what they mean together.

``-v``/``-q``/``--debug`` are added to every command (``add_common_options``), so they work
before or after the subcommand. The cell a moving command talks to comes from ``--sim`` or
``--controller``/``--pulser`` (and ``--digitizer`` for a pulser that does not digitise), or from
the environment (``UCAL_SIM``, ``UCAL_CONTROLLER``, ``UCAL_PULSER``, ``UCAL_DIGITIZER``); options
typed on the command line win over the environment (``cell_from_options``). ``--publish URL``
(or ``UCAL_PUBLISH``) sends a moving command's final result to an MQTT broker
(``publish_url``, ``ucal.cli.publishing``).
"""

from __future__ import annotations

import difflib
import functools
import json
import logging
import os
import sys
from collections.abc import Callable
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any, TypeVar

import click
import numpy as np
from click.core import ParameterSource
from rich.console import Console
from rich.highlighter import NullHighlighter
from rich.logging import RichHandler

from drivers.registry import open_controller, open_pulser
from ucal.cell_choice import CellChoice
from ucal.errors import InputError, NotConfirmed
from ucal.fleet.url import BrokerUrl, parse_broker_url

F = TypeVar("F", bound=Callable[..., Any])

#: Environment variables naming the cell (SPEC.md); options win over them.
ENV_SIM = "UCAL_SIM"
ENV_CONTROLLER = "UCAL_CONTROLLER"
ENV_PULSER = "UCAL_PULSER"
ENV_DIGITIZER = "UCAL_DIGITIZER"
ENV_THERMOMETER = "UCAL_THERMOMETER"
#: The broker a moving command publishes its result to (``--publish``).
ENV_PUBLISH = "UCAL_PUBLISH"
#: ``UCAL_SIM`` values meaning "the simulated cell with the demo truth" / "no simulated cell".
SIM_ENV_ON = frozenset({"1", "yes", "true", "on"})
SIM_ENV_OFF = frozenset({"", "0", "no", "false", "off"})
#: Columns of the tables written to a pipe or a file: no table is that wide, so none is cut.
PIPE_WIDTH = 1000


def _settings(ctx: click.Context) -> dict[str, Any]:
    root = ctx.find_root()
    root.ensure_object(dict)
    settings: dict[str, Any] = root.obj
    return settings


def _count(ctx: click.Context, param: click.Parameter, value: Any) -> None:
    """Add ``-v``/``-q``/``--debug`` wherever they are typed, then set the log level."""
    if not value:
        return
    settings = _settings(ctx)
    settings[param.name or ""] = settings.get(param.name or "", 0) + int(value)
    configure_logging(ctx)


def configure_logging(ctx: click.Context) -> None:
    """Log to stderr: warnings by default, ``-v`` info, ``-vv``/``--debug`` debug, ``-q``
    errors only (as counted so far on the command line)."""
    settings = _settings(ctx)
    debug = bool(settings.get("debug"))
    level = settings.get("verbose", 0) - settings.get("quiet", 0)
    root = logging.getLogger()
    for handler in [h for h in root.handlers if isinstance(h, _StderrLog)]:
        root.removeHandler(handler)  # configured again as more options are read
    root.addHandler(_StderrLog(debug))
    root.setLevel(
        logging.DEBUG
        if debug or level > 1
        else logging.INFO
        if level == 1
        else logging.WARNING
        if level == 0
        else logging.ERROR
    )
    # pymodbus logs its own retries and timeouts; ucal reports faults itself, in one line.
    logging.getLogger("pymodbus").setLevel(logging.DEBUG if debug else logging.CRITICAL)


#: What a log line starts with, by level: the words of the command line's own lines
#: (``warn``, the ``error:`` of a fault), so that a log line reads as one of them.
LOG_PREFIX = {logging.DEBUG: "debug: ", logging.INFO: "", logging.WARNING: "warning: "}


class _LogFormat(logging.Formatter):
    """``warning: message``, ``error: message``; with ``--debug`` the logger's name too."""

    def __init__(self, debug: bool) -> None:
        super().__init__()
        self.debug = debug

    def format(self, record: logging.LogRecord) -> str:
        prefix = LOG_PREFIX.get(record.levelno, "error: ")
        where = f"{record.name}: " if self.debug else ""
        text = prefix + where + record.getMessage()
        if record.exc_info and self.debug:
            text += "\n" + self.formatException(record.exc_info)
        return text


class _StderrLog(RichHandler):
    """The one log handler: rich's, on stderr, one line per record in the command line's own
    words (``_LogFormat``); no time stamp, level column or source path, no markup read in a
    device's text. A live progress display on the terminal keeps its place below the lines;
    in a pipe or a file no line is wrapped."""

    def __init__(self, debug: bool) -> None:
        console = Console(stderr=True, width=None if sys.stderr.isatty() else PIPE_WIDTH)
        super().__init__(
            console=console,
            show_time=False,
            show_level=False,
            show_path=False,
            markup=False,
            rich_tracebacks=False,
            highlighter=NullHighlighter(),
        )
        self.setFormatter(_LogFormat(debug))

    def render(self, *, record: logging.LogRecord, traceback: Any, message_renderable: Any) -> Any:
        """The line itself: rich's table of time, level and path columns pads it to the
        console's width."""
        return message_renderable


def _counted(flags: list[str], text: str, flag: bool = False) -> click.Option:
    """An option counted wherever it is typed (``_count``): a flag, or one that repeats."""
    return click.Option(
        flags, is_flag=flag, count=not flag, expose_value=False, callback=_count, help=text
    )


COMMON_OPTIONS = (
    _counted(["--debug"], "Show tracebacks and debug logging.", flag=True),
    _counted(["-v", "--verbose"], "More log output (-v info, -vv debug)."),
    _counted(
        ["-q", "--quiet"],
        "No progress or informational messages on stderr (errors and warnings still print).",
    ),
)


def common_options(f: F) -> F:
    """Decorator: ``--debug``, ``-v``, ``-q`` on a command."""
    params = getattr(f, "__click_params__", [])
    f.__click_params__ = params + list(COMMON_OPTIONS)  # type: ignore[attr-defined]
    return f


def add_common_options(command: click.Command) -> click.Command:
    """Give ``command`` and every command under it ``--debug``, ``-v`` and ``-q``."""
    names = {n for p in command.params for n in p.opts}
    command.params.extend(o for o in COMMON_OPTIONS if not names.intersection(o.opts))
    if isinstance(command, click.Group):
        for sub in command.commands.values():
            add_common_options(sub)
    return command


class SuggestingGroup(click.Group):
    """A command group whose "No such command" names the nearest command (``ucal calibrat``:
    "Did you mean 'calibrate'?"), exit 2; works for groups that load their commands lazily."""

    def resolve_command(
        self, ctx: click.Context, args: list[str]
    ) -> tuple[str | None, click.Command | None, list[str]]:
        name = click.utils.make_str(args[0])
        commands = self.list_commands(ctx)
        if name not in commands and not name.startswith("-") and not ctx.resilient_parsing:
            near = difflib.get_close_matches(name, commands, n=1)
            if near:
                ctx.fail(f"No such command {name!r}. Did you mean {near[0]!r}?")
        return super().resolve_command(ctx, args)


def quiet() -> bool:
    """Whether ``-q`` was given (anywhere on the command line)."""
    ctx = click.get_current_context(silent=True)
    return ctx is not None and _settings(ctx).get("quiet", 0) > 0


def info(message: str) -> None:
    """An informational line on stderr, unless ``-q``."""
    if not quiet():
        click.echo(message, err=True)


def warn(message: str) -> None:
    """A warning line on stderr, with or without ``-q``: something the user did not ask for
    and must know about."""
    click.echo(f"warning: {message}", err=True)


json_option = click.option(
    "--json", "as_json", is_flag=True, help="Print one JSON object on stdout and nothing else."
)
yes_option = click.option(
    "--yes",
    "-y",
    is_flag=True,
    help="Skip the confirmation before the first motion (required when stdin is not a terminal).",
)
dry_run_option = click.option(
    "--dry-run", is_flag=True, help="Run against the simulator and write nothing."
)


def file_option(flag: str, name: str, text: str) -> Callable[[F], F]:
    """Decorator: ``flag FILE``, one file, as the parameter ``name``; ``text`` is its help."""
    kind = click.Path(dir_okay=False, path_type=Path)
    return click.option(flag, name, type=kind, metavar="FILE", help=text)


_record_option = file_option(
    "--record",
    "record_path",
    "Write the run to FILE as JSON lines as it goes: the profile, the plan, every device "
    "call (joint readings, moves, gain, readings, times), then the measurements the solver "
    "receives and the result.",
)
_replay_option = file_option(
    "--replay",
    "replay_path",
    "Solve the measurements of a --record FILE again; moves nothing, asks nothing, writes nothing.",
)
_remeasure_option = click.option(
    "--remeasure",
    is_flag=True,
    help="With --replay: run the search again on the recorded device traffic instead.",
)


thermometer_option = click.option(
    "--thermometer",
    "thermometer",
    type=click.Path(dir_okay=False, path_type=Path),
    metavar="FILE",
    envvar=ENV_THERMOMETER,
    show_envvar=True,
    help="The tank thermometer's log (CSV: time,temperature_c with ISO 8601 times, the "
    "host's local time where they carry no zone; on a "
    "simulated cell time_min,temperature_c in minutes of its clock), read when the run is "
    "solved: its slope over the run is the drift's prior, and where the tank turned during the "
    "run beyond the log's noise, the turn is taken out of every water path ([water] "
    "thermometer_std_c: how well it follows the water).",
)


def record_options(f: F) -> F:
    """Decorator: ``--record FILE``, ``--replay FILE`` and ``--remeasure``
    (``ucal.devices.record``)."""
    return _record_option(_replay_option(_remeasure_option(f)))


def _sim_from_env(ctx: click.Context, param: click.Parameter, value: str | None) -> str | None:
    """``UCAL_SIM=1`` is ``--sim`` (demo truth), ``UCAL_SIM=WORLD`` is ``--sim WORLD``."""
    if ctx.get_parameter_source(param.name or "") != ParameterSource.ENVIRONMENT:
        return value
    text = (value or "").strip()
    if text.lower() in SIM_ENV_OFF:
        return None
    return "" if text.lower() in SIM_ENV_ON else text


sim_option = click.option(
    "--sim",
    "sim_world",
    is_flag=False,
    flag_value="",
    default=None,
    metavar="[WORLD]",
    envvar=ENV_SIM,
    show_envvar=True,
    callback=_sim_from_env,
    help="Run against the built-in simulated cell; WORLD is an optional world TOML file "
    "(without it a demo truth with hidden offsets is used; UCAL_SIM=1 means the same).",
)
controller_option = click.option(
    "--controller",
    "controller_url",
    metavar="URL",
    envvar=ENV_CONTROLLER,
    show_envvar=True,
    help="Controller URL, tcp://HOST:PORT[?state=PORT].",
)
_pulser_url_option = click.option(
    "--pulser",
    "pulser_url",
    metavar="URL",
    envvar=ENV_PULSER,
    show_envvar=True,
    help="Pulser URL, modbus-tcp://HOST:PORT[?unit=N], modbus-rtu://DEVICE[?baud=N&unit=N], "
    "ascii://DEVICE[?baud=N] (with --digitizer) or manual:// (a pulser set by hand, its front "
    "panel the profile's [pulser]; with --digitizer).",
)


def _remember_digitizer(ctx: click.Context, param: click.Parameter, value: str | None) -> None:
    """Keep ``--digitizer`` for ``digitizer_from_options`` (no command takes it as an
    argument: the cell options carry it)."""
    ctx.meta["digitizer_url"] = value or None


_digitizer_option = click.option(
    "--digitizer",
    "digitizer_url",
    metavar="URL",
    envvar=ENV_DIGITIZER,
    show_envvar=True,
    expose_value=False,
    callback=_remember_digitizer,
    help="Digitiser of a pulser that does not digitise (ascii://, manual://): "
    "visa://RESOURCE, e.g. visa://TCPIP::192.168.0.7::5025::SOCKET.",
)


def _remember_broker(ctx: click.Context, param: click.Parameter, value: str | None) -> None:
    """Parse ``--publish`` (exit 2 for a malformed URL, before anything runs) and keep it for
    ``publish_url``: the command takes it as no argument."""
    text = (value or "").strip()
    try:
        ctx.meta["publish_url"] = parse_broker_url(text) if text else None
    except ValueError as e:
        source = "--publish" if _typed(ctx, param.name or "") else ENV_PUBLISH
        raise click.BadParameter(str(e), param_hint=source) from None


publish_option = click.option(
    "--publish",
    "publish_url",
    metavar="URL",
    envvar=ENV_PUBLISH,
    show_envvar=True,
    expose_value=False,
    callback=_remember_broker,
    help="Publish the final result (the --json object, with the cell, the profile's hash, "
    "ucal's version and the time) to an MQTT broker, mqtt://HOST[:PORT]/PREFIX, at QoS 1 on "
    "PREFIX/CELL/result and retained on PREFIX/CELL/state; a broker that is down leaves it "
    "queued in PROFILE.history/outbox/ for a later run (docs/fleet.md). Never changes the "
    "exit code.",
)


def publish_url(ctx: click.Context | None = None) -> BrokerUrl | None:
    """The ``--publish`` broker (or ``UCAL_PUBLISH``) of the current command, None if none."""
    ctx = ctx or click.get_current_context(silent=True)
    if ctx is None:
        return None
    value = ctx.meta.get("publish_url")
    return value if isinstance(value, BrokerUrl) else None


def pulser_option(f: F) -> F:
    """Decorator: ``--pulser URL`` and ``--digitizer URL``."""
    return _pulser_url_option(_digitizer_option(f))


def digitizer_from_options(ctx: click.Context | None = None) -> str | None:
    """The ``--digitizer`` URL (or ``UCAL_DIGITIZER``) of the current command, None if none."""
    ctx = ctx or click.get_current_context()
    value = ctx.meta.get("digitizer_url")
    return str(value) if value else None


_SOURCES = {
    "sim_world": ("--sim", ENV_SIM),
    "controller_url": ("--controller", ENV_CONTROLLER),
    "pulser_url": ("--pulser", ENV_PULSER),
    "digitizer_url": ("--digitizer", ENV_DIGITIZER),
}


def _typed(ctx: click.Context, name: str) -> bool:
    return ctx.get_parameter_source(name) == ParameterSource.COMMANDLINE


def _origin(ctx: click.Context, name: str) -> str:
    """How a cell option was given: its flag when typed, else its environment variable."""
    flag, env = _SOURCES[name]
    return flag if _typed(ctx, name) else env


def cell_options_typed(ctx: click.Context) -> list[str]:
    """The cell options typed on the command line (``--sim``, ``--controller``, ``--pulser``,
    ``--digitizer``)."""
    return [
        _SOURCES[n][0]
        for n in _SOURCES
        if (n in ctx.params or (n == "digitizer_url" and n in ctx.meta)) and _typed(ctx, n)
    ]


def cell_from_options(
    sim_world: str | None,
    controller_url: str | None,
    pulser_url: str | None,
    *,
    dry_run: bool = False,
) -> CellChoice:
    """Check a moving command's cell options before anything is planned or asked.

    Options typed on the command line win over the environment: a typed ``--sim`` (or
    ``--dry-run``) drops ``UCAL_CONTROLLER``/``UCAL_PULSER``, a typed ``--controller`` or
    ``--pulser`` drops ``UCAL_SIM``. Raises ``InputError`` (exit 2) naming what is missing,
    what cannot be combined, a malformed URL or a missing world file. Whether the run can ask
    before moving is checked after the files (``check_can_confirm``, from ``run_job``).
    """
    ctx = click.get_current_context()
    digitizer_url = digitizer_from_options(ctx)
    if _typed(ctx, "sim_world") or dry_run:
        controller_url = controller_url if _typed(ctx, "controller_url") else None
        pulser_url = pulser_url if _typed(ctx, "pulser_url") else None
        digitizer_url = digitizer_url if _typed(ctx, "digitizer_url") else None
    if _typed(ctx, "controller_url") or _typed(ctx, "pulser_url"):
        sim_world = sim_world if _typed(ctx, "sim_world") else None
    real = [
        _origin(ctx, n)
        for n, v in (
            ("controller_url", controller_url),
            ("pulser_url", pulser_url),
            ("digitizer_url", digitizer_url),
        )
        if v
    ]
    if dry_run and real and sim_world is None:
        raise InputError(
            f"--dry-run runs against the simulator: it cannot be combined with "
            f"{'/'.join(real)} (use --sim [WORLD], or drop --dry-run)"
        )
    if sim_world is not None and real:
        raise InputError(
            f"{_origin(ctx, 'sim_world')} cannot be combined with {'/'.join(real)}: give one cell"
        )
    if dry_run and sim_world is None:
        sim_world = ""  # --dry-run runs against the simulator
    if sim_world is None:
        _check_urls(ctx, controller_url, pulser_url, digitizer_url)
    elif sim_world and not Path(sim_world).is_file():
        raise InputError(f"{sim_world}: world file not found ({_origin(ctx, 'sim_world')})")
    return CellChoice(sim_world, controller_url, pulser_url, digitizer_url)


def check_can_confirm(cell: CellChoice, yes: bool) -> None:
    """Refuse (``InputError``, exit 2) a run that would have to ask before moving ``cell``
    with no terminal to ask on: called once the options and files are checked, before any
    plan."""
    if not yes and not sys.stdin.isatty():
        raise InputError(
            f"refusing to move {cell.name} without confirmation: stdin is not a "
            "terminal; pass --yes"
        )


def _check_urls(
    ctx: click.Context,
    controller_url: str | None,
    pulser_url: str | None,
    digitizer_url: str | None = None,
) -> None:
    """Both URLs given and well-formed (parsed by their back-ends; nothing is connected), and
    a digitiser where the pulser needs one and only there."""

    if not controller_url and not pulser_url:
        raise InputError(
            "no cell given: use --sim [WORLD] for the simulated cell, or "
            "--controller URL and --pulser URL (or set UCAL_SIM, or "
            "UCAL_CONTROLLER and UCAL_PULSER)"
        )
    for name, url, other, opener in (
        ("controller_url", controller_url, "pulser_url", open_controller),
        ("pulser_url", pulser_url, "controller_url", open_pulser),
    ):
        if not url:
            flag, env = _SOURCES[name]
            raise InputError(f"{_origin(ctx, other)} given without {flag} URL (or {env})")
        try:
            if opener is open_pulser and digitizer_url:
                opener(url, digitizer=digitizer_url)
            else:
                opener(url)
        except ValueError as e:
            raise InputError(f"{_origin(ctx, name)}: {e}") from None
        except TypeError as e:  # a back-end whose from_url takes no digitiser
            if opener is not open_pulser or "digitizer" not in str(e):
                raise
            raise InputError(
                f"{_origin(ctx, 'digitizer_url')} is for a pulser that does not digitise "
                f"(ascii://, manual://); {_origin(ctx, name)} {url} takes none"
            ) from None


def choice_option(flag: str, choices: list[str], text: str) -> Callable[[F], F]:
    """Decorator: ``flag`` taking one of ``choices``, the first by default (``--help`` says
    so); ``text`` is its help."""
    return click.option(
        flag, type=click.Choice(choices), default=choices[0], show_default=True, help=text
    )


def force_option(text: str) -> Callable[[F], F]:
    """Decorator: ``--force``, writing a result out of tolerance; ``text`` says what."""
    return click.option("--force", is_flag=True, help=text)


profile_argument = click.argument(
    "profile_path", metavar="PROFILE", type=click.Path(dir_okay=False, path_type=Path)
)
#: PROFILE of a command that only reads it: it must exist (click says so, exit 2).
existing_profile_argument = click.argument(
    "profile_path", metavar="PROFILE", type=click.Path(exists=True, dir_okay=False, path_type=Path)
)


def output_option(name: str, metavar: str, kind: click.Path, text: str) -> Callable[[F], F]:
    """Decorator: the required ``-o``/``--output`` a command writes, as its parameter
    ``name`` (``kind``: a file or a directory); ``text`` is its help."""
    return click.option(
        "-o", "--output", name, required=True, metavar=metavar, type=kind, help=text
    )


@dataclass(frozen=True)
class MovingCall:
    """What every command that moves the robot is called with besides its own options: the
    profile, the cell, the record, whether to ask, write and print JSON (``moving_options``)."""

    profile_path: Path
    sim_world: str | None
    controller_url: str | None
    pulser_url: str | None
    record_path: Path | None
    replay_path: Path | None
    remeasure: bool
    yes: bool
    dry_run: bool
    as_json: bool

    def cell(self) -> CellChoice:
        """The cell the options name, checked (``cell_from_options``)."""
        return cell_from_options(
            self.sim_world, self.controller_url, self.pulser_url, dry_run=self.dry_run
        )


def moving_options(*own: Callable[[F], F]) -> Callable[[Callable[..., None]], Callable[..., None]]:
    """Decorator: a moving command's PROFILE and the options every moving command takes around
    its ``own``, in the order ``--help`` lists them: ``--sim``, ``--controller``, ``--pulser``
    (and ``--digitizer``), the command's own, ``--record``, ``--replay``, ``--remeasure``,
    ``--yes``, ``--dry-run``, ``--publish``, ``--json``. The command is called with one
    ``MovingCall`` and its own options by name."""
    shared = [f.name for f in fields(MovingCall)]

    def decorate(f: Callable[..., None]) -> Callable[..., None]:
        @functools.wraps(f)
        def command(**kwargs: Any) -> None:
            call = MovingCall(**{name: kwargs.pop(name) for name in shared})
            f(call, **kwargs)

        options: list[Callable[[Any], Any]] = [
            profile_argument,
            sim_option,
            controller_option,
            pulser_option,
            *own,
            record_options,
            yes_option,
            dry_run_option,
            publish_option,
            json_option,
        ]
        for option in reversed(options):
            command = option(command)
        return command

    return decorate


def parse_floats(text: str, n: int, what: str) -> np.ndarray:
    """Parse ``"a,b,c"`` into n floats; ``click.BadParameter`` (exit 2) names the option."""
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        raise click.BadParameter(
            f"{what} must be {n} comma-separated numbers, got {text!r}"
        ) from None
    if len(values) != n or not np.all(np.isfinite(values)):
        raise click.BadParameter(f"{what} must be {n} finite comma-separated numbers, got {text!r}")
    return np.array(values)


def table_console() -> Console:
    """The console a command draws its tables on (stdout): as wide as the terminal, or, in a
    pipe or a file, wide enough that no cell is cut (rich's default there is 80 columns)."""
    return Console() if sys.stdout.isatty() else Console(width=PIPE_WIDTH)


def emit_json(obj: Any) -> None:
    """Print one JSON object on stdout (numpy values converted)."""
    click.echo(json.dumps(obj, default=_to_jsonable))


def _to_jsonable(o: Any) -> Any:
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, np.generic):
        return o.item()
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def ask_to_move(cell: CellChoice) -> None:
    """Ask on the terminal whether to move ``cell``; no terminal → refuse (exit 2), no (or the
    end of the input) → ``NotConfirmed`` (exit 4); Ctrl-C at the question stays an
    interruption (click's ``Abort``, exit 130)."""
    if not sys.stdin.isatty():
        raise InputError(
            f"refusing to move {cell.name} without confirmation: stdin is not a "
            "terminal; pass --yes"
        )
    try:
        confirmed = click.confirm(f"Move {cell.name} now?", default=False, err=True)
    except click.exceptions.Abort as e:
        if isinstance(e.__context__, KeyboardInterrupt):
            raise
        click.echo(err=True)  # end of input: no answer is no; end the prompt's line
        confirmed = False
    if not confirmed:
        raise NotConfirmed("not confirmed: nothing moved, nothing written")


def check_output(path: Path) -> None:
    """Refuse (``InputError``, exit 2, naming the file) an output whose directory is missing or
    not writable, before any computation."""
    directory = Path(path).parent
    if not directory.is_dir():
        raise InputError(f"{path}: cannot write: directory {directory} does not exist")
    if not os.access(directory, os.W_OK | os.X_OK):
        raise InputError(f"{path}: cannot write: directory {directory} is not writable")
