"""Finding an echo from scratch: the noise floor, the acquisition gain and the raster.

Every procedure that searches an echo starts the same way: the beam is turned into open water
(``open_water``: 25° off the first posture on a wrist joint that tilts it, the other way where
that leaves the joint's range — a clipped turn would bring the beam back towards the
reflector), the empty gate's noise floor is read there, and the acquisition gain puts that
floor at a fixed share of full screen (``acquisition_gain``). Then, where the prediction shows
no echo, a raster of lines outward from it until one crosses the echo (``acquire_and_centre``).

How far apart the lines are and the floor the gain aims at belong together, and depend on the
reflector (``Raster``): a line must cross the echo's skirt above the threshold (four floors),
so the farther apart the lines, the further off normal the skirt must show, the more gain.
The block's faces are rastered with lines 2.5° apart at a floor of 2.5 % of full screen
(threshold 10 %: the side lobes of a normal echo show a degree or more around normal); the
plate with lines 1.5° apart at 5 % (threshold 20 %: half as much gain, the main lobe's skirt
within 0.75° of normal above it). The two floors are the one rule at two line spacings.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ucal.devices.rig import Rig
from ucal.errors import HardwareError
from ucal.measure.search import PeakSearch

#: Turn of a wrist joint (deg) that puts the beam in open water for the noise floor: far
#: outside every lobe that matters (the first null is 0.35° off normal).
OPEN_WATER_TURN_DEG = 25.0
#: First radius (deg of beam tilt) of the main-lobe raster (``PeakSearch.seek_main_lobe``),
#: doubled up to the raster's largest: its lines are 0.5° apart.
MAIN_LOBE_RADIUS_DEG = 4.0


def _no_face_echo(rig: Rig, label: str, reached_deg: float, moves: int) -> HardwareError:
    config, _, face = label.rpartition("/")  # "j3/XY", or the full level's "face XY (p7)"
    where = face if face.startswith("face ") else f"face {face}"
    where += f" ({config})" if config else ""
    return HardwareError(
        f"pulser at {rig.pulser.endpoint}: no echo from {where} within "
        f"±{reached_deg:g}° of the predicted posture ({moves} moves): is the block "
        "where [sample] says?"
    )


def _no_plate_echo(rig: Rig, label: str, reached_deg: float, moves: int) -> HardwareError:
    return HardwareError(
        f"{rig.pulser.endpoint}: no echo from the reflector plate within {reached_deg:g} deg "
        f"of the predicted posture ({label}); check [reflector] points_mm and [tool] in the "
        "profile"
    )


@dataclass(frozen=True)
class Raster:
    """How the echo of one kind of reflector is acquired (module docstring).

    ``line_spacings_deg``: the raster's line spacings (deg of beam tilt), tried in turn;
    ``floor_fsh``: the share of full screen the acquisition gain puts the noise floor at (the
    threshold is four floors), set by the widest spacing; ``max_radius_deg``: the largest beam
    tilt from the prediction the raster reaches, its radius doubling up to it;
    ``max_moves``: the moves one acquisition may use before it gives up (None: no bound);
    ``no_echo(rig, label, radius reached, moves)``: the error naming what was not found.
    """

    line_spacings_deg: tuple[float, ...]
    floor_fsh: float
    max_radius_deg: float
    max_moves: int | None
    no_echo: Callable[[Rig, str, float, int], HardwareError]


#: The block's faces: 2.5° lines at acquisition gain, then 0.5° where a long water path leaves
#: little more than the main lobe above the noise; up to 20° from the prediction and 100 moves
#: (the coarse raster and a fine one about ±6°: a block where the profile says is found within
#: a few lines; without the bound a missing echo kept the robot sweeping for hundreds of moves).
BLOCK_FACES = Raster((2.5, 0.5), 0.025, 20.0, 100, _no_face_echo)
#: The tool-frame plate, met at the planned water path: 1.5° lines up to 8° (the profile's
#: tool and plate are known to a fraction of that).
PLATE = Raster((1.5,), 0.05, 8.0, None, _no_plate_echo)


def open_water(
    q_deg: np.ndarray, joint: int, joint_min_deg: np.ndarray, joint_max_deg: np.ndarray
) -> np.ndarray:
    """``q_deg`` with wrist joint ``joint`` turned ``OPEN_WATER_TURN_DEG`` up, or down where up
    leaves the joint's range: the beam in open water, for the noise floor."""
    away = np.array(q_deg, float)
    turn = OPEN_WATER_TURN_DEG
    away[joint] += turn if away[joint] + turn < joint_max_deg[joint] else -turn
    return np.asarray(np.clip(away, joint_min_deg, joint_max_deg))


