"""Synthetic A-scans as a digitiser gives them: a ringing, asymmetric echo, sampled, noisy, clipped.

For tests and benchmarks of the echo estimators (``ucal.echo``) and, later, the simulated
digitiser. The echo is not the Gaussian-modulated cosine of ``ucal.sim.receiver``, nor any
shape the estimators assume:

* the transducer (``TransducerPulse``): a damped resonance ``H(ω) = iω / ((a + iω)² + ω0²)``
  (impulse response a damped sinusoid, no DC: a piezo element does not pass it) acting twice,
  on transmit and on receive, driven by a spike that rises at once and decays as
  ``(t/θ)·exp(−t/θ)`` (``E(ω) = 1/(1 + iωθ)²``, θ = 0.1/f_c): the echo ``H²·E`` rings for
  several cycles after a fast rise, so its envelope is skewed and its phase is not linear
  across the band. ``ω0`` and ``a`` are solved so that the −6 dB band of ``|H²·E|`` has its
  middle at the centre frequency and the asked fractional bandwidth (0.6 by default);
* the digitiser (``Digitiser``): its anti-alias filter, flat to 0.8 of the Nyquist frequency
  and falling as cos² to zero at it (so the record is band-limited and a shifted echo samples
  exactly as the echo shifted); ``bits`` over ``±full_scale`` with a mid-tread quantiser whose
  codes run from −2^(bits−1) to 2^(bits−1) − 1 (a sample beyond them sits on a rail); white
  Gaussian noise added before quantisation.

Arrival. An asymmetric echo has no single obvious "time": its envelope peak, its energy
centroid and its strongest cycle all differ. The arrival used here, and by the reference echo
of ``ucal.echo.reference`` (``echo_arrival_ns``), is the time at which the echo best matches
its own zero-phase twin (the symmetric pulse with the same amplitude spectrum): the maximum of
``Re ∫ |S(f)|·S(f)·exp(i2πfτ) df``. For a symmetric pulse it is its centre; it follows the
echo's cycles, so noise moves it about as little as it moves a matched-filter delay, where the
energy centroid, an envelope quantity, moves several times more. ``EchoShape`` holds the
digitised echo with its arrival at t = 0 and its peak (of the continuous waveform) at 1, so an
echo of amplitude A has its largest excursion at A.

Signal-to-noise ratio: the echo's peak over the noise's standard deviation, in dB.
``true_delay_crb_ns`` is the Cramér–Rao bound of the delay for that echo (``ucal.echo.timing``
derives it), including the quantisation noise LSB²/12.

Every draw comes from the ``numpy.random.Generator`` the caller passes.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy import fft, optimize

from ucal.echo.ascan import AScan

#: Excitation spike's time constant θ times the centre frequency.
EXCITATION_CYCLES = 0.1
#: Anti-alias filter: flat to this fraction of the Nyquist frequency, zero at it.
ANTI_ALIAS_FLAT = 0.8
#: An echo's support ends where its waveform stays below this fraction of its peak.
SUPPORT_LEVEL = 1e-6


def _resonance(f_mhz: np.ndarray, f0_mhz: float, a_per_us: float, theta_us: float) -> np.ndarray:
    """``H(ω)²·E(ω)`` of the module docstring (ω in rad/µs)."""
    w = 2.0 * np.pi * f_mhz
    h = 1j * w / ((a_per_us + 1j * w) ** 2 + (2.0 * np.pi * f0_mhz) ** 2)
    return np.asarray(h**2 / (1.0 + 1j * w * theta_us) ** 2)


def _band_6db(f_mhz: np.ndarray, magnitude: np.ndarray) -> tuple[float, float]:
    """(low, high) MHz where ``magnitude`` crosses half its peak on either side of the peak."""
    k = int(np.argmax(magnitude))
    half = 0.5 * magnitude[k]
    i = int(np.flatnonzero(magnitude[:k] < half)[-1])
    low = np.interp(half, magnitude[i : i + 2], f_mhz[i : i + 2])
    j = k + int(np.flatnonzero(magnitude[k:] < half)[0])
    high = np.interp(half, magnitude[j - 1 : j + 1][::-1], f_mhz[j - 1 : j + 1][::-1])
    return float(low), float(high)


@functools.lru_cache(maxsize=64)
def _solve_resonance(centre_mhz: float, fractional_bandwidth: float) -> tuple[float, float]:
    """(f0 MHz, a 1/µs) giving ``H²E`` its −6 dB band's middle at ``centre_mhz`` and width
    ``fractional_bandwidth·centre_mhz``."""
    theta_us = EXCITATION_CYCLES / centre_mhz
    f = np.linspace(0.01, 4.0, 8000) * centre_mhz

    def misfit(p: np.ndarray) -> np.ndarray:
        f0, a = centre_mhz * p[0], centre_mhz * p[1]
        low, high = _band_6db(f, np.abs(_resonance(f, f0, a, theta_us)))
        return np.array(
            [
                0.5 * (low + high) / centre_mhz - 1.0,
                (high - low) / centre_mhz - fractional_bandwidth,
            ]
        )

    # |H|² falls 6 dB where |H| falls 3 dB: about a half-width a/2π on each side
    start = np.array([1.0, np.pi * fractional_bandwidth])
    sol = optimize.least_squares(misfit, start, bounds=([0.3, 0.05], [3.0, 10.0]), xtol=1e-12)
    if not np.all(np.abs(misfit(sol.x)) < 1e-6):
        raise ValueError(
            f"no damped resonance gives a {fractional_bandwidth:g} fractional bandwidth "
            f"at {centre_mhz:g} MHz"
        )
    return float(centre_mhz * sol.x[0]), float(centre_mhz * sol.x[1])


def _within(name: str, value: float, lo: float, hi: float, unit: str = "") -> None:
    """ValueError naming ``name`` unless ``lo <= value <= hi``."""
    if not lo <= value <= hi:
        raise ValueError(f"{name} {value:g}{unit} out of {lo:g}…{hi:g}")


@dataclass(frozen=True)
class TransducerPulse:
    """The echo of a damped immersion transducer (module docstring): centre frequency (MHz,
    the middle of its −6 dB band) and −6 dB fractional bandwidth (0.2…1.2)."""

    centre_frequency_mhz: float
    fractional_bandwidth: float = 0.6

    def __post_init__(self) -> None:
        _within("centre frequency", self.centre_frequency_mhz, 0.1, 200.0, " MHz")
        _within("fractional bandwidth", self.fractional_bandwidth, 0.2, 1.2)

    def spectrum(self, f_mhz: np.ndarray) -> np.ndarray:
        """Complex spectrum of the echo at ``f_mhz`` (the response starts at t = 0)."""
        f0, a = _solve_resonance(self.centre_frequency_mhz, self.fractional_bandwidth)
        return _resonance(
            np.asarray(f_mhz, float), f0, a, EXCITATION_CYCLES / self.centre_frequency_mhz
        )


@dataclass(frozen=True)
class Digitiser:
    """Sample rate (MS/s, 1…10 000), resolution (bits, 4…24) and range (±``full_scale``)."""

    sample_rate_mhz: float = 200.0
    bits: int = 12
    full_scale: float = 1.0

    def __post_init__(self) -> None:
        _within("sample rate", self.sample_rate_mhz, 1.0, 10_000.0, " MS/s")
        _within("bits", self.bits, 4, 24)
        if not self.full_scale > 0.0:
            raise ValueError("full scale must be positive")

    @property
    def dt_ns(self) -> float:
        """Sample interval (ns)."""
        return 1e3 / self.sample_rate_mhz

    @property
    def lsb(self) -> float:
        """Quantisation step (the samples' units)."""
        return float(2.0 * self.full_scale / 2**self.bits)

    @property
    def rails(self) -> tuple[float, float]:
        """Lowest and highest value the digitiser returns."""
        return -(2 ** (self.bits - 1)) * self.lsb, (2 ** (self.bits - 1) - 1) * self.lsb

    def anti_alias(self, f_mhz: np.ndarray) -> np.ndarray:
        """Gain of the anti-alias filter (zero phase): 1 to 0.8·Nyquist, cos² to 0 at it."""
        nyquist = 0.5 * self.sample_rate_mhz
        x = np.clip((np.abs(f_mhz) / nyquist - ANTI_ALIAS_FLAT) / (1.0 - ANTI_ALIAS_FLAT), 0, 1)
        return np.asarray(np.cos(0.5 * np.pi * x) ** 2)

    def quantise(self, analog: np.ndarray) -> np.ndarray:
        """Round to the nearest level and hold at the rails."""
        top = 2 ** (self.bits - 1)
        return np.clip(np.round(analog / self.lsb), -top, top - 1) * self.lsb


@dataclass(frozen=True)
class EchoShape:
    """A pulse as a digitiser records it: arrival at t = 0, continuous peak 1.

    ``spectrum(f)`` is the band-limited echo's Fourier transform on that convention;
    ``arrival_offset_ns``: where the arrival sits after the transducer's response starts;
    ``scale``: 1 / the peak of ``irfft`` of the raw spectrum on the fine grid;
    ``pre_ns``/``post_ns``: the support (above ``SUPPORT_LEVEL`` of the peak) before and after
    the arrival; ``rms_bandwidth_mhz``: the Gabor bandwidth β (RMS frequency of ``|S|²`` about
    0 Hz); ``energy_ns``: ∫ s² dt; ``waveform``: s on the fine grid of ``waveform_dt_ns``, its
    arrival at sample ``len // 4``.
    """

    pulse: TransducerPulse
    digitiser: Digitiser
    arrival_offset_ns: float
    scale: float
    pre_ns: float
    post_ns: float
    rms_bandwidth_mhz: float
    energy_ns: float
    waveform_dt_ns: float = field(repr=False)
    waveform: np.ndarray = field(repr=False)

    def spectrum(self, f_mhz: np.ndarray) -> np.ndarray:
        """Fourier transform (per MHz) of the echo arriving at t = 0 with continuous peak 1."""
        f = np.asarray(f_mhz, float)
        s = self.pulse.spectrum(f) * self.digitiser.anti_alias(f)
        # ``scale`` is 1/peak of the waveform irfft(s) on the fine grid, i.e. of dt·p(t)
        s = s * (self.scale * self.waveform_dt_ns * 1e-3)
        return np.asarray(s * np.exp(2j * np.pi * f * self.arrival_offset_ns * 1e-3))


def echo_shape(pulse: TransducerPulse, digitiser: Digitiser) -> EchoShape:
    """The digitised echo of ``pulse`` with its arrival (module docstring) at t = 0.

    Computed on a grid 32 times finer than the digitiser's over 128 cycles; the arrival is the
    maximum of the twin correlation, first on that grid, then by a bounded scalar search over
    its exact Fourier sum.
    """
    fc = pulse.centre_frequency_mhz
    dt_ns = digitiser.dt_ns / 32.0
    n = fft.next_fast_len(int(128e3 / fc / dt_ns))
    f = fft.rfftfreq(n, dt_ns * 1e-3)  # MHz
    s = pulse.spectrum(f) * digitiser.anti_alias(f)
    twin = fft.irfft(np.abs(s) * s, n)
    k = int(np.argmax(twin[: n // 2]))  # the response starts at 0 and decays within n/2

    def minus_twin(tau_ns: float) -> float:
        phase = np.exp(2j * np.pi * f * tau_ns * 1e-3)
        return -float(np.sum(np.abs(s[1:]) * (s[1:] * phase[1:]).real))

    found = optimize.minimize_scalar(
        minus_twin,
        bounds=((k - 1) * dt_ns, (k + 1) * dt_ns),
        method="bounded",
        options={"xatol": 1e-7},
    )
    arrival_ns = float(found.x)
    # the waveform with the arrival at sample n // 4 of the fine grid, to find peak and support
    shift_ns = arrival_ns - (n // 4) * dt_ns
    wave = fft.irfft(s * np.exp(2j * np.pi * f * shift_ns * 1e-3), n)
    peak = float(np.max(np.abs(wave)))
    above = np.flatnonzero(np.abs(wave) > SUPPORT_LEVEL * peak)
    pre_ns = (n // 4 - above[0]) * dt_ns
    post_ns = (above[-1] - n // 4) * dt_ns
    power = np.abs(s) ** 2
    beta_mhz = math.sqrt(float(np.sum(f**2 * power) / np.sum(power)))
    energy_ns = float(np.sum((wave / peak) ** 2) * dt_ns)
    return EchoShape(
        pulse,
        digitiser,
        arrival_ns,
        1.0 / peak,
        float(pre_ns),
        float(post_ns),
        beta_mhz,
        energy_ns,
        dt_ns,
        wave / peak,
    )


def synthesise(
    shape: EchoShape,
    rng: np.random.Generator,
    *,
    t0_ns: float,
    n_samples: int,
    arrival_ns: Sequence[float] | np.ndarray,
    amplitude: float,
    noise_rms: float,
    echoes: Sequence[tuple[float, float]] = (),
    antithetic: bool = False,
) -> list[AScan]:
    """A-scans of ``n_samples`` from ``t0_ns``, one per arrival in ``arrival_ns`` (ns).

    Each holds the echo of ``amplitude`` at its arrival (anywhere from the echo's support
    before the record to as long after it) plus, for each ``(delay_ns,
    relative_amplitude)`` in ``echoes``, another of the same shape that much later (a second
    face in the gate), white noise of ``noise_rms``, then the digitiser's quantisation and
    rails. With ``antithetic`` the records come in pairs sharing one arrival and opposite
    noise (``arrival_ns`` gives one arrival per pair): the first-order effect of the noise
    cancels in a pair's mean, which measures an estimator's bias with far fewer records.
    """
    dig = shape.digitiser
    dt = dig.dt_ns
    arrivals = np.asarray(arrival_ns, float)
    margin = math.ceil((shape.pre_ns + shape.post_ns) / dt)
    max_delay = max((d for d, _ in echoes), default=0.0)
    n_fft = fft.next_fast_len(n_samples + 2 * margin + math.ceil(max_delay / dt))
    f = fft.rfftfreq(n_fft, dt * 1e-3)
    base = shape.spectrum(f) / (dt * 1e-3)  # the DFT of the samples of s(t)
    spectra = np.exp(-2j * np.pi * np.outer(arrivals - t0_ns, f) * 1e-3)
    spectra *= (
        1.0 + sum(a * np.exp(-2j * np.pi * f * d * 1e-3) for d, a in echoes) if echoes else 1.0
    )
    clean = fft.irfft(amplitude * base * spectra, n_fft, axis=-1)[:, :n_samples]
    if antithetic:
        clean = np.repeat(clean, 2, axis=0)
        noise = noise_rms * rng.standard_normal((arrivals.size, n_samples))
        noise = np.stack([noise, -noise], axis=1).reshape(-1, n_samples)
    else:
        noise = noise_rms * rng.standard_normal(clean.shape)
    records = dig.quantise(clean + noise)
    return [AScan(t0_ns, dt, row, rails=dig.rails, lsb=dig.lsb) for row in records]


def true_delay_crb_ns(shape: EchoShape, amplitude: float, noise_rms: float) -> float:
    """Cramér–Rao bound (ns) of the delay of an echo of ``amplitude`` in white noise of
    ``noise_rms``, plus the digitiser's quantisation noise LSB²/12:
    ``1 / (2π·β·√(E/σ²))``, E the echo's energy in the samples (``ucal.echo.timing``)."""
    variance = noise_rms**2 + shape.digitiser.lsb**2 / 12.0
    energy = amplitude**2 * shape.energy_ns / shape.digitiser.dt_ns
    return 1.0 / (2.0 * math.pi * shape.rms_bandwidth_mhz * 1e-3 * math.sqrt(energy / variance))


def gate_around(shape: EchoShape, arrival_ns: float, noise_samples: int = 256) -> tuple[float, int]:
    """``(t0_ns, n_samples)`` of a record holding the whole echo arriving near ``arrival_ns``
    (its support, one sample either side for a sub-sample shift) and ``noise_samples`` of
    noise, half before it, half after; t0 on the digitiser's sample clock."""
    dt = shape.digitiser.dt_ns
    first = math.floor((arrival_ns - shape.pre_ns) / dt) - 1 - noise_samples // 2
    n = math.ceil((shape.pre_ns + shape.post_ns) / dt) + 2 + noise_samples
    return first * dt, n
