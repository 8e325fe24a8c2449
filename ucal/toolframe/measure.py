"""The tool-frame measurement with the rig: every posture and edge scan of the plan.

The rig, the plate and the running tool estimate the steps share are one ``PlateRig``. Its rig
is a ``FinalApproachRig``: every static posture (the peak fits' probes, the water paths, each
probe of an edge scan) is reached from below on every joint, as in the calibration. Readings
taken during motion only find the echo, and go both ways: the acquisition raster's lines
alternate their sense; the centring crosses sweep each wrist joint in its positive sense, but
a cross whose readings came too far apart is swept again back, in the negative sense
(``Rig.line``); the rig's ``approach`` says which. The edge scans read nothing in motion:
their coarse and fine probes are static and step outward from the plate's centre
(``ucal.measure.edges``). Each edge line's correction to normal incidence is centred from the
last line's in the same orientation (on a fresh cell the prediction is a degree or two off,
where a quick centring can start on a side lobe), and held along the line as a rotation of the
tool about its centre, not as joint increments (``PlateRig.edge_scan``).

Measure (exact): noise floor with the beam off the plate; at each posture the peak search of
``ucal.measure.search`` (acquisition raster only for the first; later postures are
predicted from the beam found so far), fitted, the water path read at the peak; the beam a_T
from all peaks (``exact`` eq. E1), a_T·p_T from the paths (E2); then the edge scans with the
tool estimate updated (the beam normal to the plate within the peak precision): a coarse search
outward from the plate until the echo falls below half, a fine scan of static probes across the
edge fitted with eq. E4, in every orientation of the plan; p_T from all paths and crossings
(E3) as a first estimate (the solve of ``ucal.toolframe.solve`` starts from it). A posture
whose probes are below half of the first posture's echo is a side lobe (a prediction off by
degrees when the offsets are not yet calibrated): it is acquired again as the first.

Measure (paper): at each incidence point the quick main-lobe centring (or the acquisition
raster if no echo at the prediction) and the water path there; the beam estimate is refined
from the postures found so far to predict the next one (the solver uses only flange poses and
water paths, eqs. 12–15).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from ucal.cell import CellProfile
from ucal.devices.rig import Rig
from ucal.errors import HardwareError
from ucal.kinematics.dh import fk, transform
from ucal.kinematics.rotations import rpy_to_matrix
from ucal.measure.acquire import PLATE, acquire_and_centre, acquisition_gain, open_water
from ucal.measure.approach import FinalApproachRig
from ucal.measure.edges import EDGES, EdgeFit, coarse_edge_fall, fine_edge_scan
from ucal.measure.face import SearchMode
from ucal.measure.running import PLATE_TRUST
from ucal.measure.search import PeakResult, PeakSearch, ka_of, read_distance
from ucal.model.geometry import CellGeometry
from ucal.model.wrist import search_joints
from ucal.progress import MeasureStep, Report
from ucal.toolframe.exact import (
    BeamEstimate,
    EdgeCrossing,
    TofRecord,
    along_beam_offset_mm,
    beam_from_normal_incidence,
    rotation_for_beam,
)
from ucal.toolframe.fit import (
    PlateCrossing,
)
from ucal.toolframe.plan import EDGE_WATER_PATH_MM, EdgePlan, Target, ToolFramePlan, solve_target
from ucal.toolframe.plane import Plane

log = logging.getLogger(__name__)

#: Pulser averages per probe of a peak fit.
PEAK_AVERAGES = 8
#: A peak below this share of the first posture's amplitude (same plate, same water path) is
#: a side lobe: the piston's first side lobe is 17.6 dB (0.13) below the main lobe.
MAIN_LOBE_SHARE = 0.5


class PlateRig:
    """The rig aimed at the reflector plate, with what the measurement steps share: the plan
    and its plane, the acquisition gain, the running tool estimate (``position_mm`` and
    ``beam``, flange frame) and the last commanded readings ``q`` (deg)."""

    profile: CellProfile
    plan: ToolFramePlan
    plane: Plane
    rig: Rig
    progress: Report | None
    offsets: np.ndarray  # (6,) the profile's joint offsets (deg)
    temp: float  # water temperature (°C)
    ka: float  # the transducer's k·a at the water temperature
    position: np.ndarray  # (3,) running estimate of the TCP, flange frame (mm)
    beam: np.ndarray  # (3,) running estimate of the beam, flange frame (unit)
    acq_gain: float  # acquisition gain (dB) from the noise floor
    q: np.ndarray  # (6,) the last commanded readings (deg)
    aims: dict[float, np.ndarray]  # correction (3, 3) to normal incidence of the last edge
    # line per φ: the tool's rotation about its centre, base frame

    def __init__(
        self,
        profile: CellProfile,
        plan: ToolFramePlan,
        rig: Rig,
        progress: Report | None,
    ):
        self.profile = profile
        self.plan = plan
        self.plane = plan.plane
        self.rig = FinalApproachRig(rig)
        self.progress = progress
        self.offsets = np.asarray(profile.joint_offsets_deg, float)
        self.temp = profile.water_temperature_c
        self.ka = ka_of(profile.frequency_mhz, profile.element_diameter_mm, self.temp)
        self.position = np.asarray(profile.tool_position_mm, float).copy()
        self.beam = np.asarray(profile.tool_matrix[:3, 2], float).copy()
        self.acq_gain = 40.0
        self.q = np.asarray(plan.reference_deg, float)
        self.aims = {}

    # -- kinematics ------------------------------------------------------------------------------
    def tool(self) -> np.ndarray:
        rot = rpy_to_matrix(rotation_for_beam(self.beam, self.profile.tool_rotation_deg))
        return transform(self.position, rot)

    def flange(self, q: np.ndarray) -> np.ndarray:
        return fk(self.profile.model, q, offsets_deg=self.offsets)

    def joints(
        self,
        point: np.ndarray,
        path: float,
        phi: float,
        label: str,
        wrist_margin: float = 0.0,
        turn: np.ndarray | None = None,
    ) -> np.ndarray:
        """Checked readings for a tool pose (``plan.solve_target``; ``turn`` the tool's
        rotation about its centre from the planned orientation, base frame)."""
        return solve_target(
            self.profile,
            self.plane,
            self.tool(),
            point,
            path,
            phi,
            self.q,
            label,
            wrist_margin,
            turn=turn,
        )

    def turn_between(self, q_to: np.ndarray, q_from: np.ndarray) -> np.ndarray:
        """The rotation (3, 3, base frame) that takes the tool's orientation at readings
        ``q_from`` to that at ``q_to`` (the model's flange; the tool turns with it)."""
        return np.asarray(self.flange(q_to)[:3, :3] @ self.flange(q_from)[:3, :3].T)

    def move(self, q: np.ndarray) -> np.ndarray:
        self.q = np.asarray(q, float)
        return self.rig.move(q)

    # -- pulser ----------------------------------------------------------------------------------
    def set_gain(self, averages: int) -> float:
        """Gain for an echo at 40–85 % of full screen at the current posture; its amplitude
        (0 dB normalised)."""
        self.rig.level_gain(averages)
        return self.rig.normalised_amplitude(averages)

    def noise_floor(self, target: Target) -> None:
        """Noise floor with the beam off the plate (``ucal.measure.acquire.open_water`` on J5);
        sets the acquisition gain for the plate's raster."""
        away = open_water(target.joints_deg, 4, self.rig.joint_min_deg, self.rig.joint_max_deg)
        self.acq_gain = acquisition_gain(self.rig, away, PLATE.floor_fsh)
        self.q = away

    # -- posture search --------------------------------------------------------------------------
    def _search(self, q_pred: np.ndarray) -> PeakSearch:
        geom = CellGeometry(self.profile.model, self.tool(), self.plane.rotation)
        js, tilt_map = search_joints(geom, q_pred, self.offsets, self.plane.rotation[:, :2].T)
        return PeakSearch(self.rig, self.ka, js, tilt_map, self.temp)

    def centred(self, target: Target, measured: int) -> tuple[PeakSearch, np.ndarray]:
        """Main-lobe posture near the target, searched as the plate's trust policy says after
        ``measured`` postures (``ucal.measure.running.PLATE_TRUST``; 0: acquire)."""
        q_pred = self.joints(
            target.point_mm, target.water_path_mm, target.phi_deg, target.label, 0.0
        )
        quick = PLATE_TRUST.mode(measured, measured > 0) != SearchMode.ACQUIRE
        return self.normal_near(q_pred, target.label, quick, PLATE_TRUST.radius(measured))

    def normal_near(
        self,
        q_pred: np.ndarray,
        label: str,
        quick: bool,
        radius_deg: float = PLATE_TRUST.radius_deg,
    ) -> tuple[PeakSearch, np.ndarray]:
        """Main-lobe posture (wrist only) near ``q_pred``: a quick centring, else (or when
        ``quick`` is False) the plate's acquisition raster (``ucal.measure.acquire.PLATE``)."""
        search = self._search(q_pred)
        q_c = search.quick_centre(q_pred) if quick else None
        if q_c is None:
            q_c = acquire_and_centre(
                search,
                self.rig,
                q_pred,
                label,
                radius_deg,
                self.acq_gain,
                PLATE,
            )
        self.q = np.asarray(q_c, float)
        return search, q_c

    def update_beam(self, rots: list[np.ndarray], stds: list[float]) -> BeamEstimate:
        est = beam_from_normal_incidence(np.array(rots), self.plane.normal, np.array(stds))
        self.beam = est.direction
        return est

    # -- edge scans ------------------------------------------------------------------------------
    def edge_scan(
        self, ep: EdgePlan, lateral: float, phi: float, guess: float | None
    ) -> tuple[EdgeCrossing, EdgeFit, float, PlateCrossing]:
        """Coarse search and fine scan across edge ``ep`` on the line at ``lateral``; returns
        the crossing, its profile fit, the coarse crossing (mm from the centre) and the
        crossing as readings (for the fit with the offsets as unknowns)."""
        u, w = ep.direction, ep.along
        origin = self.plan.centre_mm + lateral * w
        tool = self.tool()
        label = f"edge {ep.name}"
        # each probe: t, amplitude, settled readings, minutes since the first reading, approach
        rows: list[tuple[float, float, np.ndarray, float, np.ndarray]] = []
        turn = self.aims.get(phi, np.eye(3))  # correction to normal incidence on this line

        def at(t: float) -> np.ndarray:
            return self.joints(origin + t * u, EDGE_WATER_PATH_MM, phi, label, turn=turn)

        def probe(t: float, averages: int) -> float:
            settled = self.move(at(t))
            a = self.rig.normalised_amplitude(averages)
            rig = self.rig
            rows.append((t, a, np.asarray(settled, float), rig.minutes(), rig.approach.copy()))
            return a

        def centre_at(t: float) -> np.ndarray:
            """Normal incidence near ``t`` from the current correction: the correction found
            (a rotation of the tool about its centre, base frame)."""
            planned = self.joints(origin + t * u, EDGE_WATER_PATH_MM, phi, label)
            _, q_n = self.normal_near(at(t), label, quick=True)
            return self.turn_between(q_n, planned)

        hi = ep.start_mm + ep.search_mm
        if guess is None:
            t = ep.start_mm
            step = EDGES.coarse_step_mm
        else:
            t = max(ep.start_mm, guess - 20.0)
            step = 0.75 * EDGES.coarse_step_mm
        # Normal incidence at the line's start: with joint offsets not yet calibrated the
        # beam turns differently in this arm configuration than at the plate centre (a few
        # tenths of a degree can put it in the first null). The correction found on the last
        # line in this orientation starts the centring: the offsets turn the beam alike along
        # neighbouring lines, and a prediction a degree or two off (a fresh cell) can put the
        # quick centring on a side lobe. The correction is held along the line as a rotation
        # of the tool about its centre, not as the wrist joints' increments the centring
        # found: near the wrist's singularity (joint 5 a dozen degrees from 0, as a 20° holder
        # turned 180° puts it) the correction takes several degrees on joints 4 and 5, and the
        # same increments turn the beam off normal as the line turns joint 4 (0.017°/mm: the
        # echo fades to half before the edge), where the rotation keeps it within hundredths.
        # Then gain on the plate, and outward until the echo falls below half.
        turn = centre_at(t)
        self.aims[phi] = turn
        self.move(at(t))
        self.set_gain(EDGES.averages)
        # the edge: a fall to half within a few steps (the footprint's 4σ = 6 mm); a beam that
        # drifts off normal along the line (offsets not yet calibrated) fades slowly
        first = probe(t, EDGES.averages)
        t_c = coarse_edge_fall(
            lambda t: probe(t, EDGES.averages), t, first, hi, step, EDGES.coarse_memory
        )
        if t_c is None:
            raise HardwareError(
                f"{self.rig.pulser.endpoint}: the echo did not fall at any "
                f"edge along {ep.name} within {hi:.0f} mm of the plate centre"
            )
        # fine scan across the coarse crossing; once more twice as wide if it does not cross
        # (the coarse fall was a dip of the echo on the plate, e.g. a bow or a scratch)
        # normal incidence again just inside the edge, for the fine scan
        turn = centre_at(t_c - EDGES.fine_half_mm - 2.0)
        ts: list[float] = []
        flanges: list[np.ndarray] = []

        def fine(t: float) -> tuple[float, float]:
            """A fine probe's scan coordinate, from its actual flange pose (the estimated
            tool centre), and amplitude."""
            a = probe(t, EDGES.averages)
            f = self.flange(rows[-1][2])
            c = (f @ tool)[:3, 3]
            ts.append(float(u @ (self.plane.project(c) - origin)))
            flanges.append(f)
            return ts[-1], a

        for half in (EDGES.fine_half_mm, 2.0 * EDGES.fine_half_mm):
            rows.clear()
            ts.clear()
            flanges.clear()
            try:
                fit = fine_edge_scan(fine, t_c, half, EDGES.fine_probes)
                break
            except ValueError as e:
                log.info("edge %s: %s (±%.0f mm)", ep.name, e, half)
        else:
            raise HardwareError(
                f"{self.rig.pulser.endpoint}: the fine scan across edge "
                f"{ep.name} near {t_c:.0f} mm from the plate centre does not "
                "show the echo falling to half: is the edge straight and "
                "clean?"
            )
        ts_arr = np.array(ts)
        i = int(np.argmin(np.abs(ts_arr - fit.crossing)))
        f = flanges[i].copy()
        shift = (fit.crossing - ts_arr[i]) * u
        f[:3, 3] += shift
        log.info(
            "edge %s lateral %+.1f phi %+.0f: crossing %.4f ± %.4f mm (σ %.3f mm, rms %.2g)",
            ep.name,
            lateral,
            phi,
            fit.crossing,
            fit.crossing_std,
            fit.width_mm,
            fit.rms,
        )
        std = max(fit.crossing_std, 1e-4)
        return (
            EdgeCrossing(f, ep.index, std, u.copy()),
            fit,
            float(t_c),
            PlateCrossing(
                f"edge {ep.name} {lateral:+.0f} mm phi {phi:+.0f}",
                rows[i][2].copy(),
                shift,
                ep.index,
                std,
                rows[i][3],
                rows[i][4],
            ),
        )


def _report(plate_rig: PlateRig, what: str, i: int, n: int, phi_deg: float | None = None) -> None:
    if plate_rig.progress:
        orientation = None if phi_deg is None else f"phi {phi_deg:+.0f}"
        plate_rig.progress(
            MeasureStep(what, i, n, orientation, "plate" if what != "solving" else None)
        )


@dataclass
class ExactMeasurements:
    """What the exact method measured: peaks and their water paths, edge crossings."""

    peaks: list[PeakResult]
    tofs: list[TofRecord]
    crossings: list[EdgeCrossing]
    plate_crossings: list[PlateCrossing]
    edge_fits: list[EdgeFit]
    beam_estimate: BeamEstimate
    position_mm: np.ndarray  # the tool centre estimated on the way (start of the first solve)
    moves: int
    reads: int


@dataclass
class PaperMeasurements:
    """What paper 002's method measured: flange poses and water paths at incidence points."""

    rotations: list[np.ndarray]
    positions_mm: list[np.ndarray]
    paths_mm: list[float]
    path_stds_mm: list[float]
    moves: int
    reads: int


ToolFrameMeasurements = ExactMeasurements | PaperMeasurements


def measure_tool_frame(
    profile: CellProfile, plan: ToolFramePlan, rig: Rig, progress: Report | None = None
) -> ToolFrameMeasurements:
    """Measure the plan (module docstring), reporting each posture and edge scan as it starts.
    The caller owns the connection, STOP and the profile."""
    plate_rig = PlateRig(profile, plan, rig, progress)
    if plan.method == "paper":
        return _measure_paper(plate_rig)
    return _measure_exact(plate_rig)


def _tof(plate_rig: PlateRig) -> tuple[float, float]:
    return read_distance(
        plate_rig.rig, plate_rig.temp, max(plate_rig.profile.procedure.tof_averages, 1)
    )


def _measure_exact(plate_rig: PlateRig) -> ExactMeasurements:
    plan = plate_rig.plan
    total = len(plan.peaks) + plan.edge_lines
    plate_rig.noise_floor(plan.peaks[0])
    rots: list[np.ndarray] = []
    stds: list[float] = []
    peaks: list[PeakResult] = []
    tofs: list[TofRecord] = []
    for i, target in enumerate(plan.peaks):
        _report(plate_rig, target.label, i, total, target.phi_deg)
        search, q_c = plate_rig.centred(target, i)
        peak = search.fit(q_c, averages=PEAK_AVERAGES, distance=lambda: _tof(plate_rig))
        if peak.tilt_std_deg > 0.02:
            log.info("%s: poor fit (σ %.3f°), centring again", target.label, peak.tilt_std_deg)
            q_again = search.quick_centre(peak.joints_deg)
            if q_again is not None:
                peak = search.fit(q_again, averages=PEAK_AVERAGES, distance=lambda: _tof(plate_rig))
        if peaks and _probe_level(peak) < MAIN_LOBE_SHARE * _probe_level(peaks[0]):
            # A prediction off by degrees (joint offsets not yet calibrated turn the beam
            # differently at each orientation) can centre on a side lobe (−17.6 dB and less):
            # acquire and centre as for the first posture.
            log.info(
                "%s: %.2g of the first peak's echo, a side lobe: acquiring",
                target.label,
                _probe_level(peak) / _probe_level(peaks[0]),
            )
            search, q_c = plate_rig.centred(target, 0)
            peak = search.fit(q_c, averages=PEAK_AVERAGES, distance=lambda: _tof(plate_rig))
            level = _probe_level(peak) / _probe_level(peaks[0])
            if level < MAIN_LOBE_SHARE:
                raise HardwareError(
                    f"{plate_rig.rig.pulser.endpoint}: {target.label}: only a side lobe "
                    f"of the plate's echo found ({level:.2g} of the first "
                    "posture's); is the plate flat and still?"
                )
        assert peak.distance is not None and peak.distance_joints_deg is not None
        peaks.append(peak)
        rots.append(plate_rig.flange(peak.joints_deg)[:3, :3])
        stds.append(max(peak.tilt_std_deg, 1e-4))
        path, path_std = peak.distance
        tofs.append(
            TofRecord(plate_rig.flange(peak.distance_joints_deg), path, max(path_std, 1e-4))
        )
        plate_rig.q = np.asarray(rig_joints(plate_rig), float)
        beam_est = plate_rig.update_beam(rots, stds)
        log.info(
            "%s: beam %s (%d postures), water path %.4f mm",
            target.label,
            np.round(beam_est.direction, 6).tolist(),
            len(rots),
            path,
        )
    beam_est = plate_rig.update_beam(rots, stds)
    # a_T·p_T from the water paths alone (E2) before the edge scans
    s, _ = along_beam_offset_mm(beam_est.direction, tofs, plate_rig.plane)
    plate_rig.position = (
        plate_rig.position + (s - beam_est.direction @ plate_rig.position) * beam_est.direction
    )
    crossings: list[EdgeCrossing] = []
    plate_crossings: list[PlateCrossing] = []
    fits: list[EdgeFit] = []
    guesses: dict[tuple[int, int], float] = {}
    k = len(plan.peaks)
    for turn in plan.edge_turns_deg:
        phi = plan.phi0_deg + turn
        for ep in plan.edges:
            for j, lateral in enumerate(ep.lateral_mm):
                turned = f", tool turned {turn:.0f}°" if turn else ""
                _report(plate_rig, f"edge {ep.name}{turned}", k, total, phi)
                k += 1
                guess = guesses.get((ep.index, j), guesses.get((ep.index, 0)))
                cr, fit, t_c, pc = plate_rig.edge_scan(ep, lateral, phi, guess)
                guesses.setdefault((ep.index, j), t_c)
                crossings.append(cr)
                plate_crossings.append(pc)
                fits.append(fit)
    # leave the robot above the plate centre
    plate_rig.move(
        plate_rig.joints(plan.centre_mm, plan.peaks[0].water_path_mm, plan.phi0_deg, "centre")
    )
    _report(plate_rig, "solving", total, total)
    return ExactMeasurements(
        peaks,
        tofs,
        crossings,
        plate_crossings,
        fits,
        beam_est,
        plate_rig.position,
        plate_rig.rig.counters.moves,
        plate_rig.rig.counters.reads,
    )


def _probe_level(peak: PeakResult) -> float:
    """Strongest echo (normalised to 0 dB) among a peak fit's probes."""
    return float(np.max(peak.probes[1])) if peak.probes is not None else peak.amplitude


def rig_joints(plate_rig: PlateRig) -> np.ndarray:
    """Current joint readings of the robot."""
    return plate_rig.rig.controller.read_joints()


def _measure_paper(plate_rig: PlateRig) -> PaperMeasurements:
    plan = plate_rig.plan
    total = len(plan.incidence)
    plate_rig.noise_floor(plan.incidence[0])
    rots: list[np.ndarray] = []
    poss: list[np.ndarray] = []
    paths: list[float] = []
    path_stds: list[float] = []
    for i, target in enumerate(plan.incidence):
        _report(plate_rig, target.label, i, total, target.phi_deg)
        _, q_c = plate_rig.centred(target, i)
        settled = plate_rig.move(q_c)
        path, std = _tof(plate_rig)
        f = plate_rig.flange(settled)
        rots.append(f[:3, :3])
        poss.append(f[:3, 3])
        paths.append(path)
        path_stds.append(std)
        # predict the next incidence posture from the postures found so far (E1)
        plate_rig.update_beam(rots, [0.01] * len(rots))
    _report(plate_rig, "solving", total, total)
    return PaperMeasurements(
        rots, poss, paths, path_stds, plate_rig.rig.counters.moves, plate_rig.rig.counters.reads
    )
