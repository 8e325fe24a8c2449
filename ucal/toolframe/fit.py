"""The tool frame with the cell's uncertain quantities as prior-constrained unknowns.

The measurements of ``ucal.toolframe.measure`` (exact method) in the notation of
``ucal.toolframe.exact``, but with every flange pose computed from the joint readings ``q``
with *unknown* joint offsets δ and DH table (``ucal.model.fit``), and the plate as an
unknown as well:

* plate: the plane of the touched points (normal ``n0``, in-plane axes ``e1, e2``, centroid
  ``A``) moved by ``plate_h_mm`` along ``n0`` and tilted by ``plate_t1_deg``, ``plate_t2_deg``
  towards ``e1``, ``e2``: ``n = (n0 + tan t1·e1 + tan t2·e2)/|…|``, through ``A + h·n0``;
* normal incidence at readings ``q_i`` (two rows): ``b_i·e1' / σ_tilt``, ``b_i·e2' / σ_tilt``
  with ``b_i = R_E(q_i+δ)·a_T`` and ``e1', e2'`` the tilted plane's axes (eq. E1);
* water path at ``q'_i`` (one row): the ray from the tool centre to the plane,
  ``L = (n·c − n·P)/(−n·b)``, against the reading ``d_i`` (computed with the profile's sound
  speed c0): ``(L − (c(t_i)/c0)·d_i + c·τ/2)/σ_d`` with the sound speed ``c``, its drift ``ċ``
  (``c(t) = c + ċ·(t − t_ref)``, ``t_i`` the reading's ``time_min``, ``t_ref`` the mean of the
  water paths' times) and the electronic delay ``τ`` as unknowns (eq. E2);
* edge crossing at ``q_j`` shifted along the scan by the fitted 50 % point (one row):
  ``(e_k·N_j − d_k)/σ_j``, ``N_j`` the beam axis's hit on the plane, ``e_k`` the in-plane normal
  of edge k at angle ``ψ_k`` from ``e1'`` (eq. E3; ψ_k, d_k free, no prior).

Every reading's joints enter at ``q + δ + (1 − approach)/2·b`` with ``b`` each joint's lost
motion, as in the calibration solvers (``ucal.model.fit``): the offsets are the positive
approach's, and ``b`` (like ``ċ``) is held at 0 where no reading sees it
(``least_squares.hold_unseen``: a joint read from one side only, readings without a time). The
tool-frame's own postures are all reached from below (``ucal.measure.approach``), so a run
measures the drift and leaves the lost motion in the offsets of that approach. The drift's
curvature c̈ is not fitted but carried in the covariance as calibrate carries it
(``ucal.model.least_squares.curvature_covariance``: 0 ± |dc/dT|·``[water]
drift_std_c_per_min`` / D over the water paths' D minutes, through the peaks' path rows, the
edge crossings holding no sound speed), and a misfit it explains is named as a drift that turns.

Each link also gives under its gravity load as the calibration solvers model it
(``ucal.model.load``): ``+ c·(τ(q) − τ(q_L))`` with ``q_L`` the load posture the profile's
offsets hold (``[calibration] load_posture_deg``; an uncalibrated cell's first peak) and each
joint's compliance ``c`` an unknown with its prior, held where the readings' torques do not
move it: the plate's postures tilt the wrist, so J5's and J4's load changes between them.

Priors (``CellPrior`` of the profile): tool ``[tool] position_std_mm``, ``rotation_std_deg``;
offsets ``[calibration] std_deg`` (wide when not calibrated); DH table; sound speed; plate height
``[reflector] points_std_mm`` (not divided by √n: a robot not yet calibrated touches every
point off the same way) and tilt ``points_std_mm`` over the points' rms spread along each axis;
delay 0 ± ``DELAY_PRIOR_STD_NS``; drift 0 (a thermometer log's, ``ucal.thermometer``) ±
``[water] drift_std_c_per_min``; lost motion 0 ± ``[robot] backlash_std_deg``.

Physics of what is observable:

* time of flight sees ``n·c − h + c·τ/2``: the tool's length along the beam, the plate's height
  and the delay are one quantity, so the tool's offset along the beam carries the plate and
  delay tolerances (and the sound speed's, through the water path) — reported as such, never a
  refusal;
* with the beam along joint 6's axis, J6's offset and the tool's azimuth about the flange axis
  are one rotation, and the last DH link's d, a, α are the tool's offset along z6, x6 and its
  twist: they are held at the profile's values (``GAUGE``; the tool is measured in the flange
  frame they define, which keeps every TCP the profile computes right);
* a rotation of the whole arm about the wrist centre (arm and wrist offsets at a fixed arm
  configuration) moves the plate, not the tool: it is absorbed by the plate's height and tilt,
  which is why the plate is an unknown.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from ucal.cell import CellProfile, WorldTruth
from ucal.kinematics.dh import dh_matrix, fk_frames, transform
from ucal.kinematics.rotations import rpy_to_matrix, tangent_basis
from ucal.model.fit import (
    BACKLASH,
    DELAY,
    DELAY_PRIOR_STD_NS,
    DH,
    DRIFT,
    MISFIT_P,
    OFFSET_PRIOR_STD_DEG,
    OFFSETS,
    PLATE,
    PRIOR_MEANING,
    SOUND,
    TOOL,
    AugmentedFit,
    CellPrior,
    FitQuality,
    ParameterTable,
    ResidualRow,
    RunEffects,
    hold_unseen,
    reference_time_min,
    rpy_matrix,
    solve_augmented,
    verdict,
)
from ucal.model.least_squares import (
    CURVATURE,
    Curvature,
    effect_gains,
    face_row_minutes,
    hold_unloaded,
)
from ucal.model.load import COMPLIANCE, URAD_DEG
from ucal.model.quality import effect_cause
from ucal.model.residuals import approach_signs
from ucal.toolframe.plane import Plane

#: Held at the profile's values, being the tool frame itself for these data: J6's offset (the
#: tool's azimuth about the flange axis with the beam near that axis) and the last link's
#: d, a, α (the flange frame's origin along z6 and x6, and its twist about x6).
GAUGE = ("J6", "dh6_d_mm", "dh6_a_mm", "dh6_alpha_deg")
#: Targets: the tool across the beam and the beam direction (one sigma).
TOLERANCE_POSITION_MM = 0.05
TOLERANCE_BEAM_DEG = 0.01


@dataclass(frozen=True)
class PlatePeak:
    """A normal-incidence posture on the plate and the water path read there."""

    label: str
    joints_deg: np.ndarray  # (6,) readings at the peak
    tilt_std_deg: float
    distance_joints_deg: np.ndarray  # (6,) readings where the TOF was read
    path_mm: float  # water path from the TOF with the profile's sound speed
    path_std_mm: float
    #: Minutes since the run's first reading (the tank's drift), and the sign (+1/-1) of each
    #: joint's last motion (6,) (lost motion), at the water path's reading.
    time_min: float | None = field(default=None, compare=False)
    approach: np.ndarray | None = field(default=None, compare=False)


@dataclass(frozen=True)
class PlateCrossing:
    """Where the beam axis crossed a plate edge: readings of the nearest probe, and the shift
    (mm, base frame) from that probe's flange position to the fitted 50 % point."""

    label: str
    joints_deg: np.ndarray
    shift_mm: np.ndarray
    edge: int
    std_mm: float
    #: As ``PlatePeak``'s, at the nearest probe's reading.
    time_min: float | None = field(default=None, compare=False)
    approach: np.ndarray | None = field(default=None, compare=False)


