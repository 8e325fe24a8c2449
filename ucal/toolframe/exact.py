"""Our tool-frame calibration: beam from normal incidence, offsets from TOF and edge reversal.

Notation as in ``ucal.toolframe.paper`` (paper 002, eqs. 5–11): flange pose ``(R_E, p_E)``,
tool centre ``p_T`` and beam ``a_T`` (unit) in the flange frame, plate plane ``n·x = h``
(``n`` unit, towards the water; ``h = n·A``), water path ``Δl``. The tool centre in the base
frame is ``c = p_E + R_E p_T`` and the beam ``b = R_E a_T``.

(a) Beam direction. An echo from a flat plate peaks at normal incidence, ``b = −n``::

    (E1)  R_E,i a_T = −n   ⇒   a_T = −R_E,iᵀ n

so each peak-amplitude posture search (``ucal.measure.search.PeakSearch``) gives the
beam in the flange frame directly, independent of the tool offsets, the plate's offset and
the time of flight. Searches at k flange orientations (turned about the beam) are combined by
least squares on the unit sphere: the normalised weighted mean of the ``−R_E,iᵀ n``
(weights 1/σ_i², σ_i the fitted posture uncertainty as beam tilt); the scatter between
orientations also absorbs what the kinematic model gets wrong.

(b) Offset along the beam. At normal incidence the water path is the tool centre's height
above the plane: ``Δl_i = n·c_i − h = n·p_E,i + n·R_E,i p_T − h``, and with (E1)
``n·R_E,i p_T = (R_E,iᵀ n)·p_T = −a_T·p_T``::

    (E2)  n·p_E,i − a_T·p_T − Δl_i = h      ⇒   a_T·p_T = n·p_E,i − Δl_i − h

Only ``a_T·p_T`` appears: a flat plate at normal incidence sees the tool centre's offset along
the beam and nothing across it (turning the tool about the beam or shifting it across the
beam changes neither the echo nor the distance). A constant time-of-flight delay ``δt`` (cable,
pulser trigger) adds ``c·δt/2`` to every ``Δl_i`` and is indistinguishable from ``a_T·p_T``
(and an error of ``h`` from the touched points likewise): this first estimate assumes zero
delay, the profile's offsets and the plane of the touched points; ``ucal.toolframe.fit`` then
carries them as unknowns with their tolerances.

(c) Offsets across the beam: edge reversal. With the beam normal to the plate, its axis
meets the plate at ``N = c + Δl b``, and the echo falls to half where N crosses a straight
edge (the footprint is a symmetric spot: half of it on the plate). With the in-plane unit
normal ``e`` of the edge (``e ⟂ n``) and the edge line ``e·x = d``::

    (E3)  e·(p_E + R_E p_T + Δl R_E a_T) = d

``e·R_E p_T`` only sees the component of ``p_T`` across the beam (``e·R_E a_T = −e·n = 0``),
and it flips sign when the flange turns 180° about the beam (``R_E → Rot(b, π) R_E`` maps
``R_E p_⊥ → −R_E p_⊥`` for ``p_⊥ ⟂ a_T``). Scanning the same line of the *estimated* tool
centre in both orientations, the two crossings differ by ``2 e·R_E p_⊥``: the unknown edge
position d cancels, and two edges with different normals give both components. The edge's
direction is not known either (only the touched points are): each edge is crossed at two
points along it, which fixes its angle ψ in the plane, ``e = cos ψ e1 + sin ψ e2``.

The 50 % point of a scan is located by fitting the footprint's edge profile: for a Gaussian
footprint of width σ the share on the plate is ``Φ(s/σ)`` with s the signed distance of the
axis from the edge, so the amplitude along the scan coordinate t is::

    (E4)  A(t) = (A0 + A1·(t − t_e)) · Φ((t_e − t)/σ)   (A0, A1, t_e, σ fitted; t_e is the
                                                            crossing)

(A1 takes up an echo that changes slowly along the scan on the plate: a beam drifting off
normal, a bow of the plate; the fit is ``ucal.measure.edges.fit_edge_profile``, which verify's
edge scans use too.)

Solution. With ``a_T`` from (a) held fixed, ``p_T`` (3), and ψ_k, d_k per edge are the
weighted least-squares solution of all (E2) and (E3) equations, in their exact ray form
(``Δl = (h − n·c)/(n·b)``, so slightly non-normal readings are modelled, not approximated).
Standard deviations from the Jacobian with the measured noise (TOF standard errors, the
crossings' fit uncertainties), scaled up by the reduced χ² when the data scatter more, plus the
propagated uncertainty of ``a_T``.

Units: mm, unit vectors; angles in degrees at the interface.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares

from ucal.kinematics.rotations import matrix_to_rpy, rpy_to_matrix, tangent_basis
from ucal.toolframe.plane import Plane

log = logging.getLogger(__name__)


# ---------------------------------------------------------------------------------------------
# (a) beam direction


@dataclass(frozen=True)
class BeamEstimate:
    """Beam direction a_T in the flange frame with its uncertainty."""

    direction: np.ndarray  # (3,) unit
    cov: np.ndarray  # (3, 3) covariance of the direction (rad², tangent plane)
    std_deg: float  # one-sigma per tilt axis (deg)
    scatter_deg: float  # rms angle of the single estimates from the mean (deg)
    estimates: np.ndarray  # (k, 3) single estimates −R_E,iᵀ n


def beam_from_normal_incidence(
    flange_rot: np.ndarray, normal: np.ndarray, tilt_std_deg: np.ndarray
) -> BeamEstimate:
    """Combine normal-incidence postures into the beam direction (eq. E1).

    ``flange_rot`` (k, 3, 3): flange orientations at the peaks; ``normal``: plate normal;
    ``tilt_std_deg`` (k,): one-sigma of each peak posture as beam tilt (deg).
    """
    rot = np.asarray(flange_rot, float)
    est = -np.einsum("kji,j->ki", rot, np.asarray(normal, float))  # −R_Eᵀ n
    sig = np.radians(np.maximum(np.asarray(tilt_std_deg, float), 1e-6))
    w = 1.0 / sig**2
    mean = (w[:, None] * est).sum(0)
    a = mean / np.linalg.norm(mean)
    tb = tangent_basis(a)
    comp = est @ tb.T  # (k, 2) small angles (rad)
    var = 1.0 / w.sum()
    k = len(est)
    scatter = float(np.degrees(np.sqrt(np.mean(np.sum(comp**2, 1)))))
    if k >= 2:
        chi2 = float(np.sum(w[:, None] * comp**2) / (2 * (k - 1)))
        var *= max(1.0, chi2)
    cov = var * tb.T @ tb
    return BeamEstimate(a, cov, float(np.degrees(np.sqrt(var))), scatter, est)


# ---------------------------------------------------------------------------------------------
# (b) + (c) offsets


@dataclass(frozen=True)
class TofRecord:
    """A water path read at (near) normal incidence."""

    flange: np.ndarray  # (4, 4) flange pose (FK of the readings, profile offsets)
    path_mm: float  # Δl from the time of flight
    std_mm: float  # its one-sigma


@dataclass(frozen=True)
class EdgeCrossing:
    """The flange pose at which the beam axis crossed a plate edge (the 50 % point)."""

    flange: np.ndarray  # (4, 4) flange pose at the crossing
    edge: int  # which edge (0, 1, …)
    std_mm: float  # one-sigma of the crossing along the scan (mm)
    scan_dir: np.ndarray  # (3,) unit scan direction (in the plane, outward)


@dataclass(frozen=True)
class OffsetEstimate:
    """Tool centre in the flange frame from (E2) and (E3)."""

    position_mm: np.ndarray  # (3,)
    cov_mm2: np.ndarray  # (3, 3)
    std_mm: np.ndarray  # (3,)
    edge_angles_deg: np.ndarray  # ψ_k (deg) from e1 towards e2
    edge_offsets_mm: np.ndarray  # d_k
    tof_residual_rms_mm: float
    edge_residual_rms_mm: float
    rms_residual_mm: float
    chi2_reduced: float
    notes: list[str] = field(default_factory=list)


def _ray_hit(
    flange: np.ndarray, p: np.ndarray, a: np.ndarray, plane: Plane
) -> tuple[np.ndarray, float]:
    """Axis hit point on the plane and the water path along the beam."""
    r, pe = flange[:3, :3], flange[:3, 3]
    c = pe + r @ p
    b = r @ a
    path = (plane.offset_mm - plane.normal @ c) / (plane.normal @ b)
    return c + path * b, float(path)


def _edge_normal(psi: float, plane: Plane) -> np.ndarray:
    return np.asarray(np.cos(psi) * plane.e1 + np.sin(psi) * plane.e2)


def offset_residuals(
    x: np.ndarray,
    beam: np.ndarray,
    tofs: list[TofRecord],
    crossings: list[EdgeCrossing],
    plane: Plane,
    n_edges: int,
    weighted: bool = True,
) -> np.ndarray:
    """Residuals of (E2) (path along the beam − Δl) and (E3) (e·N − d), in mm or in sigmas."""
    p = x[:3]
    psi = x[3 : 3 + n_edges]
    d = x[3 + n_edges : 3 + 2 * n_edges]
    out = []
    for rec in tofs:
        _, path = _ray_hit(rec.flange, p, beam, plane)
        r = path - rec.path_mm
        out.append(r / rec.std_mm if weighted else r)
    for cr in crossings:
        hit, _ = _ray_hit(cr.flange, p, beam, plane)
        e = _edge_normal(psi[cr.edge], plane)
        r = e @ hit - d[cr.edge]
        out.append(r / cr.std_mm if weighted else r)
    return np.array(out)


def along_beam_offset_mm(
    beam: np.ndarray, tofs: list[TofRecord], plane: Plane
) -> tuple[float, float]:
    """``a_T·p_T`` (mm) and its one-sigma from normal-incidence water paths alone (eq. E2):
    the weighted mean of ``n·p_E,i − Δl_i − h``."""
    if not tofs:
        raise ValueError("no water path: a_T·p_T is not determined")
    vals = np.array([plane.normal @ t.flange[:3, 3] - t.path_mm - plane.offset_mm for t in tofs])
    w = 1.0 / np.array([t.std_mm for t in tofs]) ** 2
    mean = float(np.sum(w * vals) / w.sum())
    return mean, float(np.sqrt(1.0 / w.sum()))


def planned_edges(
    crossings: list[EdgeCrossing], plane: Plane, position_mm: np.ndarray, beam: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Each edge (numbered 0, 1, …) as the scans met it: its in-plane normal's angle ψ (rad,
    from ``plane.e1``) along the scan direction, and its offset d (mm) the mean of ``e·N`` over
    its crossings, ``N`` the beam's hit for the tool centre ``position_mm`` and ``beam``."""
    psi0, d0 = [], []
    for k in sorted({c.edge for c in crossings}):
        cs = [c for c in crossings if c.edge == k]
        u = cs[0].scan_dir
        psi = float(np.arctan2(u @ plane.e2, u @ plane.e1))
        e = _edge_normal(psi, plane)
        psi0.append(psi)
        d0.append(float(np.mean([e @ _ray_hit(c.flange, position_mm, beam, plane)[0] for c in cs])))
    return np.array(psi0), np.array(d0)


