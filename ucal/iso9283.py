"""ISO 9283's figures of a robot's pose accuracy and repeatability, by the standard's formulas.

A pose Pk is commanded n times (the cycles); the attained positions x_j give the pose accuracy
``AP = |x̄ − x_c|`` (and its components ``AP_x``, ``AP_y``, ``AP_z``: x̄ − x_c) and the pose
repeatability ``RP = l̄ + 3·S_l``, with ``l_j = |x_j − x̄|``, ``l̄`` their mean and ``S_l`` their
standard deviation (n − 1); the orientation's accuracy is the mean of the attained deviations
(a, b, c) and its repeatability 3·S of each. ``verify --iso9283`` measures them
(``ucal.verify.iso9283``); a simulated cell's truth is given by the same formulas
(``ucal.sim.truth``).
"""

from __future__ import annotations

import numpy as np

#: The standard's five poses, P1 the cube's centre.
POSE_NAMES = ("P1", "P2", "P3", "P4", "P5")


def standard_figures(x: np.ndarray, commanded: np.ndarray) -> dict[str, np.ndarray]:
    """ISO 9283's position figures of attained positions ``x`` (..., n, 3) against
    ``commanded`` (3,): ``ap_xyz`` (..., 3), ``ap``, ``l_mean``, ``s_l``, ``rp`` (...)."""
    mean = x.mean(axis=-2)
    ap_xyz = mean - commanded
    dist = np.linalg.norm(x - mean[..., None, :], axis=-1)
    l_mean = dist.mean(axis=-1)
    s_l = dist.std(axis=-1, ddof=1)
    return {
        "ap_xyz": ap_xyz,
        "ap": np.linalg.norm(ap_xyz, axis=-1),
        "l_mean": l_mean,
        "s_l": s_l,
        "rp": l_mean + 3.0 * s_l,
    }


def orientation_figures(abc: np.ndarray) -> dict[str, np.ndarray]:
    """ISO 9283's orientation figures of attained deviations ``abc`` (..., n, 3; deg):
    ``ap_abc`` (mean) and ``rp_abc`` (3·S) per component."""
    return {"ap_abc": abc.mean(axis=-2), "rp_abc": 3.0 * abc.std(axis=-2, ddof=1)}
