"""The simulated receiver: a sampled broadband echo and the peak-mode gate that measures it.

An instrument does not report geometry: it digitises the echo and its gate finds the peak.
``EchoReceiver`` synthesises, for one acquisition, the analytic signal (RF + j·quadrature, as
a digital receiver's quadrature demodulator gives it) of the echo over a short window:

* spectrum: the pulse's Gaussian amplitude spectrum (``ucal.acoustics.pulse_spectrum``, centre
  frequency of the transducer, −6 dB fractional bandwidth 0.6), each frequency filtered by its
  own piston directivity ``2·J1(k(f)·a·sin 2θ)/(k(f)·a·sin 2θ)`` and its own water absorption
  relative to the 50 mm reference path (``exp(−2·α(f)·(L − 50 mm))``, α ∝ f²): the broadband
  echo of ``ucal.acoustics.broadband_echo_factor``, not the centre-frequency function that the
  peak search fits;
* time: sampled at 200 MS/s (8 samples per period at 25 MHz) on the digitiser's own clock
  (sample k at k·5 ns after time zero), 64 samples (320 ns, ±6σ of the 25 ns envelope) centred
  on the sample nearest the echo's arrival: the inverse DFT of the delayed spectrum over the
  bins that carry the pulse (3.125 MHz apart, 0…66 MHz at 25 MHz);
* noise enters the waveform: the caller adds the receiver's white noise to the samples and
  shifts the arrival by the trigger jitter before detection (``ucal.sim.cell``).

Near field (``near_field``, off unless the world asks for it): inside the near field of the
element (N = a²/λ ≈ 150 mm at 25 MHz, 6 mm, against water paths of 50–100 mm) the echo of a
tilted plane returns displaced across the element, which the far-field piston directivity
ignores: ``near_field_factor`` multiplies the echo by that overlap, so the main lobe narrows
with the water path in a way the peak search's model does not know.

Detection rule (``detect``): peak mode on the envelope |s|: the largest sample, refined by a
three-point parabola through it and its neighbours (position and height). Noise-free, the
parabola's error on the 25 ns Gaussian envelope sampled every 5 ns is at most 0.01 ns in time
and 1.1e-4 (relative) in height, periodic in the echo's sub-sample position. The digitiser is
taken to have the echo's dynamic range: the screen saturates at 100 % of full screen height,
the time measurement does not.

Sources: the pulse-echo response of a circular piston to a tilted plane reflector, per
frequency, and its spectral synthesis follow L. W. Schmerr, *Fundamentals of Ultrasonic
Nondestructive Evaluation*, 2nd ed. (Springer 2016), ch. 8 and 10; water absorption ∝ f² after
Pinkerton (1949); the sound speed after Marczak (1997) (``ucal.acoustics``).
"""

from __future__ import annotations

import logging
import math

import numpy as np
from scipy.special import j1

from ucal import acoustics

log = logging.getLogger(__name__)

#: Digitiser sample rate (Hz) and the samples synthesised around each echo.
SAMPLE_RATE_HZ = 200e6
WINDOW_SAMPLES = 64


