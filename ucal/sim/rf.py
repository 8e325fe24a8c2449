"""The receiver's RF output as an oscilloscope records it: the simulated cell's echo as a waveform.

The simulated scope (``drivers.digitizer.scpi_simulator``) asks for the analog input of its
channel over a record (start, sample interval, length, averages); ``ucal.sim.serve`` answers
with :meth:`RfOutput.record`, from the echo the cell gives at that instant (amplitude as a
fraction of full screen height, round-trip time of flight):

* the echo has ``ucal.sim.ascan``'s pulse shape (a damped resonance acting twice, ringing and
  asymmetric: not the estimator's Gaussian), its arrival at the cell's time of flight and its
  continuous peak at the cell's amplitude, band-limited by an anti-alias filter at the record's
  sample rate (``ucal.sim.ascan.Digitiser``); it is synthesised over its own support only and
  placed in the record, so a long gate costs little;
* the other echoes of the acquisition (``ucal.sim.cell.SimulatedCell.echoes``: the multiple,
  another face's echo, a corner's) follow it with their delays and relative heights
  (``later_echoes``), the same pulse shape each;
* white Gaussian noise is added to every sample: the receiver's noise, ``noise_floor`` (the
  cell's: the peak of the noise envelope over a 200 µs gate at 20 dB, ``ucal.sim.cell``) over
  ``FLOOR_PEAK_PER_SIGMA``, scaled by the gain and divided by √averages;
* ``FULL_SCREEN_V`` volts are full screen height (``drivers.pulser.ascii.AsciiScpiPulser``'s
  default ``full_screen_v``); the scope quantises and clips.

An echo outside the record is not in it; without an echo the record is noise. Every draw comes
from the generator seeded ``(world seed, RF_STREAM)``, in the order the acquisitions come.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Sequence

import numpy as np
from scipy import fft

from ucal import acoustics
from ucal.sim.ascan import Digitiser, EchoShape, TransducerPulse, echo_shape

#: RF output (V) of an echo at full screen height.
FULL_SCREEN_V = 1.0
#: Peak of the noise envelope over a 200 µs gate at 200 MS/s per sigma of one sample:
#: √(2 ln 40 000) (``ucal.sim.cell``'s noise-floor model).
FLOOR_PEAK_PER_SIGMA = 4.6
#: Random stream of the RF noise (``ucal.sim.cell`` uses 1 … 5).
RF_STREAM = 101
#: The scope's link: bits per second of a waveform transfer, and its turnaround (s).
LINK_BIT_S = 100e6
SCOPE_TURNAROUND_S = 0.002


def transfer_s(points: int, bytes_per_point: int = 2) -> float:
    """Time a scope takes to hand over a record of ``points`` samples (s)."""
    return SCOPE_TURNAROUND_S + points * bytes_per_point * 8 / LINK_BIT_S


def later_echoes(echoes: Sequence[tuple[float, float]]) -> list[tuple[float, float]]:
    """The echoes after the first of ``SimulatedCell.echoes`` (``[(tof_ns, amplitude), ...]``,
    the main one first) as ``(delay_ns, relative_amplitude)`` from it: they follow the main
    echo the instrument measured, its trigger jitter, gain error and averaging noise."""
    if len(echoes) < 2 or not echoes[0][1] > 0.0:
        return []
    tof0, amplitude0 = echoes[0]
    return [(tof - tof0, amplitude / amplitude0) for tof, amplitude in echoes[1:]]


class RfOutput:
    """The receiver's output for records of the scope (module docstring): echoes of
    ``centre_frequency_mhz`` with ``fractional_bandwidth``, noise seeded ``seed``."""

    def __init__(
        self,
        centre_frequency_mhz: float,
        noise_floor_fsh: float,
        seed: int,
        fractional_bandwidth: float = 0.6,
    ):
        self.pulse = TransducerPulse(centre_frequency_mhz, fractional_bandwidth)
        self.noise_floor_fsh = float(noise_floor_fsh)
        self._rng = np.random.default_rng([int(seed), RF_STREAM])
        self._lock = threading.Lock()
        self._shapes: dict[float, EchoShape] = {}
        self._spectra: dict[tuple[float, int], np.ndarray] = {}

    def shape(self, dt_ns: float) -> EchoShape:
        """The echo as a record sampled every ``dt_ns`` holds it (arrival at 0, peak 1)."""
        shape = self._shapes.get(dt_ns)
        if shape is None:
            shape = echo_shape(self.pulse, Digitiser(sample_rate_mhz=1e3 / dt_ns))
            self._shapes[dt_ns] = shape
        return shape

    def _spectrum(self, dt_ns: float, n_fft: int) -> np.ndarray:
        """The DFT of the samples of the echo arriving at t = 0, on ``n_fft`` points."""
        key = (dt_ns, n_fft)
        spectrum = self._spectra.get(key)
        if spectrum is None:
            f_mhz = fft.rfftfreq(n_fft, dt_ns * 1e-3)
            spectrum = self.shape(dt_ns).spectrum(f_mhz) / (dt_ns * 1e-3)
            self._spectra[key] = spectrum
        return spectrum

    def noise_rms_fsh(self, gain_db: float, averages: int) -> float:
        """One sigma of the receiver's noise in one sample (fraction of full screen)."""
        g = acoustics.gain_factor(gain_db)
        return self.noise_floor_fsh * g / FLOOR_PEAK_PER_SIGMA / math.sqrt(max(averages, 1))

    def record(
        self,
        t0_ns: float,
        dt_ns: float,
        n: int,
        amplitude_fsh: float,
        tof_ns: float,
        noise_rms_fsh: float,
        later: Sequence[tuple[float, float]] = (),
    ) -> np.ndarray:
        """Volts of ``n`` samples from ``t0_ns`` every ``dt_ns``: the echo of
        ``amplitude_fsh`` arriving at ``tof_ns`` (NaN: none), the other echoes of the
        acquisition, ``later`` = ``(delay_ns, relative_amplitude)`` after and relative to it
        (``later_echoes``), plus the noise."""
        with self._lock:
            noise = self._rng.standard_normal(n)
        out = noise * noise_rms_fsh
        if math.isfinite(tof_ns) and amplitude_fsh > 0.0:
            self._add_echo(out, t0_ns, dt_ns, amplitude_fsh, tof_ns)
            for delay_ns, relative in later:
                self._add_echo(out, t0_ns, dt_ns, amplitude_fsh * relative, tof_ns + delay_ns)
        return out * FULL_SCREEN_V

    def _add_echo(
        self, out: np.ndarray, t0_ns: float, dt_ns: float, amplitude: float, arrival_ns: float
    ) -> None:
        shape = self.shape(dt_ns)
        first = max(0, math.floor((arrival_ns - shape.pre_ns - t0_ns) / dt_ns) - 2)
        stop = min(out.size, math.ceil((arrival_ns + shape.post_ns - t0_ns) / dt_ns) + 3)
        if stop <= first:
            return  # the echo is outside the record
        m = stop - first
        support = math.ceil((shape.pre_ns + shape.post_ns) / dt_ns) + 8
        # no wrap-around into the segment: the support fits in the padding either side
        n_fft = fft.next_fast_len(m + support)
        spectrum = self._spectrum(dt_ns, n_fft)
        f_mhz = fft.rfftfreq(n_fft, dt_ns * 1e-3)
        delay_us = (arrival_ns - (t0_ns + first * dt_ns)) * 1e-3
        segment = fft.irfft(spectrum * np.exp(-2j * np.pi * f_mhz * delay_us), n_fft)[:m]
        out[first:stop] += amplitude * segment
