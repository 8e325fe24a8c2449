"""How well a calibration fit explains its measurements: the ``fit`` object of SPEC.md, each
measurement's residuals, the verdict and, for a misfit, the likely cause from where the misfit
sits and what the residuals' pattern shows (a trend with time, a split by approach).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.special import chdtrc

from ucal.model.geometry import FaceMeasurement
from ucal.model.priors import BETA, DH, OFFSETS, PRIOR_MEANING, CellPrior, ParameterTable
from ucal.model.residuals import approach_signs, measurement_label

#: Probability below which the χ² of the fit is called a misfit.
MISFIT_P = 1e-3


@dataclass(frozen=True)
class ResidualRow:
    """One measurement's normalised residuals (dimensionless) and its label; when it was
    read (min) and each joint's approach sign, where the measurement says."""

    label: str
    tilt: tuple[float, float]
    distance: float
    time_min: float | None = None
    approach: tuple[float, ...] | None = None

    @property
    def norm(self) -> float:
        return float(np.sqrt(self.tilt[0] ** 2 + self.tilt[1] ** 2 + self.distance**2))


@dataclass(frozen=True)
class FitQuality:
    """The ``fit`` object of SPEC.md, plus per-measurement residuals and the likely cause."""

    chi2_reduced: float
    dof: int
    rms_tilt_deg: float
    rms_distance_mm: float
    worst: str
    verdict: str
    cause: str = ""
    residuals: tuple[ResidualRow, ...] = ()
    prior_pulls: dict[str, float] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        return {
            "chi2_reduced": self.chi2_reduced,
            "dof": self.dof,
            "rms_tilt_deg": self.rms_tilt_deg,
            "rms_distance_mm": self.rms_distance_mm,
            "worst": self.worst,
            "verdict": self.verdict,
        }


def verdict(chi2: float, dof: int, misfit_p: float = MISFIT_P) -> str:
    """``misfit`` when P(χ²_dof > χ²) < ``misfit_p``, else ``ok``."""
    return "misfit" if float(chdtrc(dof, chi2)) < misfit_p else "ok"


def residual_rows(
    meas: list[FaceMeasurement], res: np.ndarray, extra_labels: tuple[str, ...] = ()
) -> tuple[ResidualRow, ...]:
    """The rows of ``res`` (3 per measurement, then one per extra label) as ``ResidualRow``."""
    n_face = 3 * len(meas)
    r = res[:n_face].reshape(-1, 3)
    signs = approach_signs(meas)
    return tuple(
        ResidualRow(
            measurement_label(m),
            (float(r[i, 0]), float(r[i, 1])),
            float(r[i, 2]),
            m.time_min,
            None if m.approach is None else tuple(float(s) for s in signs[i]),
        )
        for i, m in enumerate(meas)
    ) + tuple(
        ResidualRow(label, (0.0, 0.0), float(v))
        for label, v in zip(extra_labels, res[n_face : n_face + len(extra_labels)], strict=True)
    )


