"""Simulation only: where the simulated cell's hidden truth puts what a command measured.

``ucal verify`` on a simulated cell gives its result a ``truth`` section from here: the true
reached TCPs of its points, and how far its measurement was from them.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, Protocol

import numpy as np

from ucal.cell import WorldTruth
from ucal.sim.cell import SimulatedCell

#: Cycles drawn to give the expected value of an ISO 9283 figure at a run's cycles.
ISO_TRUTH_DRAWS = 20000


class ReachedPoint(Protocol):
    """One measured point of a verify pass, as the truth check reads it."""

    @property
    def pass_name(self) -> str: ...  # "before" or "after"
    @property
    def index(self) -> int: ...  # 0-based point number
    @property
    def nominal_mm(self) -> np.ndarray: ...  # (3,) block coordinates
    @property
    def commanded_deg(self) -> np.ndarray: ...  # (6,) joint readings
    @property
    def reached_mm(self) -> np.ndarray: ...  # (3,) measured reached TCP, block coordinates


def true_reached_local(truth: WorldTruth, joints_deg: np.ndarray) -> np.ndarray:
    """The TCP the true robot reaches at readings ``joints_deg`` in the coordinates of the
    *true* block (mm): what the measurement should find. The commanded points are reached from
    below on every joint, so a joint with backlash lags by half of it against a positive
    motion."""

    tcp = SimulatedCell(truth).true_tcp(joints_deg, motion_sign=np.ones(6))[:3, 3]
    s_mat = truth.sample_matrix
    return np.asarray(s_mat[:3, :3].T @ (tcp - s_mat[:3, 3]))


def verify_truth(
    truth: WorldTruth,
    points: Sequence[ReachedPoint],
    reported_after_max_mm: Sequence[float],
    profile_sample_matrix: np.ndarray | None = None,
) -> dict[str, Any]:
    """The true reached TCPs of verify's measured ``points`` and how far the measurement was
    from them (the ``truth`` section of ``verify --json`` on a simulated cell).

    The error splits into a common bias and what remains point by point. ``after_mm`` is what
    the "after" figure should have been (the true TCP against the nominal point, relative to
    the true block, as verify measures it), ``after_figure_error_mm`` how far the reported
    largest deviations (``reported_after_max_mm``, per axis) are from it; with the profile's
    block pose (``profile_sample_matrix``, 4 × 4), ``absolute_after_max_mm`` is the true TCP in
    the robot's base frame against the nominal point where the profile places it (profile's
    block axes): what the block gauge does not check.
    """
    reached: dict[str, list[Any]] = {"before": [], "after": []}
    err = []
    true_base = []
    nominal_after = []
    for p in sorted(points, key=lambda r: (r.pass_name != "before", r.index)):
        t = true_reached_local(truth, p.commanded_deg)
        reached[p.pass_name].append(t.tolist())
        err.append(p.reached_mm - t)
        if p.pass_name == "after":
            s_mat = truth.sample_matrix
            true_base.append(s_mat[:3, :3] @ t + s_mat[:3, 3])
            nominal_after.append(p.nominal_mm)
    err_arr = np.array(err)
    bias = err_arr.mean(0)
    n_before = len(reached["before"])
    nominal = np.array(nominal_after).reshape(-1, 3)
    # paper 000, Table 5: of the absolute deviations, std with ddof = 0
    true_abs = np.abs(np.array(reached["after"]).reshape(-1, 3) - nominal)
    true_after = {
        "mean": true_abs.mean(0).tolist(),
        "max": true_abs.max(0).tolist(),
        "std": true_abs.std(0).tolist(),
    }
    out = {
        "joint_offsets_deg": truth.joint_offsets_deg.tolist(),
        "reached_mm": reached,
        "measurement_error_max_mm": np.abs(err_arr).max(0).tolist(),
        "after_error_max_mm": np.abs(err_arr[n_before:]).max(0).tolist(),
        "measurement_bias_mm": bias.tolist(),
        "measurement_scatter_max_mm": np.abs(err_arr - bias).max(0).tolist(),
        "after_mm": true_after,
        "after_figure_error_mm": np.abs(
            np.array(reported_after_max_mm) - np.array(true_after["max"])
        ).tolist(),
    }
    if profile_sample_matrix is not None and true_base:
        s_mat = profile_sample_matrix
        placed = nominal @ s_mat[:3, :3].T + s_mat[:3, 3]
        absolute = (np.array(true_base) - placed) @ s_mat[:3, :3]
        out["absolute_after_max_mm"] = np.abs(absolute).max(0).tolist()
    return out


def acoustic_reached_local(truth: WorldTruth, joints_deg: np.ndarray) -> np.ndarray:
    """``true_reached_local`` moved back along the beam by what the pulser's electronic delay
    adds to every water path (``[pulser] delay_ns``: c·delay/2): the tool centre as time of
    flight sees it. A tool frame measured by its echoes (``tool-frame``) holds the tool's
    length along the beam and the delay as one quantity; so does verify's reached point."""
    cell = SimulatedCell(truth)
    tcp = cell.true_tcp(joints_deg, motion_sign=np.ones(6))
    beam_local = truth.sample_matrix[:3, :3].T @ tcp[:3, 2]
    c_mm_per_ns = cell.sound_speed_m_s() * 1e-6
    return np.asarray(
        true_reached_local(truth, joints_deg)
        - beam_local * (0.5 * c_mm_per_ns * truth.pulser.delay_ns)
    )


