"""The check's plan: calibrate's postures in two configurations, under two minutes."""

from __future__ import annotations

from pathlib import Path

from ucal.check.plan import BUDGET_S, estimate_check, plan_check, plan_summary
from ucal.model.geometry import Configuration
from ucal.profile import load_profile

EXAMPLE = Path(__file__).parents[3] / "profiles" / "example_cell.toml"


def test_six_faces_from_two_azimuths_and_their_time_on_a_real_cell() -> None:
    profile = load_profile(EXAMPLE)
    plan = plan_check(profile, None)
    assert plan.configurations == (Configuration.BASE, Configuration.J1)
    assert len(plan.targets) == 6
    assert plan.echo_labels == ("base/XY", "base/YZ", "base/XZ")
    estimate = estimate_check(plan, profile)
    # over Modbus RTU at 19,200 baud too
    assert estimate.tcp_s < estimate.rtu_s < BUDGET_S
    text = plan_summary(plan, profile, estimate)
    assert "6 normal-incidence measurements" in text and "as the reference" in text
