"""Ultrasound in water: sound speed, time of flight, piston directivity, beam footprint.

Units: temperature in °C, lengths in mm, times in ns (round trip), frequency in MHz,
angles in degrees, amplitudes as fractions of full screen height (0…1).

The echo model of the simulated cell (``ucal.sim.cell``) is

    amplitude = reference amplitude · gain factor · attenuation · directivity · footprint share

with the directivity of a circular piston seen in pulse-echo from a tilted plane reflector and
the share of a Gaussian beam footprint that lands on a finite face. ``directivity`` is the
single-frequency (centre-frequency) function that the peak search fits.

The simulated instrument (``ucal.sim.receiver``) sends a broadband pulse instead: a Gaussian
amplitude spectrum ``pulse_spectrum`` around the centre frequency with a −6 dB fractional
bandwidth of 0.6 (``PULSE_FRACTIONAL_BANDWIDTH``, typical of a damped 25 MHz immersion probe).
Each frequency is filtered by its own piston directivity and its own water absorption (∝ f²),
so the echo's peak follows ``broadband_echo_factor``: the spectrum-weighted mean of
``2·J1(x)/x`` (``broadband_directivity``), whose side lobes differ from the centre-frequency
function's, and an absorption that downshifts the spectrum with the water path (the main lobe
widens: its −6 dB half-angle is 0.20° at 50 mm, 0.24° at 100 mm and 0.28° at 150 mm for
25 MHz and 6 mm). In the geometric near field of a plane reflector (a collimated beam as
wide as the element) the returning plane wave tilted by 2θ, integrated over the element, gives
the same ``2·J1(x)/x`` at each frequency, so the per-frequency function holds at the
50–150 mm paths of the calibration.
"""

from __future__ import annotations

from typing import overload

import numpy as np
from scipy.optimize import brentq
from scipy.special import j1, ndtr

#: Marczak (1997), "Water as a standard in the measurements of speed of sound in liquids",
#: J. Acoust. Soc. Am. 102, 2776: c(T) = Σ c_i T^i in m/s, T in °C (ITS-90), 0…95 °C.
MARCZAK_COEFFS_M_S = (1402.385, 5.038813, -5.799136e-2, 3.287156e-4, -1.398845e-6, 2.787860e-9)

#: Reference amplitude (fraction of full screen) of a normal-incidence echo from a face that
#: takes the whole footprint, at ``REFERENCE_WATER_PATH_MM`` and ``REFERENCE_GAIN_DB``.
REFERENCE_AMPLITUDE = 0.8
REFERENCE_WATER_PATH_MM = 50.0
REFERENCE_GAIN_DB = 20.0  # the pulser's default gain (drivers.pulser.base.PulserSettings)

#: −6 dB full width of the pulse's amplitude spectrum as a fraction of the centre frequency.
PULSE_FRACTIONAL_BANDWIDTH = 0.6

#: Small-signal absorption of water, α/f² (Np·s²/m) at 20 °C (Pinkerton 1949, 25.3e-17 s²/cm).
WATER_ABSORPTION_NP_S2_PER_M = 25.3e-15


@overload
def sound_speed_m_s(temperature_c: float) -> float: ...
@overload
def sound_speed_m_s(temperature_c: np.ndarray) -> np.ndarray: ...
def sound_speed_m_s(temperature_c: float | np.ndarray) -> float | np.ndarray:
    """Speed of sound in pure water (m/s) at ``temperature_c`` (°C, 0…95), after Marczak (1997).

    1482.38 m/s at 20 °C.
    """
    t = np.asarray(temperature_c, dtype=float)
    c = np.zeros_like(t)
    for coeff in reversed(MARCZAK_COEFFS_M_S):  # Horner
        c = c * t + coeff
    return float(c) if c.ndim == 0 else c


def sound_speed_slope_m_s_per_c(temperature_c: float) -> float:
    """dc/dT of Marczak's c(T) at ``temperature_c`` (m/s per °C; ≈ 3.0 at 20 °C, 0 near
    74 °C), a central difference over ±0.01 °C."""
    t = float(temperature_c)
    return (sound_speed_m_s(t + 0.01) - sound_speed_m_s(t - 0.01)) / 0.02