def iso9283_truth(truth: WorldTruth, plan: Any) -> dict[str, Any]:
    """ISO 9283's figures of the simulated robot at an ISO run's poses (``plan``:
    ``ucal.verify.plan.VerifyPlan`` with ``iso``), from the world's truth by the standard's
    formulas: AP of the robot's mean attained position (the true TCP at the commanded
    readings, reached from below on every joint, as time of flight sees it:
    ``acoustic_reached_local``) against the commanded one, RP the expected
    value at the run's cycles of ``l̄ + 3·S_l`` over the scatter the world's
    ``repeatability_deg`` gives the TCP (through the true arm's Jacobian), both in the true
    block's coordinates; ``ap_abc_deg`` the true tool's mean orientation's small rotation from
    the commanded one."""
    from scipy.spatial.transform import Rotation

    from ucal.iso9283 import POSE_NAMES, standard_figures

    cell = SimulatedCell(truth)
    sigma = np.asarray(truth.repeatability_deg, float)
    cycles = int(plan.iso.cycles)
    rng = np.random.default_rng(0x150)
    first = {t.index: t for t in reversed(plan.targets)}
    s_rot = truth.sample_matrix[:3, :3]
    ap, rp, ap_xyz, abc = [], [], [], []
    for i in range(len(POSE_NAMES)):
        q = np.asarray(first[i].joints_deg, float)
        mu = acoustic_reached_local(truth, q)
        c = plan.nominal_mm[i]
        step = 1e-4
        jac = np.array(
            [(acoustic_reached_local(truth, q + step * np.eye(6)[j]) - mu) / step for j in range(6)]
        ).T
        cov = jac @ np.diag(sigma**2) @ jac.T
        w, vec = np.linalg.eigh(cov)
        root = vec * np.sqrt(np.clip(w, 0.0, None))
        draws = mu + rng.standard_normal((ISO_TRUTH_DRAWS // cycles + 1, cycles, 3)) @ root.T
        figures = standard_figures(draws, c)
        ap.append(float(np.linalg.norm(mu - c)))
        ap_xyz.append((mu - c).tolist())
        rp.append(float(np.mean(figures["rp"])))
        attained = s_rot.T @ cell.true_tcp(q, motion_sign=np.ones(6))[:3, :3]
        commanded = plan.rotation_local(i)
        abc.append(Rotation.from_matrix(attained @ commanded.T).as_rotvec(degrees=True).tolist())
    return {"ap_mm": ap, "ap_xyz_mm": ap_xyz, "rp_mm": rp, "ap_abc_deg": abc, "cycles": cycles}
