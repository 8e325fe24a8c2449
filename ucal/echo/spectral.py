"""Band-limited signals through their DFTs: the peak of a Fourier series, a sub-sample shift.

A record padded with zeros to ``n_fft`` samples and seen through its DFT is its band-limited
interpolation: ``c(τ) = (1/n)·Σ_k w_k·Re(C_k·exp(iω_kτ))`` (ω_k = 2πk/n, τ in samples, w 1 at
DC and 2 above, 0 at the Nyquist bin, where a band-limited echo carries nothing). The peak of a
cross-correlation so written is found by Newton's method on that sum, exactly, where a parabola
through three samples is exact only for a parabola.
"""

from __future__ import annotations

import functools

import numpy as np
from scipy import fft


def _weights(n_bins: int, n_fft: int) -> np.ndarray:
    w = np.full(n_bins, 2.0)
    w[0] = 1.0
    if n_fft % 2 == 0:
        w[-1] = 0.0
    return w


@functools.lru_cache(maxsize=32)
def _grid(n_bins: int, n_fft: int) -> tuple[np.ndarray, ...]:
    """The bins' ω (rad per sample), iω, −iω, ω² and weights for ``n_bins`` bins of an
    ``n_fft`` DFT, read-only: a record's correlations are refined again and again on one grid."""
    omega = 2.0 * np.pi * np.arange(n_bins) / n_fft
    arrays = (omega, 1j * omega, -1j * omega, omega**2, _weights(n_bins, n_fft))
    for a in arrays:
        a.flags.writeable = False
    return arrays


def series_peak(
    spectrum: np.ndarray, n_fft: int, lag: float, max_iterations: int = 30
) -> tuple[float, float]:
    """Refine ``lag`` (samples) to the nearest maximum of the real series of ``spectrum``
    (the ``rfft`` of a record padded to ``n_fft``); returns ``(lag, value)``.

    Newton steps on the series and its first two derivatives, each at most half a sample,
    until a step is below 1e-9 samples. Start within half a sample of the peak (the largest
    sample of the series): there the series is concave for any echo sampled above Nyquist.
    """
    omega, i_omega, _, omega2, weights = _grid(spectrum.size, n_fft)
    weighted = spectrum * weights
    for _ in range(max_iterations):
        z = weighted * np.exp(i_omega * lag)
        slope = -float(np.sum(omega * z.imag))
        curvature = -float(np.sum(omega2 * z.real))
        if curvature >= 0.0:
            break
        step = float(np.clip(-slope / curvature, -0.5, 0.5))
        lag += step
        if abs(step) < 1e-9:
            break
    value = float(np.sum((weighted * np.exp(i_omega * lag)).real)) / n_fft
    return lag, value


def shifted(spectrum: np.ndarray, n_fft: int, delay: float, derivative: bool = False) -> np.ndarray:
    """The record of ``spectrum`` (``rfft``, padded to ``n_fft``) delayed by ``delay`` samples
    (band-limited; what leaves the end comes back at the start), or its derivative with
    respect to the delay."""
    minus_i_omega = _grid(spectrum.size, n_fft)[2]
    s = spectrum * np.exp(minus_i_omega * delay)
    if derivative:
        s = s * minus_i_omega
    if n_fft % 2 == 0:
        s[-1] = 0.0
    return np.asarray(fft.irfft(s, n_fft))


def evaluate(samples: np.ndarray, positions: np.ndarray, chunk: int = 256) -> np.ndarray:
    """Band-limited interpolation of ``samples`` at fractional ``positions`` (in samples),
    with zeros outside the record (the record padded to twice its length)."""
    n_fft = fft.next_fast_len(2 * samples.size)
    spectrum = fft.rfft(samples, n_fft) * _weights(n_fft // 2 + 1, n_fft)
    omega = 2.0 * np.pi * np.arange(spectrum.size) / n_fft
    out = np.empty(positions.size)
    for i in range(0, positions.size, chunk):
        p = positions[i : i + chunk]
        out[i : i + chunk] = (np.exp(1j * np.outer(p, omega)) @ spectrum).real / n_fft
    return out
