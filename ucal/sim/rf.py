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
* through water (world ``[water] absorption``; off by default, every echo of the one shape
  above): each echo's spectrum times the water's transfer over its own path, both ways,
  ``exp(−2·α₀(T)·f²·L)`` (``water_np_per_mm_mhz2``), then scaled back to its peak: the
  transducer's ringing echo as it arrives through L of water, its spectrum moved down and its
  cycles broadened the more the longer the path (a 25 MHz, 60 % band transducer: the −6 dB
  band's middle 20.1 MHz at 50 mm, 16.4 MHz at 100 mm, 13.8 MHz at 150 mm), the multiple's
  through twice the main one's. The transfer is
  real and even (its dispersion, by Kramers–Kronig for f², is far below a picosecond over
  these paths), so the echo keeps its arrival;
* the receiver's output at rest (world ``[pulser] baseline_offset``, fraction of full screen)
  is in every sample;
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
#: Water's absorption α/f² at 20 °C: 2.17e-4 dB/(mm·MHz²) (Pinkerton 1949, the power law of
#: Szabo, *Diagnostic Ultrasound Imaging*, 2004).
WATER_DB_PER_MM_MHZ2 = 2.17e-4
#: An echo through water broadens by a Gaussian of this σ per √κ; its support is widened by
#: this many of them on either side.
BROADENING_SIGMAS = 8.0


def water_np_per_mm_mhz2(temperature_c: float) -> float:
    """Water's amplitude absorption α₀ = α/f² (Np per mm and MHz², one way) at
    ``temperature_c``: ``WATER_DB_PER_MM_MHZ2`` at 20 °C, following the temperature as the
    pure-water term A₃(T) of Francois & Garrison (1982, J. Acoust. Soc. Am. 72, 1879–1890)
    does (−2.9 % per °C at 20 °C, 0–40 °C)."""

    def a3(t: float) -> float:
        if t <= 20.0:
            return 4.937e-4 - 2.59e-5 * t + 9.11e-7 * t**2 - 1.50e-8 * t**3
        return 3.964e-4 - 1.146e-5 * t + 1.45e-7 * t**2 - 6.5e-10 * t**3

    db = WATER_DB_PER_MM_MHZ2 * a3(float(temperature_c)) / a3(20.0)
    return db * math.log(10.0) / 20.0


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
    ``centre_frequency_mhz`` with ``fractional_bandwidth``, noise seeded ``seed``; with
    ``water_absorption`` each echo through its own water path, ``baseline_offset`` (fraction
    of full screen) in every sample."""

    def __init__(
        self,
        centre_frequency_mhz: float,
        noise_floor_fsh: float,
        seed: int,
        fractional_bandwidth: float = 0.6,
        *,
        water_absorption: bool = False,
        baseline_offset: float = 0.0,
    ):
        self.pulse = TransducerPulse(centre_frequency_mhz, fractional_bandwidth)
        self.noise_floor_fsh = float(noise_floor_fsh)
        self.water_absorption = bool(water_absorption)
        self.baseline_offset = float(baseline_offset)
        self._rng = np.random.default_rng([int(seed), RF_STREAM])
        self._lock = threading.Lock()
        self._shapes: dict[float, EchoShape] = {}
        self._spectra: dict[tuple[float, int], np.ndarray] = {}
        self._fine: dict[float, tuple[np.ndarray, np.ndarray, int]] = {}

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

    def kappa(self, water_path_mm: float, temperature_c: float) -> float:
        """The water's transfer ``exp(−κ·f²)`` of an echo through ``water_path_mm`` (one way)
        and back at ``temperature_c``: κ = 2·α₀(T)·L (Np/MHz²); 0 without absorption."""
        if not self.water_absorption or not water_path_mm > 0.0:
            return 0.0
        return 2.0 * water_np_per_mm_mhz2(temperature_c) * float(water_path_mm)

    def peak_through(self, dt_ns: float, kappa: float) -> float:
        """The continuous peak of the echo of ``shape(dt_ns)`` (peak 1) through the water's
        transfer ``exp(−κ·f²)``, on the shape's fine grid."""
        fine = self._fine.get(dt_ns)
        if fine is None:
            shape = self.shape(dt_ns)
            f_mhz = fft.rfftfreq(shape.waveform.size, shape.waveform_dt_ns * 1e-3)
            fine = (f_mhz**2, fft.rfft(shape.waveform), shape.waveform.size)
            self._fine[dt_ns] = fine
        f2, spectrum, n = fine
        return float(np.max(np.abs(fft.irfft(spectrum * np.exp(-kappa * f2), n))))

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
        *,
        water_mm: Sequence[float] = (),
        temperature_c: float = 20.0,
    ) -> np.ndarray:
        """Volts of ``n`` samples from ``t0_ns`` every ``dt_ns``: the echo of
        ``amplitude_fsh`` arriving at ``tof_ns`` (NaN: none), the other echoes of the
        acquisition, ``later`` = ``(delay_ns, relative_amplitude)`` after and relative to it
        (``later_echoes``), plus the noise and the baseline offset. ``water_mm``: the water
        path (one way, mm) of the main echo, then of each in ``later``, in water at
        ``temperature_c``: with ``water_absorption`` each echo is shaped by its own (module
        docstring); an echo without one keeps the one shape."""
        with self._lock:
            noise = self._rng.standard_normal(n)
        out = noise * noise_rms_fsh
        if math.isfinite(tof_ns) and amplitude_fsh > 0.0:
            kappas = [self.kappa(path, temperature_c) for path in water_mm]
            kappas += [0.0] * (len(later) + 1 - len(kappas))
            self._add_echo(out, t0_ns, dt_ns, amplitude_fsh, tof_ns, kappas[0])
            for (delay_ns, relative), kappa in zip(later, kappas[1:], strict=False):
                self._add_echo(
                    out, t0_ns, dt_ns, amplitude_fsh * relative, tof_ns + delay_ns, kappa
                )
        if self.baseline_offset:
            out += self.baseline_offset
        return out * FULL_SCREEN_V

    def _add_echo(
        self,
        out: np.ndarray,
        t0_ns: float,
        dt_ns: float,
        amplitude: float,
        arrival_ns: float,
        kappa: float = 0.0,
    ) -> None:
        shape = self.shape(dt_ns)
        # the water's transfer is a Gaussian in time of σ = √(κ/2)/π µs: the support widens
        widen_ns = BROADENING_SIGMAS * 1e3 * math.sqrt(kappa / 2.0) / math.pi
        pre_ns, post_ns = shape.pre_ns + widen_ns, shape.post_ns + widen_ns
        first = max(0, math.floor((arrival_ns - pre_ns - t0_ns) / dt_ns) - 2)
        stop = min(out.size, math.ceil((arrival_ns + post_ns - t0_ns) / dt_ns) + 3)
        if stop <= first:
            return  # the echo is outside the record
        m = stop - first
        support = math.ceil((pre_ns + post_ns) / dt_ns) + 8
        # no wrap-around into the segment: the support fits in the padding either side
        n_fft = fft.next_fast_len(m + support)
        spectrum = self._spectrum(dt_ns, n_fft)
        f_mhz = fft.rfftfreq(n_fft, dt_ns * 1e-3)
        if kappa > 0.0:
            # through the water, its peak kept: the height is the gate's, the shape the path's
            spectrum = spectrum * (np.exp(-kappa * f_mhz**2) / self.peak_through(dt_ns, kappa))
        delay_us = (arrival_ns - (t0_ns + first * dt_ns)) * 1e-3
        segment = fft.irfft(spectrum * np.exp(-2j * np.pi * f_mhz * delay_us), n_fft)[:m]
        out[first:stop] += amplitude * segment
