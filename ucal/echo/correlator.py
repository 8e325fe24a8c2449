"""The correlation of an A-scan with its reference echo (``Correlator``), and the two ways a
record departs from the reference that the estimator of ``ucal.echo.timing`` fits: the
spectrum seen through more water (``fit_attenuation``, ``through_water``: α ∝ f²) and a second
echo over the first (``explained_by_a_pair``). Their physics is in ``ucal.echo.timing``'s
docstring."""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy import fft

from ucal.echo.ascan import (
    ReferenceEcho,
)
from ucal.echo.spectral import series_peak, shifted

#: The fitted attenuation's bounds at the template's RMS frequency β (Np: ±52 dB), its
#: steps, and the step (of that bound) below which it has settled.
ATTENUATION_LIMIT_NP = 6.0
ATTENUATION_ITERATIONS = 30
ATTENUATION_TOLERANCE = 1e-4
#: Less water than the reference's, where it is fitted (``less_water``): at most this much
#: gain at β (Np: 26 dB, about 95 mm less at 25 MHz).
LESS_WATER_LIMIT_NP = 3.0
#: ... its coarse scan's steps, 0 included.
LESS_WATER_STEPS = 13
#: An echo is overlapped when its residual's excess over the noise passes this many of the
#: excess's own standard deviations √(2m) (m samples in the echo).
OVERLAP_SIGMAS = 5.0
#: ... and its energy passes this share of the echo's (a residual 1 % of the echo's height):
#: below, what is left is taken as the echo's own shape, which the reference matches only so
#: well (its averaging over the trigger jitter, the spectrum's change with the tilt).
OVERLAP_ENERGY = 1e-4
#: A fitted κ is kept when this many of its std from 0; less, the spectrum has not changed
#: beyond the noise and the reference is used as it is.
ATTENUATION_SIGMAS = 3.0
#: A second echo is sought this many periods (1/β) or more from the first, and the two
#: fitted by turns at most this often.
SEPARATION_PERIODS = 1.5
SEPARATION_ITERATIONS = 60
#: Starts of the pair's turns on each side of the first echo (the residual's largest lobes).
SEPARATION_STARTS = 2
#: The pair's turns stop when the delay moves less than this (samples).
TURNS_TOLERANCE = 1e-6


@dataclass(frozen=True)
class Correlator:
    """A reference echo against records of ``n`` samples: its spectrum padded to ``n_fft``
    (no wrap-around between the record and the reference)."""

    n: int
    n_fft: int
    spectrum: np.ndarray
    energy: float

    @classmethod
    def of(cls, ref: ReferenceEcho, n: int) -> Correlator:
        n_fft = fft.next_fast_len(n + ref.n)
        spectrum = ref.spectrum(n_fft)
        return cls(n, n_fft, spectrum, float(np.sum(fft.irfft(spectrum, n_fft) ** 2)))

    @functools.cached_property
    def conjugate(self) -> np.ndarray:
        """The reference's spectrum conjugated: a record's correlation is its spectrum times
        this (kept: the fits of one record correlate it again and again)."""
        return np.asarray(np.conj(self.spectrum))

    def fit(self, x: np.ndarray, lag: float) -> tuple[float, float]:
        """(lag, amplitude) at the correlation peak nearest ``lag`` (samples)."""
        lag, value = series_peak(fft.rfft(x, self.n_fft) * self.conjugate, self.n_fft, lag)
        return lag, value / self.energy

    def model(self, lag: float) -> np.ndarray:
        """The reference delayed by ``lag`` samples, over the record (peak 1)."""
        return shifted(self.spectrum, self.n_fft, lag)[: self.n]


