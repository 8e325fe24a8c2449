"""The first check of a profile: its measurements against the calibration the profile holds."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ucal.cell import CellProfile
from ucal.model.fit import OFFSETS, SOUND, CellPrior, offsets_prior_std_deg, solve_cell
from ucal.model.geometry import FaceMeasurement
from ucal.model.least_squares import cell_table


@dataclass(frozen=True)
class ProfileComparison:
    """The first check of a profile: its measurements fitted with the profile's calibration as
    the prior of the joint offsets (``[calibration] std_deg``), the cell's other tolerances as
    theirs."""

    offsets_deg: np.ndarray  # as fitted
    offsets_std_deg: np.ndarray
    profile_offsets_deg: np.ndarray
    sound_speed_m_s: float
    sound_speed_std_m_s: float
    chi2_reduced: float
    dof: int
    misfit: bool
    worst: str
    cause: str


def compare_to_profile(
    profile: CellProfile, prior: CellPrior, check: list[FaceMeasurement]
) -> ProfileComparison:
    """Whether the check's measurements agree with the calibration the profile holds: the χ²
    of the fit whose joint-offset priors are the calibration's values and stds (a misfit at
    ``MISFIT_P``: the cell is not as calibrated). A few postures leave most offsets to their
    priors, so this is a consistency test, not a new calibration."""
    table = cell_table(prior)
    table.prior_stds[[table.index(n) for n in OFFSETS]] = offsets_prior_std_deg(profile)
    # the DH table, the drift and the lost motion free with their priors, as calibrate fits
    # them: held exact, a table within its tolerance misfits the check's faces
    cell = solve_cell(prior, check, table=table)
    q = cell.quality
    return ProfileComparison(
        np.array([cell.value(n) for n in OFFSETS]),
        np.array([cell.sigma(n) for n in OFFSETS]),
        np.asarray(profile.joint_offsets_deg, float),
        cell.value(SOUND[0]),
        cell.sigma(SOUND[0]),
        q.chi2_reduced,
        q.dof,
        q.verdict == "misfit",
        q.worst,
        q.cause,
    )