@dataclass(frozen=True)
class PlatePrior:
    """The touched plane and how well the touch knows it."""

    plane: Plane
    height_std_mm: float
    tilt_std_deg: np.ndarray  # (2,) towards e1, e2


def plate_prior(plane: Plane, points_mm: np.ndarray, points_std_mm: float) -> PlatePrior:
    """Height ± ``points_std_mm``, tilts ± ``points_std_mm`` / rms spread along e1, e2."""
    uv = plane.to_plane(np.asarray(points_mm, float))
    spread = np.sqrt(np.mean(uv**2, axis=0))
    tilt = np.degrees(np.arctan(points_std_mm / np.maximum(spread, 1e-9)))
    return PlatePrior(plane, float(points_std_mm), tilt)


def edge_names(n_edges: int) -> tuple[str, ...]:
    return tuple(f"edge{k + 1}_{p}" for k in range(n_edges) for p in ("psi_deg", "d_mm"))


def _plane(v: dict[str, float], plane: Plane) -> tuple[np.ndarray, float, np.ndarray]:
    """Unit normal, offset ``n·x = h`` and in-plane axes (2, 3) of the fitted plate."""
    n = (
        plane.normal
        + np.tan(np.radians(v["plate_t1_deg"])) * plane.e1
        + np.tan(np.radians(v["plate_t2_deg"])) * plane.e2
    )
    n = n / np.linalg.norm(n)
    point = plane.centroid_mm + v["plate_h_mm"] * plane.normal
    e1 = plane.e1 - (plane.e1 @ n) * n
    e1 = e1 / np.linalg.norm(e1)
    e2 = np.array(
        [n[1] * e1[2] - n[2] * e1[1], n[2] * e1[0] - n[0] * e1[2], n[0] * e1[1] - n[1] * e1[0]]
    )
    return n, float(n @ point), np.array([e1, e2])