def explained_by_a_pair(
    x: np.ndarray,
    plain: Correlator,
    watered: tuple[Correlator, float],
    lag: float,
    in_echo: np.ndarray,
    used: np.ndarray,
    period: float,
    dt_ns: float,
    sigma: float,
    over: Callable[[np.ndarray, np.ndarray], float | None],
) -> tuple[Correlator, float, tuple[float, float, float, float]] | None:
    """Two echoes that leave no excess (``over`` None): the pair with the reference as it is;
    else the water fitted on the record less that pair's other echo, and the pair again; else
    the pair with the water fitted before (a second echo makes the two look like more water
    than there is, so the reference as it is comes first). Returns (correlator, κ, pair)."""

    def explains(corr: Correlator, pair: tuple[float, float, float, float] | None) -> bool:
        if pair is None:
            return False
        other = pair[3] * corr.model(pair[2])
        return over(x - other, pair[1] * corr.model(pair[0])) is None

    _, amplitude = plain.fit(np.where(used, x, 0.0), lag)
    pair = _separate(x, plain, lag, amplitude, in_echo, used, period)
    if explains(plain, pair):
        assert pair is not None
        return plain, 0.0, pair
    if pair is not None:
        other = pair[3] * plain.model(pair[2])
        corr, kappa, lag2, amplitude2 = fit_attenuation(
            x - other, plain, pair[0], in_echo & used, dt_ns, sigma
        )
        again = _separate(x, corr, lag2, amplitude2, in_echo, used, period)
        if explains(corr, again):
            assert again is not None
            return corr, kappa, again
    corr, kappa = watered
    _, amplitude = corr.fit(np.where(used, x, 0.0), lag)
    pair = _separate(x, corr, lag, amplitude, in_echo, used, period)
    if explains(corr, pair):
        assert pair is not None
        return corr, kappa, pair
    return None


