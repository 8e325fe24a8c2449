"""The main lobe's height on one reflector, carried from water path to water path.

Every face of the block is the same reflector, so the heights of the main lobe found so far say
how high it must be at another face's water path; a centred peak far below that is a side lobe
(``ucal.measure.search``). How the height is carried, and what its fall with the path says of
the transducer, is ``MainLobe``'s.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

#: Water paths (mm) the main-lobe heights must span before their own fall with the path is
#: measured (``MainLobe.fall_np_per_mm``): over less, a dB of difference between two faces of
#: one block would read as a fall of several dB per 10 mm.
FALL_SPAN_MM = 20.0
#: A measured fall more than this factor off the profile's transducer's (either way) says the
#: transducer is not what ``[transducer]`` declares: the absorption of water grows with the
#: square of the frequency (15 MHz falls 0.36×, 40 MHz 2.6× as fast as 25 MHz).
FALL_MISMATCH = 1.8


@dataclass
class MainLobe:
    """Heights of the main lobe found so far on one reflector (the block's faces).

    ``peaks``: (amplitude at 0 dB gain, water path in mm) of each good peak fit. The echo of a
    flat reflector does not grow with the water path (absorption, and the diffraction loss of a
    piston's field integrated over the element, both fall monotonically), so each height counts
    as at least the largest found at a longer path: a side lobe or a poor fit found earlier
    cannot lower the expectation.

    The fall with the path is the water's absorption over the round trip, which grows with the
    square of the frequency, plus the diffraction loss. Before the heights span
    ``FALL_SPAN_MM`` of path it is taken as the absorption at the profile's frequency; then it
    is measured from the heights themselves, so that a transducer of another frequency than its
    profile says (a 15 MHz probe falls a third as fast as a 25 MHz one) does not make every
    face at another path look like a side lobe. The height expected at a path is carried from
    the heights nearest in path: the broadband echo loses its high frequencies first, so it
    falls fast at short paths and slowly at long ones, not as one exponential.
    """

    peaks: list[tuple[float, float]] = field(default_factory=list)
    noted: bool = False  # ``transducer_note`` already told the user

    def add(self, amplitude: float, path_mm: float) -> None:
        if amplitude > 0.0 and np.isfinite(path_mm):
            self.peaks.append((float(amplitude), float(path_mm)))

    def _envelope(self) -> tuple[np.ndarray, np.ndarray]:
        """The heights, each raised to the largest found at a longer path, and their paths."""
        heights, paths = np.array(self.peaks, float).T
        longest_first = np.argsort(-paths, kind="stable")
        raised = np.empty_like(heights)
        raised[longest_first] = np.maximum.accumulate(heights[longest_first])
        return raised, paths

    def fall_np_per_mm(self, absorption_np_per_mm: float) -> float:
        """How fast the main lobe falls with the water path (Np per mm of path): once the
        heights span ``FALL_SPAN_MM``, the median slope of their logarithms over the pairs at
        least half that far apart (Theil-Sen: one poor height cannot bend it); before, the
        round trip's absorption ``2·absorption_np_per_mm``."""
        if not self.peaks:
            return 2.0 * absorption_np_per_mm
        return _fall(*self._envelope(), absorption_np_per_mm)

    def expected(self, path_mm: float, absorption_np_per_mm: float) -> float | None:
        """Main-lobe amplitude (0 dB gain) expected at ``path_mm``, carried from the heights
        within ``FALL_SPAN_MM`` of the nearest one in path; None before the first."""
        if not self.peaks:
            return None
        heights, paths = self._envelope()
        fall = _fall(heights, paths, absorption_np_per_mm)
        away = np.abs(path_mm - paths)
        near = away <= away.min() + FALL_SPAN_MM
        return float(np.max(heights[near] * np.exp(-fall * (path_mm - paths[near]))))

    def transducer_note(self, absorption_np_per_mm: float) -> str | None:
        """A sentence when the measured fall is more than ``FALL_MISMATCH`` times off the one
        the profile's transducer gives: the transducer is not what ``[transducer]`` says."""
        nominal = 2.0 * absorption_np_per_mm
        fall = self.fall_np_per_mm(absorption_np_per_mm)
        if nominal <= 0.0 or 1 / FALL_MISMATCH <= fall / nominal <= FALL_MISMATCH:
            return None
        per_10mm = 10.0 * 20.0 / np.log(10.0)  # Np per mm → dB per 10 mm
        return (
            f"the block's echoes fall by {fall * per_10mm:.1f} dB per 10 mm of water path, where "
            f"the water's absorption at the profile's transducer frequency gives "
            f"{nominal * per_10mm:.1f}: the transducer is not what [transducer] frequency_mhz "
            "and element_diameter_mm say (absorption grows with the frequency squared)"
        )

    def typical_path_mm(self) -> float:
        return float(np.median([p for _, p in self.peaks]))


def _fall(heights: np.ndarray, paths: np.ndarray, absorption_np_per_mm: float) -> float:
    """``MainLobe.fall_np_per_mm`` of the envelope's heights at their paths."""
    if np.ptp(paths) >= FALL_SPAN_MM:
        i, j = np.triu_indices(len(paths), 1)
        apart = np.abs(paths[j] - paths[i]) >= 0.5 * FALL_SPAN_MM
        if np.any(apart):
            drop = np.log(heights[i] / heights[j])[apart] / (paths[j] - paths[i])[apart]
            return float(np.median(drop))
    return 2.0 * absorption_np_per_mm
