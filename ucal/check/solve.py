"""What moved: the check's measurements against the reference's, fitted on the profile's model.

The geometry (``compare_geometry``). The reference's face measurements and the check's enter
one fit (``ChangeFit``): the cell's unknowns of ``ucal.model.fit`` (joint offsets, block
pose, tool frame, sound speed and each joint's lost motion, with the profile's values and
tolerances as priors; the DH table held as the reference's own fit puts it) are shared by
both sets, each set has its own drift of the sound speed (the tank warms or cools at its own
rate in each run, against each reading's ``time_min``; its curvature, not fitted, carried in
the covariance about that run's own reference time as calibrate carries it), and a *suspect* —
a joint's offset, the tool frame, the block pose, the water's sound speed, the arm's growth
(every DH length of the check's longer by one factor: a warm-up, ``ucal.check.growth``) — may
add a change to the check's.
What cannot be told apart stays so: a joint-1 offset and a turn of the block about the base
axis are one rotation, and both are named.

The decision rule (the 3σ rule, applied at each step; docs/decisions/0009):

1. **Which suspects changed** — stepwise selection on the fit's χ² (``select``): from "nothing
   changed", add the suspect that leaves the least χ² after paying its threshold, provided its
   lowering of the χ² has a probability below ``SIGNIFICANCE_P`` = 0.27 % (the two-sided 3σ of
   one normal variable; for a suspect of k unknowns, the χ² distribution with k degrees of
   freedom); then drop a suspect chosen earlier whose removal no longer raises the χ²
   significantly (the others now explain it); repeat. Each step is linearised at the
   Gauss–Newton fit of the suspects chosen so far (``fit``) and at the reference's own fit,
   the likeliest ``REFINED`` fitted through. A suspect that, in place of a
   chosen one, explains the data within ``ALIKE_CHI2`` = 9 (3σ) cannot be told apart from it
   and is named with it (``alike``); so is the tank's effect, a run's drift beyond its prior
   or its turn (calibrate's score test, ``tank_alike``), that does: over a check's few faces
   a tank that turns looks like the block, or the water, moved.
2. **By how much** — the chosen suspects' changes and their one-sigma from that fit, the
   covariance scaled by ``max(1, χ²ᵣ)``.
3. **Out of tolerance** — an unknown of a chosen suspect whose change exceeds both 3σ and its
   tolerance (``JOINT_TOLERANCE_DEG``, ``POSITION_TOLERANCE_MM``, ``ROTATION_TOLERANCE_DEG``,
   the growth's ``growth.GROWTH_TOLERANCE_PPM``);
   beyond 3σ but within tolerance it is ``changed`` (a drift to watch), exit 0; a σ above the
   tolerance is ``not determined`` (``ucal.check.judge``). The water has no tolerance here: its
   change is reported as its own cause (docs/decisions/0016).

The edge crossings (``ucal.check.edges``) enter the fit as rows of their own, after the faces'
(the reference's with the cell's unknowns, the check's with the changes added): they see the
tool across the beam, which no water path does. The tool's turn about its own beam
(``tool_rz_deg``) moves no echo and no scan and is no suspect's unknown.

What is left unexplained after the selection (the χ² still a misfit at ``MISFIT_P``) is out of
tolerance too: something changed that no suspect accounts for (the kinematic model itself, a
damaged face), and the message names the worst measurement; where one run's drift, or its
turn, explains most of it (calibrate's score test at the fit, ``drift_cause``), the message
names that instead.

A run with the tank thermometer's log (``ucal.thermometer``) had its turns taken out of its
water paths, and its drift's prior mean is the log's: each run's drift and curvature take their
own run's (the reference's as its history entry keeps them, ``ChangeFit``'s
``reference_prior``), so a check with a log compares alike with a reference without one, and
the other way round.

The suspects not chosen are reported as well: each one's change fitted with the chosen ones
(linearised), i.e. how much it could have moved unseen.

The echo chain (``echo_quantities``): the mean change over the postures both measured, its
std from the changes' scatter, judged by the same rule (``AMPLITUDE_TOLERANCE_DB`` and the
others); a time of flight change is reported, never judged alone (the geometry says what it
means).

The first check after a calibration (``compare_to_profile``) has no reference: its fit with the
profile's calibration as the offsets' prior must not be a misfit; its offsets, water and echo
chain are recorded, and the A-scan's centre frequency is judged against the transducer's
nominal one.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np
from scipy.special import chdtrc, chdtri

from ucal.check import growth
from ucal.check.edges import EdgeArrays, EdgeReading, edge_residuals
from ucal.model.fit import (
    BACKLASH,
    BETA,
    BLOCK,
    DH,
    DRIFT,
    MISFIT_P,
    OFFSETS,
    SOUND,
    TOOL,
    CellPrior,
    MeasurementArrays,
    ParameterTable,
    data_residuals,
    measurement_label,
    solve_cell,
)
from ucal.model.geometry import FaceMeasurement
from ucal.model.least_squares import (
    CURVATURE,
    Curvature,
    cell_table,
    considered_covariance,
    curvature_rows,
    face_row_minutes,
    score_gain,
    sees_drift,
)
from ucal.model.load import COMPLIANCE
from ucal.model.quality import effect_pattern
from ucal.model.residuals import two_sided_joints

log = logging.getLogger(__name__)

#: Probability below which a lowering of the χ² (or a change) is significant: two-sided 3σ.
SIGNIFICANCE_P = 0.0027
#: Suspects whose χ² differ by less than this explain the data alike (3σ of one unknown).
ALIKE_CHI2 = 9.0
#: Candidates fitted through at each step of the selection (``select``).
REFINED = 3
#: Significance of one value's change: more than this many sigmas.
N_SIGMA = 3.0
#: The smallest change worth a commissioning's attention, per unknown of a suspect. Joints:
#: 0.01° moves the tool centre by 0.17 mm at a metre's reach; tool and block: 0.05 mm and
#: 0.02° (a transducer knocked in its holder, a block nudged); the water's
#: change has none: it is reported as its own cause (docs/decisions/0016).
JOINT_TOLERANCE_DEG = 0.01
POSITION_TOLERANCE_MM = 0.05
ROTATION_TOLERANCE_DEG = 0.02
#: Weak priors on the changes (one sigma): they only hold directions the data do not see.
JOINT_CHANGE_STD_DEG = 1.0
POSITION_CHANGE_STD_MM = 5.0
ROTATION_CHANGE_STD_DEG = 1.0
SOUND_CHANGE_STD_M_S = 30.0
#: The sound speed's drift during the check's run (m/s per min): the reference's run has its
#: own (``DRIFT``), both with the profile's prior (``[water] drift_std_c_per_min``).
CHECK_DRIFT = "check_" + DRIFT[0]


@dataclass(frozen=True)
class Suspect:
    """What may have moved: named unknowns of the cell (``ucal.model.fit``), their
    tolerances and the weak prior on their change (one sigma), in their units."""

    name: str  # "J2", "tool", "block", "water"
    words: str  # "joint 2", "the tool", ...
    parameters: tuple[str, ...]
    tolerances: tuple[float, ...]
    change_std: tuple[float, ...]


def suspects(prior: CellPrior) -> tuple[Suspect, ...]:
    """Every suspect of a cell: the six joints, the tool (its turn about the beam moves
    nothing), the block, the water (no tolerance: its own cause), the arm's growth
    (``ucal.check.growth``)."""
    pose_tol = (POSITION_TOLERANCE_MM,) * 3 + (ROTATION_TOLERANCE_DEG,) * 3
    pose_std = (POSITION_CHANGE_STD_MM,) * 3 + (ROTATION_CHANGE_STD_DEG,) * 3
    joints = tuple(
        Suspect(name, f"joint {name[1]}", (name,), (JOINT_TOLERANCE_DEG,), (JOINT_CHANGE_STD_DEG,))
        for name in OFFSETS
    )
    return (
        *joints,
        Suspect("tool", "the tool", TOOL[:5], pose_tol[:5], pose_std[:5]),
        Suspect("block", "the block", BLOCK, pose_tol, pose_std),
        Suspect("water", "the water", SOUND, (np.inf,), (SOUND_CHANGE_STD_M_S,)),
        Suspect(
            growth.ARM,
            growth.ARM_WORDS,
            (growth.GROWTH,),
            (growth.GROWTH_TOLERANCE_PPM,),
            (growth.GROWTH_CHANGE_STD_PPM,),
        ),
    )


def change_name(parameter: str) -> str:
    """The unknown of a parameter's change in the check."""
    return f"change_{parameter}"