def _separate(
    x: np.ndarray,
    corr: Correlator,
    lag: float,
    amplitude: float,
    in_echo: np.ndarray,
    used: np.ndarray,
    period: float,
) -> tuple[float, float, float, float] | None:
    """Another echo of the template's shape over this one, ``SEPARATION_PERIODS`` periods
    or more away (either sign), fitted with it by turns, each refitted on the record less
    the other, until both delays settle; started from the residual's largest correlation
    before the echo and after it, the pair that leaves the smaller residual kept. Returns
    (lag, amplitude, lag₂, amplitude₂), or None when none is found or the turns do not
    settle."""
    residual = np.where(used, x - amplitude * corr.model(lag), 0.0)
    c = fft.irfft(fft.rfft(residual, corr.n_fft) * corr.conjugate, corr.n_fft)
    lags = np.arange(-corr.n + 1, corr.n)
    window = np.flatnonzero(in_echo)
    near = (lags >= window[0] - corr.n // 2) & (lags <= window[-1])  # over the echo's span
    best: tuple[float, tuple[float, float, float, float]] | None = None
    for side in (
        lags <= lag - SEPARATION_PERIODS * period,
        lags >= lag + SEPARATION_PERIODS * period,
    ):
        candidates = lags[near & side]
        if not candidates.size:
            continue
        values = np.abs(c[candidates % corr.n_fft])
        # local maxima of |c|, the largest first: a ringing echo's correlation has a lobe
        # every period, and the residual of one fitted echo puts its largest on a wrong one
        peaks = np.flatnonzero((values >= np.roll(values, 1)) & (values >= np.roll(values, -1)))
        for k in peaks[np.argsort(values[peaks])[::-1][:SEPARATION_STARTS]]:
            start = float(candidates[k])
            sign = 1.0 if c[int(candidates[k]) % corr.n_fft] > 0 else -1.0
            pair = _turns(x, corr, used, lag, start, sign)
            if pair is None or abs(pair[2] - pair[0]) < 0.5 * SEPARATION_PERIODS * period:
                continue  # did not settle, or the turns merged them: not two echoes
            fit = pair[1] * corr.model(pair[0]) + pair[3] * corr.model(pair[2])
            sse = float(np.sum((x - fit)[used] ** 2))
            if best is None or sse < best[0]:
                best = (sse, pair)
    return None if best is None else best[1]


def _turns(
    x: np.ndarray, corr: Correlator, used: np.ndarray, lag: float, lag2: float, sign: float
) -> tuple[float, float, float, float] | None:
    """Two echoes fitted by turns from ``lag`` and ``lag2`` (the second of ``sign``): each
    delay and amplitude refitted on the record less the other, until both settle."""
    _, amplitude = corr.fit(np.where(used, x, 0.0), lag)
    y = np.where(used, x - amplitude * corr.model(lag), 0.0)
    lag2, a2 = corr.fit(sign * y, lag2)
    for _ in range(SEPARATION_ITERATIONS):
        new_lag, amplitude = corr.fit(np.where(used, x - sign * a2 * corr.model(lag2), 0.0), lag)
        y = np.where(used, x - amplitude * corr.model(new_lag), 0.0)
        new_lag2, a2 = corr.fit(sign * y, lag2)
        moved = max(abs(new_lag - lag), abs(new_lag2 - lag2))
        lag, lag2 = new_lag, new_lag2
        if moved < TURNS_TOLERANCE:
            return (lag, amplitude, lag2, sign * a2) if amplitude > 0.0 else None
    return None


def pair_std_ns(
    corr: Correlator,
    pair: tuple[float, float, float, float],
    used: np.ndarray,
    sigma: float,
    dt_ns: float,
) -> float:
    """The first delay's std (ns) of two echoes fitted together: ``σ²·(JᵀJ)⁻¹``, J the
    derivatives of the two echoes in their delays and amplitudes over the used samples."""
    lag, amplitude, lag2, amplitude2 = pair
    n = corr.n
    columns = [
        amplitude * shifted(corr.spectrum, corr.n_fft, lag, derivative=True)[:n],
        corr.model(lag),
        amplitude2 * shifted(corr.spectrum, corr.n_fft, lag2, derivative=True)[:n],
        corr.model(lag2),
    ]
    jacobian = np.column_stack(columns)[used]
    try:
        covariance = np.linalg.inv(jacobian.T @ jacobian)
    except np.linalg.LinAlgError:
        return math.inf
    return sigma * math.sqrt(max(float(covariance[0, 0]), 0.0)) * dt_ns


def through_water(corr: Correlator, ref: ReferenceEcho, kappa: float, dt_ns: float) -> float:
    """√⟨exp(−2κf²)⟩ over the echo's delay information (weights f²|R|²exp(−2κf²)): the
    share of the reference's noise the template keeps through κ of water, relative to the
    echo's (module docstring)."""
    if kappa == 0.0:
        return 1.0
    f2 = fft.rfftfreq(corr.n_fft, dt_ns * 1e-3) ** 2
    weights = f2 * np.abs(corr.spectrum) ** 2  # the template: |R|²·exp(−2κf²) already
    total = float(np.sum(weights))
    return math.sqrt(float(np.sum(weights * np.exp(-2.0 * kappa * f2))) / total) if total else 1.0


def fit_attenuation(
    x: np.ndarray,
    corr: Correlator,
    lag: float,
    where: np.ndarray,
    dt_ns: float,
    sigma: float,
    *,
    less_water: bool = False,
) -> tuple[Correlator, float, float, float]:
    """The template through κ Np/MHz² more water, ``R·exp(−κf²)``, fitted to the record's
    samples ``where`` (module docstring): Gauss–Newton on κ with the amplitude, the delay
    refitted at each step; κ kept only when it is ``ATTENUATION_SIGMAS`` of its own std
    from 0 (σ the noise). With ``less_water`` κ may be negative too, down to
    ``LESS_WATER_LIMIT_NP`` at β. Returns (correlator, κ, lag, amplitude)."""
    start = (corr, 0.0, lag, corr.fit(x, lag)[1])
    f2 = fft.rfftfreq(corr.n_fft, dt_ns * 1e-3) ** 2
    base = corr.spectrum
    power = np.abs(base) ** 2
    beta2 = float(np.sum(f2 * power) / np.sum(power)) if np.any(power) else 0.0
    # more water only, up to the limit at β: less (κ < 0) would amplify the template's edges
    # and the reference's noise beyond them, and the Wiener weights, which narrow a noisy
    # reference's band a little, were fitted as less water, the std widened for nothing
    limit = ATTENUATION_LIMIT_NP / beta2 if beta2 > 0.0 else 0.0
    lowest = -LESS_WATER_LIMIT_NP / beta2 if less_water and beta2 > 0.0 else 0.0
    kappa, amplitude = 0.0, start[3]
    if less_water:
        # far from the reference's water the linearised step may not even keep the echo's
        # sign: it starts from the best of a coarse scan over the less water allowed
        corr, kappa, lag, amplitude = _scanned(x, corr, lag, where, f2, lowest)
    for _ in range(ATTENUATION_ITERATIONS):
        g = shifted(corr.spectrum, corr.n_fft, lag)[: corr.n][where]
        h = shifted(-f2 * corr.spectrum, corr.n_fft, lag)[: corr.n][where]
        (a, b), *_ = np.linalg.lstsq(np.column_stack([g, h]), x[where], rcond=None)
        if not a > 0.0:
            break
        step = float(np.clip(kappa + b / a, lowest, limit)) - kappa
        kappa += step
        spectrum = base * np.exp(-kappa * f2)
        energy = float(np.sum(fft.irfft(spectrum, corr.n_fft) ** 2))
        corr = Correlator(corr.n, corr.n_fft, spectrum, energy)
        lag, amplitude = corr.fit(x, lag)
        if abs(step) * limit == 0.0 or abs(step) < ATTENUATION_TOLERANCE * limit:
            break
    # κ's std: σ over the part of a·∂g/∂κ the amplitude's column does not explain
    g = shifted(corr.spectrum, corr.n_fft, lag)[: corr.n][where]
    h = amplitude * shifted(-f2 * corr.spectrum, corr.n_fft, lag)[: corr.n][where]
    alone = h - g * float(g @ h) / max(float(g @ g), 1e-300)
    information = float(alone @ alone)
    if not (information > 0.0 and abs(kappa) * math.sqrt(information) > ATTENUATION_SIGMAS * sigma):
        return start
    return corr, kappa, lag, amplitude


def _scanned(
    x: np.ndarray,
    corr: Correlator,
    lag: float,
    where: np.ndarray,
    f2: np.ndarray,
    lowest: float,
) -> tuple[Correlator, float, float, float]:
    """The template through each of ``LESS_WATER_STEPS`` amounts of less water from 0 to
    ``lowest`` (κ < 0), its delay and amplitude fitted: the one leaving the least residual
    over ``where``, as (correlator, κ, lag, amplitude)."""
    best: tuple[float, tuple[Correlator, float, float, float]] | None = None
    for kappa in np.linspace(0.0, lowest, LESS_WATER_STEPS):
        spectrum = corr.spectrum * np.exp(-kappa * f2)
        energy = float(np.sum(fft.irfft(spectrum, corr.n_fft) ** 2))
        trial = Correlator(corr.n, corr.n_fft, spectrum, energy)
        trial_lag, amplitude = trial.fit(x, lag)
        sse = float(np.sum((x - amplitude * trial.model(trial_lag))[where] ** 2))
        if best is None or sse < best[0]:
            best = (sse, (trial, float(kappa), trial_lag, amplitude))
    assert best is not None
    return best[1]


def residual_excess(x: np.ndarray, fit: np.ndarray, where: np.ndarray, sigma: float) -> float:
    """``Σ (x − fit)²/σ² − m`` over the ``m`` samples ``where``: the residual's energy beyond
    the noise's, in units of σ² (0 for a lone echo, up to the noise's own scatter ±√(2m))."""
    if sigma <= 0.0 or not where.any():
        return 0.0
    residual = (x - fit)[where]
    return float(np.sum(residual**2)) / sigma**2 - float(residual.size)


def leaves_excess(
    x: np.ndarray,
    fitted: tuple[Correlator, float, float, float],
    where: np.ndarray,
    sigma: float,
    reference_noise: float,
) -> bool:
    """Whether the echo ``fitted`` (correlator, κ, lag, amplitude) leaves more in the
    record's samples ``where`` than the record's noise ``sigma`` and the reference's
    (``reference_noise`` of its peak) explain: the overlap test of ``ucal.echo.timing``,
    before clipping is taken into account."""
    corr, _, lag, amplitude = fitted
    sigma = math.hypot(sigma, amplitude * reference_noise)
    model = amplitude * corr.model(lag)
    excess = residual_excess(x, model, where, sigma)
    energy = float(np.sum(model[where] ** 2))
    return another_echo_shows(excess, int(np.count_nonzero(where)), sigma, energy)


def another_echo_shows(excess: float, samples: int, sigma: float, echo_energy: float) -> bool:
    """Whether a residual's ``excess`` (``residual_excess`` over ``samples`` samples, noise
    ``sigma``) shows another echo: ``OVERLAP_SIGMAS`` of its own scatter √(2m) and
    ``OVERLAP_ENERGY`` of the fitted echo's energy ``echo_energy`` (both, see the constants)."""
    return (
        excess > OVERLAP_SIGMAS * math.sqrt(2.0 * samples)
        and excess * sigma**2 > OVERLAP_ENERGY * echo_energy
    )
