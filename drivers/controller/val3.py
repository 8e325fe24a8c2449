"""What the VAL3 server makes of the values a Simple Message client exchanges with it: the
velocity it runs a trajectory point at (``velocity_on_wire``), and the STATUS it streams, in
the interface's terms (``status_from_message``) and in words (``describe_status``).
"""

from __future__ import annotations

import math
import struct

from drivers.controller.base import ControllerStatus
from drivers.controller.simple_message import Status

#: Slowest velocity sent (fraction of maximum speed). The VAL3 server turns the wire velocity
#: into a percentage and rounds it to four decimals (``interpolateVel.pgx``): below 5e-7 that is
#: 0, which ``movej`` refuses, and below 1e-4 the rounding alone changes the speed by more than
#: 1 %. 1e-4 also keeps the slowest joint of a TX90 moving at 0.02 deg/s, which the halt
#: detection (``PROGRESS_DEG`` per ``halt_timeout_s``) sees as progress.
MIN_VELOCITY = 1e-4
#: The rounded percentage that the master server's "smooth last point in traj" rule replaces by
#: an extrapolation of the previous points' wire velocities (``interpolateVel.pgx``).
VAL3_SMOOTHING_PERCENT = 0.1
#: What is sent instead of a velocity that rounds to ``VAL3_SMOOTHING_PERCENT`` (0.101 %).
VAL3_SMOOTHING_DODGE = 0.00101


def val3_percent(velocity: float) -> float:
    """The percentage the VAL3 master server compares for a wire ``velocity``.

    ``pushMotion.pgx`` multiplies the float32 it received by 100; ``interpolateVel.pgx`` rounds
    the result to four decimals.
    """
    received = struct.unpack("<f", struct.pack("<f", velocity))[0]
    return float(math.floor(received * 100.0 * 10000.0 + 0.5) / 10000.0)


def velocity_on_wire(speed: float) -> float:
    """The velocity fraction to send for ``speed`` (fraction of maximum, (0, 1]).

    Raised to ``MIN_VELOCITY``, the slowest the server runs as asked. And the released VAL3
    server replaces a velocity whose rounded percentage is exactly 0.1 (wire 0.001, not 0.1)
    by ``2·v[0] − v[1]`` of the last two wire velocities it received ("smooth last point in
    traj", ``interpolateVel.pgx``): a fraction, not a percentage, so 100 times too slow or
    negative. Such a velocity is sent as 0.00101 (0.101 %).
    """
    velocity = max(float(speed), MIN_VELOCITY)
    if val3_percent(velocity) == VAL3_SMOOTHING_PERCENT:
        return VAL3_SMOOTHING_DODGE
    return velocity


def _tri(value: int) -> bool | None:
    """Map a REP-I0006 tri-state (-1 unknown, 0 off, 1 on) to ``None``/``False``/``True``."""
    return None if value < 0 else bool(value)


def status_from_message(msg: Status) -> ControllerStatus:
    """A STATUS message in the interface's terms (``mode`` 0 unless manual or auto)."""
    return ControllerStatus(
        drives_powered=_tri(msg.drives_powered),
        e_stopped=_tri(msg.e_stopped),
        in_motion=_tri(msg.in_motion),
        in_error=_tri(msg.in_error),
        error_code=msg.error_code,
        mode=msg.mode if msg.mode in (1, 2) else 0,
        motion_possible=_tri(msg.motion_possible),
    )


def describe_status(st: ControllerStatus) -> str:
    """A STATUS in words, for messages."""

    def tri(value: bool | None, yes: str, no: str) -> str:
        return "unknown" if value is None else yes if value else no

    return (
        f"{tri(st.in_motion, 'in motion', 'not in motion')}, drives "
        f"{tri(st.drives_powered, 'powered', 'off')}, e-stop "
        f"{tri(st.e_stopped, 'engaged', 'released')}, "
        f"{tri(st.in_error, f'in error (code {st.error_code})', 'no error')}, motion "
        f"{tri(st.motion_possible, 'possible', 'not possible')}"
    )
