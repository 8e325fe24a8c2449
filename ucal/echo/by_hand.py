"""A pulser set by hand checked against what its A-scans show, before the first motion.

ucal cannot read a front panel: a cell whose pulser-receiver is set by hand
(``drivers.pulser.manual``) declares its settings in ``[pulser]`` (``ucal.profile.by_hand``),
and before anything moves ucal reads a few A-scans where the arm stands, at the declared gain
(no gain on the host) and without averaging, and refuses a declaration the records disagree
with (``ProfileError``, exit 2, naming the key and what was measured):

* **Clipping.** A record with samples on the digitiser's rails: the panel's gain is higher
  than declared, or too high for the digitiser's range; a clipped echo stays clipped whatever
  gain ucal applies on the host.
* **The gain, from the receiver's noise.** The receiver's noise referred to its input,
  σ_in (``input_noise_uv``, µV rms a sample), comes out of it amplified by the gain:
  σ_p = σ_in · 10^(g/20) / V_fs of full screen (``full_screen_v``). The records' noise σ_q is
  the median of 16-sample blocks' mean squares over the median of χ²₁₆/16 (``noise_rms``: an
  echo in a minority of the blocks does not move it); the digitiser's rounding adds LSB²/12
  (Sheppard) and its front end a noise of its own, about half a step, so the receiver's is
  σ_r = √(σ_q² − LSB²/12) at most, and the gain the noise says is g_m = g + 20·log10(σ_r/σ_p).
  Refused: noise more than ``GAIN_TOLERANCE_DB`` above both the declared gain's and the
  digitiser's own (σ_q > 2·max(σ_p, LSB): the panel's gain is higher than declared), or, where
  the declared gain's noise is well resolved (σ_p ≥ 2 LSB), records ``GAIN_TOLERANCE_DB``
  quieter than it (lower). A declared gain whose noise lies under the digitiser's step is
  checked from above only (said, not refused): the receiver's noise is then the digitiser's.
* **The centre frequency**, of an echo that stands ``ECHO_SNR_DB`` above the noise: the middle
  of its −6 dB band (``ucal.echo.ascan.echo_band``) against ``[transducer] frequency_mhz``
  (the pulse frequency the panel is tuned to), refused beyond ``FREQUENCY_TOLERANCE`` (a
  transducer's own centre is within some 10 % of its nominal; the water's α ∝ f² lowers a
  broadband echo's centre by a few per cent more over the cell's paths). Where the arm stands
  over no echo, the first echo the run times is checked the same way before it is used
  (``FirstEchoCheck``): the arm has then moved, but nothing was measured or written.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any

import numpy as np

from drivers.digitizer.base import AScanRecord, EchoTimer, EchoTiming
from drivers.pulser.base import PulserSettings
from ucal.echo.ascan import AScan, noise_rms
from ucal.echo.timing import NoEcho, estimate_echo
from ucal.errors import ProfileError

if TYPE_CHECKING:
    from drivers.pulser.manual import ManualPulser

log = logging.getLogger(__name__)

#: Largest difference between the declared gain and the one the noise says (dB): a factor 2
#: in the receiver's noise, a data sheet's figure against one receiver, or a band of other
#: width.
GAIN_TOLERANCE_DB = 6.0
#: Largest relative difference between an echo's centre frequency and the declared one.
FREQUENCY_TOLERANCE = 0.25
#: Peak signal-to-noise ratio (dB) of an echo whose spectrum is read.
ECHO_SNR_DB = 20.0
#: Records read where the arm stands.
RECORDS = 4


@dataclass(frozen=True)
class Declared:
    """What the profile declares of the pulser set by hand: its gain (dB), its pulse frequency
    (MHz, ``[transducer] frequency_mhz``), its input noise (µV rms), the digitiser's full
    screen (V), and the profile that declares it (for the messages)."""

    gain_db: float
    frequency_mhz: float
    input_noise_uv: float
    full_screen_v: float = 1.0
    profile: str = "the profile"

    @property
    def noise_fsh(self) -> float:
        """σ_p: the receiver's noise the declared gain gives (fraction of full screen)."""
        return self.input_noise_uv * 1e-6 * 10 ** (self.gain_db / 20) / self.full_screen_v


