"""Digitised records: an A-scan, a reference echo, and what can be read off them.

``AScan`` is one record of a digitiser: sample k at ``t0_ns + k·dt_ns`` (uniform sampling),
the samples in the digitiser's units, and what the digitiser can say about them: its rails
(the lowest and highest value it can give, so a sample sitting on one is clipped) and its
quantisation step (``lsb``). The estimators (``ucal.echo.timing``) take one ``AScan`` in.

``ReferenceEcho`` is the cell's own echo, on its own time axis with its arrival at t = 0
(``ucal.echo.reference`` builds one from many captures and says what "arrival" means), stored
with its peak at 1 so that an amplitude measured against it is an echo's peak. Its RMS (Gabor)
bandwidth β is the one the Cramér–Rao bound of a delay needs (``ucal.echo.timing``).

The measurements here need no reference echo:

* ``noise_rms``: the noise of the samples outside the echo, robust to other echoes in the
  record (median of block mean squares, scaled to a variance), plus the quantisation noise
  LSB²/12 when the step is known;
* ``echo_band``: centre frequency and −6 dB bandwidth of an echo's amplitude spectrum, the
  centre taken as the middle of the −6 dB band (ASTM E1065's convention for transducers).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field

import numpy as np
from scipy import fft, signal, stats

from ucal.echo.spectral import evaluate, series_peak

#: Samples per block of the robust noise estimate.
NOISE_BLOCK = 16
#: Median of χ² with ``NOISE_BLOCK`` degrees of freedom, per degree of freedom.
CHI2_MEDIAN_PER_DOF = float(stats.chi2.median(NOISE_BLOCK)) / NOISE_BLOCK
#: The reference's support: where its envelope is above this fraction of its peak.
SUPPORT_LEVEL = 1e-3
SUPPORT_NOISE = 6.0
#: β is summed over the bins whose power is above this fraction of the peak bin's (and above
#: the reference's own noise): the bound must not count the noise the averaging left.
BAND_LEVEL = 1e-4
#: Bins of a noisy reference whose power is below this many times the noise's are noise.
WIENER_MARGIN = 3.0
#: Spectral resolution of ``echo_band`` as a fraction of the sample rate (zero padding).
BAND_RESOLUTION = 1.0 / 4096.0


def sampled_row(samples: object, dt_ns: float, at_least: int, what: str) -> np.ndarray:
    """``samples`` as one finite row of at least ``at_least`` floats taken every ``dt_ns`` > 0
    ns, or ValueError naming ``what`` they were meant to be."""
    row = np.asarray(samples, dtype=float)
    if row.ndim != 1 or row.size < at_least:
        raise ValueError(f"{what} is one row of at least {at_least} samples, got {row.shape}")
    if not np.all(np.isfinite(row)):
        raise ValueError(f"{what}'s samples must be finite")
    if not (math.isfinite(dt_ns) and dt_ns > 0.0):
        raise ValueError(f"sample interval must be positive, got {dt_ns} ns")
    return row


@dataclass(frozen=True)
class AScan:
    """One digitised record: ``samples[k]`` taken at ``t0_ns + k·dt_ns``.

    ``rails``: the lowest and highest value the digitiser can return (a sample on a rail is
    clipped), None when not known. ``lsb``: the quantisation step in the samples' units, None
    when not known.
    """

    t0_ns: float
    dt_ns: float
    samples: np.ndarray = field(repr=False)
    rails: tuple[float, float] | None = None
    lsb: float | None = None

    def __post_init__(self) -> None:
        samples = sampled_row(self.samples, self.dt_ns, 8, "an A-scan")
        object.__setattr__(self, "samples", samples)

    @property
    def n(self) -> int:
        """Number of samples."""
        return int(self.samples.size)

    @property
    def t_ns(self) -> np.ndarray:
        """Time of each sample (ns)."""
        return self.t0_ns + self.dt_ns * np.arange(self.n)

    @property
    def sample_rate_mhz(self) -> float:
        """Samples per µs."""
        return 1e3 / self.dt_ns

    def at_rails(self) -> np.ndarray:
        """Mask of the samples on a rail (all False when the rails are not known)."""
        if self.rails is None:
            return np.zeros(self.n, dtype=bool)
        low, high = self.rails
        return (self.samples <= low) | (self.samples >= high)


def noise_rms(samples: np.ndarray, quiet: np.ndarray, lsb: float | None = None) -> float | None:
    """Noise standard deviation of ``samples`` (mean removed) from those where ``quiet`` holds.

    The quiet samples are cut into contiguous blocks of ``NOISE_BLOCK``; the median of the
    blocks' mean squares, divided by the median of χ²_b/b, is the variance of white Gaussian
    noise, and a second echo or a burst in a minority of the blocks does not move it (a mean
    over all samples would). With a known quantisation step LSB²/12 is added: noise below one
    step reads as a constant outside the echo, while under the echo, which sweeps through the
    levels, the rounding error is that of a uniform step; noise over several steps already
    carries it, and counting it twice overstates σ by LSB²/(24σ), a few per cent at most
    when σ is one step. None when fewer than two blocks are quiet.
    """
    idx = np.flatnonzero(quiet)
    # contiguous runs of quiet samples, each cut into whole blocks
    runs = np.split(idx, np.flatnonzero(np.diff(idx) > 1) + 1) if idx.size else []
    blocks = [
        np.mean(samples[run[: run.size - run.size % NOISE_BLOCK]].reshape(-1, NOISE_BLOCK) ** 2, 1)
        for run in runs
        if run.size >= NOISE_BLOCK
    ]
    mean_squares = np.concatenate(blocks) if blocks else np.empty(0)
    if mean_squares.size < 2:
        return None
    variance = float(np.median(mean_squares)) / CHI2_MEDIAN_PER_DOF
    if lsb is not None:
        variance += lsb**2 / 12.0
    return math.sqrt(variance)


@dataclass(frozen=True)
class EchoBand:
    """−6 dB band of an echo's amplitude spectrum (MHz); the centre is the band's middle."""

    centre_frequency_mhz: float
    bandwidth_mhz: float
    low_mhz: float
    high_mhz: float


def echo_band(segment: np.ndarray, dt_ns: float) -> EchoBand:
    """Centre frequency and −6 dB bandwidth of the echo in ``segment`` (the echo's samples, the
    record's offset removed).

    The amplitude spectrum is zero-padded to ``BAND_RESOLUTION`` of the sample rate; from its
    peak outwards the first bins below half the peak bound the band, interpolated linearly in
    amplitude between bins. Noise in the segment lifts the spectrum's floor and, at low SNR,
    can widen the band.
    """
    n_fft = fft.next_fast_len(max(int(1.0 / BAND_RESOLUTION), 8 * segment.size))
    spectrum = np.abs(fft.rfft(segment, n_fft))
    f_mhz = fft.rfftfreq(n_fft, dt_ns * 1e-3)
    k = int(np.argmax(spectrum[1:])) + 1  # not DC
    half = 0.5 * spectrum[k]
    below = np.flatnonzero(spectrum[:k] < half)
    if below.size:
        i = int(below[-1])
        low = f_mhz[i] + (half - spectrum[i]) / (spectrum[i + 1] - spectrum[i]) * (
            f_mhz[i + 1] - f_mhz[i]
        )
    else:
        low = 0.0
    above = np.flatnonzero(spectrum[k:] < half)
    if above.size:
        i = k + int(above[0])
        high = f_mhz[i - 1] + (spectrum[i - 1] - half) / (spectrum[i - 1] - spectrum[i]) * (
            f_mhz[i] - f_mhz[i - 1]
        )
    else:
        high = float(f_mhz[-1])
    return EchoBand(0.5 * (low + high), high - low, float(low), float(high))


@dataclass(frozen=True)
class ReferenceEcho:
    """One echo with its arrival at t = 0: ``samples[k]`` at ``t0_ns + k·dt_ns``.

    ``samples``: the echo without the digitiser's offset (``build_reference`` removes each
    capture's), stored with its peak (of the band-limited waveform, not of the samples, which
    miss it by up to 29 % at 4 samples a cycle) at 1; ``noise_rms`` (the noise the averaging
    left, in the input's units) is scaled alike. ``averages``: how many captures it was
    averaged from.
    """

    t0_ns: float
    dt_ns: float
    samples: np.ndarray = field(repr=False)
    noise_rms: float = 0.0
    averages: int = 1

    def __post_init__(self) -> None:
        samples = sampled_row(self.samples, self.dt_ns, 4, "a reference echo")
        peak = band_limited_peak(samples)
        if not peak > 0.0:
            raise ValueError("a reference echo cannot be all zeros")
        object.__setattr__(self, "samples", samples / peak)
        object.__setattr__(self, "noise_rms", float(self.noise_rms) / peak)

    @property
    def n(self) -> int:
        """Number of samples."""
        return int(self.samples.size)

    @functools.cached_property
    def energy(self) -> float:
        """Σ r² of the echo (the peak being 1), its noise's n·σ² taken out."""
        return max(float(np.sum(self.samples**2)) - self.n * self.noise_rms**2, 1e-300)

    def spectrum(self, n_fft: int) -> np.ndarray:
        """The echo's ``rfft`` padded to ``n_fft``, each bin weighted by ``wiener_gain``: the
        template a record is correlated with, the noise the averaging left kept out of it."""
        spectrum = fft.rfft(self.samples, n_fft)
        gain = wiener_gain(np.abs(spectrum) ** 2, self.n * self.noise_rms**2)
        gain[0] = 0.0  # an offset is not the echo
        return np.asarray(spectrum * gain)

    @functools.cached_property
    def band_power_threshold(self) -> float:
        """Power per ``rfft`` bin below which a bin of the reference is noise or nothing
        (``band_power_threshold``)."""
        return band_power_threshold(self.samples, self.noise_rms)

    @functools.cached_property
    def rms_bandwidth_mhz(self) -> float:
        """Gabor bandwidth β = √(Σ f²|R|² / Σ |R|²) (MHz) over the echo's band, about 0 Hz: for
        a band-pass echo √(f_c² + B²), B the RMS width about the centre f_c."""
        return self.rms_bandwidth_through_mhz(0.0)

    def rms_bandwidth_through_mhz(self, kappa: float) -> float:
        """β of the echo seen through κ Np/MHz² more water, |R|² weighted by exp(−2κf²)."""
        n_fft = fft.next_fast_len(4 * self.n)
        power = np.abs(fft.rfft(self.samples, n_fft)) ** 2
        f_mhz = fft.rfftfreq(n_fft, self.dt_ns * 1e-3)
        band = power >= self.band_power_threshold
        # the echo's power: the noise's expected n·σ² taken out of each bin of the band
        echo = np.clip(power[band] - self.n * self.noise_rms**2, 0.0, None)
        echo = echo * np.exp(-2.0 * kappa * f_mhz[band] ** 2)
        return math.sqrt(float(np.sum(f_mhz[band] ** 2 * echo) / np.sum(echo)))

    @functools.cached_property
    def support(self) -> tuple[int, int]:
        """``(first, stop)`` sample indices where the echo's envelope is above
        ``SUPPORT_LEVEL`` of its peak (and above ``SUPPORT_NOISE`` times its noise, which the
        envelope of noise alone passes with probability exp(−SUPPORT_NOISE²/2) a sample: a
        reference written whole with its noise is not all echo)."""
        envelope = np.abs(signal.hilbert(self.samples))
        level = max(SUPPORT_LEVEL * float(envelope.max()), SUPPORT_NOISE * self.noise_rms)
        above = np.flatnonzero(envelope >= level)
        return int(above[0]), int(above[-1]) + 1

    @functools.cached_property
    def band_top_mhz(self) -> float:
        """Highest frequency (MHz) of the echo's band (bins above ``band_power_threshold``)."""
        power = np.abs(fft.rfft(self.samples)) ** 2
        f_mhz = fft.rfftfreq(self.n, self.dt_ns * 1e-3)
        return float(f_mhz[np.flatnonzero(power >= self.band_power_threshold)[-1]])

    def resampled(self, dt_ns: float) -> ReferenceEcho:
        """The same echo sampled every ``dt_ns`` (band-limited interpolation), same t = 0.

        Raises ``ValueError`` when the echo's band reaches above that interval's Nyquist
        frequency (it cannot be sampled so coarsely without aliasing).
        """
        if abs(dt_ns - self.dt_ns) <= 1e-9 * self.dt_ns:
            return self
        if 0.5e3 / dt_ns < self.band_top_mhz:
            raise ValueError(
                f"a reference echo sampled every {self.dt_ns:g} ns cannot be resampled every "
                f"{dt_ns:g} ns: its band reaches {self.band_top_mhz:.1f} MHz, above "
                f"{0.5e3 / dt_ns:.1f} MHz"
            )
        first = math.ceil(self.t0_ns / dt_ns)
        last = math.floor((self.t0_ns + (self.n - 1) * self.dt_ns) / dt_ns)
        t_ns = np.arange(first, last + 1) * dt_ns
        values = evaluate(self.samples, (t_ns - self.t0_ns) / self.dt_ns)
        # band-limited noise has the same variance however it is sampled
        return ReferenceEcho(float(t_ns[0]), dt_ns, values, self.noise_rms, self.averages)


def wiener_gain(power: np.ndarray, noise_power: float) -> np.ndarray:
    """Zero-phase weight of each bin of a noisy echo's spectrum: ``max(1 − k·N/P, 0)`` (P the
    bin's power, N = n·σ² the white noise's expected power in it, k = ``WIENER_MARGIN``), the
    share of a bin's power that is the echo's, with a margin so that bins of noise alone (P
    exponential about N) pass in e^−k of them at most. Real and even: it does not move a
    correlation's peak (``ucal.echo.timing``)."""
    if noise_power <= 0.0:
        return np.ones_like(power)
    with np.errstate(divide="ignore", invalid="ignore"):
        gain = 1.0 - WIENER_MARGIN * noise_power / power
    return np.where(power > 0.0, np.clip(gain, 0.0, 1.0), 0.0)


def band_power_threshold(samples: np.ndarray, noise_rms: float = 0.0) -> float:
    """Power per ``rfft`` bin (unnormalised, any zero padding) below which a bin of the echo in
    ``samples`` is noise or nothing: ``BAND_LEVEL`` of the peak bin, and 4 times the expected
    power n·σ² of white noise of ``noise_rms`` over the n samples."""
    power = np.abs(fft.rfft(samples)) ** 2
    return max(BAND_LEVEL * float(power.max()), 2.0 * WIENER_MARGIN * samples.size * noise_rms**2)


def echo_noise_rms(samples: np.ndarray) -> float:
    """Noise std of a record holding one echo (its offset removed): ``noise_rms`` of the
    samples outside the echo, the echo being where the envelope stands above 4 times the
    noise, widened by a quarter (three rounds from the whole record's robust estimate); 0
    when too few samples are left outside (a reference cut tight around its echo)."""
    envelope = np.abs(signal.hilbert(samples))
    sigma = noise_rms(samples, np.ones(samples.size, dtype=bool)) or 0.0
    for _ in range(3):
        above = np.flatnonzero(envelope > max(4.0 * sigma, SUPPORT_LEVEL * envelope.max()))
        if not above.size:
            break
        margin = max(NOISE_BLOCK, (above[-1] - above[0]) // 4)
        quiet = np.ones(samples.size, dtype=bool)
        quiet[max(0, above[0] - margin) : above[-1] + margin + 1] = False
        found = noise_rms(samples, quiet)
        if found is None:
            return 0.0
        sigma = found
    return float(sigma)


def band_limited_peak(samples: np.ndarray) -> float:
    """Largest |value| of the band-limited waveform through ``samples`` (its largest sample
    refined to the waveform's extremum beside it)."""
    if not np.any(samples):
        return 0.0
    n_fft = fft.next_fast_len(2 * samples.size)
    spectrum = fft.rfft(samples, n_fft)
    best = 0.0
    for sign in (1.0, -1.0):
        k = int(np.argmax(sign * samples))
        _, value = series_peak(sign * spectrum, n_fft, float(k))
        best = max(best, value)
    return best