@dataclass(frozen=True)
class Change:
    """One unknown's change from the reference to the check."""

    parameter: str  # "J2", "tool_x_mm", "sound_speed_m_s", ...
    suspect: str
    baseline: float  # the reference's value (the joint fit's)
    change: float
    std: float
    tolerance: float
    chosen: bool  # its suspect was chosen as what moved

    @property
    def significant(self) -> bool:
        return bool(abs(self.change) > N_SIGMA * self.std)

    @property
    def out_of_tolerance(self) -> bool:
        return self.chosen and self.significant and abs(self.change) > self.tolerance


@dataclass
class GeometryComparison:
    """The geometry of the check against its reference's."""

    changes: list[Change]
    chosen: list[str]  # the suspects that changed, in the order chosen
    alike: dict[str, tuple[str, ...]]  # a chosen suspect → those the check cannot tell it from
    chi2_null: float  # nothing changed
    chi2: float  # with the chosen suspects
    dof: int
    unexplained: bool  # a misfit remains
    worst: str  # the measurement with the largest residual left
    suspects: tuple[Suspect, ...] = field(default=(), repr=False)
    #: What the misfit left shows, in words: a run's drift, or its turn, that explains most of
    #: it (``drift_cause``); "" when none does or the fit is no misfit.
    cause: str = ""
    #: A chosen suspect → the tank's effect that, in its place, explains the data alike
    #: (``tank_alike``), in words.
    tank: dict[str, str] = field(default_factory=dict)
    #: A suspect → the covariance of its unknowns' changes (as ``changes`` lists them).
    covariances: dict[str, np.ndarray] = field(default_factory=dict)