def records_at_the_panel(
    pulser: ManualPulser, declared: Declared, settings: PulserSettings
) -> tuple[list[AScanRecord], tuple[float, float]]:
    """``RECORDS`` records of ``pulser`` over the gate of ``settings``, at the declared gain
    (no gain on the host) and without averaging, and that gate (ns); ``pulser`` is left so
    configured."""
    panel = replace(settings, gain_db=declared.gain_db, averages=1)
    pulser.configure(panel)
    return [pulser.read_ascan_record() for _ in range(RECORDS)], panel.gate_ns


@dataclass(frozen=True)
class Echo:
    """An echo the records show: its peak (fraction of full screen), SNR (dB), centre
    frequency (MHz), and whether it was clipped."""

    amplitude: float
    snr_db: float
    centre_frequency_mhz: float
    clipped: bool


@dataclass(frozen=True)
class Findings:
    """What the records show: their noise σ_q and the digitiser's step (fraction of full
    screen), whether a sample sat on a rail (and the largest |sample|), the strongest echo
    (None: none ``ECHO_SNR_DB`` above the noise), the gain the noise says (``gain_db``; None
    where the declared gain's noise is under the digitiser's step, whose noise is then all
    the records show: ``gain_db_above`` is the gain that would show) and the verdict:
    ``"ok"``, ``"higher"`` or ``"lower"`` than declared, or ``"from above"``."""

    noise_fsh: float
    lsb_fsh: float
    clipped: bool
    peak_fsh: float
    echo: Echo | None
    gain_db: float | None
    gain: str
    records: int
    gain_db_above: float | None = None
    notes: list[str] = field(default_factory=list)

    def as_json(self) -> dict[str, Any]:
        """For ``ucal status`` and a run's record."""
        echo = self.echo
        return {
            "records": self.records,
            "noise_fsh": self.noise_fsh,
            "lsb_fsh": self.lsb_fsh,
            "clipped": self.clipped,
            "peak_fsh": self.peak_fsh,
            "gain_db_measured": self.gain_db,
            "gain_db_would_show_above": self.gain_db_above,
            "gain": self.gain,
            "echo": None
            if echo is None
            else {
                "amplitude": echo.amplitude,
                "snr_db": echo.snr_db,
                "centre_frequency_mhz": echo.centre_frequency_mhz,
                "clipped": echo.clipped,
            },
            "notes": list(self.notes),
        }


def echo_of(record: AScanRecord, gate_ns: tuple[float, float]) -> Echo | None:
    """The strongest echo of ``record`` in the gate, None where none stands ``ECHO_SNR_DB``
    above the noise."""
    ascan = AScan(
        record.t0_ns,
        record.dt_ns,
        np.asarray(record.samples, float),
        rails=record.rails,
        lsb=record.lsb if record.lsb > 0 else None,
    )
    try:
        found = estimate_echo(ascan, None, gate_ns=gate_ns)
    except (NoEcho, ValueError):
        return None
    if not (math.isfinite(found.snr_db) and found.snr_db >= ECHO_SNR_DB):
        return None
    return Echo(
        abs(float(found.amplitude)),
        float(found.snr_db),
        float(found.centre_frequency_mhz),
        bool(found.clipped),
    )


