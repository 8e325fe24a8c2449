"""Hayati's twist in the kinematic model agrees with the simulated cell's chain."""

from __future__ import annotations

import numpy as np

from ucal.cell import CellProfile, WorldTruth
from ucal.kinematics.dh import fk
from ucal.profile.models import load_model
from ucal.sim.cell import SimulatedCell


def test_beta_in_fk_matches_the_simulated_cell() -> None:
    model = load_model("tx90l")
    beta = np.array([0.0, 0.05, 0.0, 0.0, 0.0, 0.0])
    world = WorldTruth.nominal(CellProfile(model)).replace(dh_beta_deg=beta)
    cell = SimulatedCell(world)
    q = np.array([30.5, 31.2, 109.5, 10.0, 39.4, 30.5])
    twisted = fk(model.with_dh(model.dh, beta), q)
    np.testing.assert_allclose(twisted, cell.true_flange(q), atol=1e-9)
    # 0.05° about link 2's y axis moves the flange by about a forearm's length × 0.05°
    shift = np.linalg.norm(twisted[:3, 3] - fk(model, q)[:3, 3])
    assert 0.1 < shift < 1.0