@dataclass(frozen=True)
class _Data:
    prior: CellPrior
    plate: PlatePrior
    peaks: tuple[PlatePeak, ...]
    crossings: tuple[PlateCrossing, ...]
    n_edges: int
    #: The time the fitted sound speed is given at (min): the mean of the water paths' times.
    time_ref_min: float = 0.0
    #: The drift's curvature held at 0 (``CURVATURE`` among the names held): not carried.
    straight: bool = False

    @property
    def n_rows(self) -> int:
        return 3 * len(self.peaks) + len(self.crossings)

    @cached_property
    def minutes(self) -> np.ndarray:
        """(peaks,) minutes of each water path from ``time_ref_min`` (0 without a time)."""
        t = [p.time_min for p in self.peaks]
        return np.array([0.0 if x is None else x - self.time_ref_min for x in t], float)

    @cached_property
    def curvature(self) -> Curvature | None:
        """The drift's curvature over the run (``ucal.model.least_squares.Curvature``):
        each peak's rows at its water path's time, an edge crossing's row (no sound speed in
        it) at 0, c̈'s std from the water paths' span; None where it is held."""
        if self.straight:
            return None
        rows = np.concatenate([face_row_minutes(self.minutes), np.zeros(len(self.crossings))])
        return Curvature.of(self.prior, self.minutes, rows)

    @cached_property
    def joints_deg(self) -> np.ndarray:
        """(2·peaks + crossings, 6) the readings in ``data_residuals``' order: each peak's,
        each peak's water path's, each crossing's."""
        return np.array(
            [p.joints_deg for p in self.peaks]
            + [p.distance_joints_deg for p in self.peaks]
            + [c.joints_deg for c in self.crossings]
        ).reshape(-1, 6)

    @cached_property
    def load_nm(self) -> np.ndarray:
        """(2·peaks + crossings, 6) each reading's gravity torque less the load posture's
        (N·m, ``ucal.model.load``: the calibration's, else the first peak's); zeros where
        nothing weighs."""
        load = self.prior.posture_load(self.peaks)
        return np.zeros_like(self.joints_deg) if load is None else load.relative_nm(self.joints_deg)

    @cached_property
    def lag(self) -> np.ndarray:
        """(2·peaks + crossings, 6): how much of each joint's lost motion each posture's link
        lags behind the positive approach, (1 − approach)/2, in ``data_residuals``' order."""
        peaks = 0.5 * (1.0 - approach_signs(self.peaks))
        return np.concatenate([peaks, peaks, 0.5 * (1.0 - approach_signs(self.crossings))])


