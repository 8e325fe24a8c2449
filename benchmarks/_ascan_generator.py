"""A-scans from a generator that is not ucal's (``ucal.sim.ascan``), for the echo estimator's
benchmark (``echo_timing.py``) and tests.

The echo is written in the frequency domain and evaluated at each sample time by its Fourier
integral on a fine grid, so it is band-limited by construction and a delay is exact at any
sub-sample position; no FFT of the record, no model the estimator shares:

* the transducer: a skewed Gaussian amplitude ``(f/f_c)^SKEW·exp(−(f − f_c)²/2w²)`` (w from
  the asked −6 dB fractional bandwidth), a cubic phase across the band (an asymmetric echo),
  and a backing reverberation ``1/(1 − ρ·exp(−i2πfT))`` (T one period: the echo rings);
* the water: ``exp(−κ·f²)`` in amplitude for κ Np/MHz² (α ∝ f², no dispersion;
  ``kappa_of_water_mm``: 2.17e-3 dB/(cm·MHz²) at 20 °C, Pinkerton 1949 as Szabo's power law
  gives it, over the round trip);
* the digitiser: an analogue filter falling as cos² from 0.7 to 0.95 of the Nyquist
  frequency, white Gaussian noise, a DC offset, ``bits`` over ±1 with rails.

Every draw comes from the caller's ``numpy.random.Generator``.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from ucal.echo import AScan

#: Water's attenuation at 20 °C, dB per mm per MHz² (2.17e-3 dB/(cm·MHz²)).
ALPHA_WATER_DB_PER_MM_MHZ2 = 2.17e-4
SKEW = 1.5
CUBIC_PHASE_RAD = 1.2
RING = 0.35


def kappa_of_water_mm(extra_water_mm: float) -> float:
    """κ (Np/MHz²) of ``extra_water_mm`` more water on the way out and back."""
    return 2.0 * extra_water_mm * ALPHA_WATER_DB_PER_MM_MHZ2 / (20.0 / math.log(10.0))


@dataclass(frozen=True)
class Pulse:
    """One transducer's echo digitised at ``rate_mhz``."""

    fc_mhz: float
    rate_mhz: float
    fractional_bandwidth: float = 0.6

    @property
    def dt_ns(self) -> float:
        return 1e3 / self.rate_mhz

    def spectrum(self, f_mhz: np.ndarray, kappa: float = 0.0) -> np.ndarray:
        """The echo's spectrum at ``f_mhz`` (its time origin at 0), κ Np/MHz² of water."""
        w = self.width_mhz
        u = (f_mhz - self.fc_mhz) / self.fc_mhz
        amplitude = (f_mhz / self.fc_mhz) ** SKEW * np.exp(-0.5 * ((f_mhz - self.fc_mhz) / w) ** 2)
        ring = 1.0 / (1.0 - RING * np.exp(-2j * np.pi * f_mhz / self.fc_mhz))
        nyquist = 0.5 * self.rate_mhz
        x = np.clip((f_mhz / nyquist - 0.7) / 0.25, 0.0, 1.0)
        analogue = np.cos(0.5 * np.pi * x) ** 2
        phase = CUBIC_PHASE_RAD * u**3
        return amplitude * ring * analogue * np.exp(1j * phase - kappa * f_mhz**2)

    @functools.cached_property
    def width_mhz(self) -> float:
        return self.fractional_bandwidth * self.fc_mhz / (2.0 * math.sqrt(2.0 * math.log(2.0)))

    def frequencies(self) -> np.ndarray:
        """The integral's grid: to 8 widths above the centre (the rest is below 1e-13), at
        1/(4·50 periods), so the integral's own period is far beyond any record."""
        top = min(0.5 * self.rate_mhz, self.fc_mhz + 8.0 * self.width_mhz)
        return np.arange(1, math.ceil(top / self.fc_mhz * 200.0)) * self.fc_mhz / 200.0

    def waveforms(
        self, t_ns: np.ndarray, delays_ns: np.ndarray, kappa: float = 0.0, derivative: bool = False
    ) -> np.ndarray:
        """The echo (peak about 1 at κ = 0) delayed by each of ``delays_ns`` at ``t_ns``, one
        row a delay, or its derivative with respect to the delay (per ns)."""
        f = self.frequencies()
        s = self.spectrum(f, kappa) * (f[1] - f[0]) * 2.0
        if derivative:
            s = s * (-2j * np.pi * f * 1e-3)
        t0 = float(t_ns[0])
        basis = np.exp(2j * np.pi * np.outer((t_ns - t0) * 1e-3, f))
        shifts = s[:, None] * np.exp(-2j * np.pi * np.outer(f, (np.asarray(delays_ns) - t0) * 1e-3))
        return (basis @ shifts).real.T / self.peak

    @functools.cached_property
    def peak(self) -> float:
        f = self.frequencies()
        s = self.spectrum(f) * (f[1] - f[0]) * 2.0
        t = np.linspace(-200.0, 200.0, 4001) / self.fc_mhz
        return float(np.max(np.abs((np.exp(2j * np.pi * np.outer(t * 1e-3, f)) @ s).real)))

    def span_ns(self) -> tuple[float, float]:
        """Where the echo is (ns about its origin): its reverberation decays by 1e-4."""
        period = 1e3 / self.fc_mhz
        return -3.0 * period, (3.0 + math.log(1e-4) / math.log(RING)) * period


