"""The check's one typed result: its verdict, what moved and by how much, every checked quantity.

``CheckFindings`` is built from the comparisons of ``ucal.check.solve`` (the geometry against the
reference, or a reference check's fit against the profile) and the quantities ``ucal.check.judge``
draws from them and from the echo chain, and gives the verdict's fields, the one-line message
naming what moved, and the history entry; ``CheckResult`` adds what became of the run, and is
what the tables and the ``--json`` object are drawn from.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ucal.check.causes import Cause, causes
from ucal.check.growth import ARM, GROWTH, growth_words, temperature_rise_k
from ucal.check.history import CheckEntry
from ucal.check.judge import (
    CHANGED,
    OUT,
    Quantity,
)
from ucal.check.measure import CheckRun
from ucal.check.profile_fit import ProfileComparison
from ucal.check.solve import (
    GeometryComparison,
)
from ucal.model.fit import CellPrior, readings_approach
from ucal.model.readings import faces_to_json
from ucal.procedure import RunFacts
from ucal.timing import DurationEstimate

#: ``check --json``'s keys of the arm's growth (``CheckFindings.growth_json``).
GROWTH_KEYS = (
    "arm_growth_ppm",
    "arm_growth_ppm_std",
    "arm_temperature_rise_k",
    "arm_temperature_rise_k_std",
)


@dataclass
class CheckFindings:
    """A check's verdict and what it rests on."""

    quantities: list[Quantity]
    named: list[str]  # what moved, each in words with its change
    moved: list[str]  # the parts out of tolerance ("J2", "tool", "water", "transducer", ...)
    reference: CheckEntry | None  # compared against; None: this check records the reference
    geometry: GeometryComparison | None = None
    profile_fit: ProfileComparison | None = None
    unexplained: str = ""  # a misfit no single change accounts for
    run: CheckRun | None = field(default=None, repr=False)  # what was measured
    entry: CheckEntry | None = field(default=None, repr=False)  # once appended to the history
    #: the causes of what moved, with their sizes (``ucal.check.causes``)
    causes: list[Cause] = field(default_factory=list)
    #: changes reported as their own cause, not the cell's (the water's: decision 0016)
    noted: list[str] = field(default_factory=list)
    #: the quantities not determined (σ above the tolerance) → what would determine them
    undetermined: dict[str, str] = field(default_factory=dict)

    @property
    def out_of_tolerance(self) -> bool:
        return bool(self.named) or bool(self.unexplained)

    @property
    def verdict(self) -> str:
        return OUT if self.out_of_tolerance else "ok"

    @property
    def becomes_reference(self) -> bool:
        """A reference check that passed: later checks compare against it."""
        return self.reference is None and not self.out_of_tolerance

    def message(self) -> str:
        """The one-line error of an out-of-tolerance check: what moved and by how much."""
        what = "; ".join(self.named + ([self.unexplained] if self.unexplained else []))
        if self.reference is None:
            return f"the cell is not as its profile says: {what}; no reference recorded"
        return (
            f"the cell is not as commissioned (reference check {self.reference.id}, "
            f"{self.reference.time}): {what}"
        )

    def summary(self) -> str:
        """One line for the history: what moved; or what changed within tolerance (a drift
        to watch), else the largest change against its tolerance."""
        if self.out_of_tolerance:
            return "; ".join(self.named + ([self.unexplained] if self.unexplained else []))
        if self.reference is None:
            return "reference recorded" if self.becomes_reference else "no reference"
        return "; ".join([self._as_commissioned(), *self.noted] + self._undetermined_words())

    def _undetermined_words(self) -> list[str]:
        if not self.undetermined:
            return []
        return ["not determined: " + ", ".join(self.undetermined)]

    def _as_commissioned(self) -> str:
        drifts = [
            q
            for q in self.quantities
            if q.verdict == CHANGED and q.name != "tof_ns" and q.part != "the water"
        ]
        if drifts:
            return "as commissioned; changed within tolerance: " + ", ".join(
                f"{q.name} {_fmt(q.difference or 0.0, q.unit)}" for q in drifts
            )
        judged = [
            q
            for q in self.quantities
            if q.tolerance and q.difference is not None and np.isfinite(q.difference)
        ]
        if not judged:
            return "as commissioned"
        q = max(judged, key=lambda q: abs(q.difference or 0.0) / (q.tolerance or 1.0))
        return (
            f"as commissioned (largest change {q.name} {_fmt(q.difference or 0.0, q.unit)}, "
            f"tolerance {q.tolerance:.3g})"
        )

    def to_json(self) -> dict[str, Any]:
        """The check's fields of the ``--json`` object."""
        out: dict[str, Any] = {
            "verdict": self.verdict,
            "moved": self.moved,
            "named": self.named,
            "reference": None
            if self.reference is None
            else {"id": self.reference.id, "time": self.reference.time},
            "records_reference": self.becomes_reference,
            "quantities": [q.to_json() for q in self.quantities],
            "causes": [c.to_json() for c in self.causes],
            "noted": self.noted,
            "not_determined": [
                {"name": q.name, "std": q.std, "tolerance": q.tolerance, "determined_by": why}
                for q in self.quantities
                if (why := self.undetermined.get(q.name)) is not None
            ],
        }
        if self.run is not None:  # every face read from below: as calibrate's offsets hold
            out["approach"] = readings_approach(self.run.faces)
        out.update(self.growth_json())
        if self.geometry is not None:
            g = self.geometry
            out["fit"] = {
                "chosen": g.chosen,
                "alike": {k: list(v) for k, v in g.alike.items()},
                "tank_alike": g.tank,
                "chi2_unchanged": g.chi2_null,
                "chi2": g.chi2,
                "dof": g.dof,
                "unexplained": g.unexplained,
                "worst": g.worst,
                "cause": g.cause,
            }
        if self.profile_fit is not None:
            p = self.profile_fit
            out["fit"] = {
                "chi2_reduced": p.chi2_reduced,
                "dof": p.dof,
                "verdict": "misfit" if p.misfit else "ok",
                "worst": p.worst,
            }
        return out

    def growth_json(self) -> dict[str, float | None]:
        """The arm's growth since the reference (ppm) and its one sigma, and the temperature
        rise it means (K, aluminium's expansion): fitted with what moved where the arm was
        not chosen (how much it could have grown unseen); ``null`` without a reference."""
        c = next((c for c in self.quantities if c.name == GROWTH), None)
        if c is None or c.difference is None:
            return dict.fromkeys(GROWTH_KEYS)
        k = temperature_rise_k(1.0)
        values = (c.difference, c.std, c.difference * k, None if c.std is None else c.std * k)
        return dict(zip(GROWTH_KEYS, values, strict=True))

    def history_entry(self, digest: str, duration_s: float, prior: CellPrior) -> CheckEntry:
        """The entry this check adds to the profile's history (id and time set on append);
        ``prior``: the check's, whose water (its thermometer's log, or none) the entry keeps
        for a later check to compare with."""
        run = self.run
        assert run is not None
        return CheckEntry(
            id=0,
            time="",
            kind="check",
            verdict=self.verdict,
            reference=self.becomes_reference,
            model_digest=digest,
            duration_s=float(duration_s),
            named=list(self.named),
            summary=self.summary(),
            compared_with=None if self.reference is None else self.reference.id,
            quantities=[q.to_json() for q in self.quantities],
            faces=faces_to_json(run.faces),
            echoes=[e.to_json() for e in run.echoes],
            floor_per_gain=run.floor_per_gain,
            logged_departure_std_c=prior.logged_departure_std_c,
            drift_prior_c_per_min=prior.drift_prior_c_per_min,
            edges=[e.to_json() for e in run.edges],
        )