def data_residuals(table: ParameterTable, values: np.ndarray, data: _Data) -> np.ndarray:
    """Normalised residuals: per peak two tilt rows and one path row, then one per crossing."""
    v = dict(zip(table.names, values, strict=True))
    prior = data.prior
    dh = prior.model.dh.copy()
    dh[:, 1:4] = table.get(DH, values).reshape(6, 3)
    model = prior.model.with_dh(dh)
    offsets = table.get(OFFSETS, values)
    tool = transform(table.get(TOOL[:3], values), rpy_matrix(table.get(TOOL[3:], values)))
    n, h, axes = _plane(v, data.plate.plane)
    peaks, cross = data.peaks, data.crossings
    q = data.joints_deg
    if BACKLASH[0] in table.names:  # the offsets are the positive approach's
        q = q + data.lag * table.get(BACKLASH, values)
    if COMPLIANCE[0] in table.names:  # the offsets hold at the load posture's sag
        q = q + data.load_nm * (URAD_DEG * table.get(COMPLIANCE, values))
    flange = fk_frames(model, q, offsets)[:, 6]
    beam = flange[:, :3, :3] @ tool[:3, 2]
    tcp = flange[:, :3, :3] @ tool[:3, 3] + flange[:, :3, 3]
    k = len(peaks)
    if cross:
        tcp[2 * k :] += np.array([c.shift_mm for c in cross])
    path = (tcp @ n - h) / np.maximum(-(beam @ n), 0.5)
    out = []
    tilt_std = np.radians([p.tilt_std_deg for p in peaks])
    out.append((beam[:k] @ axes.T / tilt_std[:, None]).ravel())
    c_m_s = v[SOUND[0]] + v.get(DRIFT[0], 0.0) * data.minutes  # at each path's time
    d = np.array([p.path_mm for p in peaks])
    model_path = (c_m_s / prior.sound_speed_m_s) * d - c_m_s * 1e-6 * v[DELAY[0]] / 2.0
    out.append((path[k : 2 * k] - model_path) / np.array([p.path_std_mm for p in peaks]))
    if cross:
        hit = tcp[2 * k :] + path[2 * k :, None] * beam[2 * k :]
        psi = np.radians([v[f"edge{c.edge + 1}_psi_deg"] for c in cross])
        e = np.cos(psi)[:, None] * axes[0] + np.sin(psi)[:, None] * axes[1]
        dk = np.array([v[f"edge{c.edge + 1}_d_mm"] for c in cross])
        out.append((np.einsum("ij,ij->i", e, hit) - dk) / np.array([c.std_mm for c in cross]))
    rows = np.concatenate(out)
    # order rows per peak (tilt, tilt, path), then the crossings
    per_peak = np.column_stack([rows[: 2 * k].reshape(k, 2), rows[2 * k : 3 * k]]).ravel()
    return np.concatenate([per_peak, rows[3 * k :]])


@dataclass(frozen=True)
class ToolFrameFit:
    """The tool frame with honest stds, the plate and delay, the fit quality and a decision."""

    position_mm: np.ndarray
    rotation_deg: np.ndarray
    beam: np.ndarray
    position_std_mm: np.ndarray  # flange x, y, z
    rotation_std_deg: np.ndarray
    beam_std_deg: float  # per tilt axis
    along_beam_mm: float  # a_T·p_T
    along_beam_std_mm: float
    across_beam_std_mm: np.ndarray  # (2,) along tangent_basis(beam)
    along_beam_limited_by: dict[str, float]  # prior → share of the along-beam variance
    plate_height_mm: float
    plate_height_std_mm: float
    delay_ns: float
    delay_std_ns: float
    sound_speed_m_s: float
    sound_speed_std_m_s: float
    rms_residual_mm: float
    quality: FitQuality
    in_tolerance: bool
    refusal: str = ""
    notes: tuple[str, ...] = ()
    solution: AugmentedFit | None = field(default=None, repr=False, compare=False)
    #: The tank's drift and each joint's lost motion (held where no reading sees them), and
    #: the time (min since the run's first reading) ``sound_speed_m_s`` is given at.
    effects: RunEffects | None = None
    time_ref_min: float = 0.0


