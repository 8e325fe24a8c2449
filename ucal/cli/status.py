"""``ucal status``: connect, read joints, controller status and pulser identity; move nothing."""

from __future__ import annotations

import dataclasses
import logging
from pathlib import Path
from typing import Any

import click
from rich.table import Table

from drivers.errors import DriverError
from drivers.pulser.manual import SCHEME as MANUAL
from drivers.registry import open_controller, open_pulser
from ucal.cell import CellProfile
from ucal.cli.options import (
    controller_option,
    digitizer_from_options,
    emit_json,
    file_option,
    json_option,
    pulser_option,
    table_console,
)
from ucal.devices.session import by_hand_options
from ucal.errors import HardwareError, InputError
from ucal.profile import load_profile

log = logging.getLogger(__name__)

#: REP-I0006 RobotMode values of ``ControllerStatus.mode``.
MODES = {0: "unknown", 1: "manual", 2: "auto"}
#: Known Simple Message servers by what their state port streams: (joint message, rate (Hz),
#: joint frames per STATUS) → name (``docs/protocols/simple_message.md``).
SERVERS = {
    ("JOINT_POSITION", 50.0, 5): "VAL3 ros_server, released (staubli_val3_driver master)",
    ("JOINT_FEEDBACK", 250.0, 20): "VAL3 ros_server of staubli_val3_driver pull request #36",
}


def server_name(stream: dict[str, Any]) -> str:
    """The known server whose stream this is (rate within 20 %), or "unknown"."""
    for (message, rate_hz, every), name in SERVERS.items():
        if (
            stream["joint_message"] == message
            and stream["status_every"] == every
            and abs(stream["joint_rate_hz"] - rate_hz) <= 0.2 * rate_hz
        ):
            return name
    return "unknown"


@click.command(
    "status",
    epilog="""\b
Examples:
  ucal status --controller tcp://192.168.0.254:11000
  ucal status --controller tcp://192.168.0.254:11000 --pulser modbus-tcp://192.168.0.20:502 --json
  UCAL_CONTROLLER=tcp://192.168.0.254:11000 ucal status
""",
)
@controller_option
@pulser_option
@file_option(
    "--profile",
    "profile_path",
    "The cell's profile, for a pulser set by hand (--pulser manual://): its [pulser] declares "
    "the front panel, shown with what the digitiser's records say of it.",
)
@json_option
def cli(
    controller_url: str | None, pulser_url: str | None, profile_path: Path | None, as_json: bool
) -> None:
    """Show the joint readings, the controller's status and the pulser's identity.

    Also what the controller's state port streams (joint message, rate, STATUS cadence, how
    long the first message took) and which known server that is: the released VAL3 server
    streams JOINT_POSITION at 50 Hz with a STATUS every 5th, its pull request #36
    JOINT_FEEDBACK at 250 Hz with a STATUS every 20th; both wait 1 s before the first.

    Connects, reads and disconnects: nothing moves and no command is sent to the robot (not even
    STOP). Joint readings in degrees as the controller reports them. Exit 0 when every device given
    answered (the pulser is optional), whatever state it reports (drives off, e-stop and errors are
    shown, not treated as failures), 2 for a missing or malformed URL, 3 when a device cannot be
    reached or answers wrongly (the message names it).
    """
    profile = None if profile_path is None else load_profile(profile_path)
    out = read_status(controller_url, pulser_url, digitizer_from_options(), profile)
    if as_json:
        emit_json(out)
    else:
        show(out)


def read_status(
    controller_url: str | None,
    pulser_url: str | None,
    digitizer_url: str | None = None,
    profile: CellProfile | None = None,
) -> dict[str, Any]:
    """Read both devices; return ``{"joints_deg", "controller", "pulser"}`` (SPEC.md); a
    pulser that does not digitise is read with its digitiser (``digitizer_url``), one set by
    hand (``manual://``) with the front panel ``profile`` declares and what the records say of
    it (``by_hand``).

    Raises ``InputError`` (exit 2) for a missing or malformed URL and ``HardwareError``
    (exit 3, naming the device) for a device that cannot be reached or answers wrongly.
    """

    if not controller_url:
        raise InputError("give --controller URL (or set UCAL_CONTROLLER)")
    options: dict[str, Any] = {"digitizer": digitizer_url} if digitizer_url else {}
    manual = pulser_url is not None and pulser_url.split("://", 1)[0].strip().lower() == MANUAL
    if manual:
        assert pulser_url is not None
        if profile is None:
            raise InputError(
                f"--pulser {pulser_url}: a pulser set by hand: give --profile PROFILE, whose "
                '[pulser] (kind = "manual", gain_db, ...) declares its front panel'
            )
        options.update(by_hand_options(profile, pulser_url))
    try:
        controller = open_controller(controller_url)
        pulser = open_pulser(pulser_url, **options) if pulser_url else None
    except ValueError as e:
        raise InputError(str(e)) from None
    except TypeError as e:  # a back-end whose from_url takes no digitiser
        if "digitizer" not in str(e):
            raise
        raise InputError(
            f"--digitizer {digitizer_url}: the pulser at {pulser_url} digitises itself; a "
            "digitiser is for pulsers that do not (ascii://, manual://)"
        ) from None
    joints_deg, ctrl = _guarded("controller", controller_url, _read_controller, controller)
    pulse = None
    if pulser is not None:
        read = _read_pulser if not manual else lambda p: by_hand(p, profile)
        pulse = _guarded("pulser", pulser_url, read, pulser)
    return {"joints_deg": joints_deg, "controller": ctrl, "pulser": pulse}