def fit_quality(
    table: ParameterTable,
    estimate: np.ndarray,
    prior: CellPrior,
    meas: list[FaceMeasurement],
    res: np.ndarray,
    n_data: int,
    chi2: float,
    dof: int,
    misfit_p: float,
    extra_labels: tuple[str, ...] = (),
    gains: dict[str, float] | None = None,
) -> FitQuality:
    """The quality of a ``solve_cell`` fit from its residual vector ``res`` (data rows, then
    one prior row per free parameter that has a prior); ``gains``: the χ² each of the run's
    effects would remove (``ucal.model.least_squares.effect_gains``)."""
    rows = residual_rows(meas, res[:n_data], extra_labels)
    r = res[: 3 * len(meas)].reshape(-1, 3)
    tilt_deg = np.array([r[i, :2] * m.tilt_std_deg for i, m in enumerate(meas)])
    dist_mm = np.array([r[i, 2] * m.distance_std_mm for i, m in enumerate(meas)])
    free = table.free_names
    prior_names = [n for n in free if np.isfinite(table.prior_stds[table.index(n)])]
    pulls = {n: float(v) for n, v in zip(prior_names, res[n_data:], strict=True)}
    worst_row = max(rows, key=lambda x: x.norm)
    worst_pull = max(
        ((n, v) for n, v in pulls.items() if n not in OFFSETS),
        key=lambda kv: abs(kv[1]),
        default=("", 0.0),
    )
    worst = worst_row.label
    if abs(worst_pull[1]) > worst_row.norm:
        worst = f"prior {worst_pull[0]}"
    judged = verdict(chi2, dof, misfit_p)
    cause = likely_cause(rows, pulls, table, estimate, prior, gains) if judged == "misfit" else ""
    return FitQuality(
        chi2_reduced=chi2 / dof,
        dof=dof,
        rms_tilt_deg=float(np.sqrt(np.mean(tilt_deg**2))),
        rms_distance_mm=float(np.sqrt(np.mean(dist_mm**2))),
        worst=worst,
        verdict=judged,
        cause=cause,
        residuals=rows,
        prior_pulls=pulls,
    )


#: A pull beyond this many of its prior's σ is evidence that something is absorbed there, not
#: by itself the cause.
FAR_PULL_SIGMA = 10.0
#: How far from its profile value each kind of quantity can physically be (the sound speed: the
#: range of water from 0 to 70 °C, m/s; its drift: 1 °C/min; lost motion: a worn gear's
#: 0.2°); a fit beyond it explains nothing about the cell.
PHYSICAL_SPAN: dict[str, float | tuple[float, float]] = {
    "sound_speed_m_s": (1400.0, 1560.0),
    "sound_speed_drift_m_s_per_min": 3.0,
    **{f"backlash_J{j}": 0.2 for j in range(1, 7)},
    "block_x_mm": 50.0,
    "block_y_mm": 50.0,
    "block_z_mm": 50.0,
    "block_rx_deg": 5.0,
    "block_ry_deg": 5.0,
    "block_rz_deg": 10.0,
    "tool_x_mm": 5.0,
    "tool_y_mm": 5.0,
    "tool_z_mm": 10.0,
    "tool_rx_deg": 5.0,
    "tool_ry_deg": 5.0,
    "tool_rz_deg": 10.0,
    **{n: 2.0 for n in DH if n.endswith("_mm")},
    **{n: 0.5 for n in DH if n.endswith("_deg")},
}
#: Correlation of the water-path residuals with time beyond which they trend.
TREND_CORRELATION = 0.8
#: Difference of the mean residual between the two approaches of a joint, in its standard
#: error, beyond which the residuals split by approach.
SPLIT_SIGMA = 4.0


def physically_possible(name: str, value: float, profile_value: float) -> bool:
    """Whether a fitted quantity lies where a real cell could put it (``PHYSICAL_SPAN``)."""
    span = PHYSICAL_SPAN.get(name)
    if span is None:
        return True
    if isinstance(span, tuple):
        return span[0] <= value <= span[1]
    return abs(value - profile_value) <= span


def trend_pattern(rows: tuple[ResidualRow, ...]) -> str:
    """The water paths' residuals trending with the readings' time (with their order where
    the readings carry no time), in words, or ""."""
    timed = [r for r in rows if r.time_min is not None]
    with_time = len(timed) >= 6
    if not with_time:
        timed = list(rows)
    dist = np.array([r.distance for r in timed], float)
    if len(dist) < 6 or float(np.std(dist)) == 0.0:
        return ""
    t = (
        np.array([r.time_min for r in timed], float)
        if with_time
        else np.arange(len(timed), dtype=float)
    )
    if float(np.std(t)) == 0.0:
        return ""
    corr = float(np.corrcoef(t, dist)[0, 1])
    if abs(corr) < TREND_CORRELATION:
        return ""
    what = "with their time" if with_time else "with the order of the readings (their time)"
    return (
        f"the water-path residuals trend {what} (correlation {corr:+.2f}): a drift during "
        "the run, most often the tank warming or cooling (the sound speed changing) faster "
        "than [water] drift_std_c_per_min allows or not at a steady rate; let the water "
        "settle, state its drift, or measure again and compare"
    )


