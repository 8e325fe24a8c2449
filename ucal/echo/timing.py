"""Time of flight and amplitude of an echo in one A-scan, with the std the reading deserves.

Model. The record holds ``x_n = A·r(t_n − τ) + w_n`` (n = 0…N−1, sample interval Δt): the
reference echo ``r`` (``ReferenceEcho``, band-limited, arrival at t = 0) delayed by τ and
scaled by A, in white Gaussian noise ``w`` of variance σ².

Cramér–Rao bound. The log-likelihood is ``−Σ (x_n − A·r(t_n − τ))² / 2σ²``, whose Fisher
information is

    I_ττ = (A²/σ²)·Σ r'(t_n − τ)²,   I_AA = Σ r(t_n − τ)² / σ²,   I_Aτ = −(A/σ²)·Σ r·r' = 0

(the cross term vanishes for an echo wholly inside the record: ∫ r·r' dt = [r²/2] = 0), so
``var τ̂ ≥ σ² / (A²·Σ r'²)``. For a band-limited echo sampled above Nyquist, Parseval turns the
sums into integrals, ``Σ r² = (1/Δt)·∫|R(f)|² df`` and ``Σ r'² = (1/Δt)·(2π)²·∫ f²|R(f)|² df``,
so ``Σ r'² = (2πβ)²·Σ r²`` with β the RMS (Gabor) bandwidth about 0 Hz,

    β² = ∫ f²·|R(f)|² df / ∫ |R(f)|² df = f_c² + B²

(f_c the power-weighted centre frequency, B the RMS width about it), and

    σ_τ ≥ 1 / (2π·β·√SNR_eff),   SNR_eff = A²·Σ r² / σ² = 2E/N0

(E the echo's energy, N0/2 = σ²·Δt the noise's two-sided spectral density). This is the bound
of an estimator that follows the carrier's phase; it holds above the ambiguity threshold,
where no correlation peak a cycle away can win (SNR_eff well above (f_c/B)²). The envelope
alone carries only B: its bound is f_c/B times larger, several times for a 60 % bandwidth.

Estimator (``method = "reference"``). The maximum-likelihood delay maximises the correlation
``c(τ) = Σ x_n·r(t_n − τ)``, and ``Â = c(τ̂)/Σ r²``; at high SNR it reaches the bound. The
largest sample of the full cross-correlation (``scipy.signal.correlate``) gives the whole
sample; Newton's method on the correlation's Fourier series (``ucal.echo.spectral``) gives the
rest. The correlation of band-limited records is band-limited and that series is its exact
interpolation, so the estimate does not depend on where the peak falls between samples; a
parabola through three correlation samples assumes a shape the correlation has not (a
cosine under an envelope) and errs by a fraction of a sample that does, most at a few samples
a cycle.

Reported std. The bound with the record's own numbers: σ̂ the noise of the samples outside the
echo (``ucal.echo.ascan.noise_rms``: robust to a second echo, plus the quantisation noise
LSB²/12 when the step is known), Â the fit, β the reference's (over its band, so that
the noise the averaging left in it does not count). Samples that carry no information, on a
rail or outside the record (an echo cut by its edge), are left out of the Fisher sum: the
std is multiplied by √(Σ_all r'² / Σ_used r'²).

The strongest echo is the largest correlation of the reference's polarity within the gate.

A second echo. A weaker echo elsewhere in the gate (the multiple, another face's) correlates
less than the main one and is not taken; in the record's quiet part it does not raise σ̂ (the
noise estimate is robust to it). One over the main echo pulls the correlation's peak by up
to about ``ρ/(2πβ)`` (ρ its relative height) — a ringing echo's tail is long, so one two
periods later pulled a plain correlation 0.5–2 ns. The fit's residual over the echo's m
samples shows it: its energy beyond the noise's, ``ε = Σ res²/σ̂² − m``, is the part of the
other echo the fitted one does not explain. When ε passes ``OVERLAP_SIGMAS``·√(2m) (the
noise's own scatter of it) and ε·σ̂² passes ``OVERLAP_ENERGY`` of the echo's energy (less is
the echo's own shape, which the reference matches only so well), the other echo is sought
(``_separate``): the residual's largest correlation, of either sign, ``SEPARATION_PERIODS``
periods (1/β) or more from the first (its ``SEPARATION_STARTS`` largest lobes on each side:
a ringing echo's correlation has a lobe every period), then the two fitted by turns, each
delay and amplitude refitted on the record less the other (a coordinate ascent on the
two-echo least squares, which converges when their correlation at that spacing is below 1),
the pair leaving the smallest residual kept. The reference as it is comes first: two echoes
summed look like an echo through more water, and a water fitted to them (κ of tens of mm)
misleads the pair; only when that pair leaves an excess is the water fitted on the record
less the other echo and the pair fitted again. When the pair leaves no
excess the estimate says ``separated`` and its std is the pair's bound, ``σ²·(JᵀJ)⁻¹``
over (τ₁, A₁, τ₂, A₂) — above a lone echo's by the pair's correlation. Otherwise (closer
than 1.5 periods, or not of the reference's shape) it says ``overlapped`` and its std is
multiplied by √(1 + ε): the other echo's pull on the delay is at most ‖u‖/(A‖r'‖) by
Cauchy–Schwarz (u the other echo), and ε·σ̂² is the part of ‖u‖² left in the residual,
comparable to the rest for delays past a quarter period. Closer, the fit takes most of the
other echo for a shift of this one and leaves a residual of the order of the delay squared:
the std widened so covers the pull past a quarter period (a 25 MHz echo at 64 dB: 0.3 of it
23 ns later, pull 0.9 ns, std 1.4 ns) and falls short before (0.1 of it 7 ns later: pull
0.5 ns, std 0.15 ns), where the flag is what tells — and its weight, 1/std², is what the
solver sees.

Clipping. A sample on a rail says only "at least the rail": a censored observation. The fit
replaces each by its expectation given the current fit and σ̂ (``m + σ·φ(α)/Q(α)``,
α = (rail − m)/σ; expectation–maximisation for censored Gaussian data) and refits until the
delay settles, so the echo is timed by its unclipped flanks; the result says ``clipped``.
Without the digitiser's rails (a CSV file), samples at the record's extreme value are taken as
clipped when there are two or more (a rail is a plateau) and a fit without them puts the echo
well beyond them. (The envelope
method flags clipping only when the rails are known, and widens its std over the clipped
samples.)

The reference's own noise. A reference is itself a noisy echo: ``r̃ = r + v`` (v white,
σ_r per sample relative to its peak: the noise ``build_reference`` measured, or the one
``ucal.echo.files.reference_from_samples`` finds outside the echo of a file written whole).
The estimator solves ``Σ x_n·g'(t_n − τ̂) = 0`` for the template g it correlates with; to
first order, with g = r̃,

    δτ = (Σ w·r' + A·Σ r·v')/(A·Σ r'²) + Σ w·v'/(A·Σ r'²),

and Σ r·v' = −Σ r'·v (by parts), so the first term's variance is (σ² + A²σ_r²)/(A²·Σ r'²):
the two noises add, the reference's scaled by the echo's height. It is the bound of a delay
between two noisy copies of one unknown echo (Knapp & Carter 1976, IEEE Trans. ASSP 24,
320–327: 1/var = Σ_f ω²S²/(N_x·N_r + S·(N_x + N_r)), here at a high SNR in the band) — not
beaten by any estimator. The second term, Σ w·v', correlates the record's noise with the
reference's over the whole band up to Nyquist, weighted by ω²: with a reference written
whole (hundreds of samples of noise) it dominated at 500 MS/s (1.5–2.5 × the bound), and the
same noise counted in β made the std several times too small. So the template is the
reference's spectrum weighted bin by bin by ``ucal.echo.ascan.wiener_gain`` (zero-phase:
``c(τ) = A·Σ_f |R|²·H·cos ω(τ − τ₀)`` still peaks at τ₀), which keeps the bins of the echo and
drops those of noise; β and the energy are summed from the band's power less its noise
(n·σ_r² a bin); the reported std is the bound with σ² + A²σ_r². Its error in t = 0 is
common to every reading, a constant in every time of flight (the calibration's electronic
delay ``tof_delay_ns`` absorbs it).

Water. A reading through Δd more water than the reference's (one way) has the reference's
spectrum times the water's transfer ``exp(−α(f)·2Δd)``, with α = α₀·f² (viscous and thermal
absorption; α₀ = 2.17e-3 dB/(cm·MHz²) = 2.5e-5 Np/(mm·MHz²) at 20 °C, Pinkerton 1949 as
Szabo 2004 gives the power law; its dispersion, by Kramers–Kronig for f², is far below a ps
over these paths): ``X(f) = A·R(f)·exp(−κf²)·exp(−i2πfτ)``, κ = 2α₀Δd Np/MHz² — the
transducer's spectrum (the reference's) seen through the water. A real, even factor does not
move the correlation's peak (``X·R̄ = A|R|²e^{−κf²}e^{−iωτ}``), so the delay is not biased;
but the shape is no longer the reference's: 25 MHz through 60 mm more loses 17 dB at the
centre and the spectrum moves down by several MHz, the residual took that for another echo
and widened the std 9–44 ×, and β was the reference's, not the echo's. So κ is fitted with
the amplitude and the delay (``fit_attenuation``: Gauss–Newton over the echo's samples on
the template ``R·exp(−κf²)``, κ ≥ 0 and at most ``ATTENUATION_LIMIT_NP`` at β, the delay
refitted by the correlation at each step), kept only when ``ATTENUATION_SIGMAS`` of its std
from 0 (κ and τ are orthogonal to first order, an even and an odd change of the echo, so a
free κ costs the delay nothing), and the bound is that of the echo as it arrives: β through
the water (|R|²·exp(−2κf²)), the template's energy, and the reference's noise as the
template keeps it (``through_water``). The amplitude is the peak of the echo as it arrives;
``extra_water_mm`` = κ/(2α₀) says what the spectrum saw (at 20 °C; α₀ falls with the
temperature, and the beam's diffraction changes the spectrum with the path too: κ takes what
of it is even, so read it as an equivalent path). Less water than the reference's (κ < 0) is
fitted only where the reference as it is leaves an excess in the echo's samples (the overlap
test below, on the record's and the reference's noise) and the template through less water,
down to ``LESS_WATER_LIMIT_NP`` of gain at β and started from the best of a coarse scan
(76 mm nearer, the linearised step lost the echo's sign), leaves none. Fitted always, it
would amplify the template's edges, where the reference's noise is (and the Wiener weights,
which narrow a noisy reference's band a little, read as less water: 1.8 × the bound at
5 MHz, 500 MS/s, 40 dB). A reading 20 mm nearer than a 25 MHz reference, through the
simulated cell's water (``ucal.sim.rf``), was flagged overlapped with its std 1,400 times
its spread; fitted, it is timed as one 20 mm further is.

Offsets. An echo has no DC: the reference's mean is its offset, removed when it is read
(``reference_from_samples``; 30 % of the peak left in made its peak, hence every amplitude,
wrong, and its DC correlated with the record's); the template's DC bin is zero, so a
record's offset does not reach the correlation, and the record's is the mean of its quiet
samples, removed before the noise and the residual.

No echo (``NoEcho``, never a time). A constant record (zeros, a digitiser with nothing
above one step) has nothing to time. Noise alone: the correlation over the gate's L whole
lags, in units of its noise std σ̂·√Σr², is √SNR_eff at the echo and N(0, 1) at each lag for
noise alone; the record holds an echo only when its peak passes ``Q⁻¹(FALSE_ALARM/L)``
(Bonferroni over the lags, which overcounts correlated ones: noise alone passes it in fewer
than ``FALSE_ALARM`` of the records; 4.7 σ for a thousand lags). The bound needs more still
(above the ambiguity threshold), but an echo between the two is timed, its std honest only
when no cycle a period away wins. An echo of the other polarity (its negative peak above the
threshold and above the positive one by ``INVERTED_SIGMAS`` of their difference's noise) is
another reflector's, or a reference of the wrong sign: no echo. An echo with more than
``CUT_SHARE`` of its energy beyond the record's ends is cut: its time would rest on a part
of it. Without a reference, the band-passed envelope's peak is tested against its noise's
(Rayleigh: |z| > t with probability exp(−t²/E|z|²) per position), and an echo whose
envelope does not fall to a quarter of its peak before an end of the record is cut. A record
without noise (σ̂ = 0: a synthetic one, or noise below the file's printed precision) is known
to the step its values are given to: σ̂ is that step over √12, so the std and the SNR stay
finite.

Without a reference (``method = "envelope (coarse: no reference echo)"``): the envelope of the
record's analytic signal, band-passed to the echo's own −6 dB band (a Gaussian filter twice as
wide), its largest sample refined by a parabola, as a peak-mode gate does. Its std propagates
σ̂ through the filter and the parabola to first order; it follows the envelope, not the
carrier, so it is several times that of the reference method, and it is not the reference's
arrival: an asymmetric echo's envelope peaks away from its phase centre by an amount of its
shape.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import fft, signal, stats

from ucal.echo.ascan import (
    AScan,
    ReferenceEcho,
    band_limited_peak,
    echo_band,
    noise_rms,
)
from ucal.echo.correlator import (
    Correlator,
    another_echo_shows,
    explained_by_a_pair,
    fit_attenuation,
    leaves_excess,
    pair_std_ns,
    residual_excess,
    through_water,
)
from ucal.echo.spectral import shifted

#: ``EchoEstimate.method`` of the two estimators.
METHOD_REFERENCE = "reference"
METHOD_ENVELOPE = "envelope (coarse: no reference echo)"
#: Clipped samples: refits until the delay moves less than this (samples), at most this often.
CLIP_TOLERANCE = 1e-6
CLIP_ITERATIONS = 50
#: Rails unknown: samples at the record's extremes are clipped when the fit without them puts
#: the echo this many σ beyond them, σ the noise and, in quadrature, ``CLIP_SHAPE`` of the
#: echo's height (how well a reference predicts a record's samples it was not fitted to:
#: 2–4 % at four samples a cycle).
CLIP_SIGMAS = 4.0
CLIP_SHAPE = 0.02
#: Water's attenuation at 20 °C: 2.17e-3 dB/(cm·MHz²) (Pinkerton 1949, the power law of
#: Szabo, Diagnostic Ultrasound Imaging, 2004), in Np/(mm·MHz²).
WATER_NP_PER_MM_MHZ2 = 2.17e-4 / (20.0 / math.log(10.0))
#: Chance that noise alone passes the detection threshold anywhere in a record.
FALSE_ALARM = 1e-3
#: An echo is inverted when the other polarity's correlation peak passes this one's by this
#: many of their difference's std (at a few samples a cycle and a low SNR a ringing echo's
#: two peaks half a period apart differ by less than their noise).
INVERTED_SIGMAS = 3.0
#: An echo with more than this share of its energy beyond the record's ends is cut by them.
CUT_SHARE = 0.01


class NoEcho(ValueError):
    """The record holds no echo to time; ``reason`` says why (a constant record, noise
    alone, an echo of the other polarity, an echo cut by the record's ends)."""

    def __init__(self, reason: str):
        super().__init__(f"no echo: {reason}")
        self.reason = reason


def detection_threshold(n_positions: int) -> float:
    """Smallest √SNR_eff (matched-filter output over its noise) that noise alone passes at
    ``n_positions`` independent positions with probability ``FALSE_ALARM`` at most:
    ``Q⁻¹(FALSE_ALARM / n)``, Bonferroni over the positions searched (module docstring)."""
    return float(stats.norm.isf(FALSE_ALARM / max(n_positions, 1)))


@dataclass(frozen=True)
class EchoEstimate:
    """One echo: its time of flight (ns, the arrival on the reference's convention) and one
    sigma, its amplitude (the echo's peak in the record's units) and one sigma, its peak
    signal-to-noise ratio (dB), the centre frequency and −6 dB bandwidth of its spectrum
    (MHz), the record's noise (one sigma, record units), how it was timed, and whether
    samples of it sat on the digitiser's rails; ``overlapped``: the echo's samples hold more
    than the fitted echo and the noise (another echo over it; its std widened for it);
    ``extra_water_mm``: the water (one way, at 20 °C) that the echo's spectrum says it
    crossed beyond the reference's; ``separated``: another echo over this one was fitted with
    it, its time and std those of the two fitted together."""

    tof_ns: float
    tof_std_ns: float
    amplitude: float
    amplitude_std: float
    snr_db: float
    centre_frequency_mhz: float
    bandwidth_mhz: float
    noise_rms: float
    method: str
    clipped: bool
    overlapped: bool = False
    extra_water_mm: float = 0.0
    separated: bool = False

    def as_json(self) -> dict[str, float | str | bool | None]:
        """The fields of ``ucal echo --json``: finite numbers only (None where a number is
        not finite: JSON has no Infinity or NaN)."""
        return {
            "tof_ns": _finite(self.tof_ns),
            "tof_std_ns": _finite(self.tof_std_ns),
            "amplitude": _finite(self.amplitude),
            "snr_db": _finite(self.snr_db),
            "centre_frequency_mhz": _finite(self.centre_frequency_mhz),
            "bandwidth_mhz": _finite(self.bandwidth_mhz),
            "method": self.method,
            "clipped": self.clipped,
            "overlapped": self.overlapped,
            "separated": self.separated,
        }


def _finite(value: float) -> float | None:
    return float(value) if math.isfinite(value) else None


def delay_crb_ns(rms_bandwidth_mhz: float, snr_eff: float) -> float:
    """Cramér–Rao bound of a delay (ns): ``1 / (2π·β·√SNR_eff)``, β in MHz, SNR_eff = 2E/N0
    (module docstring)."""
    if not snr_eff > 0.0:
        return math.inf
    return 1.0 / (2.0 * math.pi * rms_bandwidth_mhz * 1e-3 * math.sqrt(snr_eff))


def estimate_echo(
    ascan: AScan,
    reference: ReferenceEcho | None = None,
    *,
    gate_ns: tuple[float, float] | None = None,
) -> EchoEstimate:
    """Time the strongest echo of ``ascan`` whose arrival lies in ``gate_ns`` (default: the
    record), against ``reference`` or, without one, by its envelope (module docstring).

    The reference is resampled to the record's interval when they differ. Raises ``NoEcho``
    (a ``ValueError``) when the record holds no echo to time, ``ValueError`` when the gate
    holds no sample of the record.
    """
    gate = _gate(ascan, gate_ns)
    if float(np.ptp(ascan.samples)) == 0.0:
        raise NoEcho(f"every sample is {float(ascan.samples[0]):g}: a constant record")
    if reference is None:
        return _envelope_estimate(ascan, gate)
    return _reference_estimate(ascan, reference.resampled(ascan.dt_ns), gate)


def correlation_tof_ns(
    ascan: AScan, reference: ReferenceEcho, *, gate_ns: tuple[float, float] | None = None
) -> float:
    """The arrival (ns) of the echo in ``gate_ns`` at the peak of its correlation with
    ``reference`` (same sample interval), and nothing else: no noise, water, clipping or
    second echo. What aligns the captures of one echo at one posture, where a reading's
    full estimate (``estimate_echo``) would look for a second echo behind the crude template
    of a first round."""
    _, _, _, lag, _ = _correlation_peak(ascan, reference, _gate(ascan, gate_ns))
    return ascan.t0_ns - reference.t0_ns + lag * ascan.dt_ns


def _gate(ascan: AScan, gate_ns: tuple[float, float] | None) -> tuple[float, float]:
    """``gate_ns`` (default: the record) within the record; ``ValueError`` when it holds
    no sample."""
    lo, hi = gate_ns if gate_ns is not None else (-math.inf, math.inf)
    lo = max(lo, ascan.t0_ns)
    hi = min(hi, ascan.t0_ns + (ascan.n - 1) * ascan.dt_ns)
    if hi < lo:
        raise ValueError(
            f"the gate {gate_ns} ns holds no sample of the record "
            f"({ascan.t0_ns:g}…{ascan.t0_ns + (ascan.n - 1) * ascan.dt_ns:g} ns)"
        )
    return lo, hi


def _correlation_peak(
    ascan: AScan, ref: ReferenceEcho, gate: tuple[float, float]
) -> tuple[Correlator, np.ndarray, np.ndarray, float, float]:
    """The record's correlation with ``ref`` and its peak in the gate: (correlator, its
    correlation at the lags whose arrival is in the gate, those lags, the peak's lag in
    samples, its amplitude)."""
    raw = ascan.samples
    n, dt = ascan.n, ascan.dt_ns
    corr = Correlator.of(ref, n)
    # arrival = t0 − ref.t0 + lag·dt: the whole-sample lag of the largest correlation sample
    # whose arrival is in the gate, then its peak
    x = raw - np.mean(raw)  # an echo sums to 0: the mean is the offset
    c = fft.irfft(fft.rfft(x, corr.n_fft) * corr.conjugate, corr.n_fft)
    lags = np.arange(-(ref.n - 1), n)
    c = c[lags % corr.n_fft]  # the template's correlation at every lag it overlaps the record
    arrivals = ascan.t0_ns - ref.t0_ns + lags * dt
    inside = (arrivals >= gate[0] - 1e-9 * dt) & (arrivals <= gate[1] + 1e-9 * dt)
    if not inside.any():  # a gate narrower than a sample
        inside = np.abs(arrivals - 0.5 * (gate[0] + gate[1])) <= dt
    lag, amplitude = corr.fit(x, float(lags[inside][np.argmax(c[inside])]))
    return corr, c[inside], lags[inside], lag, amplitude


def _reference_estimate(
    ascan: AScan, ref: ReferenceEcho, gate: tuple[float, float]
) -> EchoEstimate:
    raw = ascan.samples
    n, dt = ascan.n, ascan.dt_ns
    corr, c_inside, lags_inside, lag, amplitude = _correlation_peak(ascan, ref, gate)

    # the echo's samples and the quiet ones: the noise, from the quiet ones only
    s0, s1 = ref.support
    idx = np.arange(n)
    in_echo = (idx >= math.floor(lag) + s0 - 2) & (idx < math.ceil(lag) + s1 + 2)
    quiet = ~in_echo & ~ascan.at_rails()
    dc = float(np.mean(raw[quiet] if np.count_nonzero(quiet) >= 32 else raw))
    x = raw - dc
    sigma = noise_rms(x, quiet, ascan.lsb)
    if sigma is None:  # no room outside the echo: the fit's residual
        sigma = float(np.sqrt(np.sum((x - amplitude * corr.model(lag)) ** 2) / max(n - 2, 1)))
        if ascan.lsb is not None:
            sigma = math.hypot(sigma, ascan.lsb / math.sqrt(12.0))
    if not sigma > 0.0:  # a record without noise: its samples' own rounding
        sigma = _resolution(raw) / math.sqrt(12.0)
    _detect(corr, x, c_inside, lags_inside, amplitude, sigma)
    _within_record(corr, lag)
    # the water between: the echo's spectrum is the reference's times exp(−κ·f²)
    plain = corr
    fitted = fit_attenuation(x, corr, lag, in_echo & ~ascan.at_rails(), dt, sigma)
    if fitted[1] == 0.0 and leaves_excess(x, fitted, in_echo, sigma, ref.noise_rms):
        # less water than the reference's: fitted only where the reference as it is leaves
        # an excess that the spectrum through less water takes away (module docstring)
        less = fit_attenuation(
            x, corr, lag, in_echo & ~ascan.at_rails(), dt, sigma, less_water=True
        )
        if less[1] < 0.0 and not leaves_excess(x, less, in_echo, sigma, ref.noise_rms):
            fitted = less
    corr, kappa, lag, amplitude = fitted

    # clipped samples: censored, the echo refitted by the others
    if ascan.rails is None:
        rails = (float(np.min(x)), float(np.max(x)))
        clipped = _guess_clipped(x, rails, corr, lag, amplitude, sigma)
    else:
        rails = (ascan.rails[0] - dc, ascan.rails[1] - dc)
        clipped = ascan.at_rails()
    clipped_echo = bool(np.any(clipped & in_echo))
    if clipped_echo:
        x, lag, amplitude = _refit_censored(x, clipped, rails, corr, lag, amplitude, sigma)

    # the bound with the record's own numbers, and the share of the information the used
    # samples carry (the slope over the reference's band: not the noise the averaging left)
    band = np.abs(ref.spectrum(corr.n_fft)) ** 2 >= ref.band_power_threshold  # before water
    slope = shifted(corr.spectrum * band, corr.n_fft, lag, derivative=True)
    used = ~clipped
    info_all = float(np.sum(slope**2))
    info_used = float(np.sum(slope[:n][used] ** 2))
    # the reference's own noise moves the correlation's peak as the record's does (module
    # docstring): the two add, the reference's scaled by the echo's height
    sigma_eff = math.hypot(sigma, amplitude * ref.noise_rms * through_water(corr, ref, kappa, dt))
    snr_eff = amplitude**2 * corr.energy / sigma_eff**2 if sigma_eff > 0 else math.inf
    std_ns = delay_crb_ns(ref.rms_bandwidth_through_mhz(kappa), snr_eff)
    std_ns *= math.sqrt(info_all / info_used) if info_used > 0 else math.inf
    model = corr.model(lag)
    energy_used = float(np.sum(model[used] ** 2))

    def over(y: np.ndarray, fit: np.ndarray) -> float | None:
        """The residual's excess when another echo shows in it (module docstring), else None."""
        where = in_echo & used
        excess = residual_excess(y, fit, where, sigma_eff)
        samples = int(np.count_nonzero(where))
        shows = another_echo_shows(excess, samples, sigma_eff, amplitude**2 * energy_used)
        return excess if shows else None

    # another echo over this one: more in the echo's samples than the fit and the noise
    excess = over(x, amplitude * model)
    separated = False
    if excess is not None:
        period = 1e3 / ref.rms_bandwidth_mhz / dt  # samples
        found = explained_by_a_pair(
            x, plain, (corr, kappa), lag, in_echo, used, period, dt, sigma, over
        )
        if found is not None:
            corr, kappa, pair = found
            lag, amplitude = pair[:2]
            model = corr.model(lag)
            through = through_water(corr, ref, kappa, dt)
            sigma_eff = math.hypot(sigma, amplitude * ref.noise_rms * through)
            separated, excess = True, None
            std_ns = pair_std_ns(corr, pair, used, sigma_eff, dt)
    overlapped = excess is not None
    if excess is not None:
        std_ns *= math.sqrt(1.0 + excess)
    band_mhz = echo_band(x[in_echo], dt)
    # the amplitude against the reference seen through the water: its peak is the echo's
    peak = band_limited_peak(fft.irfft(corr.spectrum, corr.n_fft)) if kappa != 0.0 else 1.0
    return EchoEstimate(
        tof_ns=ascan.t0_ns - ref.t0_ns + lag * dt,
        tof_std_ns=std_ns,
        amplitude=amplitude * peak,
        amplitude_std=peak * sigma / math.sqrt(energy_used) if energy_used > 0 else math.inf,
        snr_db=_snr_db(amplitude, sigma),
        centre_frequency_mhz=band_mhz.centre_frequency_mhz,
        bandwidth_mhz=band_mhz.bandwidth_mhz,
        noise_rms=sigma,
        method=METHOD_REFERENCE,
        clipped=clipped_echo,
        overlapped=overlapped,
        extra_water_mm=kappa / (2.0 * WATER_NP_PER_MM_MHZ2),
        separated=separated,
    )


def _resolution(samples: np.ndarray) -> float:
    """The step the samples are given to (the smallest difference between two of their
    values): a record without noise is known to that step."""
    steps = np.diff(np.unique(samples))
    return float(steps.min()) if steps.size else 0.0


def _detect(
    corr: Correlator,
    x: np.ndarray,
    c: np.ndarray,
    lags: np.ndarray,
    amplitude: float,
    sigma: float,
) -> None:
    """Raise ``NoEcho`` unless the correlation ``c`` (record ⋆ reference at the gate's whole
    lags ``lags``) has a peak of the reference's polarity, ``amplitude`` (refined) against
    the reference, that noise alone would not give, and none of the other larger."""
    scale = sigma * math.sqrt(corr.energy)  # the std of c for noise alone
    threshold = detection_threshold(c.size)
    best = amplitude * corr.energy / scale
    # the other polarity's peak, refined as this one's (at a few samples a cycle the samples
    # of the correlation miss either by up to a third)
    _, other = corr.fit(-x, float(lags[int(np.argmin(c))]))
    worst = other * corr.energy / scale
    if worst >= threshold and worst - best > INVERTED_SIGMAS * math.sqrt(2.0):  # noise: √2
        raise NoEcho(
            f"the strongest echo is inverted ({worst:.1f} σ against {best:.1f} σ of the "
            "reference's polarity): another reflector's, or a reference of the other sign"
        )
    if best < threshold:
        raise NoEcho(
            f"noise alone: the best match to the reference is {best:.1f} σ, below the "
            f"{threshold:.1f} σ noise passes once in {1 / FALSE_ALARM:.0f} records"
        )


def _within_record(corr: Correlator, lag: float) -> None:
    """Raise ``NoEcho`` when the echo at ``lag`` has more than ``CUT_SHARE`` of its energy
    beyond the record's ends."""
    full = shifted(corr.spectrum, corr.n_fft, lag)
    total = float(np.sum(full**2))
    inside = float(np.sum(full[: corr.n] ** 2))
    if total > 0.0 and inside < (1.0 - CUT_SHARE) * total:
        end = "end" if lag > 0.5 * corr.n else "start"
        raise NoEcho(
            f"the echo is cut by the record's {end}: {100 * (1 - inside / total):.0f} % of "
            "it lies beyond"
        )


def _snr_db(amplitude: float, sigma: float) -> float:
    if sigma <= 0.0:
        return math.inf
    return 20.0 * math.log10(max(abs(amplitude), 1e-300) / sigma)


def _guess_clipped(
    x: np.ndarray,
    rails: tuple[float, float],
    corr: Correlator,
    lag: float,
    amplitude: float,
    sigma: float,
) -> np.ndarray:
    """Rails unknown (``rails``: the record's extremes): the samples on one are clipped when a
    fit without them has the echo more than ``CLIP_SIGMAS`` of the noise and the reference's
    mismatch (``CLIP_SHAPE``) beyond it at one of them (a
    sample at the top of an unclipped record sits above the fit, not below it). Without
    them, not taken as censored: a censored fit pushes each beyond its rail, lifts the echo,
    and so pushes them further, and clean records at four samples a cycle came out clipped."""
    candidates = (x <= rails[0]) | (x >= rails[1])
    _, lag, amplitude = _refit_censored(
        x, candidates, rails, corr, lag, amplitude, sigma, censored=False
    )
    model = amplitude * corr.model(lag)
    clipped = np.zeros(x.size, dtype=bool)
    for sign, rail in ((-1.0, rails[0]), (1.0, rails[1])):
        at = sign * x >= sign * rail
        margin = CLIP_SIGMAS * math.hypot(sigma, CLIP_SHAPE * amplitude)
        # a rail is a plateau: one sample alone at the extreme is the echo's peak, however
        # badly one echo predicts it (another echo over it lifts the peak)
        if np.count_nonzero(at) >= 2 and np.any(sign * model[at] > sign * rail + margin):
            clipped |= at
    return clipped


def _refit_censored(
    x: np.ndarray,
    clipped: np.ndarray,
    rails: tuple[float, float],
    corr: Correlator,
    lag: float,
    amplitude: float,
    sigma: float,
    censored: bool = True,
) -> tuple[np.ndarray, float, float]:
    """Refit with each clipped sample replaced by its expectation beyond its rail given the
    fit (module docstring), or (``censored`` False) by the fit itself, as missing; returns
    (filled record, lag, amplitude)."""
    bottom, top = rails
    high = clipped & (x >= top)
    low = clipped & (x <= bottom)
    filled = x.copy()
    for _ in range(CLIP_ITERATIONS):
        model = amplitude * corr.model(lag)
        if not censored:
            filled[clipped] = model[clipped]
        elif sigma > 0.0:
            filled[high] = model[high] + sigma * _mills((top - model[high]) / sigma)
            filled[low] = model[low] - sigma * _mills((model[low] - bottom) / sigma)
        if censored:
            filled[high] = np.maximum(filled[high], top)
            filled[low] = np.minimum(filled[low], bottom)
        new_lag, amplitude = corr.fit(filled, lag)
        moved = abs(new_lag - lag)
        lag = new_lag
        if moved < CLIP_TOLERANCE:
            break
    return filled, lag, amplitude


def _mills(a: np.ndarray) -> np.ndarray:
    """φ(a)/Q(a): the mean excess over the rail of a unit Gaussian beyond ``a``."""
    return np.asarray(np.exp(stats.norm.logpdf(a) - stats.norm.logsf(a)))


def _envelope_estimate(ascan: AScan, gate: tuple[float, float]) -> EchoEstimate:
    raw = ascan.samples
    n, dt = ascan.n, ascan.dt_ns
    k_lo = max(0, math.ceil((gate[0] - ascan.t0_ns) / dt - 1e-9))
    k_hi = min(n - 1, math.floor((gate[1] - ascan.t0_ns) / dt + 1e-9))
    x = raw - np.mean(raw)
    envelope = np.abs(signal.hilbert(x))
    k = k_lo + int(np.argmax(envelope[k_lo : k_hi + 1]))
    # the echo: where the envelope stays above a quarter of its peak, widened threefold
    below = envelope < 0.25 * envelope[k]
    start = k - int(np.argmax(below[k::-1])) if below[: k + 1].any() else 0
    stop = k + int(np.argmax(below[k:])) if below[k:].any() else n
    in_echo = np.zeros(n, dtype=bool)
    in_echo[max(0, 2 * start - stop) : min(n, 2 * stop - start)] = True
    clipped = ascan.at_rails()
    quiet = ~in_echo & ~clipped
    if np.count_nonzero(quiet) >= 32:
        x = raw - float(np.mean(raw[quiet]))
    if not (below[: k + 1].any() and below[k:].any()):
        raise NoEcho(
            "the echo is cut by the record's "
            + ("start" if not below[: k + 1].any() else "end")
            + ": its envelope does not fall to a quarter of its peak before it"
        )
    sigma = noise_rms(x, quiet, ascan.lsb)
    if sigma is None:  # no room outside the echo: all that is not the echo, or all
        sigma = float(np.std(x[~in_echo] if (~in_echo).any() else x))
    if not sigma > 0.0:
        sigma = _resolution(raw) / math.sqrt(12.0)
    band = echo_band(x[in_echo], dt)

    # the analytic signal band-passed to the echo: a Gaussian of twice the echo's −6 dB width
    n_fft = fft.next_fast_len(2 * n)
    f_mhz = fft.fftfreq(n_fft, dt * 1e-3)
    width_mhz = max(2.0 * band.bandwidth_mhz, 4.0 / (n_fft * dt * 1e-3))
    s_mhz = width_mhz / (2.0 * math.sqrt(2.0 * math.log(2.0)))
    response = np.where(
        f_mhz > 0.0, 2.0 * np.exp(-0.5 * ((f_mhz - band.centre_frequency_mhz) / s_mhz) ** 2), 0.0
    )
    analytic = fft.ifft(fft.fft(x, n_fft) * response)[:n]
    envelope = np.abs(analytic)
    k = k_lo + int(np.argmax(envelope[k_lo : k_hi + 1]))
    # noise alone: |z| Rayleigh with E|z|² = σ²·Σ|h|², above t with probability exp(−t²/E|z|²)
    noise_z = sigma * math.sqrt(float(np.sum(response**2)) / n_fft)
    threshold = noise_z * math.sqrt(math.log(max(k_hi - k_lo + 1, 1) / FALSE_ALARM))
    if envelope[k] < threshold:
        raise NoEcho(
            f"noise alone: the envelope's peak is {envelope[k] / noise_z:.1f} times its noise, "
            f"below the {threshold / noise_z:.1f} noise passes once in {1 / FALSE_ALARM:.0f} "
            "records"
        )
    k = min(max(k, 1), n - 2)
    a, b, c = envelope[k - 1 : k + 2]
    d, curvature = a - c, a - 2.0 * b + c
    if curvature < 0.0:
        delta = 0.5 * d / curvature
        height = b - 0.25 * d * delta
        # first order: ∂δ/∂(a, b, c) and ∂height/∂(a, b, c), then through the filter
        d_delta = np.array([0.5 * (curvature - d), d, -0.5 * (curvature + d)]) / curvature**2
        d_height = np.array([-0.25 * delta, 1.0, 0.25 * delta]) - 0.25 * d * d_delta
        impulse = fft.ifft(response)
        std_ns = sigma * _propagated(d_delta, k, analytic, impulse) * dt
        amplitude_std = sigma * _propagated(d_height, k, analytic, impulse)
    else:  # no peak between samples: the sample itself, to within one interval
        delta, height, std_ns, amplitude_std = 0.0, float(b), dt, sigma
    clipped_echo = bool(np.any(clipped & in_echo))
    if clipped_echo:
        # a flat top: the peak may be anywhere among the clipped samples
        run = np.flatnonzero(clipped & in_echo)
        std_ns = math.hypot(std_ns, (run[-1] - run[0] + 1) * dt / math.sqrt(12.0))
    return EchoEstimate(
        tof_ns=ascan.t0_ns + (k + delta) * dt,
        tof_std_ns=std_ns,
        amplitude=float(height),
        amplitude_std=amplitude_std,
        snr_db=_snr_db(float(height), sigma),
        centre_frequency_mhz=band.centre_frequency_mhz,
        bandwidth_mhz=band.bandwidth_mhz,
        noise_rms=sigma,
        method=METHOD_ENVELOPE,
        clipped=clipped_echo,
    )


def _propagated(weights: np.ndarray, k: int, analytic: np.ndarray, impulse: np.ndarray) -> float:
    """‖∂q/∂x‖ of ``q = Σ_j weights_j·|z_j|`` (j = k−1, k, k+1), ``z = h ⊛ x`` the filtered
    analytic signal: ``∂|z_j|/∂x_n = Re(ū_j·h_{j−n})``, u_j = z_j/|z_j|. Times σ, the std
    of q for white noise."""
    n, n_fft = analytic.size, impulse.size
    gradient = np.zeros(n)
    for j, w in zip(range(k - 1, k + 2), weights, strict=True):
        u = analytic[j] / abs(analytic[j])
        gradient += w * (np.conj(u) * impulse[(j - np.arange(n)) % n_fft]).real
    return float(np.linalg.norm(gradient))
