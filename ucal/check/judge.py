"""The checked quantities and their verdicts: each change against its 3σ and its tolerance.

``ucal.check.solve`` says what moved and by how much; this module turns its comparisons, and the
echo chain's figures, into ``Quantity`` rows judged by one rule (``judge``: beyond 3σ and beyond
the tolerance is out of tolerance; beyond 3σ within it, changed; docs/decisions/0009), which the
result, the tables and ``--json`` are drawn from.

Three verdicts for what the check compares: *moved* (``OUT``: beyond 3σ and its tolerance, a
cause named with its size, exit 1), ``OK`` (within 3σ of no change, its σ within its
tolerance) and ``NOT_DETERMINED`` (its σ above its tolerance: the postures cannot tell whether
it moved by its tolerance, so it is never called ok; ``ucal.check.observe`` says what would
determine it); ``CHANGED`` (beyond 3σ within the tolerance) is a drift to watch. The water
has no tolerance in a check: its change beyond 3σ is ``CHANGED``, reported as its own cause
(docs/decisions/0016).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ucal.check.causes import temperature_of
from ucal.check.growth import GROWTH, temperature_rise_k
from ucal.check.profile_fit import ProfileComparison
from ucal.check.solve import (
    N_SIGMA,
    GeometryComparison,
)
from ucal.model.fit import OFFSETS, SOUND, CellPrior

#: Verdicts of a checked quantity.
OK = "ok"
CHANGED = "changed"  # beyond 3σ but within tolerance: a drift to watch
OUT = "out of tolerance"
RECORDED = "recorded"  # a reference check: nothing to compare with
NOT_MEASURED = "not measured"
NOT_DETERMINED = "not determined"  # its σ above its tolerance: neither ok nor moved

#: The echo chain's tolerances: amplitude and SNR (dB) against the reference; the centre
#: frequency and the −6 dB bandwidth as fractions of the reference's (EN 12668-2's tolerances
#: of a transducer against its data sheet: ±10 % and ±15 %), the centre frequency of a reference
#: check against the profile's ``[transducer] frequency_mhz``.
AMPLITUDE_TOLERANCE_DB = 2.0
SNR_TOLERANCE_DB = 6.0
CENTRE_FREQUENCY_TOLERANCE = 0.10
BANDWIDTH_TOLERANCE = 0.15
#: Floors of the echo figures' stds: amplitude (dB, a few readings at the peak), the open-water
#: noise floor (dB, the median of eight readings of a quantised amplitude: where the floor reads
#: one level, it is known to within a level, ±50 %, 2.5 dB at one sigma; a check one level apart
#: from its reference moves the SNR by 6 dB, on the simulated cell's 8-bit amplitude too),
#: A-scan frequencies (MHz).
AMPLITUDE_STD_FLOOR_DB = 0.05
FLOOR_STD_DB = 2.5
FREQUENCY_STD_FLOOR_MHZ = 0.05


@dataclass(frozen=True)
class Quantity:
    """One checked quantity: the check's value against the reference's, its one-sigma, the
    tolerance it is judged by and the verdict (``OK``, ``CHANGED``, ``OUT``, ``RECORDED``,
    ``NOT_MEASURED``)."""

    name: str  # "J2", "tool_rx_deg", "sound_speed_m_s", "amplitude_db", ...
    part: str  # what it belongs to: "joint 2", "the tool", "the water", "the transducer", ...
    unit: str
    value: float | None
    baseline: float | None
    std: float | None
    tolerance: float | None
    verdict: str

    @property
    def difference(self) -> float | None:
        if self.value is None or self.baseline is None:
            return None
        return self.value - self.baseline

    def to_json(self) -> dict[str, object]:
        def num(v: float | None) -> float | None:
            return None if v is None or not np.isfinite(v) else float(v)

        return {
            "name": self.name,
            "part": self.part,
            "unit": self.unit,
            "value": num(self.value),
            "baseline": num(self.baseline),
            "difference": num(self.difference),
            "std": num(self.std),
            "tolerance": num(self.tolerance),
            "verdict": self.verdict,
        }


def judge(difference: float, std: float, tolerance: float | None, may_fail: bool = True) -> str:
    """The 3σ-and-tolerance rule: ``OUT`` beyond both (when ``may_fail``), ``CHANGED`` beyond
    3σ only, ``NOT_DETERMINED`` within 3σ with a σ above the tolerance (or none), else
    ``OK``; ``NOT_MEASURED`` without a difference."""
    if not np.isfinite(difference):
        return NOT_MEASURED
    if not abs(difference) > N_SIGMA * std:
        return NOT_DETERMINED if tolerance is not None and not std <= tolerance else OK
    if may_fail and tolerance is not None and abs(difference) > tolerance:
        return OUT
    return CHANGED


def unit_of(parameter: str) -> str:
    """The unit of a cell unknown, from its name."""
    if parameter in OFFSETS or parameter.endswith("_deg"):
        return "deg"
    if parameter.endswith("_mm"):
        return "mm"
    if parameter.endswith("_ppm"):
        return "ppm"
    return "m/s"


def geometry_quantities(comparison: GeometryComparison, prior: CellPrior) -> list[Quantity]:
    """Each unknown of every suspect, the water's temperature and the arm's temperature rise
    its growth means (``ucal.check.growth``), as checked quantities (module docstring: the
    water without a tolerance)."""
    words = {s.name: s.words for s in comparison.suspects}
    out = []
    for c in comparison.changes:
        tolerance = c.tolerance if np.isfinite(c.tolerance) else None
        if c.out_of_tolerance:
            verdict = OUT
        elif c.chosen and c.significant:
            verdict = CHANGED
        else:
            verdict = NOT_DETERMINED if tolerance is not None and not c.std <= tolerance else OK
        out.append(
            Quantity(
                c.parameter,
                words[c.suspect],
                unit_of(c.parameter),
                c.baseline + c.change,
                c.baseline,
                c.std,
                tolerance,
                verdict,
            )
        )
        if c.parameter == SOUND[0]:
            t0 = temperature_of(prior, c.baseline)
            t1 = temperature_of(prior, c.baseline + c.change)
            slope = c.change / (t1 - t0) if t1 != t0 else 1.0
            out.append(
                Quantity(
                    "water_temperature_c",
                    words[c.suspect],
                    "°C",
                    t1,
                    t0,
                    c.std / abs(slope),
                    None,
                    verdict,
                )
            )
        if c.parameter == GROWTH:  # the temperature rise it means: K per ppm
            k, part = temperature_rise_k(1.0), words[c.suspect]
            rise = (c.change * k, 0.0, c.std * k, c.tolerance * k, verdict)
            out.append(Quantity("arm_temperature_rise_k", part, "K", *rise))
    return out


def profile_quantities(comparison: ProfileComparison, prior: CellPrior) -> list[Quantity]:
    """A reference check's offsets and water as fitted, against the profile's (recorded)."""
    out = [
        Quantity(
            name,
            f"joint {name[1]}",
            "deg",
            float(comparison.offsets_deg[j]),
            float(comparison.profile_offsets_deg[j]),
            float(comparison.offsets_std_deg[j]),
            None,
            RECORDED,
        )
        for j, name in enumerate(OFFSETS)
    ]
    c0 = prior.sound_speed_m_s
    out.append(
        Quantity(
            SOUND[0],
            "the water",
            "m/s",
            comparison.sound_speed_m_s,
            c0,
            comparison.sound_speed_std_m_s,
            None,
            RECORDED,
        )
    )
    return out


def _pairs(reference: list[Any], check: list[Any], key: str) -> list[tuple[float, float]]:
    """The figure ``key`` of the readings at the postures both measured (finite in both)."""
    ref = {r.label: getattr(r, key) for r in reference}
    out = []
    for c in check:
        a, b = ref.get(c.label), getattr(c, key)
        if a is not None and b is not None and np.isfinite(a) and np.isfinite(b):
            out.append((float(a), float(b)))
    return out


def _mean_change(pairs: list[tuple[float, float]], floor: float) -> tuple[float, float, float]:
    """Mean reference value, mean check value, and the std of the mean change (from the
    changes' scatter, not below ``floor``)."""
    ref = np.array([p[0] for p in pairs])
    chk = np.array([p[1] for p in pairs])
    d = chk - ref
    scatter = float(np.std(d, ddof=1) / np.sqrt(d.size)) if d.size > 1 else floor
    return float(ref.mean()), float(chk.mean()), max(scatter, floor)


def echo_quantities(reference: list[Any], check: list[Any]) -> list[Quantity]:
    """The echo chain against the reference's (``EchoReading``s at the same postures): mean
    time of flight, amplitude at 0 dB gain, SNR, the A-scans' centre frequency and bandwidth."""
    out = []
    tof = _pairs(reference, check, "tof_ns")
    if tof:
        stds = {r.label: r.tof_std_ns for r in reference}
        var = sum(stds.get(c.label, 0.0) ** 2 + c.tof_std_ns**2 for c in check)
        base, value, _ = _mean_change(tof, 0.0)
        std = float(np.sqrt(var)) / len(tof)
        # the geometry decides what a time of flight change means: never out by itself
        verdict = judge(value - base, std, None, may_fail=False)
        out.append(Quantity("tof_ns", "the echo", "ns", value, base, std, None, verdict))
    specs: tuple[tuple[str, str, str, float, float | None, bool], ...] = (
        (
            "amplitude_db",
            "the transducer",
            "dB",
            AMPLITUDE_STD_FLOOR_DB,
            AMPLITUDE_TOLERANCE_DB,
            False,
        ),
        ("snr_db", "the transducer or the receiver", "dB", 0.0, SNR_TOLERANCE_DB, False),
        (
            "centre_frequency_mhz",
            "the transducer",
            "MHz",
            FREQUENCY_STD_FLOOR_MHZ,
            CENTRE_FREQUENCY_TOLERANCE,
            True,
        ),
        (
            "bandwidth_mhz",
            "the transducer",
            "MHz",
            FREQUENCY_STD_FLOOR_MHZ,
            BANDWIDTH_TOLERANCE,
            True,
        ),
    )
    amp_std = AMPLITUDE_STD_FLOOR_DB
    for name, part, unit, floor, tol, relative in specs:
        pairs = _pairs(reference, check, name)
        if not pairs:
            out.append(Quantity(name, part, unit, None, None, None, None, NOT_MEASURED))
            continue
        base, value, std = _mean_change(pairs, floor)
        if name == "amplitude_db":
            amp_std = std
        elif name == "snr_db":
            std = float(np.hypot(amp_std, FLOOR_STD_DB))
        tolerance = None if tol is None else tol * abs(base) if relative else tol
        out.append(
            Quantity(
                name, part, unit, value, base, std, tolerance, judge(value - base, std, tolerance)
            )
        )
    return out


def echo_record(check: list[Any], frequency_mhz: float) -> list[Quantity]:
    """A reference check's echo chain: recorded, and the A-scans' centre frequency against the
    transducer's nominal one (``CENTRE_FREQUENCY_TOLERANCE`` of it)."""
    out = []
    for name, part, unit in (
        ("tof_ns", "the echo", "ns"),
        ("amplitude_db", "the transducer", "dB"),
        ("snr_db", "the transducer or the receiver", "dB"),
        ("centre_frequency_mhz", "the transducer", "MHz"),
        ("bandwidth_mhz", "the transducer", "MHz"),
    ):
        values = np.array(
            [v for c in check if (v := getattr(c, name)) is not None and np.isfinite(v)]
        )
        if not values.size:
            out.append(Quantity(name, part, unit, None, None, None, None, NOT_MEASURED))
            continue
        mean = float(values.mean())
        if unit != "MHz":  # the postures' water paths differ: their mean has no one-sigma
            out.append(Quantity(name, part, unit, mean, None, None, None, RECORDED))
            continue
        scatter = float(np.std(values, ddof=1) / np.sqrt(values.size)) if values.size > 1 else 0.0
        std = max(scatter, FREQUENCY_STD_FLOOR_MHZ)
        if name == "centre_frequency_mhz":
            tol = CENTRE_FREQUENCY_TOLERANCE * frequency_mhz
            verdict = judge(mean - frequency_mhz, std, tol)
            verdict = RECORDED if verdict == OK else verdict
            out.append(Quantity(name, part, unit, mean, frequency_mhz, std, tol, verdict))
        else:
            out.append(Quantity(name, part, unit, mean, None, std, None, RECORDED))
    return out