def approach_pattern(rows: tuple[ResidualRow, ...]) -> str:
    """The residuals splitting by the approach of one joint (readings reached from above
    against those from below), in words, or ""."""
    sided = [r for r in rows if r.approach is not None]
    if len(sided) < 4:
        return ""
    signs = np.array([r.approach for r in sided], float)
    res = np.array([[r.tilt[0], r.tilt[1], r.distance] for r in sided], float)
    best = (0.0, -1)
    for j in range(6):
        up, down = res[signs[:, j] > 0], res[signs[:, j] < 0]
        if len(up) < 2 or len(down) < 2:
            continue
        # unit-variance rows: the standard error of a difference of means
        split = np.abs(up.mean(0) - down.mean(0)) / np.sqrt(1 / len(up) + 1 / len(down))
        if float(split.max()) > best[0]:
            best = (float(split.max()), j)
    if best[0] < SPLIT_SIGMA:
        return ""
    return (
        f"the residuals split by the approach of J{best[1] + 1} ({best[0]:.1f}σ between the "
        "readings reached from above and from below): lost motion beyond [robot] "
        "backlash_std_deg, or a joint whose lost motion changes with the load; state it, or "
        "approach every posture from one side"
    )


#: Share of the data's χ² an effect must remove to be named as the misfit's cause.
EXPLAINED_SHARE = 0.5


def effect_pattern(gains: dict[str, float], chi2: float, run: str = "the run") -> str:
    """The effect of the run that explains most of a misfit (``gains``: the χ² each would
    remove, freed beyond its prior), in words, or "" if none explains ``EXPLAINED_SHARE`` of
    the fit's χ² ``chi2`` (its data rows' and the nuisance priors' pulls); ``run`` names the
    run the tank's effects belong to (a check fits two)."""
    if not gains:
        return ""
    name, gain = max(gains.items(), key=lambda kv: kv[1])
    if gain < max(25.0, EXPLAINED_SHARE * chi2):
        return ""
    share = f"{100 * min(gain / chi2, 1.0):.0f} % of the misfit"
    if name.startswith("backlash_J"):
        joint = name.removeprefix("backlash_")
        return (
            f"lost motion of {joint} explains {share}: the residuals split by the approach of "
            f"{joint} (readings reached from above against those from below) beyond [robot] "
            "backlash_std_deg; state it, or approach every posture from one side"
        )
    if name.startswith("sound_speed_curvature"):
        return (
            f"a drift of the sound speed that turns during {run} explains {share}: the "
            "water-path residuals bend with their time, the tank's rate changing (water "
            "settling towards the room, a heater cycling) faster than [water] "
            "drift_std_c_per_min allows over the run; let the water settle or hold the heater "
            "off while measuring"
        )
    return (
        f"a drift of the sound speed during {run} explains {share}: the water-path "
        "residuals trend with their time, the tank warming or cooling faster than [water] "
        "drift_std_c_per_min allows; let the water settle, or state its drift"
    )


def residual_pattern(rows: tuple[ResidualRow, ...]) -> str:
    """What the residuals' pattern shows, or "": a trend with time points at a drift (the
    tank), a split by a joint's approach at its lost motion, not at a quantity of the cell."""
    return trend_pattern(rows) or approach_pattern(rows)


