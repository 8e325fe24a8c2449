"""Finding normal incidence: echo acquisition and the peak-amplitude posture search.

The echo of a flat face exists only within a fraction of a degree of normal incidence (for
25 MHz and a 6 mm element the −6 dB half-angle is 0.20°, the first null 0.35°), while ±5°
joint offsets misaim the beam by up to 15°. So the search works in three stages, with the
wrist joints only (they turn the beam about W without moving it):

1. **Acquire** (high gain, continuous sweeps). At high gain the piston's side lobes are well
   above the noise a couple of degrees around normal, so raster lines a few degrees apart
   catch the echo. Each raster line is one joint-space move during which the pulser is read
   as fast as it answers; every reading is paired with the streamed joint positions by
   interpolation at its arrival time. Lines are taken outward from the predicted posture.
2. **Centre** (cross sweeps, gain stepped down). The side-lobe pattern along a line is
   symmetric about the line's point nearest to normal, so the middle of the run of readings
   above threshold locates that point even where the screen saturates. Alternating sweeps
   along the two search joints, shorter and at lower gain each time, converge on the main
   lobe.
3. **Fit** (static probes). A 3×3 grid of settled postures on the main lobe's flanks is fitted
   with the piston directivity ``A = A0·|2 J1(x)/x|``, ``x = ka·sin 2θ``, with the tilt θ a
   quadratic form of the joint deviations from the unknown peak: ``θ² = Δuᵀ G Δu`` (G free,
   so any linear distortion of the nominal joint-to-tilt map is absorbed). A second grid,
   tighter and centred on the first estimate, gives the normal-incidence posture to a few
   thousandths of a degree; its covariance gives the posture uncertainty.

**Side lobes.** Beyond the main lobe the echo does not vanish: a piston's side lobes (the first
17.6 dB down at one frequency; for the broadband pulse a skirt 20-50 dB down with bumps a
couple of degrees off normal) are local maxima too, and a search started degrees off normal
(a poor first prediction) can centre on one and fit it, its tilt σ tens of times the main
lobe's. Every face of the block is the same reflector, so the main lobe's height at a water
path is known once one face has been measured (``ucal.measure.lobe.MainLobe``: the heights
found so far, carried to another path by their measured fall). A centred peak more than
``SIDE_LOBE_MARGIN_DB`` below it is a side lobe (``PeakSearch.side_lobe_db``); the search
then goes on to the main lobe with a raster at a gain that leaves the side lobes below its
level (``PeakSearch.seek_main_lobe``).
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np
from scipy.optimize import least_squares

from ucal.acoustics import piston_directivity, water_path_mm, wavenumber_per_mm
from ucal.devices.rig import Rig, Sweep
from ucal.errors import HardwareError
from ucal.measure.lobe import MainLobe

log = logging.getLogger(__name__)


#: Pulser averages of the peak fit's probes, multiplied by this once the amplitude has shown
#: itself quantised: the fit's precision then rests on fewer effective levels, and four times
#: the averages halve the noise the levels add to (a pulse costs microseconds, a read a Modbus
#: round trip, so the run takes as many reads and hardly longer).
QUANTISED_FIT_AVERAGES = 4

#: A centred peak this far (dB) or more below the main lobe expected at its water path is a side
#: lobe: the first side lobe of a piston is 17.6 dB down, the broadband pulse's skirt 20-50 dB;
#: the expectation, carried from another path by the centre frequency's absorption, errs by
#: up to 5 dB over 90 mm of path (the broadband echo falls more slowly) and faces of one block
#: differ by a dB or two.
SIDE_LOBE_MARGIN_DB = 12.0
#: A quick centring whose last round still moved a joint this far (deg) has not centred: its
#: ±0.6° crosses step at most half their reach towards a main lobe beyond it, so a centring
#: that walks had started on a side lobe, a degree or more off normal. Applied where the
#: reflector's main-lobe heights are not known (the plate); the block's faces judge a side lobe
#: by those heights (``side_lobe_db``), and a walk that reached the main lobe is kept there.
QUICK_CENTRE_WALK_DEG = 0.1
#: The main-lobe raster's level (dB below the expected main lobe) and its line spacing (deg of
#: beam tilt): the broadband main lobe stays above −18 dB to 0.4° off normal, so lines 0.5°
#: apart cross it, while the side lobes a degree or more off normal (29 dB down and lower)
#: stay below the level.
MAIN_LOBE_RASTER_DB = 18.0
MAIN_LOBE_LINE_SPACING_DEG = 0.5
#: Height (fraction of full screen) the main-lobe raster's gain puts the expected main lobe at:
#: unsaturated, so that the centring that follows needs no gain steps.
MAIN_LOBE_SCREEN_FSH = 0.4


@dataclass(frozen=True)
class PeakResult:
    """Normal-incidence posture found by the fit, with its quality."""

    joints_deg: np.ndarray  # (6,) readings at the fitted peak
    amplitude: float  # fitted peak amplitude (FSH)
    tilt_std_deg: float  # one-sigma of the peak posture, as beam tilt
    residual_rms: float  # amplitude fit residual (FSH)
    distance: tuple[float, float] | None = None  # water path and its σ (mm), if read
    distance_joints_deg: np.ndarray | None = None  # readings where it was read
    probes: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None  # (pts, amps, q) fitted
    time_min: float | None = None  # minutes since the run's first reading, at the water path
    approach: np.ndarray | None = None  # (6,) sign of each joint's last motion, there


def _run_centre(u: np.ndarray, amps: np.ndarray, level: float) -> float | None:
    """Middle of the span above ``level`` along a sweep coordinate ``u``.

    Each end of the span is where the amplitude crosses ``level``, interpolated linearly
    between the last reading below and the first above (the ends of the sweep where the span
    reaches them).
    """
    above = np.flatnonzero(amps >= level)
    if above.size == 0:
        return None
    order = np.argsort(u)
    u, amps = np.asarray(u, float)[order], np.asarray(amps, float)[order]
    above = np.flatnonzero(amps >= level)
    first, last = int(above[0]), int(above[-1])

    def crossing(inside: int, outside: int) -> float:
        a_in, a_out = amps[inside], amps[outside]
        f = (a_in - level) / (a_in - a_out) if a_in > a_out else 0.0
        return float(u[inside] + f * (u[outside] - u[inside]))

    lo = crossing(first, first - 1) if first > 0 else float(u[first])
    hi = crossing(last, last + 1) if last < len(u) - 1 else float(u[last])
    return 0.5 * (lo + hi)


class PeakSearch:
    """Acquisition and peak-posture search for one face (see module docstring)."""

    def __init__(
        self,
        rig: Rig,
        ka: float,
        joints: tuple[int, int],
        tilt_map: np.ndarray,
        temperature_c: float,
        beam_components: Callable[[np.ndarray], np.ndarray] | None = None,
        absorption_np_per_mm: float = 0.0,
        main_lobe: MainLobe | None = None,
    ):
        """``beam_components(q (n, 6)) -> (n, 3)``: the nominal beam's two components across
        the face (sines of the tilt, rad) and the tool centre's coordinate along the face
        normal (mm), from the forward kinematics; without it the fit uses the linear
        ``tilt_map``. ``absorption_np_per_mm``: water absorption (one way) at the frequency.
        ``main_lobe``: the heights found so far on this reflector (module docstring), if
        known; without them no peak is taken for a side lobe."""
        self.absorption = absorption_np_per_mm
        self.main_lobe = main_lobe
        # The last main-lobe cross's highest reading: (amplitude at 0 dB gain, water path mm).
        self.last_peak: tuple[float, float] | None = None
        self.amp_sigma_rel: float | None = None  # measured relative amplitude repeatability
        self.beam_components = beam_components
        self.rig = rig
        self.ka = ka
        self.ja, self.jb = joints
        self.ja_jb = tuple(joints)
        self.m = np.asarray(tilt_map, float)  # (2, 2): joint deg → tilt rad (nominal)
        self.per_deg = np.degrees(np.linalg.norm(self.m, axis=0))  # tilt deg per joint deg
        self.temperature_c = temperature_c

    # -- helpers ---------------------------------------------------------------------------------
    def _with(self, q: np.ndarray, ua: float, ub: float) -> np.ndarray:
        out = np.array(q, float)
        out[self.ja] = ua
        out[self.jb] = ub
        return self.rig.clip(out)

    # -- stage 1: acquisition ----------------------------------------------------------------------
    def acquire(
        self,
        q_pred: np.ndarray,
        radius_tilt_deg: float,
        gain_db: float,
        spacing_tilt_deg: float = 1.5,
        max_moves: int | None = None,
        level: float | None = None,
    ) -> tuple[np.ndarray, float] | None:
        """Raster outward from ``q_pred`` until an echo reaches ``level`` (FSH; default the
        detection threshold); returns (posture, level).

        None when the raster ends without an echo, or when it has used ``max_moves`` moves
        (the line in progress is finished first).
        """
        first_move = self.rig.counters.moves
        self.rig.configure(gain_db=gain_db)
        level = max(level or 0.0, self.rig.threshold())
        half_a = radius_tilt_deg / self.per_deg[0]
        step_b = spacing_tilt_deg / self.per_deg[1]
        n_lines = int(np.ceil(radius_tilt_deg / spacing_tilt_deg))
        order = [0] + [s * i for i in range(1, n_lines + 1) for s in (1, -1)]
        ua0, ub0 = q_pred[self.ja], q_pred[self.jb]
        direction = 1.0
        for i in order:
            if max_moves is not None and self.rig.counters.moves - first_move >= max_moves:
                log.info("acquisition stopped after %d moves", self.rig.counters.moves - first_move)
                return None
            ub = ub0 + i * step_b
            start = self._with(q_pred, ua0 - direction * half_a, ub)
            end = self._with(q_pred, ua0 + direction * half_a, ub)
            # Reads along a line no farther apart than the lines: the echo the raster is
            # meant to catch spans at least the line spacing.
            along = min(self.rig.spacing.acquire_deg, 0.4 * spacing_tilt_deg / self.per_deg[0])
            q, amps, _ = self.rig.line(start, end, along)
            direction = -direction
            if np.max(amps) >= level:
                k = int(np.argmax(amps))
                centre = _run_centre(q[:, self.ja], amps, level)
                best = q[k].copy()
                best[self.ja] = centre if centre is not None else best[self.ja]
                best[self.jb] = ub
                log.info("echo acquired on line %+d: amplitude %.3f", i, amps[k])
                return best, level
        return None

    # -- stage 2: centring -------------------------------------------------------------------------
    def _cross(
        self, q: np.ndarray, j: int, half_tilt_deg: float, max_step_deg: float = 0.04
    ) -> tuple[np.ndarray, float]:
        """Sweep joint ``j`` through ``q``; move ``q[j]`` to the middle of the half-max run.

        The highest reading, with its water path, is kept in ``last_peak``."""
        qs, amps, tofs = self._sweep_through(q, j, half_tilt_deg, max_step_deg)
        k = int(np.argmax(amps))
        peak = float(amps[k])
        q = q.copy()
        if peak >= self.rig.threshold() and np.isfinite(tofs[k]):
            gain = 10 ** (self.rig.settings.gain_db / 20)
            path = float(water_path_mm(tofs[k], self.temperature_c))
            self.last_peak = (peak / gain, path)
        if peak >= self.rig.threshold():
            c = _run_centre(qs[:, j], amps, 0.5 * peak)
            if c is not None:
                q[j] = c
        return q, peak

    def centre(self, q: np.ndarray, half_tilt_deg: float, gain_db: float) -> np.ndarray:
        """Cross sweeps through ``q``, gain and length adapted, then main-lobe crosses.

        The side-lobe pattern along a sweep is symmetric about the sweep's point nearest to
        normal, so the middle of the run above half the sweep's maximum finds that point even
        when the line misses the main lobe. That holds only if the run lies inside the sweep
        (else the sweep is lengthened) and is not a saturated plateau (else the gain drops
        20 dB). Once the peak no longer saturates, the half-maximum run is the main lobe.
        """
        q = np.array(q, float)
        half = half_tilt_deg
        gain = float(np.clip(gain_db, 0.0, 80.0))
        for _ in range(14):
            self.rig.configure(gain_db=gain)
            clipped = saturated = lost = False
            peak = 0.0
            for j in (self.jb, self.ja):
                qs, amps, _ = self._sweep_through(q, j, half)
                peak = float(np.max(amps))
                if peak < self.rig.threshold():
                    lost = True
                    continue
                above = amps >= 0.5 * peak
                clipped |= bool(above[0] or above[-1])
                saturated |= bool(np.mean(amps >= 0.98) > 0.2)
                c = _run_centre(qs[:, j], amps, 0.5 * peak)
                if c is not None:
                    q[j] = c
            if lost or clipped:
                half = min(half * 2.0, 12.0)
            elif saturated and gain > 0.0:
                gain = max(gain - 20.0, 0.0)
            elif peak < 0.98 and half <= 1.2:
                break
            else:
                half = max(half * 0.5, 1.0)
        # Main lobe, finely: at fit gain the side lobes sink below half the peak.
        self.last_peak = None
        self.set_fit_gain(q, averages=1)
        for _ in range(3):
            before = q.copy()
            q, _ = self._cross(q, self.ja, 0.6, self.rig.spacing.main_lobe_deg)
            q, _ = self._cross(q, self.jb, 0.6, self.rig.spacing.main_lobe_deg)
            if np.all(np.abs(q - before) < 0.01):
                break
            self.set_fit_gain(q, averages=1)
        return q

    def _sweep_through(
        self, q: np.ndarray, j: int, half_tilt_deg: float, max_step_deg: float | None = None
    ) -> Sweep:
        """Sweep joint ``j`` over ±``half_tilt_deg`` of beam tilt through ``q``: the postures,
        amplitudes and times of flight read.

        Without ``max_step_deg`` the spacing is ``SweepSpacing.centre_deg``.
        """
        per = self.per_deg[0] if j == self.ja else self.per_deg[1]
        h = half_tilt_deg / per
        if max_step_deg is None:
            max_step_deg = self.rig.spacing.centre_deg(h)
        a, b = q.copy(), q.copy()
        a[j] -= h
        b[j] += h
        return self.rig.line(self.rig.clip(a), self.rig.clip(b), max_step_deg)

    def quick_centre(self, q_pred: np.ndarray) -> np.ndarray | None:
        """Main-lobe cross at fit gain straight from a good prediction; None if no echo, if
        the crosses are still walking after three rounds (the main lobe lies beyond their
        reach: the prediction was not good, and an echo above the threshold at it was a side
        lobe's), or if the peak it centred on is a side lobe (``side_lobe_db``)."""
        self.last_peak = None
        self.set_fit_gain(q_pred, averages=1)
        if self.rig.read().amplitude < self.rig.threshold():
            return None
        q = np.array(q_pred, float)
        for _ in range(3):
            before = q.copy()
            q, pa = self._cross(q, self.ja, 0.6, self.rig.spacing.main_lobe_deg)
            q, pb = self._cross(q, self.jb, 0.6, self.rig.spacing.main_lobe_deg)
            if max(pa, pb) < self.rig.threshold():
                return None
            if np.all(np.abs(q - before) < 0.01):
                break
            self.set_fit_gain(q, averages=1)
        if self.main_lobe is None and np.any(np.abs(q - before) > QUICK_CENTRE_WALK_DEG):
            # no main-lobe heights to judge a side lobe by (the tool-frame plate): a centring
            # that still walks is taken for one (on the block, ``side_lobe_db`` below judges)
            log.info(
                "the quick centring still walks %.2f°: not centred", np.max(np.abs(q - before))
            )
            return None
        below = self.side_lobe_db()
        if below is not None:
            log.info("centred on a side lobe: %.0f dB below the main lobe expected", below)
            return None
        return q

    # -- side lobes ----------------------------------------------------------------------------
    def expected_peak(self, path_mm: float) -> float | None:
        """Main-lobe amplitude (0 dB gain) expected at ``path_mm``; None without a reference."""
        if self.main_lobe is None:
            return None
        return self.main_lobe.expected(path_mm, self.absorption)

    def transducer_note(self) -> str | None:
        """``MainLobe.transducer_note`` of this reflector's heights, if any."""
        return None if self.main_lobe is None else self.main_lobe.transducer_note(self.absorption)

    def side_lobe_db(self, peak: tuple[float, float] | None = None) -> float | None:
        """How far (dB) a peak, (amplitude at 0 dB gain, water path mm), by default the last
        centred one (``last_peak``), lies below the main lobe expected at its water path, if it
        is a side lobe (more than ``SIDE_LOBE_MARGIN_DB``); None if it is not, or if there is
        no reference or no peak to judge."""
        peak = peak or self.last_peak
        if peak is None:
            return None
        amplitude, path = peak
        expected = self.expected_peak(path)
        if expected is None:
            return None
        below = float(20 * np.log10(expected / max(amplitude, 1e-12)))
        return below if below > SIDE_LOBE_MARGIN_DB else None

    def seek_main_lobe(
        self, q_pred: np.ndarray, radius_tilt_deg: float, max_moves: int | None = None
    ) -> np.ndarray | None:
        """Raster outward from ``q_pred`` at a gain where only the main lobe shows, then centre.

        The gain puts the main lobe expected (at the water path of the last peak, or the
        reference's typical one) at ``MAIN_LOBE_SCREEN_FSH`` and the raster's level
        ``MAIN_LOBE_RASTER_DB`` below it, so the side lobes a degree or more off normal do not
        reach it; lines ``MAIN_LOBE_LINE_SPACING_DEG`` apart. None without a reference, or
        when nothing reached the level within ``radius_tilt_deg`` or ``max_moves``. The caller
        judges the centred peak (``side_lobe_db``).
        """
        if self.main_lobe is None or not self.main_lobe.peaks:
            return None
        path = self.last_peak[1] if self.last_peak else self.main_lobe.typical_path_mm()
        expected = self.expected_peak(path)
        assert expected is not None
        gain_db = float(np.clip(20 * np.log10(MAIN_LOBE_SCREEN_FSH / expected), 0.0, 80.0))
        level = expected * 10 ** ((gain_db - MAIN_LOBE_RASTER_DB) / 20)
        log.info(
            "seeking the main lobe within ±%g° at %.1f dB (level %.3f FSH)",
            radius_tilt_deg,
            gain_db,
            level,
        )
        found = self.acquire(
            q_pred, radius_tilt_deg, gain_db, MAIN_LOBE_LINE_SPACING_DEG, max_moves, level
        )
        if found is None:
            return None
        return self.centre(found[0], 1.0, gain_db)

    # -- stage 3: fit ------------------------------------------------------------------------------
    def set_fit_gain(self, q: np.ndarray, averages: int) -> None:
        """Move to ``q`` and level the gain there (``Rig.level_gain``)."""
        self.rig.move(q)
        self.rig.level_gain(averages)

    def fit(
        self,
        q_centre: np.ndarray,
        averages: int,
        half_tilt_deg: float = 0.14,
        distance: Callable[[], tuple[float, float]] | None = None,
    ) -> PeakResult:
        """Static probes around the peak, fitted with the piston directivity.

        Round 1: a 3×3 grid (the centre and eight neighbours); round 2: a plus pattern, tighter,
        centred on the first estimate; both rounds are fitted together. ``distance``, if given,
        is called with the robot settled at round 2's centre (the TOF reading is taken there,
        saving a move); its result is returned in ``PeakResult.distance``.
        """
        q = np.array(q_centre, float)
        if self.rig.amplitude_step_fsh > 0.0:
            averages *= QUANTISED_FIT_AVERAGES
        g_init = self.m.T @ self.m  # nominal metric, rad² per deg²
        grid = np.array([(i, j) for i in (-1, 0, 1) for j in (-1, 0, 1) if (i, j) != (0, 0)], float)
        plus = np.array([(1, 0), (-1, 0), (0, 1), (0, -1)], float)
        pts: list[list[float]] = []
        amps: list[float] = []
        dist = None
        result = None
        for pattern, half in ((grid, half_tilt_deg), (plus, 0.7 * half_tilt_deg)):
            if (
                pattern is plus
                and result is not None
                and (distance is None or dist is not None)
                and self._settled_fit(result, q, half)
            ):
                break  # round 1 already centred and precise: no second grid needed
            self.set_fit_gain(q, averages)  # leaves the robot settled at q
            settled = self.rig.controller.read_joints()
            amps.append(self.rig.normalised_amplitude(averages))
            if self.amp_sigma_rel is None:
                # Amplitude repeatability measured here, without moving: a floor under the
                # fit's residual-based σ, which rests on a handful of degrees of freedom.
                rep = [amps[-1]] + [self.rig.normalised_amplitude(averages) for _ in range(5)]
                self.amp_sigma_rel = float(np.std(rep, ddof=1) / max(float(np.mean(rep)), 1e-12))
            pts.append([settled[self.ja], settled[self.jb]])
            if distance is not None:
                # TOF at this round's centre (the last good one is kept); a first centre off the
                # lobe may have no echo in the gate.
                try:
                    path = distance()
                    dist = (path, settled.copy(), self.rig.minutes(), self.rig.approach.copy())
                except HardwareError:
                    if pattern is plus:
                        raise
            for d in pattern:
                p = self._with(
                    q,
                    q[self.ja] + d[0] * half / self.per_deg[0],
                    q[self.jb] + d[1] * half / self.per_deg[1],
                )
                settled = self.rig.move(p)
                amps.append(self.rig.normalised_amplitude(averages))
                pts.append([settled[self.ja], settled[self.jb]])
            result = self._fit_grid(np.array(pts), np.array(amps), q, g_init)
            log.info(
                "peak fit: %s amp %.4g tilt σ %.2e° rms %.2e (gain %.1f dB)",
                np.round(result.joints_deg[3:], 5).tolist(),
                result.amplitude,
                result.tilt_std_deg,
                result.residual_rms,
                self.rig.settings.gain_db,
            )
            if result.tilt_std_deg > 0.02:
                log.info(
                    "poor fit data: pts %s amps %s",
                    np.round(np.array(pts), 4).tolist(),
                    np.round(np.array(amps) * 10 ** (self.rig.settings.gain_db / 20), 4).tolist(),
                )
            q = result.joints_deg
        assert result is not None
        result = replace(result, probes=(np.array(pts), np.array(amps), np.array(q_centre, float)))
        if dist is not None:
            path, joints, minutes, approach = dist
            result = replace(
                result,
                distance=path,
                distance_joints_deg=joints,
                time_min=minutes,
                approach=approach,
            )
        return result

    def _settled_fit(self, result: PeakResult, q: np.ndarray, half_tilt_deg: float) -> bool:
        """True if the fitted peak lies well inside the grid around ``q`` and is precise."""
        off = np.array(
            [
                (result.joints_deg[self.ja] - q[self.ja]) * self.per_deg[0],
                (result.joints_deg[self.jb] - q[self.jb]) * self.per_deg[1],
            ]
        )
        return bool(np.max(np.abs(off)) < 0.15 * half_tilt_deg and result.tilt_std_deg < 0.002)

    def refit(self, probes: tuple[np.ndarray, np.ndarray, np.ndarray]) -> PeakResult:
        """Fit recorded probes again (e.g. with better kinematics in ``beam_components``)."""
        pts, amps, q = probes
        res = self._fit_grid(pts, amps, q, self.m.T @ self.m)
        return replace(res, probes=probes)

    def _fit_grid(
        self, pts: np.ndarray, amps: np.ndarray, q: np.ndarray, g_init: np.ndarray
    ) -> PeakResult:
        """Fit ``A = A0·|2J1(x)/x|``, ``x = ka·sin 2θ`` to probes at joint pairs ``pts``.

        The tilt θ at a probe is ``|Lᵀ·(f(u) − f(u*))|`` with f the nominal beam components
        across the face (forward kinematics: exact to second order in the joint steps), u* the
        unknown peak posture and L a free 2×2 lower-triangular matrix (identity for an exact
        nominal model; it absorbs the first-order distortion that unknown offsets cause).
        Without forward kinematics f is the linear map of ``tilt_map``.
        """
        ka = self.ka
        ja, jb = self.ja, self.jb

        beam_components = self.beam_components
        if beam_components is not None:

            def comps(u: np.ndarray) -> np.ndarray:
                qq = np.tile(q, (len(u), 1))
                qq[:, ja] = u[:, 0]
                qq[:, jb] = u[:, 1]
                return beam_components(qq)
        else:
            m = self.m  # rad per deg

            def comps(u: np.ndarray) -> np.ndarray:
                return np.column_stack([u @ m.T, np.zeros(len(u))])

        l_init = np.eye(2)
        c_pts = comps(pts)
        f_pts, path_pts = c_pts[:, :2], c_pts[:, 2]
        # Water absorption over the round trip: moving the wrist changes the path (an angled
        # tool moves its centre), which tilts the amplitude hill and shifts its top off normal.
        absorb = np.exp(-2.0 * self.absorption * (path_pts - path_pts.mean()))

        def model(p: np.ndarray) -> np.ndarray:
            a0, ua, ub, l11, l21, l22 = p
            lmat = np.array([[l11, 0.0], [l21, l22]])
            d = (f_pts - comps(np.array([[ua, ub]]))[:, :2]) @ lmat
            t = np.arcsin(np.clip(np.linalg.norm(d, axis=1), 0.0, 1.0))
            return np.asarray(a0 * absorb * np.abs(piston_directivity(ka * np.sin(2 * t))))

        i = int(np.argmax(amps))
        p0 = np.array(
            [amps[i] * 1.05, pts[i, 0], pts[i, 1], l_init[0, 0], l_init[1, 0], l_init[1, 1]]
        )
        span = np.ptp(pts, axis=0) + 1e-6
        lo = np.array([0.0, pts[:, 0].min() - span[0], pts[:, 1].min() - span[1], 0.3, -0.7, 0.3])
        hi = np.array([np.inf, pts[:, 0].max() + span[0], pts[:, 1].max() + span[1], 3.0, 0.7, 3.0])
        p0 = np.clip(p0, lo + 1e-12, hi - 1e-12)
        sol = least_squares(
            lambda p: model(p) - amps,
            p0,
            method="trf",
            bounds=(lo, hi),
            x_scale=np.array([max(amps[i], 1e-9), 0.01, 0.01, 0.1, 0.1, 0.1]),
            xtol=1e-15,
            ftol=1e-15,
            gtol=1e-15,
            max_nfev=5000,
        )
        res = sol.fun
        dof = max(1, len(amps) - len(p0))
        # A quantised register rounds every reading by up to one level: with little noise to
        # dither it, the error repeats from probe to probe instead of averaging out, and the
        # few residual degrees of freedom (or six identical repeats) can hide it. Its variance
        # (a uniform level, step²/12, at the fit's gain) is added to the measured one.
        measured = max(
            float(np.sqrt(res @ res / dof)),
            1e-6 * sol.x[0],
            (self.amp_sigma_rel or 0.0) * float(np.mean(amps)),
        )
        step = self.rig.amplitude_step_fsh / 10 ** (self.rig.settings.gain_db / 20)
        sigma = float(np.hypot(measured, step / np.sqrt(12.0)))
        cov = np.linalg.pinv(sol.jac.T @ sol.jac) * sigma**2
        # Peak-posture covariance (deg²) → tilt covariance (rad²) through the local map.
        cov_tilt = self._tilt_cov(cov[1:3, 1:3], sol.x)
        tilt_std_deg = float(np.degrees(np.sqrt(max(np.trace(cov_tilt), 0.0) / 2.0)))
        out = self._with(q, sol.x[1], sol.x[2])
        gain = 10 ** (self.rig.settings.gain_db / 20)
        return PeakResult(
            out, float(sol.x[0]) * gain, tilt_std_deg, float(np.sqrt(np.mean(res**2))) * gain
        )

    def _tilt_cov(self, cov_u_deg2: np.ndarray, p: np.ndarray) -> np.ndarray:
        lmat = np.array([[p[3], 0.0], [p[4], p[5]]])
        jac = lmat.T @ self.m  # rad of tilt per deg of joint
        return np.asarray(jac @ cov_u_deg2 @ jac.T)


def read_distance(
    rig: Rig, temperature_c: float, averages: int, repeats: int = 8
) -> tuple[float, float]:
    """Water path (mm) from averaged TOF readings at the current posture, and its one-sigma.

    The one-sigma is the standard error of the readings' mean: their scatter over √repeats,
    or, when every reading carries its own std (an echo timed on the host from its A-scan:
    the record's SNR and bandwidth, ``GateReading.tof_std_ns``), their root mean square over
    √repeats if that is larger. The scatter of a few readings is itself uncertain by a
    quarter; the readings' own stds are not, but they leave out what moves the echo between
    readings (trigger jitter, the arm), which the scatter shows.

    A host-timed run without a reference echo captures it here first (``ucal.echo.capture``):
    the first distance a run reads is at the first face's normal incidence.
    """
    if rig.reference_capture is not None:  # the first distance: the cell's reference echo
        rig.reference_capture.ensure(rig)
    tofs, stds = [], []
    for _ in range(repeats):
        r = rig.read(averages)
        if not r.has_echo:
            log.info("no echo: %s at gain %.1f dB", r, rig.settings.gain_db)
            raise HardwareError(f"{rig.pulser.endpoint}: no echo in the gate at the peak posture")
        tofs.append(r.tof_ns)
        stds.append(r.tof_std_ns)
        log.debug("distance reading %s", r)
    tof_ns = np.array(tofs)
    mean = float(np.mean(tof_ns))
    # Standard error of the mean, with a floor of the float32 register resolution.
    sem = max(float(np.std(tof_ns, ddof=1) / np.sqrt(len(tof_ns))), 0.004)
    own = np.array(stds)
    if np.all(np.isfinite(own)):
        sem = max(sem, float(np.sqrt(np.mean(own**2) / own.size)))
    path = float(water_path_mm(mean, temperature_c))
    return path, float(water_path_mm(sem, temperature_c))


def ka_of(frequency_mhz: float, element_diameter_mm: float, temperature_c: float) -> float:
    """k·a of the transducer (dimensionless)."""
    return wavenumber_per_mm(frequency_mhz, temperature_c) * element_diameter_mm / 2.0
