"""The quick centring's verdict on its own crosses: a centre where they settle, none where they
still walk towards a main lobe beyond their reach (no processes, the crosses stubbed)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from ucal.measure.search import PeakSearch


class CrossTowards(PeakSearch):
    """A search whose cross sweeps step towards a main lobe at ``lobe`` (deg, per joint) by at
    most ``reach`` (deg) each: the half-maximum run of a ±0.6° sweep that does not hold the
    lobe lies at the sweep's end nearest to it. The gain is levelled at once."""

    lobe: np.ndarray
    reach: float

    def _cross(
        self, q: np.ndarray, j: int, half_tilt_deg: float, max_step_deg: float = 0.04
    ) -> tuple[np.ndarray, float]:
        q = q.copy()
        q[j] += float(np.clip(self.lobe[j] - q[j], -self.reach, self.reach))
        return q, 0.5

    def set_fit_gain(self, q: np.ndarray, averages: int) -> None:
        pass


@pytest.mark.parametrize(("lobe_deg", "centred"), [(0.4, True), (3.0, False)])
def test_a_quick_centring_still_walking_after_its_rounds_has_not_centred(
    lobe_deg: float, centred: bool
) -> None:
    """The main lobe 0.4° from the prediction is centred; 3° away (an echo above the threshold
    at the prediction: a side lobe's), the crosses still step towards it after their three
    rounds: no centre, so that the caller acquires instead of fitting a peak half-way."""
    rig = SimpleNamespace(
        read=lambda: SimpleNamespace(amplitude=0.5),
        threshold=lambda: 0.02,
        spacing=SimpleNamespace(main_lobe_deg=0.04),
    )
    search = CrossTowards(rig, 300.0, (3, 4), np.radians(np.eye(2)), 20.0)  # type: ignore[arg-type]
    q_pred = np.array([0.0, 30.0, 100.0, 0.0, 50.0, 0.0])
    search.lobe = q_pred + np.array([0, 0, 0, 0.1, lobe_deg, 0])
    search.reach = 0.3
    q = search.quick_centre(q_pred)
    if centred:
        assert q is not None
        np.testing.assert_allclose(q, search.lobe, atol=1e-9)
    else:
        assert q is None