@dataclass(frozen=True)
class CheckResult:
    """``check``'s result: the findings, and what became of the run (``run.written``: the
    check appended to the history; the profile itself is never written)."""

    findings: CheckFindings
    run: RunFacts
    estimate: DurationEstimate
    postures: list[str]  # the planned postures' labels

    @property
    def measured(self) -> CheckRun:
        assert self.findings.run is not None
        return self.findings.run

    def to_json(self) -> dict[str, Any]:
        """The ``check --json`` object."""
        found, run = self.findings, self.run
        out: dict[str, Any] = {
            **found.to_json(),
            "profile": str(run.profile_path),
            # a check never writes the profile; it is appended to the profile's history
            "written": False,
            "recorded": run.written,
            "history_entry": None if found.entry is None else found.entry.id,
            # time the run took on the cell: simulated time on the simulated cell
            "duration_s": run.duration_s,
            "estimated_s": {"tcp": self.estimate.tcp_s, "rtu": self.estimate.rtu_s},
            "moves": run.moves,
            "pulser_reads": run.reads,
            "postures": self.postures,
            "echoes": [e.to_json() for e in self.measured.echoes],
        }
        if run.truth is not None:
            out["truth_offsets_deg"] = run.truth.joint_offsets_deg
        return out


def _fmt(value: float, unit: str) -> str:
    digits = {"deg": 4, "mm": 3, "m/s": 2, "°C": 2, "dB": 2, "MHz": 2, "ns": 1}.get(unit, 3)
    return f"{value:+.{digits}f} {unit}"


