"""The cell's reference echo: many captures aligned and averaged, its arrival put at t = 0.

Arrival. An asymmetric, ringing echo has no single obvious time: its envelope peak, its energy
centroid and its strongest cycle differ by a fraction of its length. ucal's convention
(``echo_arrival_ns``) is the time at which the echo best matches its own zero-phase twin, the
symmetric pulse with the same amplitude spectrum: the maximum of

    c(τ) = Re ∫ |S(f)|·S(f)·exp(i2πfτ) df,

the correlation of the echo with that twin. For a symmetric pulse it is the centre; it is a
property of the shape alone (the same echo later arrives that much later), and it follows the
carrier, so the noise left in an averaged echo moves it about as little as it moves a matched
filter's delay. The energy centroid, the obvious alternative, is an envelope quantity that
the same noise moves several times more, and a reference's error in t = 0 is an error in
every time of flight timed against it. The simulated digitiser (``ucal.sim.ascan``) defines
its echoes' arrival the same way, from their exact spectrum.

Building (``build_reference``). The captures are echoes of one reflector at one posture, many
shots (a digitiser's averaging, or a burst of records), each record holding the whole echo
(its mean is taken as the digitiser's offset: an echo sums to 0). The first capture's echo,
cut where its envelope exceeds a tenth of its peak, times all of them by their correlation's
peak (``ucal.echo.timing.correlation_tof_ns``: one echo at one posture, so no second echo is
sought behind the first round's crude template, as a reading's estimate would);
each is shifted by its own delay (band-limited, sub-sample) onto a common axis and the shifted
records are averaged; the average times them again, three rounds in all, so the shot-to-shot
jitter does not smear it. The average is cut to the run of samples around its envelope's peak that
stands above 4 times the noise left in it (the captures' scatter about it, over √M), widened
by a quarter and tapered there; its arrival is put at t = 0, with the twin correlation summed
over the echo's band (above that noise), where noise alone would pull it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from scipy import fft, signal

from ucal.echo.ascan import AScan, ReferenceEcho
from ucal.echo.spectral import series_peak
from ucal.echo.timing import correlation_tof_ns

#: Alignment rounds of ``build_reference``.
ROUNDS = 3
#: The average is kept where its envelope is above this many times its noise (and 1e-4 of
#: its peak), plus a margin of a quarter of that length on each side, tapered.
KEEP_NOISE_FACTOR = 4.0
KEEP_LEVEL = 1e-4
#: Samples kept clear of each record's ends when averaging.
EDGE = 32


def echo_arrival_ns(
    t0_ns: float, dt_ns: float, samples: np.ndarray, noise_rms: float = 0.0
) -> float:
    """Arrival (ns) of the echo in ``samples`` (sample k at ``t0_ns + k·dt_ns``): the maximum of
    its correlation with its zero-phase twin (module docstring), within the record.

    With ``noise_rms`` (white noise left in the samples) the correlation is summed over the
    bins above 4 times that noise's expected power, n·σ², only: a bin that holds only noise
    would weight the noise's phase by its own power, and far above the echo's band its slope
    would pull the peak.
    """
    n = samples.size
    n_fft = fft.next_fast_len(2 * n)
    spectrum = fft.rfft(samples, n_fft)
    twin = np.where(np.abs(spectrum) ** 2 >= 4.0 * n * noise_rms**2, spectrum, 0.0)
    twin[0] = 0.0  # an offset is not the echo
    twin = twin * np.abs(spectrum)
    series = fft.irfft(twin, n_fft)[:n]
    lag, _ = series_peak(twin, n_fft, float(np.argmax(series)))
    return t0_ns + lag * dt_ns


def build_reference(
    captures: Sequence[AScan], *, gate_ns: tuple[float, float] | None = None
) -> ReferenceEcho:
    """The averaged echo of ``captures`` (same interval; the echo in ``gate_ns``, default
    the whole record) with its arrival at t = 0 (module docstring).

    Raises ``ValueError`` for no captures, captures of different intervals, or captures that
    do not share the averaged window around their echoes.
    """
    if not captures:
        raise ValueError("no captures to build a reference echo from")
    dt = captures[0].dt_ns
    if any(abs(c.dt_ns - dt) > 1e-9 * dt for c in captures):
        raise ValueError("the captures of a reference echo must share one sample interval")
    template = _first_cut(captures[0], gate_ns)
    for _ in range(ROUNDS):
        template = _average(captures, template, gate_ns)
    arrival = echo_arrival_ns(template.t0_ns, dt, template.samples, template.noise_rms)
    # ReferenceEcho normalised the template's samples and noise: build from them as they are
    return ReferenceEcho(
        template.t0_ns - arrival, dt, template.samples, template.noise_rms, len(captures)
    )


def _first_cut(capture: AScan, gate_ns: tuple[float, float] | None) -> ReferenceEcho:
    """The capture's echo where its envelope exceeds a tenth of its peak, t = 0 at the peak."""
    x = capture.samples - np.mean(capture.samples)
    envelope = np.abs(signal.hilbert(x))
    t = capture.t_ns
    allowed = np.ones(capture.n, bool) if gate_ns is None else (t >= gate_ns[0]) & (t <= gate_ns[1])
    if not allowed.any():
        raise ValueError(f"the gate {gate_ns} ns holds no sample of the first capture")
    k = int(np.flatnonzero(allowed)[np.argmax(envelope[allowed])])
    below = envelope < 0.1 * envelope[k]
    start = k - int(np.argmax(below[k::-1])) if below[: k + 1].any() else 0
    stop = k + int(np.argmax(below[k:])) if below[k:].any() else capture.n
    return ReferenceEcho(float(t[start] - t[k]), capture.dt_ns, x[start:stop])