def effect_cause(
    rows: tuple[ResidualRow, ...],
    pulls: dict[str, float],
    table: ParameterTable,
    estimate: np.ndarray,
    gains: dict[str, float] | None = None,
) -> str:
    """The cause of a misfit that the priors or the run's effects name, or "" (then the
    measurements themselves disagree with the model, which each solver words for its own).

    If the priors carry most of the χ² (the data fit, but only by moving a quantity beyond its
    tolerance), the cell is outside its declared tolerance (block placed worse than stated,
    water warmer, tool off, a tank drifting faster). A quantity dragged beyond
    ``FAR_PULL_SIGMA`` is named as evidence; dragged where no real cell could put it
    (``PHYSICAL_SPAN``), it is not offered as the cause: the residuals' pattern is (a drift
    over the run, lost motion), or the message says that the model does not explain the data.
    The pattern is the run's effect that would remove most of the χ² (``effect_pattern`` of
    ``gains``; named before any quantity it drags, however far), else what the residuals show
    by themselves (``residual_pattern``). ``pulls``: every prior row's pull by name (the
    offsets' are not causes and are left out).
    """
    tilt2 = sum(r.tilt[0] ** 2 + r.tilt[1] ** 2 for r in rows)
    dist2 = sum(r.distance**2 for r in rows)
    nuisance = {n: p for n, p in pulls.items() if n not in OFFSETS}
    prior2 = sum(p**2 for p in nuisance.values())
    # the score test's Δχ² is the whole fit's: an effect the priors absorbed shows there
    effect = effect_pattern(gains or {}, tilt2 + dist2 + prior2)
    pattern = effect or residual_pattern(rows)
    if nuisance and prior2 > tilt2 + dist2:
        name, pull = max(nuisance.items(), key=lambda kv: abs(kv[1]))
        value = estimate[table.index(name)]
        prior_v = table.prior[table.index(name)]
        what = PRIOR_MEANING.get(name, name)
        evidence = (
            f"{name} fitted at {value:.4g}, {abs(pull):.1f}σ from the profile's {prior_v:.4g}"
        )
        if not physically_possible(name, float(value), float(prior_v)):
            return (
                f"the model does not explain the data: to fit them it drags {evidence}, where no "
                f"cell can be (evidence, not a cause); "
                + (
                    pattern
                    or "look for what the model lacks: lost motion (residuals that change sign "
                    "with the approach direction), a drift over the run (residuals that trend "
                    "with time), the transducer's frequency or size, or the DH table"
                )
            )
        if effect or (abs(pull) > FAR_PULL_SIGMA and pattern):
            return f"{pattern} ({evidence}, absorbing it)"
        return f"{evidence}: the cell is outside {what}; correct the profile or widen its tolerance"
    return pattern


def likely_cause(
    rows: tuple[ResidualRow, ...],
    pulls: dict[str, float],
    table: ParameterTable,
    estimate: np.ndarray,
    prior: CellPrior,
    gains: dict[str, float] | None = None,
) -> str:
    """A sentence naming the most likely cause of a misfit, from where the misfit sits: the
    priors or the run's effects (``effect_cause``); otherwise the measurements themselves
    disagree with the model: residuals mostly in the water paths point at the kinematic model
    (link lengths; at the full level, whose table carries Hayati's twist, at an error the
    identified table does not describe), mostly in the tilts at the tool frame or the block's
    faces.
    """
    cause = effect_cause(rows, pulls, table, estimate, gains)
    if cause:
        return cause
    tilt2 = sum(r.tilt[0] ** 2 + r.tilt[1] ** 2 for r in rows)
    dist2 = sum(r.distance**2 for r in rows)
    full_level = BETA[0] in table.names
    if dist2 >= tilt2 and full_level:
        return (
            "the water paths disagree with the identified kinematic model: an error the DH "
            "table with Hayati's twist does not describe (elasticity under the arm's weight, a "
            "gear's eccentricity), or check the sound speed, the step and the block faces"
        )
    if dist2 >= tilt2:
        return (
            "the water paths disagree with the kinematic model across the stepped "
            "configurations (link lengths or joint twists differ from the DH table): "
            "calibrate with --level full, or check the sound speed and the block faces"
        )
    return (
        "the normal-incidence postures disagree with the model: check the tool frame "
        "(run tool-frame) and that the block's faces are flat and perpendicular"
        + ("" if full_level else "; a kinematic model error (--level full) can also show here")
    )
