"""The main lobe's height carried from one water path to another (``MainLobe``): measured from
the heights found, not assumed from the profile's transducer, so a transducer of another
frequency is said to be one, and its faces are not taken for side lobes."""

from __future__ import annotations

import numpy as np
import pytest

from ucal.acoustics import water_absorption_np_per_mm
from ucal.cell import CellProfile, WorldTruth
from ucal.measure.lobe import MainLobe
from ucal.measure.search import SIDE_LOBE_MARGIN_DB
from ucal.profile.models import load_model
from ucal.sim.cell import SimulatedCell

#: The water paths (mm) of the demo calibration's faces, in the order it measures them.
PATHS_MM = (100.0, 100.0, 132.0, 130.8, 152.9, 97.8, 100.0, 42.3, 171.6)
#: The absorption the 25 MHz profile's transducer gives (one way, Np per mm).
PROFILE_ABSORPTION = water_absorption_np_per_mm(25.0)


def heights(frequency_mhz: float) -> list[tuple[float, float]]:
    """The simulated cell's noise-free main-lobe heights at normal incidence on ``PATHS_MM``
    for a transducer of ``frequency_mhz`` (the broadband echo of the simulator's receiver)."""
    world = WorldTruth.nominal(CellProfile(model=load_model("tx90l")))
    cell = SimulatedCell(world.replace(frequency_mhz=frequency_mhz))
    return [(cell._peak(0.0, path, 1482.4), path) for path in PATHS_MM]


def db_off(expected: float | None, true: float) -> float:
    assert expected is not None
    return float(20 * np.log10(expected / true))


@pytest.mark.parametrize("frequency_mhz", [15.0, 25.0, 40.0])
def test_each_face_is_expected_near_its_main_lobe_whatever_the_transducer(
    frequency_mhz: float,
) -> None:
    """Each face judged by the heights measured before it: never expected so far above its
    main lobe that the main lobe would read as a side lobe (an echo stronger than expected is
    never one: below its path range the 40 MHz probe's is 15 dB stronger than carried)."""
    peaks = heights(frequency_mhz)
    for k in range(2, len(peaks)):
        lobe = MainLobe(list(peaks[:k]))
        true, path = peaks[k]
        off = db_off(lobe.expected(path, PROFILE_ABSORPTION), true)
        assert off < SIDE_LOBE_MARGIN_DB / 2, (k, path, off)


def test_the_profiles_absorption_alone_took_a_15_mhz_face_for_a_side_lobe() -> None:
    """What the measured fall mends: carried by the 25 MHz absorption from the faces before
    it, the 15 MHz probe's 42 mm face is expected far above its main lobe."""
    peaks = heights(15.0)
    true, path = peaks[7]
    carried = max(a * np.exp(-2 * PROFILE_ABSORPTION * (path - p)) for a, p in peaks[:7])
    assert db_off(carried, true) > SIDE_LOBE_MARGIN_DB


def test_a_transducer_off_its_profile_is_named_from_the_fall() -> None:
    slow = MainLobe(heights(15.0))
    note = slow.transducer_note(PROFILE_ABSORPTION)
    assert note is not None and "[transducer] frequency_mhz" in note
    # water absorbs as the frequency squared: 15 MHz falls about (15/25)² as fast
    ratio = slow.fall_np_per_mm(PROFILE_ABSORPTION) / (2 * PROFILE_ABSORPTION)
    assert ratio == pytest.approx((15 / 25) ** 2, rel=0.3)
    assert MainLobe(heights(25.0)).transducer_note(PROFILE_ABSORPTION) is None


def test_the_fall_is_measured_only_over_a_span_of_paths() -> None:
    near = MainLobe([(0.01, 100.0), (0.002, 110.0)])  # a 14 dB step over 10 mm: two faces
    assert near.fall_np_per_mm(PROFILE_ABSORPTION) == 2 * PROFILE_ABSORPTION
    assert near.transducer_note(PROFILE_ABSORPTION) is None
    # one poor height among several cannot bend the fall (the median of the pairs' slopes)
    fall = 0.02
    good = [(np.exp(-fall * p), p) for p in (60.0, 90.0, 120.0, 150.0)]
    lobe = MainLobe([*good, (1e-3 * np.exp(-fall * 100.0), 100.0)])
    assert lobe.fall_np_per_mm(PROFILE_ABSORPTION) == pytest.approx(fall, rel=0.05)
