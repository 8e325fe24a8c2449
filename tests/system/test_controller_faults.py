"""Fault matrix: ``ucal calibrate`` against the VAL3-faithful simulated cell, one fault a case.

Every case runs the whole command (in this process, on 127.0.0.1) against the simulated cell
behaving as the released VAL3 server, injects one controller fault, and checks what SPEC.md
promises: the exit code, a one-line message naming the controller, STOP on the wire wherever
a motion connection was served, and the profile byte for byte as it was. The profile's
``[controller]`` timeouts are short so that a case takes a fraction of a second; the server's
start-up silence is shortened the same way except where the silence is the fault. The plan of
the one profile is computed once for the module (the cases differ in the fault, not the plan).
"""

from __future__ import annotations

import functools
import re
import socket
import struct
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from drivers.controller.simple_message import CommType, OtherMessage, ReplyCode
from ucal.cli import main
from ucal.profile import create_profile, load_profile, write_profile
from ucal.sim.demo import demo_world
from ucal.sim.serve import SimulatedCellServer

pytestmark = pytest.mark.system

TIMEOUTS = {
    "connect_timeout_s": 1.0,
    "first_state_timeout_s": 0.6,
    "state_timeout_s": 0.5,
    "reply_timeout_s": 0.3,
    "halt_timeout_s": 0.3,
    "settle_timeout_s": 10.0,
}


@pytest.fixture(scope="module")
def profile(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Path]:
    path = tmp_path_factory.mktemp("faults") / "cell.toml"
    create_profile(path, "tx90l")
    write_profile(path, {"controller": TIMEOUTS}, "short timeouts for the fault matrix")
    from ucal.calibration import procedure

    real = procedure.plan_calibration
    plan = functools.cache(lambda: real(load_profile(path)))
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(procedure, "plan_calibration", lambda p: plan() if p.path == path else real(p))
        yield path


def at_point(n: int, act: Callable[[SimulatedCellServer], None]):
    """A fault that strikes as the controller receives its ``n``-th point."""

    def arm(cell: SimulatedCellServer) -> None:
        cell.controller.on_point = lambda count: act(cell) if count == n else None

    return arm


def other_clients(cell: SimulatedCellServer) -> None:
    """Another client holds both ports (served until the case ends)."""
    ctl = cell.controller
    cell.held = [
        socket.create_connection(("127.0.0.1", port)) for port in (ctl.motion_port, ctl.state_port)
    ]
    deadline = time.monotonic() + 2.0
    while not (ctl._motion_clients and ctl._state_clients) and time.monotonic() < deadline:
        time.sleep(0.005)


GARBAGE = b"\x00garbage bytes that are not a frame at all"
LONG = struct.pack("<4i", 0x7FFFFFFF, 11, 3, 1)
UNKNOWN = OtherMessage(77, CommType.SERVICE_REPLY, ReplyCode.SUCCESS, b"????").pack()

# id, fault, start-up silence (s), exit code, message, STOP expected on the wire
CASES = [
    (
        "e-stop",
        at_point(2, lambda c: c.controller.set_fault(e_stopped=True)),
        0.05,
        3,
        r"controller stopped the motion .* e-stop engaged",
        True,
    ),
    (
        "drives off",
        at_point(2, lambda c: c.controller.set_fault(drives_powered=False)),
        0.05,
        3,
        r"controller stopped the motion .* drives off",
        True,
    ),
    (
        "halt",
        at_point(2, lambda c: c.controller.hold(in_motion=False)),
        0.05,
        3,
        r"controller halted the motion .* it reports not in motion",
        True,
    ),
    (
        "held in motion",
        at_point(2, lambda c: c.controller.hold(in_motion=True)),
        0.05,
        3,
        r"controller halted the motion .* it reports in motion",
        True,
    ),
    (
        "garbage reply",
        at_point(2, lambda c: c.controller.inject_reply(GARBAGE)),
        0.05,
        3,
        r"length field",
        True,
    ),
    (
        "length 0x7fffffff",
        at_point(2, lambda c: c.controller.inject_reply(LONG)),
        0.05,
        3,
        r"length field 2147483647",
        True,
    ),
    (
        "unknown reply type",
        at_point(2, lambda c: c.controller.inject_reply(UNKNOWN)),
        0.05,
        3,
        r"reply timeout ran out \(reply_timeout_s = 0.3 s\): no reply to trajectory point 1",
        True,
    ),
    (
        "garbage on the state port",
        at_point(2, lambda c: c.controller.inject_state(GARBAGE)),
        0.05,
        3,
        r"length field",
        True,
    ),
    (
        "VAL3 silence beyond the first-state timeout",
        lambda c: None,
        1.0,
        3,
        r"first-state timeout ran out \(first_state_timeout_s = 0.6 s\)",
        True,
    ),
    ("second client", other_clients, 0.05, 3, r"one client per port", False),
    (
        "killed",
        at_point(2, lambda c: threading.Thread(target=c.controller.kill).start()),
        0.05,
        3,
        r"connection|reply timeout",
        False,
    ),
    (
        "e-stop before the first motion",
        lambda c: c.controller.set_fault(e_stopped=True),
        0.05,
        4,
        r"emergency stop is engaged",
        True,
    ),
]