def temperature_for_speed_c(speed_m_s: float) -> float | None:
    """The water temperature (°C, 0…70) at which Marczak's c(T) is ``speed_m_s``: the
    temperature a measured sound speed is converted with; None outside that range."""
    lo, hi = 0.0, 70.0  # c(T) rises monotonically here
    if not float(sound_speed_m_s(lo)) < speed_m_s < float(sound_speed_m_s(hi)):
        return None
    return float(brentq(lambda t: float(sound_speed_m_s(t)) - speed_m_s, lo, hi, xtol=1e-9))


def tof_ns(water_path_mm: float | np.ndarray, temperature_c: float) -> float | np.ndarray:
    """Round-trip time of flight (ns) over a one-way water path (mm): ``2 L / c(T)``.

    A 50 mm path at 20 °C reads 67 459 ns.
    """
    # mm / (m/s) = 1e-3 s; in ns ×1e9 → factor 1e6
    return 2.0 * np.asarray(water_path_mm, dtype=float) * 1e6 / sound_speed_m_s(temperature_c)


def water_path_mm(tof_ns: float | np.ndarray, temperature_c: float) -> float | np.ndarray:
    """One-way water path (mm) of a round-trip time of flight (ns): the inverse of ``tof_ns``."""
    return np.asarray(tof_ns, dtype=float) * sound_speed_m_s(temperature_c) / 2e6


def wavenumber_per_mm(frequency_mhz: float, temperature_c: float) -> float:
    """Acoustic wavenumber k = 2πf/c in rad/mm."""
    # f in Hz = 1e6·MHz, c in mm/s = 1e3·m/s
    return 2.0 * np.pi * frequency_mhz * 1e3 / sound_speed_m_s(temperature_c)


def piston_directivity(x: float | np.ndarray) -> float | np.ndarray:
    """Far-field directivity ``2·J1(x)/x`` of a circular piston (1 at x = 0, signed)."""
    x = np.asarray(x, dtype=float)
    small = np.abs(x) < 1e-6
    safe = np.where(small, 1.0, x)
    d = np.where(small, 1.0 - x * x / 8.0, 2.0 * j1(safe) / safe)
    return float(d) if d.ndim == 0 else d


def directivity(
    tilt_deg: float | np.ndarray,
    frequency_mhz: float,
    element_diameter_mm: float,
    temperature_c: float,
) -> float | np.ndarray:
    """Pulse-echo amplitude factor (0…1) of a plane reflector tilted ``tilt_deg`` off normal.

    A reflector tilted by θ sends the echo back 2θ off the transducer axis, where the piston's
    receiving directivity is ``2·J1(x)/x`` with ``x = k·a·sin 2θ`` (a = element radius).
    Returns the magnitude: side lobes give positive amplitudes like a rectified A-scan.
    For 25 MHz, a 6 mm element and 20 °C the −6 dB (0.5) half-angle is 0.20°.
    """
    ka = wavenumber_per_mm(frequency_mhz, temperature_c) * element_diameter_mm / 2.0
    x = ka * np.sin(2.0 * np.radians(np.asarray(tilt_deg, dtype=float)))
    return np.abs(piston_directivity(x))


def directivity_half_angle_deg(
    level: float, frequency_mhz: float, element_diameter_mm: float, temperature_c: float
) -> float:
    """Tilt (deg) at which ``directivity`` falls to ``level`` (0 < level < 1) in the main lobe."""
    if not 0.0 < level < 1.0:
        raise ValueError(f"level must be in (0, 1), got {level}")
    # imported here, the one use of scipy.optimize in the simulated cell: a process that only
    # serves the cell does not load it
    from scipy.optimize import brentq

    x = brentq(lambda v: piston_directivity(v) - level, 1e-9, 3.8317)  # first zero of J1
    ka = wavenumber_per_mm(frequency_mhz, temperature_c) * element_diameter_mm / 2.0
    return float(np.degrees(np.arcsin(x / ka) / 2.0))


def footprint_sigma_mm(element_diameter_mm: float) -> float:
    """Standard deviation (mm) of the Gaussian beam footprint of an element: ``σ = D/4``.

    The footprint is taken as wide as the element (a 6 mm element at 50 mm is in its near
    field, N = D²/4λ ≈ 150 mm at 25 MHz, where the beam is about the element's width). σ = D/4
    = a/2 is the Gaussian with the same per-axis second moment (a²/4) as a uniform disc of
    radius a, so the share that crosses a straight edge rises over the same distance as for the
    element's own aperture; ±2σ spans the diameter (95 % of the 1-D profile).
    """
    return element_diameter_mm / 4.0


