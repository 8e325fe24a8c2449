"""What each of the check's measurements sees, and which quantities its postures determine.

Computed from the fit the check solves (``ucal.check.solve.ChangeFit``), linearised at the
profile's values, with the planned postures read twice (the reference and the check) at a
nominal noise (``NOMINAL``: a water path to 0.01 mm, a normal incidence to 0.002°, a crossing
to 0.015 mm, what the simulated cell's 8-bit amplitude leaves):

* a measurement *sees* a quantity when a change of the quantity's tolerance moves one of its
  rows by more than its one sigma (the water: a change of ``WATER_SEEN_C``);
* a quantity is *determined* when its change alone (the others held) is known to within its
  tolerance (σ ≤ tolerance), as ``ucal.check.judge`` rules: a σ above it is ``not
  determined``, never ``ok``;
* a quantity is *not told* from another suspect when a change of ``ALIKE_TOLERANCES`` of its
  tolerances, which the readings see (χ² above ``ALIKE_CHI2``), is explained by that suspect
  within ``ALIKE_CHI2`` (the cell's other unknowns free): the check would name both.

The faces see the joints, the beam's direction, the tool along the beam, the block, the
water (its paths of 40 to 160 mm tell the sound speed from a length) and the arm's growth
(each tool centre moved in proportion to its flange's distance from the base,
``ucal.check.growth``); the edge crossings see
the tool across the beam, which no water path does, and the block in x and y. A turn of joint
6 turns the beam about itself, on a tool whose centre is on the joint's axis: nothing an echo
sees, nothing a scan feels; ``what_would_determine`` says so with the figures of the tool.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ucal.acoustics import sound_speed_slope_m_s_per_c
from ucal.cell import CellProfile
from ucal.check.edges import EdgeLine, EdgeReading
from ucal.check.growth import GROWTH
from ucal.check.solve import ALIKE_CHI2, ChangeFit, Linearised, change_name, suspects
from ucal.kinematics.ik import ik
from ucal.model.geometry import FaceMeasurement
from ucal.model.priors import SOUND, CellPrior, prior_from_profile
from ucal.model.residuals import measurement_label
from ucal.model.targets import PlannedTarget

#: The nominal one sigma of a water path (mm), a normal incidence (deg) and a crossing (mm).
NOMINAL = (0.01, 0.002, 0.015)
#: A change of the water this large (°C) is what a measurement must see to see the water.
WATER_SEEN_C = 0.1
#: The change (in tolerances) at which two suspects are said to be told apart or not.
ALIKE_TOLERANCES = 5.0
#: The quantities the plan speaks of, by the suspects' unknowns.
GROUPS = {
    **{f"J{j}": (f"J{j}",) for j in range(1, 7)},
    "tool across": ("tool_x_mm", "tool_y_mm"),
    "tool along": ("tool_z_mm",),
    "beam direction": ("tool_rx_deg", "tool_ry_deg"),
    "block": ("block_x_mm", "block_y_mm", "block_z_mm"),
    "block turn": ("block_rx_deg", "block_ry_deg", "block_rz_deg"),
    "water": SOUND,
    "arm growth": (GROWTH,),
}


@dataclass(frozen=True)
class Observability:
    """What each measurement sees (label → the ``GROUPS`` it sees), and each unknown's one
    sigma of its change alone against its tolerance."""

    sees: dict[str, tuple[str, ...]]
    std: dict[str, float]
    tolerance: dict[str, float]
    #: an unknown → the other suspects that explain its change alike (module docstring)
    alike: dict[str, tuple[str, ...]] = field(default_factory=dict)

    def determined(self, parameter: str) -> bool:
        return bool(self.std[parameter] <= self.tolerance[parameter])

    def undetermined(self) -> list[str]:
        return [p for p in self.std if not self.determined(p)]


def nominal_readings(
    profile: CellProfile, targets: tuple[PlannedTarget, ...], edges: tuple[EdgeLine, ...]
) -> tuple[list[FaceMeasurement], list[EdgeReading]]:
    """The planned postures as readings at ``NOMINAL`` noise (their values do not matter to a
    linearised fit's covariance; their postures do)."""
    path_std, tilt_std, crossing_std = NOMINAL
    faces = [
        FaceMeasurement(t.config, t.face, t.joints_deg, t.water_path_mm, path_std, tilt_std)
        for t in targets
    ]
    readings = []
    for line in edges:
        q = ik(
            profile.model,
            line.at(line.edge_mm),
            profile.tool_matrix,
            np.asarray(profile.joint_offsets_deg, float),
            near_deg=line.start_deg,
        )
        size = float(profile.sample_face_size_mm)
        readings.append(EdgeReading(line.label, line.axis, q, np.zeros(3), crossing_std, size))
    return faces, readings


def observability(
    profile: CellProfile, targets: tuple[PlannedTarget, ...], edges: tuple[EdgeLine, ...]
) -> Observability:
    """What the planned measurements see and determine (module docstring)."""
    prior = prior_from_profile(profile)
    faces, readings = nominal_readings(profile, targets, edges)
    problem = ChangeFit(prior, faces, faces, suspects(prior), None, (readings, readings))
    lin = Linearised(problem, problem.table.prior.copy())
    table = problem.table
    std: dict[str, float] = {}
    tolerance: dict[str, float] = {}
    for s in problem.suspects:
        _, _, cols, cov = lin.solve([s.name])
        where = {int(c): k for k, c in enumerate(cols)}
        for p, tol in zip(s.parameters, s.tolerances, strict=True):
            k = where[table.index(change_name(p))]
            std[p] = float(np.sqrt(max(cov[k, k], 0.0)))
            tolerance[p] = tol if np.isfinite(tol) else _water_seen(prior)
    sees = _sees(problem, lin, tolerance, faces, readings)
    return Observability(sees, std, tolerance, _alike(problem, lin, tolerance))


def _alike(
    problem: ChangeFit, lin: Linearised, tolerance: dict[str, float]
) -> dict[str, tuple[str, ...]]:
    """Each unknown → the other suspects that explain a change of ``ALIKE_TOLERANCES`` of its
    tolerances within ``ALIKE_CHI2``, the cell's unknowns free with their priors."""
    table = problem.table
    column = {int(c): k for k, c in enumerate(lin.cols)}
    base = [k for k, c in enumerate(lin.cols) if not table.names[c].startswith("change_")]

    def cols(parameters: tuple[str, ...]) -> list[int]:
        return [column[table.index(change_name(p))] for p in parameters]

    out: dict[str, tuple[str, ...]] = {}
    for a in problem.suspects:
        for p in a.parameters:
            (k,) = cols((p,))
            d = lin.jac[:, k] * ALIKE_TOLERANCES * tolerance[p]
            if not d @ d > ALIKE_CHI2:
                continue  # not seen: not determined, not a likeness
            alike = []
            for b in problem.suspects:
                if b.name == a.name:
                    continue
                free = base + cols(b.parameters)
                m = np.vstack([lin.jac[:, free], np.diag(lin.prior_d[free])])
                target = np.r_[d, np.zeros(len(free))]
                x, *_ = np.linalg.lstsq(m, target, rcond=None)
                if float(np.sum((m @ x - target) ** 2)) < ALIKE_CHI2:
                    alike.append(b.words)
            if alike:
                out[p] = tuple(alike)
    return out


def _water_seen(prior: CellPrior) -> float:
    return WATER_SEEN_C * abs(sound_speed_slope_m_s_per_c(prior.water_temperature_c))


def _sees(
    problem: ChangeFit,
    lin: Linearised,
    tolerance: dict[str, float],
    faces: list[FaceMeasurement],
    readings: list[EdgeReading],
) -> dict[str, tuple[str, ...]]:
    """Each of the check's measurements (its rows in the fit) → the groups it sees."""
    n_ref, n_chk = len(faces), len(faces)
    face_rows = [range(3 * (n_ref + i), 3 * (n_ref + i) + 3) for i in range(n_chk)]
    first_edge = problem.n_faces + len(readings)
    edge_rows = [range(first_edge + i, first_edge + i + 1) for i in range(len(readings))]
    labels = [measurement_label(f) for f in faces] + [r.label for r in readings]
    column = {int(c): k for k, c in enumerate(lin.cols)}
    out: dict[str, tuple[str, ...]] = {}
    for label, rows in zip(labels, face_rows + edge_rows, strict=True):
        seen = []
        for group, parameters in GROUPS.items():
            effect = 0.0
            for p in parameters:
                k = column[problem.table.index(change_name(p))]
                effect = max(effect, float(np.max(np.abs(lin.jac[list(rows), k]))) * tolerance[p])
            if effect > 1.0:
                seen.append(group)
        out[label] = tuple(seen)
    return out


def what_would_determine(parameter: str, profile: CellProfile, edges_read: bool) -> str:
    """What would determine ``parameter`` where the check's postures do not, in words."""
    if parameter in GROUPS["tool across"]:
        if edges_read:
            return "edge crossings repeating better (more probes across the XY face's edges)"
        return (
            "an edge crossing (the XY face's far edges with the beam normal to it, as the check "
            "scans them where the arm reaches them and the reference has them)"
        )
    if parameter == "J6":
        tool = profile.tool_matrix
        off_axis = float(np.hypot(*tool[:2, 3]))
        tilt = float(np.degrees(np.arccos(np.clip(tool[2, 2], -1.0, 1.0))))
        return (
            f"a tool off the joint-6 axis: this one's centre is {off_axis:.2f} mm from it and "
            f"its beam {tilt:.2f} deg off it, so a turn of joint 6 turns the beam about itself "
            "(what no echo sees moves no scan)"
        )
    if parameter in (GROWTH, "arm_temperature_rise_k"):
        return (
            "postures that read one face at reaches further apart (a growth moves each tool "
            "centre in proportion to the flange's distance from the base; ucal calibrate's)"
        )
    if not any(parameter in ps for ps in GROUPS.values()):
        return "more readings of the echo chain than the reference's and the check's"
    return "more postures than a check's (ucal calibrate)"


def observability_lines(obs: Observability, profile: CellProfile, edges_read: bool) -> list[str]:
    """The plan's statement of what each measurement sees and what the postures determine."""
    lines = ["What each measurement sees (a change of its tolerance beyond the reading's 1σ):"]
    lines += [f"  {label:<16} {', '.join(seen) or 'nothing'}" for label, seen in obs.sees.items()]
    determined = [g for g, ps in GROUPS.items() if all(obs.determined(p) for p in ps)]
    lines.append(
        "Determined (each change alone, 1σ within its tolerance): " + ", ".join(determined)
    )
    for p, others in obs.alike.items():
        lines.append(f"Not told apart: {p} from {' or '.join(others)} (both would be named)")
    for p in obs.undetermined():
        lines.append(
            f"Not determined: {p} (1σ {obs.std[p]:.2g} against {obs.tolerance[p]:g}): "
            f"{what_would_determine(p, profile, edges_read)}"
        )
    return lines
