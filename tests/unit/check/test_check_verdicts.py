"""The check's verdicts (moved, ok, not determined), the causes they name with their sizes, and
the plan's statement of what its postures see and determine (no processes, no motion)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from ucal.check.causes import causes, suspect_causes
from ucal.check.judge import (
    CHANGED,
    NOT_DETERMINED,
    OK,
    OUT,
    geometry_quantities,
    judge,
)
from ucal.check.observe import observability
from ucal.check.plan import plan_check
from ucal.check.solve import Change, GeometryComparison, suspects
from ucal.model.fit import prior_from_profile
from ucal.profile import load_profile

EXAMPLE = Path(__file__).parents[3] / "profiles" / "example_cell.toml"


@pytest.mark.parametrize(
    ("difference", "std", "tolerance", "verdict"),
    [
        (0.30, 0.01, 0.05, OUT),  # beyond 3σ and its tolerance: moved
        (0.03, 0.005, 0.05, CHANGED),  # beyond 3σ within its tolerance: a drift to watch
        (0.01, 0.01, 0.05, OK),  # within 3σ, σ within its tolerance
        (0.0, 1.59, 0.05, NOT_DETERMINED),  # σ far above its tolerance: never ok
        (1.017, 1.59, 0.05, NOT_DETERMINED),  # the tool of the issue: +1.017 mm, σ 1.59 mm
    ],
)
def test_the_judge_says_moved_ok_or_not_determined(
    difference: float, std: float, tolerance: float, verdict: str
) -> None:
    assert judge(difference, std, tolerance) == verdict


def comparison(changes: dict[str, tuple[float, float]], chosen: list[str]) -> GeometryComparison:
    """A comparison whose every suspect's unknowns change as ``changes`` says (name → change,
    std; the rest 0 ± 0.001), ``chosen`` having moved."""
    prior = prior_from_profile(load_profile(EXAMPLE))
    found = suspects(prior)
    rows = [
        Change(p, s.name, 0.0, *changes.get(p, (0.0, 0.001)), tol, s.name in chosen)
        for s in found
        for p, tol in zip(s.parameters, s.tolerances, strict=True)
    ]
    return GeometryComparison(rows, chosen, {}, 100.0, 10.0, 36, False, "", found)


def test_an_unchosen_quantity_whose_sigma_exceeds_its_tolerance_is_not_determined() -> None:
    prior = prior_from_profile(load_profile(EXAMPLE))
    geometry = comparison({"J6": (0.0007, 0.074), "tool_y_mm": (0.02, 1.68)}, [])
    q = {q.name: q for q in geometry_quantities(geometry, prior)}
    assert q["J6"].verdict == NOT_DETERMINED and q["tool_y_mm"].verdict == NOT_DETERMINED
    assert q["J2"].verdict == OK and q["block_x_mm"].verdict == OK
    # the water has no tolerance in a check: its change is its own cause (decision 16)
    assert q["sound_speed_m_s"].tolerance is None and q["sound_speed_m_s"].verdict == OK
    assert "tool_rz_deg" not in q  # a turn of the tool about its beam moves nothing


def test_a_warmer_tank_is_changed_never_out_of_tolerance() -> None:
    prior = prior_from_profile(load_profile(EXAMPLE))
    geometry = comparison({"sound_speed_m_s": (3.08, 0.003)}, ["water"])
    q = {q.name: q for q in geometry_quantities(geometry, prior)}
    assert q["sound_speed_m_s"].verdict == CHANGED
    assert q["water_temperature_c"].verdict == CHANGED
    assert causes(geometry) == []  # nothing of the cell moved


def test_a_tool_remounted_across_the_beam_is_named_across_with_its_length() -> None:
    geometry = comparison({"tool_x_mm": (0.2121, 0.011), "tool_y_mm": (-0.2121, 0.011)}, ["tool"])
    (cause,) = causes(geometry)
    assert (cause.part, cause.what) == ("tool", "across the beam")
    assert cause.size == pytest.approx(0.3, abs=1e-3) and cause.std == pytest.approx(0.011)
    along = {c.what: c for c in suspect_causes(geometry, "tool")}["along the beam"]
    assert abs(along.size) < 1e-9 and not along.moved


def test_the_plan_states_what_its_edges_and_faces_see_and_determine() -> None:
    profile = load_profile(EXAMPLE)
    plan = plan_check(profile, None)
    assert [line.axis for line in plan.edges] == [0, 0, 1, 1]
    obs = observability(profile, plan.targets, plan.edges)
    # the faces see the tool along the beam, never across it; the edges see it across
    assert all("tool across" not in obs.sees[t.label] for t in plan.targets)
    assert all("tool along" in obs.sees[t.label] for t in plan.targets)
    assert all("tool across" in obs.sees[line.label] for line in plan.edges)
    for name in ("J2", "tool_x_mm", "tool_y_mm", "tool_z_mm", "block_x_mm", "sound_speed_m_s"):
        assert obs.determined(name), (name, obs.std[name])
    # a turn of joint 6 turns the beam about itself: not determined
    assert obs.undetermined() == ["J6"]
    # joint 1 and a turn of the block about the base axis are one rotation; the second
    # azimuth tells joint 2 from a tilt of the block
    assert "the block" in obs.alike["J1"] and "J2" not in obs.alike
    # without the edges the tool across the beam is not determined
    blind = observability(profile, plan.targets, ())
    assert {"tool_x_mm", "tool_y_mm"} <= set(blind.undetermined())
    assert np.isfinite(blind.std["tool_x_mm"]) and blind.std["tool_x_mm"] > 1.0