def _average(
    captures: Sequence[AScan], template: ReferenceEcho, gate_ns: tuple[float, float] | None
) -> ReferenceEcho:
    """Time every capture against ``template``, average them on a common axis around their
    echoes (the template's span, widened by its length on each side, within every record
    and ``EDGE`` samples from its ends), and cut the average to its echo."""
    dt = template.dt_ns
    tofs = np.array([correlation_tof_ns(c, template, gate_ns=gate_ns) for c in captures])
    span = template.n * dt
    start = template.t0_ns - span
    stop = template.t0_ns + 2.0 * span
    for c, tof in zip(captures, tofs, strict=True):
        # a sub-sample shift rings near a record's ends (its noise stops there): keep away
        start = max(start, c.t0_ns - tof + EDGE * dt)
        stop = min(stop, c.t0_ns + (c.n - 1 - EDGE) * dt - tof)
    m = math.floor((stop - start) / dt) + 1
    if m < 8:
        raise ValueError("the captures do not share a window around their echoes")
    rows = np.empty((len(captures), m))
    for i, (c, tof) in enumerate(zip(captures, tofs, strict=True)):
        position = (tof + start - c.t0_ns) / dt  # of the window's first sample in the record
        whole = math.floor(position)
        n_fft = fft.next_fast_len(c.n + 2 * EDGE)
        x = c.samples - np.mean(c.samples)  # an echo sums to 0: the mean is the offset
        omega = 2.0 * np.pi * np.arange(n_fft // 2 + 1) / n_fft
        moved = fft.irfft(fft.rfft(x, n_fft) * np.exp(1j * omega * (position - whole)), n_fft)
        rows[i] = moved[whole : whole + m]
    average = rows.mean(axis=0)
    k = len(captures)
    noise = float(np.sqrt(np.mean((rows - average) ** 2) * k / max(k - 1, 1) / k))
    # the echo: the run of samples around the envelope's peak above 4 times that noise
    envelope = np.abs(signal.hilbert(average))
    peak = int(np.argmax(envelope))
    below = envelope < max(KEEP_NOISE_FACTOR * noise, KEEP_LEVEL * float(envelope[peak]))
    first = peak - int(np.argmax(below[peak::-1])) + 1 if below[: peak + 1].any() else 0
    last = peak + int(np.argmax(below[peak:])) if below[peak:].any() else m
    # widened by a quarter on each side where the window allows, tapered over what was added
    margin = max(4, (last - first) // 4)
    before, after = min(margin, first), min(margin, m - last)
    taper = np.ones(last - first + before + after)
    taper[:before] = signal.windows.hann(2 * before + 1)[:before]
    taper[taper.size - after :] = signal.windows.hann(2 * after + 1)[after + 1 :]
    first, last = first - before, last + after
    return ReferenceEcho(start + first * dt, dt, average[first:last] * taper, noise, k)