class EchoReceiver:
    """Sampled broadband echoes of one transducer and their peak-mode detection."""

    def __init__(
        self,
        frequency_mhz: float,
        element_diameter_mm: float,
        fractional_bandwidth: float = acoustics.PULSE_FRACTIONAL_BANDWIDTH,
        sample_rate_hz: float = SAMPLE_RATE_HZ,
        window_samples: int = WINDOW_SAMPLES,
        near_field: bool = False,
    ):
        self.sample_ns = 1e9 / float(sample_rate_hz)
        self.near_field = bool(near_field)
        # near-field length N = a²/λ at the centre frequency (mm), 20 °C
        lam_mm = acoustics.sound_speed_m_s(20.0) * 1e-3 / float(frequency_mhz)
        self._near_field_mm = (element_diameter_mm / 2.0) ** 2 / lam_mm
        self.n = int(window_samples)
        # positive-frequency bins of the window's FFT (MHz): the analytic signal has no others;
        # DC and Nyquist are left out, and so are bins where the pulse has no energy (< 1e-9)
        f_mhz = np.arange(1, self.n // 2) * 1e3 / (self.n * self.sample_ns)
        p = acoustics.pulse_spectrum(f_mhz, frequency_mhz, fractional_bandwidth)
        keep = p > 1e-9 * p.max()
        self._f_mhz = f_mhz[keep]
        self._p = p[keep] / p[keep].sum()  # s(τ) = 1 at normal incidence on the reference path
        self._alpha_np_per_mm = acoustics.water_absorption_np_per_mm(1.0) * self._f_mhz**2
        self._radius_mm = element_diameter_mm / 2.0
        self._omega_rad_per_ns = 2.0 * np.pi * self._f_mhz * 1e-3
        # s_k = Σ_m X_m·exp(iω_m·k·Δt): the inverse DFT restricted to the kept bins
        k = np.arange(self.n)
        self._synthesis = np.exp(1j * np.outer(k * self.sample_ns, self._omega_rad_per_ns))
        # (sound speed m/s, wavenumbers rad/mm) of the last call, one tuple so that threads
        # never see one without the other
        self._k_cache: tuple[float, np.ndarray] = (float("nan"), self._omega_rad_per_ns)

    def spectrum(self, tilt_deg: float, water_path_mm: float, sound_speed_m_s: float) -> np.ndarray:
        """Real amplitude spectrum (per kept bin) of the echo from a plane tilted ``tilt_deg``
        at ``water_path_mm`` in water of ``sound_speed_m_s``, normalised so that its sum is the
        echo's centre height."""
        cached_c_m_s, k_per_mm = self._k_cache
        if sound_speed_m_s != cached_c_m_s:
            # k = ω/c with c in mm/ns = 1e-6 · (m/s)
            k_per_mm = self._omega_rad_per_ns * 1e6 / sound_speed_m_s
            self._k_cache = (sound_speed_m_s, k_per_mm)
        s = self._p
        sin_2t = math.sin(2.0 * math.radians(tilt_deg))
        if sin_2t != 0.0:
            x = k_per_mm * (self._radius_mm * abs(sin_2t))  # > 0: every kept f > 0
            s = s * (2.0 * j1(x) / x)
        if self.near_field and sin_2t != 0.0:
            s = s * self.near_field_factor(tilt_deg, water_path_mm)
        if water_path_mm != acoustics.REFERENCE_WATER_PATH_MM:
            s = s * np.exp(
                -2.0 * (water_path_mm - acoustics.REFERENCE_WATER_PATH_MM) * self._alpha_np_per_mm
            )
        return np.asarray(s)

    def near_field_factor(self, tilt_deg: float, water_path_mm: float) -> float:
        """Overlap of the returning echo with the element (near field): the reflection of a
        plane tilted θ comes back displaced by Δ = 2L·tan 2θ; within the near field
        (2L ≲ N = a²/λ) it is about as wide as the element, a Gaussian of σ = a/2 per axis, so
        the overlap is ``exp(−Δ²/(4σ²)·g)``, ``g = 1/(1 + (2L/N)²)²`` fading it out where the
        echo has spread (the far field, where the piston directivity alone holds)."""
        delta = 2.0 * water_path_mm * math.tan(2.0 * math.radians(tilt_deg))
        sigma = self._radius_mm / 2.0
        g = 1.0 / (1.0 + (2.0 * water_path_mm / self._near_field_mm) ** 2) ** 2
        return math.exp(-(delta**2) / (4.0 * sigma**2) * g)

    def waveform(
        self, arrival_ns: float, scale: float, spectrum: np.ndarray
    ) -> tuple[float, np.ndarray]:
        """Analytic echo ``(t0_ns, samples)``: ``scale``·echo arriving at ``arrival_ns``, sampled
        at ``t0_ns + k·sample_ns`` (k = 0…n−1) on the digitiser's clock, centred on the echo."""
        centre = round(arrival_ns / self.sample_ns)
        t0_ns = (centre - self.n // 2) * self.sample_ns
        # X_m = S_m·exp(−iω_m(τ − t0)), s_k = Σ_m X_m·exp(iω_m·k·Δt)
        x = (scale * spectrum) * np.exp(-1j * (arrival_ns - t0_ns) * self._omega_rad_per_ns)
        return t0_ns, self._synthesis @ x

    def detect(self, t0_ns: float, samples: np.ndarray) -> tuple[float, float]:
        """Peak-mode gate on the envelope: ``(peak height, time of the peak in ns)``."""
        env = np.abs(samples)
        k = int(env.argmax())
        if 0 < k < len(env) - 1:
            a, b, c = float(env[k - 1]), float(env[k]), float(env[k + 1])
            curvature = a - 2.0 * b + c
            if curvature < 0.0:
                delta = 0.5 * (a - c) / curvature
                return b - 0.25 * (a - c) * delta, t0_ns + (k + delta) * self.sample_ns
        return float(env[k]), t0_ns + k * self.sample_ns