def _table(
    prior: CellPrior,
    plate: PlatePrior,
    offsets_std_deg: np.ndarray,
    edge_start: np.ndarray,
    data: _Data,
    fixed: tuple[str, ...],
) -> ParameterTable:
    n_edges = len(edge_start) // 2
    names = OFFSETS + TOOL + SOUND + DH + PLATE + DELAY + DRIFT + BACKLASH + COMPLIANCE
    names += edge_names(n_edges)
    dh = prior.model.dh[:, 1:4].ravel()
    values = np.concatenate(
        [
            prior.offsets_deg,
            prior.tool_position_mm,
            prior.tool_rotation_deg,
            [prior.sound_speed_m_s],
            dh,
            np.zeros(3),
            [0.0],
            [prior.drift_prior_m_s_per_min],  # the drift: its log's, else none
            np.zeros(6),  # the lost motion: none unless the data show it
            prior.compliance_urad_per_nm,
            edge_start,
        ]
    )
    stds = np.concatenate(
        [
            offsets_std_deg,
            prior.tool_position_std_mm,
            prior.tool_rotation_std_deg,
            [prior.sound_speed_std_m_s],
            prior.dh_prior_stds(),
            [plate.height_std_mm],
            plate.tilt_std_deg,
            [DELAY_PRIOR_STD_NS],
            [prior.drift_std_m_s_per_min],
            np.broadcast_to(prior.backlash_std_deg, 6),
            prior.compliance_std_urad_per_nm,
            np.full(2 * n_edges, np.inf),
        ]
    )
    table = ParameterTable(names, values, stds)
    for name in GAUGE + fixed:
        if name != CURVATURE:  # not an unknown: held, it is not carried
            table.free[table.index(name)] = False
    hold_unseen(table, (*data.peaks, *data.crossings))
    hold_unloaded(table, data)
    table.free &= table.prior_stds > 0
    return table


def solve_tool_frame(
    prior: CellPrior,
    plate: PlatePrior,
    offsets_std_deg: np.ndarray,
    peaks: list[PlatePeak],
    crossings: list[PlateCrossing],
    edge_start: np.ndarray,
    tool_start: np.ndarray | None = None,
    misfit_p: float = MISFIT_P,
    fixed: tuple[str, ...] = (),
) -> ToolFrameFit:
    """Fit the tool frame with the cell's other quantities as unknowns (module docstring).

    ``edge_start``: ψ_k (deg, from the touched plane's e1) and d_k (mm) per edge to start from,
    flattened as (ψ1, d1, ψ2, d2, …); ``tool_start``: position (3) and rotation (3) to start
    from (a first estimate), or the prior's; ``fixed``: names held at their priors (besides
    ``GAUGE``, and the drift and lost motion no reading sees; ``CURVATURE``: the drift's
    curvature not carried, as the fit was before it carried it).
    """
    n_edges = len(edge_start) // 2
    data = _Data(
        prior,
        plate,
        tuple(peaks),
        tuple(crossings),
        n_edges,
        reference_time_min(peaks),
        CURVATURE in fixed,
    )
    table = _table(
        prior,
        plate,
        np.asarray(offsets_std_deg, float),
        np.asarray(edge_start, float),
        data,
        tuple(fixed),
    )
    start = table.values.copy()
    if tool_start is not None:
        for name, val in zip(TOOL, tool_start, strict=True):
            start[table.index(name)] = val
    sol = solve_augmented(
        table,
        lambda v: data_residuals(table, v, data),
        start[table.free].copy(),
        tol=1e-10,
        max_nfev=100,
        measured=TOOL,
        curvature=data.curvature,
    )
    return _conclude(sol, data, misfit_p)