@dataclass(frozen=True)
class Digitiser:
    bits: int = 12
    offset: float = 0.0

    @property
    def lsb(self) -> float:
        return 2.0 / 2**self.bits

    def digitise(self, clean: np.ndarray, noise: float, rng: np.random.Generator) -> np.ndarray:
        x = clean + self.offset + noise * rng.standard_normal(clean.shape)
        codes = np.clip(np.round(x / self.lsb), -(2 ** (self.bits - 1)), 2 ** (self.bits - 1) - 1)
        return codes * self.lsb


def record_axis(pulse: Pulse, arrival_ns: float, margin_periods: float = 10.0) -> np.ndarray:
    """Sample times around an echo at ``arrival_ns``: its span and a margin of noise."""
    lo, hi = pulse.span_ns()
    pad = margin_periods * 1e3 / pulse.fc_mhz
    first = math.floor((arrival_ns + lo - pad) / pulse.dt_ns)
    last = math.ceil((arrival_ns + hi + pad) / pulse.dt_ns)
    return np.arange(first, last + 1) * pulse.dt_ns


def records(
    pulse: Pulse,
    rng: np.random.Generator,
    t_ns: np.ndarray,
    delays_ns: np.ndarray,
    *,
    amplitude: float,
    noise: float,
    digitiser: Digitiser = Digitiser(),
    kappa: float = 0.0,
    second: tuple[float, float] | None = None,
) -> list[AScan]:
    """One record per delay; ``second``: (relative height, delay after the first, ns) of
    another echo of the same shape."""
    delays_ns = np.asarray(delays_ns, float)
    clean = amplitude * pulse.waveforms(t_ns, delays_ns, kappa)
    if second is not None:
        clean += second[0] * amplitude * pulse.waveforms(t_ns, delays_ns + second[1], kappa)
    return [
        AScan(float(t_ns[0]), pulse.dt_ns, digitiser.digitise(row, noise, rng), lsb=digitiser.lsb)
        for row in clean
    ]


def delay_bound_ns(
    pulse: Pulse,
    t_ns: np.ndarray,
    arrival_ns: float,
    amplitude: float,
    noise: float,
    lsb: float,
    kappa: float = 0.0,
) -> float:
    """Cramér–Rao bound of the delay for the true echo in white noise (quantisation LSB²/12
    included): σ / (A·√Σ s'(t_n)²)."""
    slope = pulse.waveforms(t_ns, np.array([arrival_ns]), kappa, derivative=True)[0]
    variance = noise**2 + lsb**2 / 12.0
    return math.sqrt(variance) / (amplitude * math.sqrt(float(np.sum(slope**2))))


def pair_bound_ns(
    pulse: Pulse,
    t_ns: np.ndarray,
    arrival_ns: float,
    amplitude: float,
    second: tuple[float, float],
    noise: float,
    lsb: float,
) -> float:
    """Cramér–Rao bound of the first delay with another echo (relative height, delay after
    it in ns) over it, both delays and amplitudes unknown: √(σ²·(JᵀJ)⁻¹₀₀)."""
    delays = np.array([arrival_ns, arrival_ns + second[1]])
    shapes = pulse.waveforms(t_ns, delays)
    slopes = pulse.waveforms(t_ns, delays, derivative=True)
    heights = amplitude * np.array([1.0, second[0]])
    jacobian = np.column_stack(
        [heights[0] * slopes[0], shapes[0], heights[1] * slopes[1], shapes[1]]
    )
    covariance = np.linalg.inv(jacobian.T @ jacobian)
    return math.sqrt((noise**2 + lsb**2 / 12.0) * covariance[0, 0])
