"""The echo timer ucal gives a back-end that only digitises (``drivers.digitizer.base.EchoTimer``).

A back-end such as ``drivers.pulser.ascii.AsciiScpiPulser`` records the A-scan and asks its
injected timer for the echo; ``drivers`` never imports ``ucal``, so the session
(``ucal.devices.session``) builds a :class:`HostEchoTimer` and hands it over. The timer is the
project's estimator (``ucal.echo.timing.estimate_echo``): against the cell's reference echo when
there is one, else the coarse envelope fallback, whose label (``METHOD_ENVELOPE``) every reading
carries.

A record holds the whole gate (a 400 µs gate at 200 MS/s is 80 000 samples) and the echo a
microsecond of it. The timer cuts the record to the neighbourhood of its largest excursion from
its mean before estimating — the echo's support (the reference's, or ``SEARCH_HALF_NS``
without one) plus ``NOISE_MARGIN`` samples of noise on each side for the noise estimate — so a
reading costs the same whatever the gate. The strongest echo's largest sample is the largest
excursion unless a second echo of nearly the same height is in the gate; the estimator then
times whichever of the two is in the cut, as a peak-mode gate would.

A record with nothing in it (every sample equal: noise below one step of the digitiser), or
one the estimator finds no echo in (``ucal.echo.timing.NoEcho``: noise alone, an echo of the
other polarity, an echo cut by the record's ends), has amplitude 0 and no time of flight: the
pulser's reading says ``has_echo`` False, as a gate that saw no echo does, and the
measurement never hands it to the solver (``ucal.measure.search``).
"""

from __future__ import annotations

import logging
import math
from collections import Counter

import numpy as np

from drivers.digitizer.base import AScanRecord, EchoTiming
from ucal.echo.ascan import AScan, ReferenceEcho
from ucal.echo.timing import METHOD_ENVELOPE, METHOD_REFERENCE, NoEcho, estimate_echo

log = logging.getLogger(__name__)

#: Without a reference: the cut spans this long on either side of the largest excursion (ns).
SEARCH_HALF_NS = 1500.0
#: Samples of the record kept beyond the echo on each side (noise estimate: ≥ 2 blocks of 16).
NOISE_MARGIN = 96


class HostEchoTimer:
    """Times the strongest echo of a record on the host (module docstring).

    ``reference`` is the cell's reference echo (None: the coarse envelope fallback).
    """

    def __init__(self, reference: ReferenceEcho | None = None):
        self.reference = reference
        #: Echoes timed so far, by method (the fallback's count: readings before a reference).
        self.timed: Counter[str] = Counter()
        #: Records without an echo to time, by reason (``ucal.echo.timing.NoEcho``).
        self.no_echo: Counter[str] = Counter()

    @property
    def label(self) -> str:
        """How echoes are timed: ``"host: reference"`` or the labelled fallback."""
        return f"host: {METHOD_REFERENCE if self.reference is not None else METHOD_ENVELOPE}"

    def window_ns(self, dt_ns: float) -> float:
        """Half width (ns) of the record this timer reads around the largest excursion, for
        records sampled every ``dt_ns``: the cut of ``_cut``."""
        return self._half_ns() + NOISE_MARGIN * dt_ns

    def _half_ns(self) -> float:
        if self.reference is not None:  # the largest sample anywhere in the echo
            return self.reference.n * self.reference.dt_ns
        return SEARCH_HALF_NS

    def __call__(self, record: AScanRecord, gate_ns: tuple[float, float]) -> EchoTiming:
        """The strongest echo of ``record`` whose time lies in ``gate_ns``."""
        samples = np.asarray(record.samples, float)
        if samples.size < 8 or float(np.ptp(samples)) == 0.0:
            return self._nothing()
        first, stop = self._cut(record, samples, gate_ns)
        ascan = AScan(
            record.t0_ns + first * record.dt_ns,
            record.dt_ns,
            samples[first:stop],
            rails=record.rails,
            lsb=record.lsb if record.lsb > 0 else None,
        )
        try:
            echo = estimate_echo(ascan, self.reference, gate_ns=gate_ns)
        except NoEcho as e:  # a no-reading, as a gate that saw no echo gives: never solved
            log.debug("no echo in the record: %s", e.reason)
            self.no_echo[e.reason.split(":")[0]] += 1
            return self._nothing()
        except ValueError:  # the gate holds no sample of the cut: nothing to time
            return self._nothing()
        if not (math.isfinite(echo.amplitude) and math.isfinite(echo.tof_ns)):
            return self._nothing()
        self.timed[echo.method] += 1
        return EchoTiming(
            amplitude=abs(float(echo.amplitude)),
            tof_ns=float(echo.tof_ns),
            tof_std_ns=float(echo.tof_std_ns),
            method=echo.method,
            clipped=bool(echo.clipped),
        )

    def _nothing(self) -> EchoTiming:
        method = METHOD_REFERENCE if self.reference is not None else METHOD_ENVELOPE
        return EchoTiming(0.0, float("nan"), float("nan"), method)

    def _cut(
        self, record: AScanRecord, samples: np.ndarray, gate_ns: tuple[float, float]
    ) -> tuple[int, int]:
        """``(first, stop)`` sample indices around the largest excursion inside the gate."""
        n, dt = samples.size, record.dt_ns
        lo = max(0, math.ceil((gate_ns[0] - record.t0_ns) / dt))
        hi = min(n, math.floor((gate_ns[1] - record.t0_ns) / dt) + 1)
        if hi <= lo:
            lo, hi = 0, n
        inside = samples[lo:hi]
        # the offset is the mean: an echo has no DC (a median would cost more than the rest)
        k = lo + int(np.argmax(np.abs(inside - np.mean(inside))))
        half = math.ceil(self._half_ns() / dt) + NOISE_MARGIN
        return max(0, k - half), min(n, k + half + 1)