def _conclude(sol: AugmentedFit, data: _Data, misfit_p: float) -> ToolFrameFit:
    table = sol.table
    est = sol.estimate
    pos = table.get(TOOL[:3], est)
    rot = table.get(TOOL[3:], est)
    beam = rpy_to_matrix(rot)[:, 2]
    free = table.free_names
    idx_p = [free.index(n) for n in TOOL[:3]]
    cov_p = sol.cov[np.ix_(idx_p, idx_p)]
    tb = tangent_basis(beam)
    along_std = float(np.sqrt(beam @ cov_p @ beam))
    across_std = np.sqrt(np.clip(np.diag(tb @ cov_p @ tb.T), 0.0, None))
    # beam direction: its two tilts from the tool rotation's covariance
    idx_r = [free.index(n) for n in TOOL[3:] if n in free]
    jac_a = np.zeros((3, len(idx_r)))
    for j, name in enumerate(n for n in TOOL[3:] if n in free):
        r2 = rot.copy()
        r2[TOOL[3:].index(name)] += 1e-6
        jac_a[:, j] = (rpy_to_matrix(r2)[:, 2] - beam) / 1e-6
    cov_tilt = tb @ jac_a @ sol.cov[np.ix_(idx_r, idx_r)] @ jac_a.T @ tb.T  # rad²
    beam_std = float(np.degrees(np.sqrt(max(np.trace(cov_tilt), 0.0) / 2.0)))
    g_along = sol.gradient(dict(zip(TOOL[:3], beam, strict=True)))
    along_shares = sol.shares(g_along)
    limited = {n: s for n, s in along_shares.items() if n != "data" and s >= 0.05}

    quality = _quality(sol, data, misfit_p)
    notes = (
        (
            "time of flight sees the tool's length along the beam, the plate's height and the "
            "electronic delay as one quantity: the offset along the beam carries the plate and "
            "delay tolerances ([reflector] points_std_mm) and the sound speed's"
        ),
        (
            "J6's offset and the tool's azimuth about the flange axis are one rotation: the tool "
            "is measured in the flange frame of the profile's J6 offset"
        ),
        (
            "the rotation about the beam is invisible to an echo: rotation_deg keeps the "
            "profile's azimuth within its tolerance"
        ),
    )
    refusal = ""
    if quality.verdict == "misfit":
        refusal = (
            f"the measurements disagree with the model (χ²ᵣ {quality.chi2_reduced:.3g}, "
            f"worst {quality.worst}): {quality.cause}"
        )
    elif np.max(across_std) > TOLERANCE_POSITION_MM or beam_std > TOLERANCE_BEAM_DEG:
        if np.max(across_std) > TOLERANCE_POSITION_MM:
            what = (
                f"the tool centre across the beam is known to ± {np.max(across_std):.3f} mm "
                f"(tolerance {TOLERANCE_POSITION_MM} mm)"
            )
            shares = sol.shares(sol.gradient(dict(zip(TOOL[:3], tb.T, strict=True))))
        else:
            what = (
                f"the beam direction is known to ± {beam_std:.4f} deg (tolerance "
                f"{TOLERANCE_BEAM_DEG} deg)"
            )
            shares = sol.shares(sol.gradient({n: np.ones(1) for n in TOOL[3:5]}))
        offsets_std = table.prior_stds[[table.index(n) for n in OFFSETS]]
        # the edge lines in each orientation the run scanned: two per edge
        turns = len(data.crossings) // max(2 * data.n_edges, 1)
        calibrated = bool(np.all(offsets_std < OFFSET_PRIOR_STD_DEG))
        refusal = what + ": " + _cause(shares, calibrated, turns)
    rms = _rms_mm(sol, data)
    v = dict(zip(table.names, est, strict=True))
    return ToolFrameFit(
        position_mm=pos,
        rotation_deg=rot,
        beam=beam,
        position_std_mm=table.get(TOOL[:3], sol.std),
        rotation_std_deg=np.nan_to_num(table.get(TOOL[3:], sol.std), nan=0.0),
        beam_std_deg=beam_std,
        along_beam_mm=float(beam @ pos),
        along_beam_std_mm=along_std,
        across_beam_std_mm=across_std,
        along_beam_limited_by=limited,
        plate_height_mm=v["plate_h_mm"],
        plate_height_std_mm=sol.std[table.index("plate_h_mm")],
        delay_ns=v[DELAY[0]],
        delay_std_ns=sol.std[table.index(DELAY[0])],
        sound_speed_m_s=v[SOUND[0]],
        sound_speed_std_m_s=sol.std[table.index(SOUND[0])],
        rms_residual_mm=rms,
        quality=quality,
        in_tolerance=not refusal,
        refusal=refusal,
        notes=notes,
        solution=sol,
        effects=RunEffects.of(sol),
        time_ref_min=data.time_ref_min,
    )