def look(records: list[AScanRecord], declared: Declared, gate_ns: tuple[float, float]) -> Findings:
    """What ``records`` (fractions of full screen, no gain on the host, no averaging) show
    (module docstring)."""
    if not records:
        raise ValueError("no record to look at")
    lsb = max(float(r.lsb) for r in records)
    sigmas = []
    for r in records:
        x = np.asarray(r.samples, float)
        sigma = noise_rms(x - np.mean(x), np.ones(x.size, bool))
        sigmas.append(0.0 if sigma is None else sigma)
    sigma_q = float(np.median(sigmas))
    clipped = any(r.clipped for r in records)
    peak = max(float(np.max(np.abs(r.samples))) for r in records)
    echoes = [e for e in (echo_of(r, gate_ns) for r in records) if e is not None]
    echo = max(echoes, key=lambda e: e.snr_db) if echoes else None
    sigma_p = declared.noise_fsh
    sigma_r = math.sqrt(max(sigma_q**2 - lsb**2 / 12.0, 1e-12 * sigma_q**2, 1e-300))
    gain_db = declared.gain_db + 20 * math.log10(sigma_r / sigma_p)
    tolerance = 10 ** (GAIN_TOLERANCE_DB / 20)
    notes: list[str] = []
    above = None
    if sigma_q > tolerance * max(sigma_p, lsb):
        verdict = "higher"
    elif sigma_p >= tolerance * lsb:
        verdict = "lower" if sigma_r < sigma_p / tolerance else "ok"
    else:
        verdict = "from above"
        above = declared.gain_db + 20 * math.log10(tolerance * lsb / sigma_p)
        notes.append(
            f"the declared gain's noise ({sigma_p:.3g} of full screen) is under the "
            f"digitiser's step ({lsb:.3g}): the records ({sigma_q:.3g}) would show a gain "
            f"above {above:.1f} dB, not a lower one"
        )
    found = gain_db if verdict != "from above" else None
    return Findings(sigma_q, lsb, clipped, peak, echo, found, verdict, len(records), above, notes)


def judge(found: Findings, declared: Declared) -> None:
    """Refuse (``ProfileError``, exit 2) a declaration the records disagree with (module
    docstring); log what could not be checked."""
    where = declared.profile
    gain = declared.gain_db
    if found.clipped:
        raise ProfileError(
            where,
            "pulser.gain_db",
            f"{gain:g} dB, but the A-scans where the arm stands are clipped (a sample on the "
            f"digitiser's rail, {found.peak_fsh:.2f} of full screen): the front panel's gain "
            "is higher than declared, or too high for the digitiser's range",
        )
    if found.gain in ("higher", "lower"):
        raise ProfileError(
            where,
            "pulser.gain_db",
            f"{gain:g} dB, but the A-scans' noise says {found.gain_db:.1f} dB "
            f"({found.noise_fsh:.3g} of full screen for an input noise of "
            f"{declared.input_noise_uv:g} µV, pulser.input_noise_uv): set the front panel to "
            "the profile's gain, or declare the one it has",
        )
    for note in found.notes:
        log.info("pulser set by hand (%s): %s", where, note)
    if found.echo is not None:
        judge_frequency(found.echo, declared, "where the arm stands")


def judge_frequency(echo: Echo, declared: Declared, where: str) -> None:
    """Refuse an echo whose centre frequency is not the declared one (``ProfileError``)."""
    f_d, f_m = declared.frequency_mhz, echo.centre_frequency_mhz
    if not abs(f_m - f_d) <= FREQUENCY_TOLERANCE * f_d:
        raise ProfileError(
            declared.profile,
            "transducer.frequency_mhz",
            f"{f_d:g} MHz, but the echo {where} is centred at {f_m:.2f} MHz (beyond "
            f"±{100 * FREQUENCY_TOLERANCE:g} %): the pulser's frequency or the transducer is "
            "not the profile's",
        )


class FirstEchoCheck:
    """An echo timer that checks the centre frequency of the first echo it times
    (``judge_frequency``) before handing it on, then times as ``timer`` does; every other
    attribute is ``timer``'s."""

    def __init__(self, timer: EchoTimer, declared: Declared):
        self.timer = timer
        self.declared = declared
        self.checked = False

    def __getattr__(self, name: str) -> Any:
        return getattr(self.__dict__["timer"], name)

    def __call__(self, record: AScanRecord, gate_ns: tuple[float, float]) -> EchoTiming:
        timing = self.timer(record, gate_ns)
        if not self.checked and math.isfinite(timing.tof_ns):
            echo = echo_of(record, gate_ns)
            if echo is not None:
                judge_frequency(echo, self.declared, "first timed")
                self.checked = True
        return timing
