"""The arm's growth (warm-up) as a suspect of the check: every link's d and a longer by one
factor ``1 + g`` (g in ppm, ``GROWTH``), the twists, the tool and the block as they were.

What a check's postures see of it. The flange's position is homogeneous of degree one in the DH
lengths (every translation of the chain is a d or an a, every rotation a joint angle or a
twist), so a uniform growth moves the flange from ``p`` to ``(1 + g)·p`` about the base origin
and turns nothing: the beam's direction, which the tilt rows see, is unchanged; the tool
centre moves by ``g·p`` (p: the flange's position in the base frame, about 0.7–1 m on a check's
postures), and each water path to a face of normal ``n`` shortens by ``g·n·p``. So, against
the other suspects:

* **a joint's offset** turns the beam (the tilt rows see it, 0.01° at 0.002° a reading):
  growth turns nothing;
* **the block moving** shifts every path to a face by the same ``n·Δc``: growth by
  ``g·n·p``, the mean of which is a block shift of ``−g·p̄`` (115 ppm: 0.09 mm at 0.8 m);
  what tells them apart is the spread of ``n·p`` over the postures that read one face at
  different reaches (a few tenths of the mean: 0.01–0.03 mm at 115 ppm, above a path's
  few µm). Where the postures do not spread, the selection names both (``alike``);
* **the tool along its beam** lengthens every path by the same amount, whatever the face;
* **the water's sound speed** scales every water path by ``c/c₀`` (the paths of 40 to 160 mm
  at the posture's own length): growth does not scale the water path, it moves the arm's lever
  arm ``n·p`` (hundreds of mm, and different from the path's length), so postures whose water
  paths and reaches differ separate the two.

An unwarmed arm grows by nothing: its fitted change is within 3σ of zero (σ from the fit's
covariance, as every suspect's). The equivalent temperature rise is ``g / α``, α aluminium's
``ALUMINIUM_EXPANSION_PER_K`` (the TX90 family's castings).

Its tolerance (``GROWTH_TOLERANCE_PPM`` = 50 ppm): the block and tool's position tolerance,
0.05 mm, over a metre's reach; 2.2 K of aluminium. Beyond 3σ and 50 ppm the arm is out of
tolerance (exit 1: a scan carries the growth, calibrate warm or wait for the arm to settle);
a σ above 50 ppm is ``not determined``.
"""

from __future__ import annotations

import numpy as np

from ucal.cell import ALUMINIUM_EXPANSION_PER_K
from ucal.model.priors import DH

#: The arm's uniform growth since the reference (ppm): the unknown of the ``"arm"`` suspect.
GROWTH = "arm_growth_ppm"
#: The growth worth a commissioning's attention (module docstring).
GROWTH_TOLERANCE_PPM = 50.0
#: Weak prior on the growth's change (one sigma, ppm: about 40 K of aluminium).
GROWTH_CHANGE_STD_PPM = 1000.0
#: The suspect's name and its words in a message.
ARM = "arm"
ARM_WORDS = "the arm's growth (warm-up)"
#: The DH table's lengths (names in ``ucal.model.priors.DH``) the growth scales.
LENGTHS = tuple(n for n in DH if n.endswith("_mm"))


def grown(values: np.ndarray, lengths: np.ndarray, growth_idx: int) -> np.ndarray:
    """``values`` with the DH lengths (indices ``lengths``) scaled by ``1 + g``, g the growth
    at ``growth_idx`` (ppm); ``values`` itself where it is 0."""
    g = float(values[growth_idx])
    if g == 0.0:
        return values
    out = values.copy()
    out[lengths] *= 1.0 + 1e-6 * g
    return out


def temperature_rise_k(growth_ppm: float) -> float:
    """The arm's temperature rise (K) a growth (ppm) means, aluminium's expansion."""
    return float(growth_ppm * 1e-6 / ALUMINIUM_EXPANSION_PER_K)


def growth_words(size: float, std: float, tolerance: float) -> str:
    """A moved arm in words: its growth and the temperature rise it means."""
    return (
        f"the arm grew (warm-up) by {size:+.0f} ppm (± {std:.2g}; tolerance {tolerance:g} ppm), "
        f"as an arm {temperature_rise_k(size):+.1f} K warmer than at the reference "
        f"(aluminium, {ALUMINIUM_EXPANSION_PER_K * 1e6:g} ppm/K); every scan carries it: let "
        "the arm reach its working temperature before checking, or calibrate it warm"
    )