def _cause(shares: dict[str, float], calibrated: bool, turns: int = 2) -> str:
    """Name what a std comes from: the data's noise, or the tolerances that carry most of it
    (the priors grouped by what they stand for), with the physical reason where a tolerance
    of the arm's model carries it and what to do; ``calibrated``: the profile's joint
    offsets were measured (``[calibration] std_deg``); ``turns``: the orientations about the
    beam the edges were scanned in (2: half a turn apart, 4: quarter turns)."""
    noise = shares.get("data", 0.0)
    groups: dict[str, tuple[float, list[str]]] = {}
    for name, share in shares.items():
        if name != "data":
            meaning = PRIOR_MEANING.get(name, name)
            total, names = groups.get(meaning, (0.0, []))
            groups[meaning] = (total + share, [*names, name])
    ranked = sorted(groups.items(), key=lambda kv: -kv[1][0])
    if noise >= 0.5 or not ranked:
        # the noise's share is what the unknowns leave it: offsets not yet calibrated compete
        # with the tool for the same crossings and amplify it (a fresh cell's holders in both
        # orders: measured by benchmarks/drift.py --case tool-frame)
        return f"{100 * noise:.0f} % of its variance is measurement noise: " + (
            "more postures (--points) or more averaging"
            if calibrated
            else "with the joint offsets measured the same scans pin the tool better: run "
            "ucal calibrate first, then tool-frame again"
        )
    top, total, named = [], 0.0, []
    for meaning, (share, names) in ranked:
        if total >= 0.5 or share < 0.05:
            break
        top.append(f"{meaning} {100 * share:.0f} %")
        named += names
        total += share
    if noise >= 0.05:
        top.append(f"measurement noise {100 * noise:.0f} %")
    hint = ""
    if any(n in DH for n in named):
        hint = (
            "; turned 180° about the beam, the tool puts the wrist in another posture, and "
            "link lengths and twists within the DH table's tolerance move the flange between "
            "the two as a tool off the beam would"
            if turns <= 2
            else f"; the edges scanned a quarter turn apart about the beam ({turns} "
            "orientations), the tool puts the wrist in as many postures, and link lengths and "
            "twists within the DH table's tolerance move the flange between them as a tool off "
            "the beam would, more than the quarter turns tell apart"
        )
        hint += (
            ": with the joint offsets measured, the same postures pin those links and the tool "
            "better: run ucal calibrate first, then tool-frame again"
            if not calibrated
            else ": the arm's model allows the tool-frame no better on this plate"
        )
    elif any(n in OFFSETS for n in named):
        hint += (
            "; calibrate the joint offsets first (ucal calibrate), or state them with "
            "[calibration] std_deg"
        )
    if any(n.startswith("plate_") for n in named):
        hint += "; a plate touched more precisely ([reflector] points_std_mm) helps"
    return "its variance comes from " + ", ".join(top) + hint


def _rms_mm(sol: AugmentedFit, data: _Data) -> float:
    """Rms of the path and edge residuals in mm."""
    k = len(data.peaks)
    r = sol.res[: data.n_rows]
    path = r[2 : 3 * k : 3] * np.array([p.path_std_mm for p in data.peaks])
    edge = r[3 * k :] * np.array([c.std_mm for c in data.crossings])
    both = np.concatenate([path, edge])
    return float(np.sqrt(np.mean(both**2))) if len(both) else 0.0