def named_changes(
    geometry: GeometryComparison | None,
    echo: list[Quantity],
    prior: CellPrior,
) -> tuple[list[str], list[str]]:
    """What moved out of tolerance, in words with the change and its std, and the parts'
    short names (``CheckFindings.named``, ``moved``)."""
    named: list[str] = []
    moved: list[str] = []
    if geometry is not None:
        words = {s.name: s.words for s in geometry.suspects}
        found = causes(geometry)
        for suspect in geometry.chosen:
            out = [c for c in found if c.part == suspect]
            if not out:
                continue
            alike = [words[a] for a in geometry.alike.get(suspect, ())]
            tank = geometry.tank.get(suspect)
            alike += [] if tank is None else [tank]
            also = f" (or {' or '.join(alike)}: the check cannot tell them apart)" if alike else ""
            if suspect == ARM:
                text = growth_words(out[0].size, out[0].std, out[0].tolerance)
            elif suspect.startswith("J"):
                c = out[0]
                text = (
                    f"{words[suspect]} ({suspect}) moved by {_fmt(c.size, 'deg')} "
                    f"(± {c.std:.2g} deg; tolerance {c.tolerance:g} deg)"
                )
            else:
                text = f"{words[suspect]} moved: " + "; ".join(c.words() for c in out)
            named.append(text + also)
            moved.append(suspect)
    bad = [q for q in echo if q.verdict == OUT and q.name != "tof_ns"]
    if bad:
        parts = ", ".join(
            f"{q.name} {_fmt(q.difference or 0.0, q.unit)} (± {q.std or 0.0:.2g}; tolerance "
            f"{q.tolerance or 0.0:.2f} {q.unit})"
            for q in bad
        )
        named.append(f"the transducer changed: {parts}")
        moved.append("transducer")
    return named, moved


def unexplained_text(geometry: GeometryComparison) -> str:
    """The misfit left after the selection, in words ("" when none)."""
    if not geometry.unexplained:
        return ""
    return (
        f"the measurements disagree with the reference's beyond what a change of a joint, the "
        f"tool, the block, the water or the arm's length explains (χ² {geometry.chi2:.1f} on "
        f"{geometry.dof} measurements; worst {geometry.worst}): "
        + (geometry.cause or "check the block's faces and the kinematic model (calibrate again)")
    )


def misfit_text(fit: ProfileComparison) -> str:
    """A reference check's disagreement with the profile's calibration, in words."""
    return (
        f"its measurements disagree with the profile's calibration (χ²ᵣ "
        f"{fit.chi2_reduced:.3g} on {fit.dof} measurements; worst {fit.worst}); likely cause: "
        f"{fit.cause}"
    )