def solve_offsets(
    beam: BeamEstimate,
    tofs: list[TofRecord],
    crossings: list[EdgeCrossing],
    plane: Plane,
    position0_mm: np.ndarray,
) -> OffsetEstimate:
    """Tool centre p_T (flange frame) from water paths (E2) and edge crossings (E3).

    Needs at least one water path, and per edge crossings at two points along it in both
    orientations (for two edges with different normals). ``position0_mm`` starts the solver.
    """
    if not tofs:
        raise ValueError("no water path: a_T·p_T is not determined")
    a = beam.direction
    edges = sorted({c.edge for c in crossings})
    if edges != list(range(len(edges))):
        raise ValueError("edges must be numbered 0, 1, … without gaps")
    n_edges = len(edges)
    p0 = np.asarray(position0_mm, float)
    psi0, d0 = planned_edges(crossings, plane, p0, a)
    x0 = np.concatenate([p0, psi0, d0])
    sol = least_squares(
        offset_residuals,
        x0,
        args=(a, tofs, crossings, plane, n_edges),
        method="lm" if len(tofs) + len(crossings) >= len(x0) else "trf",
        xtol=1e-15,
        ftol=1e-15,
        gtol=1e-15,
        max_nfev=2000,
    )
    x = sol.x
    jac = sol.jac
    m, k = jac.shape
    dof = m - k
    chi2 = float(sol.fun @ sol.fun / dof) if dof > 0 else 1.0
    jtj = jac.T @ jac
    sv = np.linalg.svd(jac, compute_uv=False)
    notes: list[str] = []
    if sv[-1] < 1e-6 * sv[0]:
        notes.append(
            "the edge crossings do not determine every parameter (singular "
            "design); the offsets across the beam are unreliable"
        )
    inv = np.linalg.pinv(jtj)
    cov = inv * max(1.0, chi2)
    # propagate the beam direction's uncertainty: x depends on a through the residuals
    tb = tangent_basis(a)
    ja = np.zeros((m, 2))
    h = 1e-7
    for i in range(2):
        ap = a + h * tb[i]
        am = a - h * tb[i]
        ja[:, i] = (
            offset_residuals(x, ap / np.linalg.norm(ap), tofs, crossings, plane, n_edges)
            - offset_residuals(x, am / np.linalg.norm(am), tofs, crossings, plane, n_edges)
        ) / (2 * h)
    dxda = -inv @ jac.T @ ja
    cov_a2 = tb @ beam.cov @ tb.T
    cov = cov + dxda @ cov_a2 @ dxda.T
    cov_p = cov[:3, :3]
    raw = offset_residuals(x, a, tofs, crossings, plane, n_edges, weighted=False)
    n_t = len(tofs)
    tof_rms = float(np.sqrt(np.mean(raw[:n_t] ** 2)))
    edge_rms = float(np.sqrt(np.mean(raw[n_t:] ** 2))) if len(raw) > n_t else 0.0
    return OffsetEstimate(
        x[:3].copy(),
        cov_p,
        np.sqrt(np.maximum(np.diag(cov_p), 0.0)),
        np.degrees(x[3 : 3 + n_edges]),
        x[3 + n_edges :].copy(),
        tof_rms,
        edge_rms,
        float(np.sqrt(np.mean(raw**2))),
        chi2,
        notes,
    )