class ChangeFit:
    """The reference's and the check's face measurements in one prior-augmented fit: the cell's
    unknowns shared (``ucal.model.least_squares.cell_table``, the DH table held at the
    reference's fit), each suspect's change added to the check's, and each run its own drift
    of the sound speed (``CHECK_DRIFT``: the tank warms or cools at its own rate in each;
    module docstring)."""

    def __init__(
        self,
        prior: CellPrior,
        reference: list[FaceMeasurement],
        check: list[FaceMeasurement],
        all_suspects: tuple[Suspect, ...],
        reference_prior: CellPrior | None = None,
        edges: tuple[list[EdgeReading], list[EdgeReading]] = ([], []),
    ) -> None:
        self.prior = prior
        #: The reference run's water as its own thermometer's log left it (its drift's prior
        #: mean, the turn its paths may still hold), the cell's as ``prior`` says.
        self.reference_prior = prior if reference_prior is None else reference_prior
        self.suspects = all_suspects
        self.changed = tuple(p for s in all_suspects for p in s.parameters)
        cell = cell_table(self.reference_prior)  # the cell's unknowns, Hayati's β₂ among them
        # the arm's growth: 0 at the reference by definition (held), its change the check's
        names = (
            cell.names + (CHECK_DRIFT, growth.GROWTH) + tuple(change_name(p) for p in self.changed)
        )
        drift_std = prior.drift_std_m_s_per_min
        values = np.concatenate(
            [cell.prior, [prior.drift_prior_m_s_per_min, 0.0], np.zeros(len(self.changed))]
        )
        stds = np.concatenate(
            [
                cell_table(prior).prior_stds,
                [drift_std, growth.GROWTH_CHANGE_STD_PPM],
                [v for s in all_suspects for v in s.change_std],
            ]
        )
        self.table = ParameterTable(names, values, stds)
        # the cell's unknowns with their priors, the DH table held where the reference's own fit
        # puts it (``start``: the two runs read the same postures, so its error is common to
        # both; freed in the joint fit, it takes up the changes themselves); each run's drift
        # where its readings carry times, each joint's lost motion where either run reads it
        # from both sides (``ucal.model.least_squares.hold_unseen``)
        seen = dict(zip(BACKLASH, two_sided_joints([*reference, *check]), strict=True))
        seen[DRIFT[0]] = sees_drift(reference)
        seen.update(dict.fromkeys(DH + BETA + COMPLIANCE, False))  # as the DH table: common
        self.base_free = np.array(
            [*(seen.get(n, True) for n in cell.names), sees_drift(check), False]
        )
        self.drift_idx = self.table.index(DRIFT[0])
        self.check_drift_idx = self.table.index(CHECK_DRIFT)
        self.growth_idx = self.table.index(growth.GROWTH)
        self.length_idx = np.array([self.table.index(n) for n in growth.LENGTHS])
        self.base_idx = np.array([self.table.index(p) for p in self.changed])
        self.change_idx = np.array([self.table.index(change_name(p)) for p in self.changed])
        self.reference = reference
        self.check = check
        load = self.reference_prior.posture_load(reference)
        self._ref = MeasurementArrays.of(reference, load=load)
        self._chk = MeasurementArrays.of(check, load=load)

        #: the reference's edge crossings and the check's (their rows after the faces')
        self.edges = edges
        self._edges = (EdgeArrays.of(edges[0]), EdgeArrays.of(edges[1]))
        self.n_faces = 3 * (len(reference) + len(check))
        self.n_data = self.n_faces + len(edges[0]) + len(edges[1])
        # each run's drift curving about its own reference time, over its own rows
        ref_rows, chk_rows = (
            face_row_minutes(self._ref.minutes),
            face_row_minutes(self._chk.minutes),
        )
        self.curvatures = (
            (
                self.drift_idx,
                Curvature.of(
                    self.reference_prior,
                    self._ref.minutes,
                    np.r_[ref_rows, np.zeros(chk_rows.size)],
                ),
            ),
            (
                self.check_drift_idx,
                Curvature.of(prior, self._chk.minutes, np.r_[np.zeros(ref_rows.size), chk_rows]),
            ),
        )

    def data(self, values: np.ndarray) -> np.ndarray:
        """Normalised residuals of the reference's faces, then of the check's, then the
        reference's edge crossings and the check's."""
        model, c0 = self.prior.model, self.prior.sound_speed_m_s
        r_ref = data_residuals(self.table, values, model, self._ref, c0)
        moved = values.copy()
        moved[self.base_idx] += values[self.change_idx]
        moved[self.drift_idx] = values[self.check_drift_idx]
        moved = growth.grown(moved, self.length_idx, self.growth_idx)
        r_chk = data_residuals(self.table, moved, model, self._chk, c0)
        e_ref = edge_residuals(self.table, values, model, self._edges[0])
        e_chk = edge_residuals(self.table, moved, model, self._edges[1])
        return np.concatenate([r_ref.ravel(), r_chk.ravel(), e_ref, e_chk])

    def curvature_covariance(
        self, jac: np.ndarray, cov: np.ndarray, cols: np.ndarray
    ) -> np.ndarray:
        """What each run's drift curvature adds to the covariance ``cov`` (unscaled) of the
        unknowns ``cols`` (indices into the value vector, the columns of ``jac``: the data
        rows, then the priors'): each run's c̈ a consider parameter of its own, 0 ± the std
        its span gives, through its own water paths
        (``ucal.model.least_squares.curvature_covariance``); none for a run whose
        drift is held, or with the sound speed held."""
        out = np.zeros((cols.size, cols.size))
        where = {int(i): k for k, i in enumerate(cols)}
        sound = where.get(self.table.index(SOUND[0]))
        if sound is None:
            return out
        for drift, curvature in self.curvatures:
            if drift in where:
                g = curvature_rows(jac[:, sound], curvature.row_minutes)
                out += considered_covariance(jac, cov, g, curvature.std_m_s_per_min2)
        return out

    def free_mask(self, chosen: list[str]) -> np.ndarray:
        """The unknowns free when ``chosen`` suspects may have changed."""
        params = {p for s in self.suspects if s.name in chosen for p in s.parameters}
        changes = np.array([p in params for p in self.changed])
        return np.concatenate([self.base_free, changes])

    def start(self) -> np.ndarray:
        """A full value vector to start from: the reference's own fit (its DH table within
        the profile's tolerance, as calibrate fits it, then held), nothing changed."""
        estimate = solve_cell(self.reference_prior, self.reference).estimate
        return np.concatenate([estimate, np.zeros(2 + len(self.changed))])

    def chi2(self, values: np.ndarray, chosen: list[str]) -> float:
        """χ² of the data and of the priors of the unknowns free with ``chosen``."""
        free = self.free_mask(chosen)
        t = self.table
        pulls = (values - t.prior)[free] / t.prior_stds[free]
        r = self.data(values)
        return float(r @ r + pulls @ pulls)