def edge_share(signed_distance_mm: float | np.ndarray, sigma_mm: float) -> float | np.ndarray:
    """Share of a Gaussian footprint on the inner side of one straight edge: Φ(s/σ).

    ``signed_distance_mm`` is from the beam-axis hit point to the edge, positive inside the
    face: 0.5 with the axis on the edge, → 1 well inside, → 0 well outside.
    """
    s = ndtr(np.asarray(signed_distance_mm, dtype=float) / sigma_mm)
    return float(s) if np.ndim(s) == 0 else s


def rectangle_share(edge_distances_mm: np.ndarray, sigma_mm: float) -> float | np.ndarray:
    """Share of an isotropic Gaussian footprint that lands on a rectangle.

    ``edge_distances_mm`` (…, 4) are the signed distances of the axis hit point to the edges
    ``u_min, u_max, v_min, v_max`` (positive inside). The isotropic Gaussian separates along u
    and v, so the exact 2-D integral is the product over the two axes of
    ``Φ(d_min/σ) + Φ(d_max/σ) − 1`` (= Φ(d_min/σ) − Φ(−d_max/σ)). Footprint stretching on a
    tilted face (1/cos θ) is neglected: echoes exist only within a fraction of a degree of
    normal incidence.
    """
    d = np.asarray(edge_distances_mm, dtype=float)
    phi = ndtr(d / sigma_mm)
    if phi.shape == (4,):  # one hit, at every simulated reading: the same sums on floats
        u_min, u_max, v_min, v_max = phi.tolist()
        return float(
            min(max(u_min + u_max - 1.0, 0.0), 1.0) * min(max(v_min + v_max - 1.0, 0.0), 1.0)
        )
    share_u = phi[..., 0] + phi[..., 1] - 1.0
    share_v = phi[..., 2] + phi[..., 3] - 1.0
    s = np.clip(share_u, 0.0, 1.0) * np.clip(share_v, 0.0, 1.0)
    return float(s) if np.ndim(s) == 0 else s


def gain_factor(gain_db: float, reference_gain_db: float = REFERENCE_GAIN_DB) -> float:
    """Amplitude factor of a receiver gain relative to the reference gain: 10^(Δg/20)."""
    return float(10.0 ** ((gain_db - reference_gain_db) / 20.0))


def water_absorption_np_per_mm(frequency_mhz: float) -> float:
    """Amplitude absorption coefficient of water (Np/mm, one way): ``α = 25.3e-15·f²`` Np/m."""
    return WATER_ABSORPTION_NP_S2_PER_M * (frequency_mhz * 1e6) ** 2 * 1e-3


def water_attenuation(
    water_path_mm: float | np.ndarray,
    frequency_mhz: float,
    reference_path_mm: float = REFERENCE_WATER_PATH_MM,
) -> float | np.ndarray:
    """Amplitude factor of water absorption over the round trip, relative to the reference path.

    ``exp(−α·2·(L − L_ref))`` with ``α = 25.3e-15·f²`` Np/m (classical absorption, ∝ f²):
    0.0158 Np/mm at 25 MHz, i.e. about −0.27 dB per mm of extra one-way path.
    """
    alpha_np_per_mm = water_absorption_np_per_mm(frequency_mhz)
    a = np.exp(
        -alpha_np_per_mm * 2.0 * (np.asarray(water_path_mm, dtype=float) - reference_path_mm)
    )
    return float(a) if np.ndim(a) == 0 else a


def echo_amplitude(
    tilt_deg: float,
    share: float,
    water_path_mm: float,
    gain_db: float,
    frequency_mhz: float,
    element_diameter_mm: float,
    temperature_c: float,
) -> float:
    """Noise-free echo amplitude (fraction of full screen, clipped at 1.0 = saturation).

    ``REFERENCE_AMPLITUDE`` (0.8 at normal incidence, whole footprint on the face, 50 mm path,
    20 dB gain) × ``gain_factor`` × ``water_attenuation`` × ``directivity`` × ``share``.
    """
    a = (
        REFERENCE_AMPLITUDE
        * gain_factor(gain_db)
        * water_attenuation(water_path_mm, frequency_mhz)
        * directivity(tilt_deg, frequency_mhz, element_diameter_mm, temperature_c)
        * share
    )
    return float(min(a, 1.0))