# ---------------------------------------------------------------------------------------------
# rotation_deg from the beam


def rotation_for_beam(beam: np.ndarray, nominal_rotation_deg: np.ndarray) -> np.ndarray:
    """Staubli ``[rx, ry, rz]`` (deg) of the tool rotation closest to the nominal one that maps
    the tool z axis onto ``beam`` (flange frame).

    The beam fixes only the tool's z axis; the rotation about it is invisible to an echo. Of
    all ``R`` with ``R e_z = beam`` (``R = Q R0 Rz(γ)``, Q the smallest rotation taking the
    nominal ``R0 e_z`` onto the beam), the nominal ``R0`` is nearest (least rotation angle of
    ``R0ᵀ R``) at γ = 0: ``R0ᵀ Q R0`` turns about an axis ⟂ e_z by α, and
    ``trace(Rx(α) Rz(γ)) = cos γ (1 + cos α) + cos α`` is largest at γ = 0.
    """
    r0 = rpy_to_matrix(np.asarray(nominal_rotation_deg, float))
    z0 = r0[:, 2]
    b = np.asarray(beam, float) / np.linalg.norm(beam)
    axis = np.cross(z0, b)
    s = np.linalg.norm(axis)
    c = float(z0 @ b)
    if s < 1e-15:
        q = np.eye(3) if c > 0 else rot_about(_any_perp(z0), np.pi)
    else:
        q = rot_about(axis / s, float(np.arctan2(s, c)))
    return matrix_to_rpy(q @ r0)


def _any_perp(v: np.ndarray) -> np.ndarray:
    return np.asarray(tangent_basis(v / np.linalg.norm(v))[0])


def rot_about(axis: np.ndarray, angle_rad: float) -> np.ndarray:
    """Rotation matrix about the unit ``axis`` by ``angle_rad`` (Rodrigues)."""
    k = np.asarray(axis, float)
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.asarray(np.eye(3) + np.sin(angle_rad) * kx + (1 - np.cos(angle_rad)) * kx @ kx)