class Linearised:
    """The joint fit linearised at ``values``: every suspect set is then a linear least-squares
    problem (the selection tries many). The Jacobian is taken by central differences over every
    unknown that any suspect set frees."""

    def __init__(self, problem: ChangeFit, values: np.ndarray) -> None:
        self.problem = problem
        self.values = values
        table = problem.table
        self.cols = np.flatnonzero(problem.free_mask([s.name for s in problem.suspects]))
        self.r0 = problem.data(values)
        jac = np.empty((self.r0.size, self.cols.size))
        for k, i in enumerate(self.cols):
            h = 1e-5 * max(1.0, abs(values[i]) * 1e-2)
            up, down = values.copy(), values.copy()
            up[i] += h
            down[i] -= h
            jac[:, k] = (problem.data(up) - problem.data(down)) / (2 * h)
        self.jac = jac
        sigma = table.prior_stds[self.cols]
        self.prior_r0 = (values[self.cols] - table.prior[self.cols]) / sigma
        self.prior_d = 1.0 / sigma

    def _step(
        self, chosen: list[str]
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The least-squares step with ``chosen`` suspects changed (the changes of the others
        held at zero): the system's matrix (the data rows, then the free unknowns' priors), the
        residuals after the step, the free unknowns (indices into the value vector), the
        step, and the unknowns held back at zero (indices)."""
        free = self.problem.free_mask(chosen)
        mask = free[self.cols]
        # a change no longer chosen goes back to zero
        held = ~mask & (self.values[self.cols] != 0.0)
        r_data = self.r0 - self.jac[:, held] @ self.values[self.cols[held]]
        a = np.vstack([self.jac[:, mask], np.diag(self.prior_d[mask])])
        r = np.concatenate([r_data, self.prior_r0[mask]])
        step, *_ = np.linalg.lstsq(a, -r, rcond=None)
        return a, r + a @ step, self.cols[mask], step, self.cols[held]

    def solve(self, chosen: list[str]) -> tuple[float, np.ndarray, np.ndarray, np.ndarray]:
        """The least-squares step with ``chosen`` suspects changed (the changes of the others
        held at zero): its χ² (data and the priors of the free unknowns), the value vector it
        reaches, the free unknowns (indices into that vector) and their covariance (scaled by
        ``max(1, χ²ᵣ)``, plus what each run's drift curvature adds,
        ``ChangeFit.curvature_covariance``)."""
        a, res, cols, step, held = self._step(chosen)
        chi2 = float(res @ res)
        cov = np.linalg.pinv(a.T @ a)
        cov = cov * max(1.0, chi2 / self.r0.size) + self.problem.curvature_covariance(a, cov, cols)
        values = self.values.copy()
        values[held] = 0.0
        values[cols] += step
        return chi2, values, cols, cov

    def effect_gains(self, chosen: list[str]) -> dict[str, dict[str, float]]:
        """How much of the χ² each run's drift and its curvature would remove, were it free
        beyond its prior, with ``chosen`` suspects changed: calibrate's score test
        (``ucal.model.least_squares.score_gain``) of the drift's column with its prior
        row left out, and of the curvature's (``curvature_rows`` of the sound speed's column
        over that run's rows), by run (``"reference"``, ``"check"``) and effect
        (``DRIFT[0]``, ``CURVATURE``). A run whose drift is held (readings at one time), or a
        sound speed held, has none."""
        a, res, cols, _, _ = self._step(chosen)
        where = {int(i): k for k, i in enumerate(cols)}
        n_data = self.r0.size
        sound = where.get(self.problem.table.index(SOUND[0]))
        out: dict[str, dict[str, float]] = {}
        runs = zip(("reference", "check"), self.problem.curvatures, strict=True)
        for run, (drift, curvature) in runs:
            k = where.get(drift)
            if k is None or sound is None:
                continue
            g = a[:, k].copy()
            g[n_data:] = 0.0  # freed beyond its prior
            gains = score_gain(DRIFT[0], g, res, a)
            bend = curvature_rows(a[:, sound], curvature.row_minutes)
            out[run] = {**gains, **score_gain(CURVATURE, bend, res, a)}
        return out


def fit(
    problem: ChangeFit, values: np.ndarray, chosen: list[str], iterations: int = 12
) -> tuple[np.ndarray, Linearised]:
    """Gauss–Newton on the joint fit with ``chosen`` suspects changed, from ``values`` (the
    changes of the others set to zero; the step halved while it raises the χ²); the solution
    and the fit linearised there."""
    values = values.copy()
    values[problem.change_idx[~problem.free_mask(chosen)[problem.change_idx]]] = 0.0
    lin = Linearised(problem, values)
    chi2 = problem.chi2(values, chosen)
    for _ in range(iterations):
        target = lin.solve(chosen)[1]
        for _ in range(20):
            trial_chi2 = problem.chi2(target, chosen)
            if trial_chi2 <= chi2 * (1 + 1e-12) + 1e-12:
                break
            target = values + (target - values) / 2
        else:
            break
        done = chi2 - trial_chi2 < 1e-6 * max(chi2, 1.0)
        values, chi2 = target, trial_chi2
        lin = Linearised(problem, values)
        if done:
            break
    return values, lin


def _score(after: float, k: int) -> float:
    """The χ² a suspect of ``k`` unknowns leaves, plus what it must pay to be chosen."""
    return after + chi2_threshold(k)


def _significant(lowering: float, k: int) -> bool:
    return float(chdtrc(k, max(lowering, 0.0))) < SIGNIFICANCE_P


def select(
    problem: ChangeFit, values: np.ndarray
) -> tuple[list[str], np.ndarray, Linearised, float]:
    """Stepwise selection of the suspects that changed (module docstring, rule 1), each step
    linearised at the fit so far and at ``values`` (the reference's own fit: a change seen at
    a thousand sigmas drags the fit where nothing changed decimetres from the cell), the
    likeliest few fitted through (a linearisation favours the suspect of many unknowns,
    which takes up its curvature). Returns the chosen suspects, their fit, its linearisation
    and the χ² of the fit where nothing changed."""
    size = {s.name: len(s.parameters) for s in problem.suspects}
    chosen: list[str] = []
    anchor = Linearised(problem, values)
    values, lin = fit(problem, values, chosen)
    chi2_null = problem.chi2(values, chosen)
    tried: set[tuple[str, ...]] = {()}
    for _ in range(3 * len(size)):
        chi2 = lin.solve(chosen)[0]
        after = {}
        for n in (n for n in size if n not in chosen):
            here, there = lin.solve([*chosen, n]), anchor.solve([*chosen, n])
            after[n] = min((here[0], here[1]), (there[0], there[1]), key=lambda s: s[0])
        if not after:
            break
        ranked = sorted(after, key=lambda n: (_score(after[n][0], size[n]), size[n]))
        for n in ranked[:REFINED]:
            refined, _ = fit(problem, after[n][1], [*chosen, n], iterations=4)
            after[n] = min(after[n], (problem.chi2(refined, [*chosen, n]), refined))
        best = min(after, key=lambda n: (_score(after[n][0], size[n]), size[n]))
        if not _significant(chi2 - after[best][0], size[best]):
            break
        log.info("check: %s changed (χ² %.1f → %.1f)", best, chi2, after[best][0])
        chosen.append(best)
        values, lin = fit(problem, after[best][1], chosen)
        while len(chosen) > 1:
            chi2 = lin.solve(chosen)[0]
            rise = {n: lin.solve([c for c in chosen if c != n])[0] - chi2 for n in chosen[:-1]}
            drop = min(rise, key=lambda n: rise[n] - chi2_threshold(size[n]))
            if _significant(rise[drop], size[drop]):
                break
            log.info("check: %s explained by the others (χ² +%.1f without it)", drop, rise[drop])
            chosen.remove(drop)
            values, lin = fit(problem, values, chosen)
        if tuple(sorted(chosen)) in tried:
            break
        tried.add(tuple(sorted(chosen)))
    return chosen, values, lin, chi2_null


def alike(lin: Linearised, chosen: list[str], names: list[str]) -> dict[str, tuple[str, ...]]:
    """For each chosen suspect, the others that, in its place, explain the data within
    ``ALIKE_CHI2`` of the χ²: what the check cannot tell it from."""
    chi2 = lin.solve(chosen)[0]
    out = {}
    for c in chosen:
        rest = [n for n in chosen if n != c]
        out[c] = tuple(
            n for n in names if n not in chosen and lin.solve([*rest, n])[0] - chi2 < ALIKE_CHI2
        )
    return out


def compare_geometry(
    prior: CellPrior,
    reference: list[FaceMeasurement],
    check: list[FaceMeasurement],
    reference_prior: CellPrior | None = None,
    edges: tuple[list[EdgeReading], list[EdgeReading]] = ([], []),
) -> GeometryComparison:
    """What moved between the reference's measurements and the check's (module docstring);
    ``reference_prior``: the cell's prior with the reference run's own water (its
    thermometer's log, or none: ``ChangeFit``), ``prior``'s where not given; ``edges``: the
    reference's edge crossings and the check's."""
    problem = ChangeFit(prior, reference, check, suspects(prior), reference_prior, edges)
    start = problem.start()
    chosen, values, lin, chi2_null = select(problem, start)
    chi2, _, cols, cov = lin.solve(chosen)
    table = problem.table
    changes: list[Change] = []
    covariances = {}
    for s in problem.suspects:
        if s.name in chosen:
            v, c, cv = values, cols, cov
        else:  # how much it could have moved unseen: fitted with the chosen, linearised
            _, v, c, cv = lin.solve([*chosen, s.name])
        std = np.full(values.size, np.nan)
        std[c] = np.sqrt(np.clip(np.diag(cv), 0.0, None))
        at = [int(np.flatnonzero(c == table.index(change_name(p)))[0]) for p in s.parameters]
        covariances[s.name] = cv[np.ix_(at, at)]
        for p, tol in zip(s.parameters, s.tolerances, strict=True):
            i = table.index(change_name(p))
            changes.append(
                Change(
                    p,
                    s.name,
                    float(values[table.index(p)]),
                    float(v[i]),
                    float(std[i]),
                    tol,
                    s.name in chosen,
                )
            )
    n = problem.n_faces
    res = np.r_[np.linalg.norm(lin.r0[:n].reshape(-1, 3), axis=1), np.abs(lin.r0[n:])]
    labels = [f"reference {measurement_label(m)}" for m in reference] + [
        measurement_label(m) for m in check
    ]
    labels += [f"reference {e.label}" for e in edges[0]] + [e.label for e in edges[1]]
    worst = labels[int(np.argmax(res))]
    dof = problem.n_data
    unexplained = float(chdtrc(dof, chi2)) < MISFIT_P
    return GeometryComparison(
        changes,
        chosen,
        alike(lin, chosen, [s.name for s in problem.suspects]),
        chi2_null,
        chi2,
        dof,
        unexplained,
        worst,
        problem.suspects,
        drift_cause(lin.effect_gains(chosen), chi2) if unexplained else "",
        tank_alike(lin, chosen),
        covariances,
    )


#: The runs of a check's fit in words, by ``Linearised.effect_gains``' keys.
RUN_WORDS = {"reference": "the reference's run", "check": "the check's run"}


#: A run's tank effects in words, by ``Linearised.effect_gains``' names.
EFFECT_WORDS = {
    DRIFT[0]: "a drift of the sound speed during {run} faster than [water] drift_std_c_per_min "
    "allows",
    CURVATURE: "a drift of the sound speed that turns during {run}",
}


def tank_alike(lin: Linearised, chosen: list[str]) -> dict[str, str]:
    """For each chosen suspect, the tank's effect (a run's drift beyond its prior, or its
    turn: ``Linearised.effect_gains``) that, freed in its place, explains the data within
    ``ALIKE_CHI2`` of the χ², in words (``EFFECT_WORDS``); suspects none explains so are left
    out. A turn of the tank over a few faces looks like the block, or the water, moved: a
    thermometer's log tells them apart."""
    chi2 = lin.solve(chosen)[0]
    out = {}
    for c in chosen:
        rest = [n for n in chosen if n != c]
        after = lin.solve(rest)[0]
        gains = lin.effect_gains(rest)
        best = max(
            ((g, run, name) for run, by in gains.items() for name, g in by.items()),
            default=None,
        )
        if best is not None and after - best[0] - chi2 < ALIKE_CHI2:
            out[c] = EFFECT_WORDS[best[2]].format(run=RUN_WORDS[best[1]])
    return out


def drift_cause(gains: dict[str, dict[str, float]], chi2: float) -> str:
    """The run's drift, or its turn, that explains most of a misfit of χ² ``chi2`` (``gains``:
    ``Linearised.effect_gains``), in calibrate's words (``effect_pattern``) with the run
    named; "" when none explains enough of it."""
    if not gains:
        return ""
    run = max(gains, key=lambda r: max(gains[r].values(), default=0.0))
    return effect_pattern(gains[run], chi2, RUN_WORDS[run])


def chi2_threshold(k: int) -> float:
    """The χ² lowering a suspect of ``k`` unknowns needs to be chosen."""
    return float(chdtri(k, SIGNIFICANCE_P))