def _quality(sol: AugmentedFit, data: _Data, misfit_p: float) -> FitQuality:
    k = len(data.peaks)
    r = sol.res[: data.n_rows]
    signs = approach_signs((*data.peaks, *data.crossings))
    rows = [
        ResidualRow(
            p.label,
            (float(r[3 * i]), float(r[3 * i + 1])),
            float(r[3 * i + 2]),
            p.time_min,
            None if p.approach is None else tuple(signs[i]),
        )
        for i, p in enumerate(data.peaks)
    ]
    rows += [
        ResidualRow(
            c.label,
            (0.0, 0.0),
            float(r[3 * k + j]),
            c.time_min,
            None if c.approach is None else tuple(signs[k + j]),
        )
        for j, c in enumerate(data.crossings)
    ]
    tilt_deg = (
        np.concatenate([r[3 * i : 3 * i + 2] * p.tilt_std_deg for i, p in enumerate(data.peaks)])
        if k
        else np.zeros(1)
    )
    pulls = dict(zip(sol.prior_rows, sol.res[data.n_rows :], strict=True))
    worst_row = max(rows, key=lambda x: x.norm)
    worst = worst_row.label
    nuisance = {n: p for n, p in pulls.items() if n not in TOOL}
    worst_pull = max(nuisance.items(), key=lambda kv: abs(kv[1]), default=("", 0.0))
    if abs(worst_pull[1]) > worst_row.norm:
        worst = f"prior {worst_pull[0]}"
    result = verdict(sol.chi2, sol.dof, misfit_p)
    cause = _misfit_cause(tuple(rows), pulls, sol, data) if result == "misfit" else ""
    return FitQuality(
        chi2_reduced=sol.chi2 / sol.dof,
        dof=sol.dof,
        rms_tilt_deg=float(np.sqrt(np.mean(tilt_deg**2))),
        rms_distance_mm=_rms_mm(sol, data),
        worst=worst,
        verdict=result,
        cause=cause,
        residuals=tuple(rows),
        prior_pulls=pulls,
    )


def _misfit_cause(
    rows: tuple[ResidualRow, ...], pulls: dict[str, float], sol: AugmentedFit, data: _Data
) -> str:
    """Where the misfit sits: a prior pulled beyond its tolerance or the run's effects (the
    tank's drift, lost motion: the calibration's ``effect_cause``), else the edges or the
    peaks."""
    table = sol.table
    gains = effect_gains(
        table,
        sol.estimate,
        lambda v: data_residuals(table, v, data),
        sol.res,
        sol.jac,
        data.curvature,
    )
    nuisance = {n: p for n, p in pulls.items() if n not in TOOL}
    cause = effect_cause(rows, nuisance, table, sol.estimate, gains)
    if cause:
        return cause
    tilt2 = sum(r.tilt[0] ** 2 + r.tilt[1] ** 2 for r in rows)
    path2 = sum(r.distance**2 for r in rows if not r.label.startswith("edge"))
    edge2 = sum(r.distance**2 for r in rows if r.label.startswith("edge"))
    if edge2 >= tilt2 + path2:
        return (
            "the edge crossings disagree between the orientations about the beam: "
            "check that the plate's edges are straight and clean, and the joint offsets"
        )
    return (
        "the normal-incidence postures or water paths disagree with the model: check that "
        "the plate is flat and still, and the joint offsets (run calibrate)"
    )


def truth_in_profile_flange(profile: CellProfile, truth: WorldTruth) -> np.ndarray:
    """Simulation only: the true tool frame (4, 4) in the flange frame the profile's J6 offset
    and last DH link define (``GAUGE``), i.e. what the tool-frame fit should find:
    ``A6(profile)⁻¹ · A6(truth) · tool`` at the same joint-6 reading, the link reached from
    below (lagging its encoder by half J6's lost motion, ``ucal.measure.approach``)."""

    def link6(row: np.ndarray, offset_deg: float, beta_deg: float) -> np.ndarray:
        a6 = dh_matrix(np.radians(row[0] + offset_deg), row[1], row[2], np.radians(row[3]))
        return np.asarray(
            a6 @ transform(np.zeros(3), rpy_to_matrix(np.array([0.0, beta_deg, 0.0])))
        )

    mine = link6(profile.model.dh[5], float(profile.joint_offsets_deg[5]), 0.0)
    lagged = float(truth.joint_offsets_deg[5]) - 0.5 * float(truth.backlash_deg[5])
    true = link6(truth.model.dh[5], lagged, float(truth.dh_beta_deg[5]))
    return np.asarray(np.linalg.inv(mine) @ true @ truth.beam_matrix)