def by_hand(pulser: Any, profile: Any) -> dict[str, Any]:
    """A pulser set by hand: ``"set_by_hand": true``, its declared settings, the digitiser's
    identity, and ``"check"``, what a few records at the declared gain say of the declaration
    (``ucal.echo.by_hand``; ``"verdict"``: ``"ok"`` or the message a moving command would
    refuse with)."""
    from ucal.devices.rig import DEFAULT_SETTINGS
    from ucal.echo.by_hand import judge, look, records_at_the_panel
    from ucal.errors import ProfileError
    from ucal.profile.by_hand import declared_of

    declared = declared_of(profile, pulser.full_screen_v)
    with pulser:
        out: dict[str, Any] = {"endpoint": pulser.endpoint, **pulser.identity()}
        records, gate_ns = records_at_the_panel(pulser, declared, DEFAULT_SETTINGS)
        out["settings"] = dataclasses.asdict(pulser.settings())
    found = look(records, declared, gate_ns)
    try:
        judge(found, declared)
        verdict = "ok"
    except ProfileError as e:
        verdict = str(e)
    out["check"] = {**found.as_json(), "verdict": verdict}
    return out


def _guarded(device: str, url: str | None, read: Any, arg: Any) -> Any:
    """``read(arg)`` with every fault turned into a ``HardwareError`` naming the device."""

    try:
        return read(arg)
    except DriverError as e:
        raise HardwareError(str(e)) from None
    except (OSError, ValueError) as e:  # an answer that does not decode
        raise HardwareError(f"{device} at {url}: {e}") from None


def _read_controller(controller: Any) -> tuple[list[float], dict[str, Any]]:
    """Joint readings (deg), status and what the state port streams (when the back-end says);
    the connection is closed without sending anything."""
    controller.connect()
    stream = None
    try:
        joints = [float(v) for v in controller.read_joints()]
        st = controller.status()
        stream_info = getattr(controller, "stream_info", None)
        if callable(stream_info):
            stream = stream_info()
            stream["server"] = server_name(stream)
    finally:
        controller.close()  # not the context manager's exit: that sends STOP
    out = {
        "endpoint": controller.endpoint,
        "drives_powered": st.drives_powered,
        "e_stopped": st.e_stopped,
        "in_motion": st.in_motion,
        "in_error": st.in_error,
        "error_code": int(st.error_code),
        "mode": MODES.get(int(st.mode), f"unknown ({st.mode})"),
        "motion_possible": st.motion_possible,
    }
    if stream is not None:
        out["stream"] = stream
    return joints, out


def _read_pulser(pulser: Any) -> dict[str, Any]:
    """Identity (what the back-end exposes), settings and gate threshold."""
    with pulser:
        out: dict[str, Any] = {"endpoint": pulser.endpoint, **pulser.identity()}
        out["settings"] = dataclasses.asdict(pulser.settings())
        threshold = getattr(pulser, "gate_threshold", None)
        if callable(threshold):
            out["gate_threshold"] = float(threshold())
    return out


def _shown(key: str, value: Any) -> str:
    """One cell of the pulser's table: a set by hand pulser's declaration, digitiser and check
    on a line each, anything else as it is."""
    if not isinstance(value, dict):
        return str(value)
    if key == "declared":
        skip = ("gate_start_us", "gate_width_us", "averages")
        return ", ".join(f"{k} {v:g}" for k, v in value.items() if k not in skip)
    if key == "digitizer" and "model" in value:
        return f"{value.get('manufacturer', '')} {value['model']} at {value['endpoint']}".strip()
    if key == "check":
        gain = value["gain_db_measured"]
        said = "not resolved" if gain is None else f"{gain:.1f} dB"
        return (
            f"{value['verdict']} (noise {value['noise_fsh']:.3g} of full screen, step "
            f"{value['lsb_fsh']:.3g}: gain {said}; echo "
            f"{'none' if value['echo'] is None else value['echo']['centre_frequency_mhz']}"
            f"{'' if value['echo'] is None else ' MHz'})"
        )
    return str(value)


def _flag(value: bool | None, yes: str, no: str) -> str:
    return "unknown" if value is None else yes if value else no


def show(out: dict[str, Any]) -> None:
    """The status as tables on stdout."""

    console = table_console()
    c = out["controller"]
    table = Table(title=f"controller {c['endpoint']}", show_header=False)
    table.add_column("what")
    table.add_column("value")
    table.add_row("J1..J6 (deg)", " ".join(f"{v:+.4f}" for v in out["joints_deg"]))
    table.add_row("drives", _flag(c["drives_powered"], "powered", "off"))
    table.add_row("emergency stop", _flag(c["e_stopped"], "ENGAGED", "released"))
    table.add_row("motion", _flag(c["in_motion"], "moving", "at rest"))
    table.add_row("error", _flag(c["in_error"], f"IN ERROR (code {c['error_code']})", "none"))
    table.add_row("mode", c["mode"])
    if "stream" in c:
        s = c["stream"]
        table.add_row(
            "state stream",
            f"{s['joint_message']} at {s['joint_rate_hz']:g} Hz, "
            f"STATUS every {s['status_every']}, first after "
            f"{s['first_state_s']:.2f} s",
        )
        table.add_row("server", s["server"])
    console.print(table)
    p = out["pulser"]
    if p is None:
        console.print("pulser: not given (--pulser URL or UCAL_PULSER)")
        return
    title = f"pulser {p['endpoint']}" + (" (set by hand)" if p.get("set_by_hand") else "")
    table = Table(title=title, show_header=False)
    table.add_column("what")
    table.add_column("value")
    for key, value in p.items():
        if key in ("endpoint", "settings", "set_by_hand"):
            continue
        table.add_row(key.replace("_", " "), _shown(key, value))
    for key, value in p["settings"].items():
        table.add_row(key, f"{value:g}" if isinstance(value, float) else str(value))
    console.print(table)
