"""The block gauge of joint 1: what is known relative to the block, what absolutely."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ucal.model.gauge import GAUGE_BASE, GAUGE_BLOCK, J1Gauge, j1_relative_to_block


def test_a_level_block_turns_j1_by_its_yaw_off_the_placed_one() -> None:
    assert j1_relative_to_block(0.8, np.array([0.0, 0.0, 0.3]), 0.0) == pytest.approx(0.5)
    assert j1_relative_to_block(0.8, np.array([0.0, 0.0, 10.3]), 10.0) == pytest.approx(0.5)
    # tilted, the block's yaw about its own axis is a turn about the base axis to second order
    tilted = j1_relative_to_block(0.8, np.array([0.5, -0.5, 0.3]), 0.0)
    assert tilted == pytest.approx(0.5, abs=1e-5) and tilted != 0.5


def test_hand_placed_block_leaves_j1_relative_a_fixture_makes_it_absolute() -> None:
    hand = J1Gauge(0.003, 0.5)
    assert hand.frame == GAUGE_BLOCK
    assert hand.absolute_std_deg == pytest.approx(math.hypot(0.003, 0.5))
    assert "relative to the block as placed" in hand.statement()
    fixture = J1Gauge(0.003, 0.01)
    assert fixture.frame == GAUGE_BASE and "J1 absolute" in fixture.statement()
    unseen = J1Gauge(float("nan"), 0.5)
    assert "not determined" in unseen.statement()
