"""A misfit's likely cause names physics: never a quantity fitted where no cell can be."""

from __future__ import annotations

import numpy as np

from ucal.model.fit import PARAMETERS, CellPrior, ParameterTable, ResidualRow, likely_cause
from ucal.profile.models import load_model

PRIOR = CellPrior(
    load_model("tx90l"),
    np.zeros(6),
    np.array([0.0, 0.0, 80.0]),
    np.zeros(3),
    np.array([600.0, 0.0, -300.0]),
    np.zeros(3),
    20.0,
)
TABLE = ParameterTable(PARAMETERS, PRIOR.values(), PRIOR.stds())


def rows(distances: list[float]) -> tuple[ResidualRow, ...]:
    return tuple(ResidualRow(f"m{i}", (0.1, -0.1), d) for i, d in enumerate(distances))


def dragged(name: str, value: float, pull: float) -> tuple[dict[str, float], np.ndarray]:
    estimate = TABLE.prior.copy()
    estimate[TABLE.index(name)] = value
    return {name: pull, "J2": 0.1}, estimate


def test_a_sound_speed_no_water_has_is_evidence_not_the_cause() -> None:
    pulls, estimate = dragged("sound_speed_m_s", 1025.0, -74.0)
    cause = likely_cause(rows([0.5, -0.3, 0.2, -0.4, 0.1, 0.3]), pulls, TABLE, estimate, PRIOR)
    assert cause.startswith("the model does not explain the data")
    assert "1025" in cause and "not a cause" in cause and "outside the" not in cause
    assert "lost motion" in cause and "drift" in cause


def test_residuals_trending_with_time_name_a_drift() -> None:
    trend = [-3.0, -2.1, -1.0, -0.2, 0.9, 2.0, 3.1, 3.9]
    pulls, estimate = dragged("sound_speed_m_s", 1025.0, -74.0)
    cause = likely_cause(rows(trend), pulls, TABLE, estimate, PRIOR)
    assert "trend with the order of the readings" in cause and "tank" in cause
    # a plausible quantity dragged far: the drift it absorbs is named, the quantity as evidence
    pulls, estimate = dragged("dh2_a_mm", TABLE.prior[TABLE.index("dh2_a_mm")] + 0.3, 31.4)
    cause = likely_cause(rows(trend), pulls, TABLE, estimate, PRIOR)
    assert cause.startswith("the water-path residuals trend") and "dh2_a_mm fitted at" in cause


def test_a_plausible_quantity_beyond_its_tolerance_stays_the_cause() -> None:
    a = TABLE.prior[TABLE.index("dh2_a_mm")]
    pulls, estimate = dragged("dh2_a_mm", a + 0.3, 31.4)
    cause = likely_cause(rows([0.5, -0.3, 0.2, -0.4, 0.1, 0.3]), pulls, TABLE, estimate, PRIOR)
    assert cause.startswith("dh2_a_mm fitted at") and "outside the kinematic model" in cause


def test_an_effect_the_priors_absorbed_is_named_before_the_quantity_it_drags() -> None:
    """A DH length 5σ off carries most of the χ²: alone it is the cause; where the score
    test says a drift of the tank would remove nearly all of it, the drift is named and the length
    is the evidence that absorbed it."""
    d = TABLE.prior[TABLE.index("dh5_d_mm")]
    pulls, estimate = dragged("dh5_d_mm", d + 1.02, 5.1)
    pulls |= {"dh5_a_mm": 3.0, "sound_speed_m_s": 2.1}
    data = rows([0.9, -0.8, 0.7, -0.9, 0.8, -0.7, 0.9, -0.8])
    assert likely_cause(data, pulls, TABLE, estimate, PRIOR).startswith("dh5_d_mm fitted at")
    gains = {"sound_speed_drift_m_s_per_min": 47.3}
    cause = likely_cause(data, pulls, TABLE, estimate, PRIOR, gains)
    assert cause.startswith("a drift of the sound speed during the run explains")
    assert cause.endswith("(dh5_d_mm fitted at 1.02, 5.1σ from the profile's 0, absorbing it)")