def acquisition_gain(
    rig: Rig, q_away: np.ndarray, floor_fsh: float = BLOCK_FACES.floor_fsh
) -> float:
    """Measure the noise floor with the beam in open water at ``q_away``; return the gain (dB)
    that puts the floor at ``floor_fsh`` of full screen (``Raster.floor_fsh``).

    The move there is the rig's own: the floor is read in open water, where no posture is
    measured and lost motion does not matter."""
    rig.configure(gain_db=20.0, averages=1)
    rig.move(rig.clip(q_away))
    rig.measure_floor()
    assert rig.floor_per_gain is not None
    return float(np.clip(20 * np.log10(floor_fsh / rig.floor_per_gain), 20.0, 80.0))


def noise_floor(rig: Rig, q_deg: np.ndarray, joint: int, raster: Raster) -> float:
    """The acquisition gain (dB) for ``raster`` from the noise floor read with the beam in open
    water off ``q_deg`` (``open_water`` on ``joint``)."""
    away = open_water(q_deg, joint, rig.joint_min_deg, rig.joint_max_deg)
    return acquisition_gain(rig, away, raster.floor_fsh)


def side_lobe_error(
    search: PeakSearch,
    label: str,
    below_db: float,
    moves: int,
    reached_deg: float | None = None,
) -> HardwareError:
    """The search found only a side lobe (``PeakSearch.side_lobe_db``) on the face of ``label``;
    where the faces' heights say the transducer is not the profile's, the error says that."""
    within = "" if reached_deg is None else f" within ±{reached_deg:g}° of the predicted posture"
    note = search.transducer_note()
    return HardwareError(
        f"pulser at {search.rig.pulser.endpoint}: {label}: the peak found{within} is "
        f"{below_db:.0f} dB below the main lobe that the faces measured so far give at its water "
        "path: "
        + (
            f"a side lobe, and no main lobe found ({moves} moves)"
            if note is None
            else f"{note} ({moves} moves)"
        )
    )


def acquire_and_centre(
    search: PeakSearch,
    rig: Rig,
    q_pred: np.ndarray,
    label: str,
    radius_deg: float,
    gain_db: float,
    raster: Raster = BLOCK_FACES,
) -> np.ndarray:
    """Raster outward from the prediction, then centre on the main lobe.

    Once the search has a main-lobe height to expect (``PeakSearch.main_lobe``), a raster
    where only the main lobe shows comes first (``PeakSearch.seek_main_lobe``, radius from
    ``MAIN_LOBE_RADIUS_DEG`` doubling to the raster's largest, half of its moves). Otherwise,
    or if it finds nothing, for each of ``raster``'s line spacings in turn the radius widens
    from ``radius_deg`` up to the largest. After the raster's moves without an echo it gives up
    with its ``no_echo`` error (exit 3): for a face it names the pulser and the face — the block
    is not where ``[sample]`` says, or the beam does not reach it (water, transducer, gate). A
    centred peak that is a side lobe, with no main lobe found, is a ``HardwareError`` naming the
    face too. The lines are swept both ways in turn (``PeakSearch.acquire``): they find the
    echo, the static probes of the fit measure it.
    """
    max_moves, max_radius_deg = raster.max_moves, raster.max_radius_deg
    first_move = rig.counters.moves
    reached = 0.0
    if search.main_lobe is not None and search.main_lobe.peaks:
        r = min(MAIN_LOBE_RADIUS_DEG, max_radius_deg)
        budget = None if max_moves is None else max_moves // 2  # the rest: the usual raster
        while True:
            left = None if budget is None else budget - (rig.counters.moves - first_move)
            if left is not None and left <= 0:
                break
            q = search.seek_main_lobe(q_pred, r, left)
            if q is not None:
                below = search.side_lobe_db()
                if below is None:
                    return q
                raise side_lobe_error(search, label, below, rig.counters.moves - first_move, r)
            reached = max(reached, r)
            if r >= max_radius_deg:
                break
            r = min(2 * r, max_radius_deg)
    for spacing in raster.line_spacings_deg:
        r = min(radius_deg, max_radius_deg)
        while True:
            left = None if max_moves is None else max_moves - (rig.counters.moves - first_move)
            if left is not None and left <= 0:
                break
            found = search.acquire(q_pred, r, gain_db, spacing_tilt_deg=spacing, max_moves=left)
            if found is not None:
                q = search.centre(found[0], 3.0, gain_db)
                below = search.side_lobe_db()
                if below is not None:
                    raise side_lobe_error(search, label, below, rig.counters.moves - first_move, r)
                return q
            reached = max(reached, r)
            if r >= max_radius_deg:
                break
            r = min(2 * r, max_radius_deg)
    raise raster.no_echo(rig, label, reached, rig.counters.moves - first_move)
