"""The offsets level's solve: the exact solution with the cell's tolerances as priors and
paper 000's for comparison, from the faces ``ucal.measure.sequence`` measured."""

from __future__ import annotations

import logging

from ucal.calibration.exact import OffsetSolution, solve_exact_with_priors
from ucal.calibration.paper import solve_paper
from ucal.cell import CellProfile
from ucal.measure.sequence import CalibrationRun
from ucal.model.fit import TOOL, prior_from_profile
from ucal.model.targets import geometry

log = logging.getLogger(__name__)


def beam_fixed(beam: str) -> tuple[str, ...]:
    """The unknowns ``--beam fixed`` holds at the profile's values: the tool's orientation
    (and so the beam direction); none otherwise."""
    return TOOL[3:] if beam == "fixed" else ()


def solve(
    profile: CellProfile, run: CalibrationRun, beam: str = "auto"
) -> tuple[OffsetSolution, OffsetSolution | None]:
    """Both solutions from one run's measurements: exact with the cell's tolerances as priors,
    and paper 000's (None if it cannot be applied, e.g. a DH table of another structure).

    ``beam``: "fixed" holds the tool orientation (and so the beam direction) at the profile's
    value; otherwise it is an unknown with the profile's tolerance as prior.
    """
    prior = prior_from_profile(profile)
    exact = solve_exact_with_priors(prior, run.measurements, fixed=beam_fixed(beam))
    try:
        paper = solve_paper(
            geometry(profile),
            run.measurements,
            profile.joint_offsets_deg,
            exact.unobservable_joints,
            exact.condition_number,
            prior=prior,
            reasons=exact.unobservable_reasons,
        )
    except Exception as e:
        log.warning("paper method failed: %s", e)
        paper = None
    return exact, paper