@pytest.mark.parametrize(
    "case, fault, silence_s, code, message, stop", CASES, ids=[c[0] for c in CASES]
)
def test_fault_gives_its_exit_code_a_one_line_message_stop_and_an_untouched_profile(
    profile: Path,
    capsys: pytest.CaptureFixture[str],
    case: str,
    fault: Callable[[SimulatedCellServer], None],
    silence_s: float,
    code: int,
    message: str,
    stop: bool,
) -> None:
    before = profile.read_bytes()
    prof = load_profile(profile)
    world = demo_world(prof).replace(controller_silence_s=silence_s)
    with SimulatedCellServer(world, prof, time_scale=0.0, server="val3") as cell:
        cell.held = []
        fault(cell)
        urls = cell.urls
        try:
            main(
                [
                    "calibrate",
                    str(profile),
                    "--controller",
                    urls["controller"],
                    "--pulser",
                    urls["pulser"],
                    "--yes",
                ]
            )
            exit_code = 0
        except SystemExit as e:
            exit_code = e.code
        err = capsys.readouterr().err
        deadline = time.monotonic() + 2.0  # a STOP sent without waiting for its reply
        while stop and cell.controller.stops_received == 0 and time.monotonic() < deadline:
            time.sleep(0.01)
        stops = cell.controller.stops_received
        for sock in cell.held:
            sock.close()
    assert exit_code == code, err
    errors = [line for line in err.splitlines() if line.startswith("error: ")]
    assert len(errors) == 1, err
    assert errors[0].startswith(f"error: controller at {urls['controller']}: "), err
    assert re.search(message, errors[0]), errors[0]
    assert "Traceback" not in err
    assert (stops >= 1) == stop, f"{stops} STOP received"
    assert profile.read_bytes() == before
    assert not (profile.parent / "cell.toml.history" / "0002-before.toml").exists()


def test_the_val3_silence_costs_simulated_time_in_process(tmp_path: Path) -> None:
    """``--sim`` with a VAL3 world: the server's 1 s of silence passes on the simulated clock,
    and the profile's ``[controller]`` timeouts reach the driver and the rig."""
    from ucal.devices.session import open_cell

    path = tmp_path / "cell.toml"
    create_profile(path, "tx90l")
    write_profile(
        path,
        {
            "controller": {
                "first_state_timeout_s": 3.0,
                "halt_timeout_s": 0.8,
                "settle_timeout_s": 20.0,
            }
        },
        "test",
    )
    world = tmp_path / "world.toml"
    world.write_text('[controller]\nserver = "val3"\n')
    with open_cell(load_profile(path), str(world), None, None) as cell:
        cell.rig.controller.status()
        assert 1.0 <= cell.elapsed_s <= 1.2
        assert (
            cell.rig.controller.first_state_timeout_s,
            cell.rig.controller.halt_timeout_s,
            cell.rig.move_timeout_s,
        ) == (3.0, 0.8, 20.0)