@overload
def pulse_spectrum(
    frequency_mhz: float, centre_frequency_mhz: float, fractional_bandwidth: float = ...
) -> float: ...
@overload
def pulse_spectrum(
    frequency_mhz: np.ndarray, centre_frequency_mhz: float, fractional_bandwidth: float = ...
) -> np.ndarray: ...
def pulse_spectrum(
    frequency_mhz: float | np.ndarray,
    centre_frequency_mhz: float,
    fractional_bandwidth: float = PULSE_FRACTIONAL_BANDWIDTH,
) -> float | np.ndarray:
    """Gaussian amplitude spectrum (1 at the centre) of the pulse-echo response.

    Its −6 dB (0.5) full width is ``fractional_bandwidth · centre_frequency_mhz``: σ_f =
    bw·f_c / (2·√(2 ln 2)); in time the envelope's σ_t = 1 / (2π σ_f), 25 ns at 25 MHz and 0.6.
    """
    sigma_mhz = fractional_bandwidth * centre_frequency_mhz / (2.0 * np.sqrt(2.0 * np.log(2.0)))
    p = np.exp(
        -0.5 * ((np.asarray(frequency_mhz, dtype=float) - centre_frequency_mhz) / sigma_mhz) ** 2
    )
    return float(p) if np.ndim(p) == 0 else p


def _band_mhz(frequency_mhz: float, fractional_bandwidth: float) -> np.ndarray:
    """Frequency grid (MHz) over which a pulse's spectrum is integrated: 0 … f_c·(1 + 3·bw)."""
    return np.linspace(0.0, frequency_mhz * (1.0 + 3.0 * fractional_bandwidth), 601)[1:]


def broadband_echo_factor(
    tilt_deg: float | np.ndarray,
    water_path_mm: float,
    frequency_mhz: float,
    element_diameter_mm: float,
    temperature_c: float,
    fractional_bandwidth: float = PULSE_FRACTIONAL_BANDWIDTH,
    reference_path_mm: float = REFERENCE_WATER_PATH_MM,
) -> float | np.ndarray:
    """Peak of a broadband echo relative to normal incidence at the reference path (0…1+).

    ``|∫ P(f)·exp(−2α(f)(L − L_ref))·D(f, θ) df| / ∫ P(f) df`` with ``P`` =
    ``pulse_spectrum``, ``α(f)`` the water absorption (∝ f², Pinkerton) and
    ``D = 2·J1(x)/x, x = k(f)·a·sin 2θ`` (signed, so that frequencies on either side of a null
    cancel): the height of the echo envelope at its centre time, which is its peak in the
    main lobe. Beyond it (≳ 0.3° at 25 MHz, 6 mm) the echo splits into the two edge waves of
    the element and its envelope peaks off centre, above this value. Above 1 for paths shorter
    than the reference (less absorption).
    """
    f = _band_mhz(frequency_mhz, fractional_bandwidth)
    p = pulse_spectrum(f, frequency_mhz, fractional_bandwidth)
    att = np.exp(
        -2.0 * water_absorption_np_per_mm(1.0) * f**2 * (float(water_path_mm) - reference_path_mm)
    )
    ka = (2.0 * np.pi * f * 1e3 / sound_speed_m_s(temperature_c)) * element_diameter_mm / 2.0
    s2 = np.sin(2.0 * np.radians(np.asarray(tilt_deg, dtype=float)))
    d = piston_directivity(np.multiply.outer(s2, ka))
    out = np.abs((d * (p * att)).sum(-1)) / p.sum()
    return float(out) if np.ndim(out) == 0 else out


def broadband_directivity(
    tilt_deg: float | np.ndarray,
    frequency_mhz: float,
    element_diameter_mm: float,
    temperature_c: float,
    fractional_bandwidth: float = PULSE_FRACTIONAL_BANDWIDTH,
) -> float | np.ndarray:
    """Pulse-echo directivity of a broadband pulse: ``2·J1(x)/x`` averaged over its spectrum.

    ``broadband_echo_factor`` at the reference path (no absorption weighting): 1 at normal
    incidence; for 25 MHz, 6 mm, 20 °C and a bandwidth of 0.6 it is 0.50 at 0.20° like the
    centre-frequency ``directivity``, but 0.17 at 0.30° where the latter is 0.13, and its side
    lobes differ.
    """
    return broadband_echo_factor(
        tilt_deg,
        REFERENCE_WATER_PATH_MM,
        frequency_mhz,
        element_diameter_mm,
        temperature_c,
        fractional_bandwidth,
    )
