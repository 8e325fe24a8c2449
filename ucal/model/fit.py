"""Joint offsets with the cell's uncertain quantities as prior-constrained unknowns.

Unknowns (named, see ``PARAMETERS``): the six joint offsets δ (deg), the block pose (corner
``c`` in mm, orientation ``[rx, ry, rz]`` in deg, Staubli convention), the tool frame in the
flange (position mm, orientation deg), the speed of sound ``c_w`` (m/s) and its drift ``ċ``
(m/s per min), the DH table's lengths and twists (``d``, ``a`` in mm, ``α`` in deg) and each
joint's lost motion ``b`` (deg). Each has a prior: the profile's value
with the profile's declared one-sigma tolerance (``[sample] position_std_mm``,
``rotation_std_deg``; ``[tool]`` likewise; the sound speed from ``[water] temperature_c`` ±
``temperature_std_c`` through Marczak's c(T), the drift 0 ± |dc/dT|·``[water]
drift_std_c_per_min``; ``[robot] dh_length_std_mm``, ``dh_angle_std_deg`` for a table that was
not identified on this robot, ``[calibration] dh_std`` for each parameter the full level
identified; the lost motion 0 ± ``[robot] backlash_std_deg``); the offsets get a broad prior
(``OFFSET_PRIOR_STD_DEG``) that only regularises what the data cannot see. Each face
measurement (``ucal.model.geometry``) contributes three rows

    r_tilt = tilt_components(b(q+δ)) / σ_tilt                         model eq. (1), two rows
    r_dist = (n_k·(p(q'+δ) − c)/cos θ − (c_w(t)/c_0)·d) / σ_d        model eq. (2)

with ``d`` the water path computed with the profile's sound speed ``c_0``, read at the
readings ``q'`` (``distance_joints``), where the beam may be θ off normal (cos θ = −n_k·b), at
the sound speed of its time ``c_w(t) = c_w + ċ·(t − t_ref)`` (``t_ref`` the mean time of the
readings: ``c_w`` is the speed in the middle of the run; a reading without a time sees
``c_w``); each prior one row ``(x − x_prior)/σ_prior``.

Lost motion: the link lags its encoder by half of it against the joint's last motion (the
reading's ``approach``, ±1), ``q_link = q_read − approach·b/2``. The offsets ``δ`` are those of
the positive approach (SPEC.md ``approach``: every posture reached from below), so the joints
enter at ``q + δ + (1 − approach)/2·b``: ``b`` is seen only where a joint is read from both
sides, and is held at 0 elsewhere (a gauge, ``least_squares.hold_unseen``); the drift likewise
when the readings carry no time. ``scipy.optimize.least_squares`` minimises the sum of squares and
returns its own (forward-difference) Jacobian ``J`` of the whole augmented problem.

Uncertainty: ``Cov = (JᵀJ)⁻¹`` of the augmented problem is the covariance of every unknown
with the nuisance unknowns marginalised (their priors enter as rows, so the declared
tolerances propagate into the offsets' std), multiplied by ``max(1, χ²ᵣ)`` when the data
disagree with the model, plus what the drift's curvature moves them by
(``least_squares.curvature_covariance``): a real tank does not warm at a steady rate (it
approaches the room's temperature, a heater cycles), so each reading's sound speed is off the
fitted line by ½·c̈·(t − t_ref)²; c̈ is not fitted but carried as 0 ± |dc/dT|·``[water]
drift_std_c_per_min`` / D, the rate turning by its declared tolerance over the run's D
minutes. Physics decides what that std carries:

* the block's yaw and δ1 are one rotation about the base axis: no measurement separates them,
  so ``std(δ1) ≥ rotation_std_deg[2]`` in the robot's base frame; the callers hold the yaw as
  placed and give δ1 relative to the block (``ucal.model.gauge``), absolute only with a
  doweled, levelled fixture;
* at one J1 azimuth, a block tilt about the joint-2 axis and δ2 are one rotation about that
  axis (the corner takes up the translation): ``std(δ2)`` carries the tilt tolerance unless
  the block is also seen from another J1 azimuth (configuration ``"j1"`` of the sequence);
* a constant time-of-flight delay and the tool's offset along the beam shift every water path
  alike: the block corner along the three normals absorbs them (they are not fitted apart);
* with the beam on the joint-6 axis, δ6 turns nothing the data see (only the tool tilt's
  azimuth, itself a tolerance).

A joint whose std exceeds ``max_std_deg`` and whose variance comes mainly from a prior (its own
broad prior: the data do not see it; a tolerance: it is confounded with that quantity) is
reported unobservable with the reason, and keeps its profile value.

Fit quality: ``χ²`` over all rows has ``dof`` = number of data rows (every unknown has a prior
row); ``verdict`` is ``misfit`` when P(χ²_dof > χ²) < ``MISFIT_P``.

The code lives in four modules, re-exported here: ``priors`` (the unknowns, their priors and
the parameter table), ``residuals`` (the rows above), ``least_squares`` (the fit and its
covariance) and ``quality`` (the fit's verdict and the likely cause of a misfit).
"""

from __future__ import annotations

from ucal.model.least_squares import (
    MAX_STD_DEG,
    AugmentedFit,
    CellFit,
    ExtraRows,
    RunEffects,
    hold_unseen,
    solve_augmented,
    solve_cell,
)
from ucal.model.priors import (
    BACKLASH,
    BETA,
    BLOCK,
    DELAY,
    DELAY_PRIOR_STD_NS,
    DH,
    DRIFT,
    OFFSET_PRIOR_STD_DEG,
    OFFSETS,
    PARAMETERS,
    PLATE,
    PRIOR_MEANING,
    SOUND,
    TOOL,
    CellPrior,
    ParameterTable,
    offsets_prior_std_deg,
    prior_from_profile,
)
from ucal.model.quality import (
    FAR_PULL_SIGMA,
    MISFIT_P,
    PHYSICAL_SPAN,
    FitQuality,
    ResidualRow,
    likely_cause,
    physically_possible,
    residual_pattern,
    verdict,
)
from ucal.model.residuals import (
    MeasurementArrays,
    cell_geometry,
    data_residuals,
    measurement_label,
    readings_approach,
    reference_time_min,
    rpy_matrix,
    table_geometry,
)

__all__ = [
    "BACKLASH",
    "BETA",
    "BLOCK",
    "DELAY",
    "DELAY_PRIOR_STD_NS",
    "DH",
    "DRIFT",
    "FAR_PULL_SIGMA",
    "MAX_STD_DEG",
    "MISFIT_P",
    "OFFSETS",
    "OFFSET_PRIOR_STD_DEG",
    "PARAMETERS",
    "PHYSICAL_SPAN",
    "PLATE",
    "PRIOR_MEANING",
    "SOUND",
    "TOOL",
    "AugmentedFit",
    "CellFit",
    "CellPrior",
    "ExtraRows",
    "FitQuality",
    "MeasurementArrays",
    "ParameterTable",
    "ResidualRow",
    "RunEffects",
    "cell_geometry",
    "data_residuals",
    "hold_unseen",
    "likely_cause",
    "measurement_label",
    "offsets_prior_std_deg",
    "physically_possible",
    "prior_from_profile",
    "readings_approach",
    "reference_time_min",
    "residual_pattern",
    "rpy_matrix",
    "solve_augmented",
    "solve_cell",
    "table_geometry",
    "verdict",
]
