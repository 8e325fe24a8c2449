"""The simulated cell: the echo a transducer on the true robot receives from the true reflectors.

``SimulatedCell(world)`` turns joint readings into what the pulser reports, ``(amplitude,
tof_ns)``. Its truth is richer than the solvers' model (``ucal.calibration``), on purpose:

1. true joint angles = readings + ``world.joint_offsets_deg`` (SPEC.md: actual = reading +
   offset) − ``motion_sign`` · ``world.backlash_deg`` / 2 (the link lags the encoder by half
   the lost motion, against the direction of the joint's last motion; sign 0 or None = no
   shift), on the world's true DH table with Hayati's twist ``dh_beta_deg`` after each link
   (``A_i = Rz(θ)·Tz(d)·Tx(a)·Rx(α)·Ry(β)``), with the true tool frame → TCP and beam (tool +Z);
   where the world says so (``world.arm``, ``ucal.sim.arm``), each link's d and a grown with
   the arm's temperature at the reading's simulated time and each joint turned further by the
   gravity torque over its stiffness (the arm sags; the encoder does not see it);
2. the echoing face is the nearest face whose plane the beam meets in front of the transducer,
   facing it, with some of the footprint on it (``ucal.sim.geometry``), unless the axis misses
   that face and the face behind it that the axis meets gives the larger echo with the rest
   of the footprint (a step's edge a few mm beside the beam leaves the face under it its echo);
   a face met from behind does not reflect, and where the beam axis crosses it, it hides the
   faces behind it;
3. the echo arrives at ``2 L / c(T(t)) + delay`` with L the water path from the TCP to the axis
   hit point, ``T(t) = temperature_c + drift_c_per_min · t_s / 60`` (Marczak's c) at the
   simulated time ``t_s`` of the reading, or the thermometer's ``temperature_log`` at
   ``t_s / 60`` minutes where the world gives one, and the pulser's fixed ``delay_ns``;
4. the receiver (``ucal.sim.receiver``) synthesises the sampled broadband echo (piston
   directivity and water absorption per frequency, so not the centre-frequency directivity
   and absorption that the search fits: the main lobe widens with the water path, and the
   echo's height falls with it more slowly, −0.023 instead of −0.032 Np/mm at 100 mm, as
   absorption shifts the spectrum down), scaled by 0.8 of full screen at normal incidence,
   50 mm and 20 dB
   (``ucal.acoustics.REFERENCE_AMPLITUDE``) × 10^((gain + gain error − 20)/20) × the
   footprint's share on the face; its peak-mode gate reports the envelope's peak and its time;
5. noise as the world says, in the waveform: the trigger jitter ``noise.tof_ns`` shifts the
   echo, ``noise.amplitude`` scales it, the receiver's white noise (its peak over a 200 µs
   gate is ``noise_floor`` at 20 dB) is added to every sample, each divided by √averages;
6. the reported amplitude saturates at 1.0 and is truncated to ``2^amplitude_bits`` levels of
   full screen when ``[pulser] amplitude_bits`` > 0 (below one level it reads 0); the gain
   error (one sigma ``gain_error_db``) is drawn anew whenever the requested gain changes.

7. the other echoes of an A-scan (``echoes``, noise-free, the RF output's: ``ucal.sim.rf``):
   the first multiple, the echo of the face's image in the transducer's face (twice the path,
   twice the tilt) × ``TRANSDUCER_FACE_REFLECTION`` (0.35, a matched epoxy face) ×
   ``BLOCK_FACE_REFLECTION`` (0.94, steel) × the share: 8.1 % of the main echo at 50 mm and
   normal incidence (water absorption at 100 mm of path takes 0.25 of it), 2 % at 100 mm;
   the specular echo of a face behind the main one that the footprint reaches (the step's
   face under it, a face of a tilted plate), at the path along the axis to its plane, its
   broadband height at its tilt (none past 45°) × the footprint's share on it (σ widened by
   the beam's one-way −6 dB spread from the piston's directivity) less the nearer faces'
   shares; and the corner echo of two block faces: a ray that meets both comes back parallel
   to itself (a dihedral retro-reflector), mirrored across their edge, at the round trip of
   the distance along the beam to the edge point nearest the axis, tilted by the beam's angle
   to the edge. Its height is × ``BLOCK_FACE_REFLECTION`` × the share of the element whose rays
   meet both faces before they are back at the transducer (a band min(S, t)·sin ψ either side
   of the edge, ψ the beam's lean towards the other face) and land on the element again
   (``_mirror_overlap``) × the footprint's share along the edge. Normal to a face no ray meets
   the other one: no corner echo; 1° off the XY face, 1 mm from the YZ face, at 50 mm: 0.24
   of full screen, 23 ns after the main echo, which has fallen to 0.015 (the corner of three
   faces is not modelled).

Every random source is a ``numpy.random.Generator`` seeded with ``(world.noise.seed, stream)``,
one stream per effect, so the same world and seed give the same readings for the same calls,
and adding an effect never shifts another's draws. Below the gate threshold (``threshold``,
fraction of full screen) or the receiver's noise floor no TOF is reported (NaN) and the
amplitude is at least the noise floor. A pulser that applies its own gate and threshold
(``drivers.pulser.simulator``) gets the raw echo with ``threshold=0``. ``echo`` is called from
the pulser server thread at every acquisition: constant matrices are built once, and the
generators and the gain state are guarded by a lock.
"""

from __future__ import annotations

import logging
import math
import threading
from enum import IntEnum
from typing import NamedTuple

import numpy as np
from scipy.special import ndtr

from ucal import acoustics
from ucal.cell import WorldTruth
from ucal.sim.arm import SAG_ITERATIONS, ArmLoad
from ucal.sim.geometry import (
    Face,
    FaceHit,
    beam_ray,
    block_faces,
    bowed_hit,
    intersect,
    intersect_all,
    reflector_face,
    step_face,
)
from ucal.sim.receiver import EchoReceiver

log = logging.getLogger(__name__)

#: Default gate threshold (fraction of full screen): weaker echoes give no time of flight.
DEFAULT_THRESHOLD = 0.02
#: Peak of the receiver's electronic noise in the gate at the reference gain (fraction of FS):
#: 78 dB below the reference echo, the dynamic range of a good 25 MHz pulser-receiver with a
#: flat reflector in its near field.
DEFAULT_NOISE_FLOOR = 0.0001
#: Relative one-sigma fluctuation of the noise-floor peak of a single acquisition.
_NOISE_FLOOR_SPREAD = 0.25
#: Expected peak of the noise envelope over a 200 µs gate at 200 MS/s (40 000 samples) in units
#: of the per-component sigma of complex white noise: √(2 ln 40 000) ≈ 4.6.
_FLOOR_PEAK_PER_SIGMA = 4.6
#: Footprint share below which a face is considered missed.
_MIN_SHARE = 1e-9
#: Pressure reflection coefficient of the transducer's face seen from the water (a quarter-wave
#: matched epoxy face of about 3.1 MRayl against water's 1.48: (3.1 − 1.48)/(3.1 + 1.48)).
TRANSDUCER_FACE_REFLECTION = 0.35
#: Pressure reflection coefficient of a block face (steel, 45.7 MRayl, against water): each
#: bounce beyond the first of an echo (the multiple, the corner) multiplies it by this.
BLOCK_FACE_REFLECTION = 0.94
#: A face tilted more than this from the beam sends its specular echo 90° or more off the
#: transducer's axis: no echo.
_MAX_SPECULAR_TILT_DEG = 45.0
#: Echoes weaker than this (fraction of full screen) are left out of ``echoes``.
_MIN_ECHO = 1e-6


class Echo(NamedTuple):
    """One echo of an acquisition, noise-free: when it arrives (ns), its envelope's peak
    (fraction of full screen) and the water its sound crossed, one way (mm)."""

    tof_ns: float
    amplitude: float
    water_path_mm: float


class _Stream(IntEnum):
    """One random stream per effect, seeded with ``(seed, stream)``."""

    TOF_JITTER = 1
    AMPLITUDE = 2
    RECEIVER_NOISE = 3
    NOISE_FLOOR = 4
    GAIN_ERROR = 5


class SimulatedCell:
    """The physics of a cell's truth: echoes at joint readings, true TCP and beam."""

    def __init__(
        self,
        world: WorldTruth,
        threshold: float = DEFAULT_THRESHOLD,
        noise_floor: float = DEFAULT_NOISE_FLOOR,
    ):
        self.world = world
        self.threshold = float(threshold)
        self.noise_floor = float(noise_floor)
        model = world.model
        # constant parts of the DH chain
        self._angle_offset_deg = np.asarray(model.theta_offset_deg, float) + np.asarray(
            world.joint_offsets_deg, float
        )
        self._half_backlash_deg = 0.5 * np.asarray(world.backlash_deg, float)
        alpha = np.radians(model.alpha_deg)
        self._ca = np.cos(alpha)
        self._sa = np.sin(alpha)
        self._d_mm = np.asarray(model.d_mm, float).copy()
        self._a_mm = np.asarray(model.a_mm, float).copy()
        self._links = np.zeros((6, 4, 4))
        self._links[:, 2, 1] = self._sa
        self._links[:, 2, 2] = self._ca
        self._links[:, 2, 3] = self._d_mm
        self._links[:, 3, 3] = 1.0
        # Hayati's twist about each link's y axis, appended to its DH transform
        self._twists: list[np.ndarray | None] = []
        for beta_deg in np.asarray(world.dh_beta_deg, float):
            if beta_deg == 0.0:
                self._twists.append(None)
                continue
            from scipy.spatial.transform import Rotation  # only a twisted table needs it

            ry = np.eye(4)
            ry[:3, :3] = Rotation.from_euler("y", beta_deg, degrees=True).as_matrix()
            self._twists.append(ry)
        # the arm bent by gravity and grown by heat, where the world says so
        self._load: ArmLoad | None = None
        if world.arm.bends or world.arm.warms:
            zero = self._chain(np.radians(model.theta_offset_deg), self._d_mm, self._a_mm)
            self._load = ArmLoad(world.arm, self._d_mm, self._a_mm, zero)
        self._tool = world.beam_matrix  # tool centre, z along the acoustic axis (squint)
        faces: list[Face] = list(block_faces(world.sample_matrix, world.sample_face_size_mm))
        if world.step is not None:
            # the step's top: met before the XY face under it, so the beam does not reach that
            faces.append(step_face(world.sample_matrix, world.step))
        self._plate: Face | None = None
        if world.reflector is not None:
            self._plate = reflector_face(world.reflector)
            faces.append(self._plate)
        self.faces: tuple[Face, ...] = tuple(faces)
        self._sigma_mm = acoustics.footprint_sigma_mm(world.element_diameter_mm)
        self._spread_tan: float | None = None  # tan of the beam's spread, on first use
        self._c_m_s = acoustics.sound_speed_m_s(world.water_temperature_c)
        self._receiver = EchoReceiver(
            world.frequency_mhz, world.element_diameter_mm, near_field=world.near_field
        )
        seed = int(world.noise.seed)
        self._rng = {s: np.random.default_rng([seed, int(s)]) for s in _Stream}
        self._gain_state: tuple[float, float] | None = None  # (requested dB, its error dB)
        self._lock = threading.Lock()

    # --- truth --------------------------------------------------------------------------------
    def joint_angles_deg(
        self, joint_readings_deg: np.ndarray, motion_sign: np.ndarray | None = None
    ) -> np.ndarray:
        """True DH angles (deg, (6,)): reading + θ offset + joint offset − sign · backlash / 2.

        ``motion_sign`` (6 values, sign taken) is the direction of each joint's last motion;
        None or 0 leaves the link where the encoder says.
        """
        th = np.asarray(joint_readings_deg, float) + self._angle_offset_deg
        if motion_sign is not None:
            th = th - np.sign(np.asarray(motion_sign, float)) * self._half_backlash_deg
        return np.asarray(th)

    def true_flange(
        self,
        joint_readings_deg: np.ndarray,
        motion_sign: np.ndarray | None = None,
        t_s: float = 0.0,
    ) -> np.ndarray:
        """True flange frame (4, 4) in the base frame for joint readings (deg, (6,)) at ``t_s``
        seconds of the cell's clock: the links as long as the arm's temperature makes them and
        bent by gravity where the world gives them a stiffness (``ucal.sim.arm``)."""
        th = np.radians(self.joint_angles_deg(joint_readings_deg, motion_sign))
        load = self._load
        if load is None:
            return self._chain(th, self._d_mm, self._a_mm)[-1]
        d_mm, a_mm = load.lengths_mm(t_s)
        frames = self._chain(th, d_mm, a_mm)
        if load.bends:
            for _ in range(SAG_ITERATIONS):
                frames = self._chain(th + load.sag_rad(frames), d_mm, a_mm)
        return frames[-1]

    def sag_deg(
        self,
        joint_readings_deg: np.ndarray,
        motion_sign: np.ndarray | None = None,
        t_s: float = 0.0,
    ) -> np.ndarray:
        """How far each link stands from its reading + offset under gravity (deg, (6,)) at
        ``t_s``: the sag ``true_flange`` bends the arm by (zeros on a rigid arm)."""
        load = self._load
        if load is None or not load.bends:
            return np.zeros(6)
        th = np.radians(self.joint_angles_deg(joint_readings_deg, motion_sign))
        d_mm, a_mm = load.lengths_mm(t_s)
        sag = np.zeros(6)
        for _ in range(SAG_ITERATIONS):
            sag = load.sag_rad(self._chain(th + sag, d_mm, a_mm))
        return np.degrees(sag)

    def _chain(self, th: np.ndarray, d_mm: np.ndarray, a_mm: np.ndarray) -> np.ndarray:
        """The DH frames T_1..T_6 (6, 4, 4) in the base frame of DH angles ``th`` (rad) on
        links of lengths ``d_mm``, ``a_mm``."""
        ct, st = np.cos(th), np.sin(th)
        # the six DH links at once: rows 3 and 4 are constant, rows 1 and 2 turn with θ
        links = self._links.copy()
        ca, sa, a = self._ca, self._sa, a_mm
        links[:, 0, 0] = ct
        links[:, 0, 1] = -st * ca
        links[:, 0, 2] = st * sa
        links[:, 0, 3] = a * ct
        links[:, 1, 0] = st
        links[:, 1, 1] = ct * ca
        links[:, 1, 2] = -ct * sa
        links[:, 1, 3] = a * st
        links[:, 2, 3] = d_mm
        frames = np.empty((6, 4, 4))
        t = links[0]
        for i in range(6):
            if i:
                t = t @ links[i]
            twist = self._twists[i]
            if twist is not None:
                t = t @ twist
            frames[i] = t
        return frames

    def true_tcp(
        self,
        joint_readings_deg: np.ndarray,
        motion_sign: np.ndarray | None = None,
        t_s: float = 0.0,
    ) -> np.ndarray:
        """True tool-centre-point frame (4, 4) in the base frame for joint readings (deg) at
        ``t_s`` seconds of the cell's clock."""
        return np.asarray(self.true_flange(joint_readings_deg, motion_sign, t_s) @ self._tool)

    def true_beam(
        self,
        joint_readings_deg: np.ndarray,
        motion_sign: np.ndarray | None = None,
        t_s: float = 0.0,
    ) -> tuple[np.ndarray, np.ndarray]:
        """True beam: origin (TCP, mm, (3,)) and unit direction (tool +Z, (3,)), base frame."""
        return beam_ray(self.true_tcp(joint_readings_deg, motion_sign, t_s))

    def hit(
        self,
        joint_readings_deg: np.ndarray,
        motion_sign: np.ndarray | None = None,
        t_s: float = 0.0,
    ) -> FaceHit | None:
        """The face that echoes at these readings (see module doc), or None."""
        found = self._echoing_hit(*self.true_beam(joint_readings_deg, motion_sign, t_s))
        return None if found is None else found[0]

    def water_temperature_c(self, t_s: float = 0.0) -> float:
        """Water temperature (°C) ``t_s`` seconds of simulated time after the cell started:
        the thermometer's log where the world gives one, else the linear drift."""
        log = self.world.water_temperature_log
        if log is not None:
            return log.at(t_s / 60.0)
        return self.world.water_temperature_c + self.world.water_drift_c_per_min * t_s / 60.0

    def sound_speed_m_s(self, t_s: float = 0.0) -> float:
        """Speed of sound in the tank (m/s, Marczak) ``t_s`` seconds after the cell started."""
        if self.world.water_drift_c_per_min == 0.0 and self.world.water_temperature_log is None:
            return self._c_m_s
        c = 0.0
        for coeff in reversed(acoustics.MARCZAK_COEFFS_M_S):  # Horner on a float: fast
            c = c * self.water_temperature_c(t_s) + coeff
        return c

    def _echoing_hit(
        self, origin: np.ndarray, direction: np.ndarray
    ) -> tuple[FaceHit, float] | None:
        """The echoing face's hit and the footprint's share on it, or None."""
        hits = [h for h in intersect_all(origin, direction, self.faces) if h is not None]
        refl = self.world.reflector
        if refl is not None and refl.flatness_mm > 0.0:
            hits = [
                bowed_hit(h, direction, refl.flatness_mm, refl.size_mm)
                if h.face is self._plate
                else h
                for h in hits
            ]
        hits.sort(key=lambda h: h.distance_mm)
        first: tuple[FaceHit, float] | None = None
        for h in hits:
            if h.facing:
                share = self._share(h)
                if share <= _MIN_SHARE:
                    continue
                if first is None:
                    if h.inside:
                        return h, share
                    first = (h, share)  # the axis misses it: a face behind may hold more
                elif h.inside:
                    # the face the axis meets, less what the nearer face took of the footprint
                    # (exact for a face inside another, as the step on the XY face): the
                    # larger echo of the two is the one the gate reports
                    rest = share - first[1]
                    c_m_s = self._c_m_s
                    near = self._peak(first[0].tilt_deg, first[0].distance_mm, c_m_s) * first[1]
                    far = self._peak(h.tilt_deg, h.distance_mm, c_m_s) * rest
                    return (h, rest) if far > near else first
            elif h.inside:
                break  # a face seen from behind blocks the beam and does not reflect
        return first

    def _share(self, h: FaceHit) -> float:
        # one hit's (4,) edge distances: a single share
        return float(acoustics.rectangle_share(h.edge_distances_mm, self._sigma_mm))

    # --- echoes -------------------------------------------------------------------------------
    def echoes(
        self,
        joint_readings_deg: np.ndarray,
        gain_db: float = acoustics.REFERENCE_GAIN_DB,
        t_s: float = 0.0,
        motion_sign: np.ndarray | None = None,
        *,
        gate_ns: tuple[float, float] | None = None,
    ) -> list[tuple[float, float]]:
        """Noise-free echoes ``[(tof_ns, amplitude), ...]`` the receiver gets at these readings:
        the main echo first (that of ``echo``, its arrival and its envelope's peak before
        saturation), then the others in time order; empty without an echoing face.

        The others (``ucal.sim`` echo model in docs): the first multiple of the main echo, the
        specular echo of any other face the beam's footprint reaches, and the corner echo of two
        block faces that the footprint spans. ``gate_ns`` (start, stop) keeps only the echoes
        arriving inside it (the main one too).
        """
        beam = self.true_beam(joint_readings_deg, motion_sign, t_s)
        found = self.echoes_along(beam, gain_db, t_s)
        if gate_ns is not None:
            found = [e for e in found if gate_ns[0] <= e.tof_ns <= gate_ns[1]]
        return [(e.tof_ns, e.amplitude) for e in found]

    def echoes_along(
        self, beam: tuple[np.ndarray, np.ndarray], gain_db: float, t_s: float = 0.0
    ) -> list[Echo]:
        """``echoes`` of the true ``beam`` (origin, direction: ``true_beam``), each with the
        water its sound crossed (``Echo.water_path_mm``, one way: the multiple's is twice the
        main one's), for the A-scan's echo shapes."""
        g = acoustics.REFERENCE_AMPLITUDE * acoustics.gain_factor(float(gain_db))
        return self._echo_list(beam[0], beam[1], g, self.sound_speed_m_s(t_s))

    def _echo_list(
        self, origin: np.ndarray, direction: np.ndarray, scale: float, c_m_s: float
    ) -> list[Echo]:
        """``echoes_along`` for a beam ray, ``scale`` = reference amplitude × gain factor."""
        found = self._echoing_hit(origin, direction)
        if found is None:
            return []
        h, share = found
        main = (
            self._arrival_ns(h.distance_mm, c_m_s),
            self._peak(h.tilt_deg, h.distance_mm, c_m_s),
        )
        out = [Echo(main[0], main[1] * scale * share, h.distance_mm)]
        others: list[Echo] = []
        # the multiple: the image of the face in the transducer's face, at twice the path and
        # twice the tilt, one more bounce on the face and one on the transducer
        if 2.0 * h.tilt_deg < _MAX_SPECULAR_TILT_DEG:
            peak = self._peak(2.0 * h.tilt_deg, 2.0 * h.distance_mm, c_m_s)
            factor = TRANSDUCER_FACE_REFLECTION * BLOCK_FACE_REFLECTION * share
            others.append(self._echo(2.0 * h.distance_mm, c_m_s, peak * scale * factor))
        others += self._other_faces(origin, direction, h, share, scale, c_m_s)
        others += self._corners(origin, direction, scale, c_m_s)
        out += sorted(e for e in others if e.amplitude > _MIN_ECHO)
        return out

    def _echo(self, water_path_mm: float, c_m_s: float, amplitude: float) -> Echo:
        """The echo of ``amplitude`` through ``water_path_mm`` (one way)."""
        return Echo(self._arrival_ns(water_path_mm, c_m_s), amplitude, water_path_mm)

    def _peak(self, tilt_deg: float, water_path_mm: float, c_m_s: float) -> float:
        """Envelope peak of the noise-free broadband echo of unit scale (the receiver's)."""
        rx = self._receiver
        t0_ns, samples = rx.waveform(0.0, 1.0, rx.spectrum(tilt_deg, water_path_mm, c_m_s))
        return rx.detect(t0_ns, samples)[0]

    def _footprint_sigma_mm(self, water_path_mm: float) -> float:
        """The footprint's σ at a water path: the element's (``acoustics.footprint_sigma_mm``)
        widened by the beam's spread, the one-way −6 dB half-angle of the piston's directivity
        (twice the pulse-echo tilt of ``acoustics.directivity_half_angle_deg``), 0.40° at
        25 MHz and 6 mm: 0.35 mm of half width at 50 mm, σ 1.50 → 1.53 mm."""
        if self._spread_tan is None:
            w = self.world
            spread_deg = 2.0 * acoustics.directivity_half_angle_deg(
                0.5, w.frequency_mhz, w.element_diameter_mm, w.water_temperature_c
            )
            self._spread_tan = math.tan(math.radians(spread_deg))
        half_width_mm = water_path_mm * self._spread_tan
        # a Gaussian's half width at half height is 1.177 σ
        return math.hypot(self._sigma_mm, half_width_mm / math.sqrt(2.0 * math.log(2.0)))

    def _other_faces(
        self,
        origin: np.ndarray,
        direction: np.ndarray,
        main: FaceHit,
        main_share: float,
        scale: float,
        c_m_s: float,
    ) -> list[Echo]:
        """Specular echoes of the other faces that the footprint reaches: the footprint's share
        on each (σ of ``_footprint_sigma_mm``), less the share the nearer faces took (exact for
        a face inside another, as the step on the XY face), at the path along the axis to its
        plane and the broadband echo's height at its tilt. A face nearer than the main one is
        one the axis misses that gives the smaller echo (``_echoing_hit``)."""
        out: list[Echo] = []
        taken = main_share
        hits = [
            hit
            for f in self.faces
            if f is not main.face
            and (hit := intersect(origin, direction, f)) is not None
            and hit.facing
            and (
                hit.distance_mm > main.distance_mm
                or (not hit.inside and self._share(hit) > _MIN_SHARE)
            )
            and hit.tilt_deg < _MAX_SPECULAR_TILT_DEG
        ]
        for hit in sorted(hits, key=lambda x: x.distance_mm):
            sigma = self._footprint_sigma_mm(hit.distance_mm)
            share = float(acoustics.rectangle_share(hit.edge_distances_mm, sigma))
            if hit.distance_mm > main.distance_mm:
                share -= taken
            if share <= _MIN_SHARE:
                continue
            taken += share
            peak = self._peak(hit.tilt_deg, hit.distance_mm, c_m_s)
            out.append(self._echo(hit.distance_mm, c_m_s, peak * scale * share))
        return out

    def _corners(
        self, origin: np.ndarray, direction: np.ndarray, scale: float, c_m_s: float
    ) -> list[Echo]:
        """Corner echoes of the block's pairs of faces (module doc of ``ucal.sim`` echoes)."""
        m = self.world.sample_matrix
        corner = m[:3, 3]
        size = float(self.world.sample_face_size_mm)
        radius = 0.5 * float(self.world.element_diameter_mm)
        d = np.asarray(direction, float)
        out: list[Echo] = []
        for i, j in ((0, 1), (0, 2), (1, 2)):
            n_i, n_j, e = m[:3, i], m[:3, j], m[:3, 3 - i - j]
            if not (d @ n_i < 0.0 and d @ n_j < 0.0):
                continue  # the beam comes from behind one of the faces
            # the point C of the edge nearest the beam axis: C = corner + s·e, axis point O + t·d
            b = float(d @ e)
            if b * b >= 1.0:
                continue  # the beam along the edge, to rounding: no ray meets both faces
            w0 = corner - origin
            s = (b * float(d @ w0) - float(e @ w0)) / (1.0 - b * b)
            t = float(d @ w0) + s * b
            if t <= 0.0:
                continue
            offset_mm = float(np.linalg.norm(origin + t * d - (corner + s * e)))
            # across the edge, each face seen along the beam is a band S·|n_other·τ| wide; a
            # ray returns from the corner if it meets the other face before it is back at the
            # transducer, t from the edge: the band of both is min(S, t)·min|n·τ|
            tau = np.cross(d, e)
            tau /= np.linalg.norm(tau)
            band_mm = min(size, t) * min(abs(float(n_i @ tau)), abs(float(n_j @ tau)))
            frac = _mirror_overlap(offset_mm, band_mm, radius)
            sigma = self._sigma_mm
            along = float(ndtr(s / sigma) + ndtr((size - s) / sigma) - 1.0)
            amp = frac * max(along, 0.0) * BLOCK_FACE_REFLECTION
            if amp <= _MIN_SHARE:
                continue
            tilt_deg = math.degrees(math.asin(min(abs(b), 1.0)))
            peak = self._peak(tilt_deg, t, c_m_s)
            out.append(self._echo(t, c_m_s, peak * scale * amp))
        return out

    def ideal_echo(
        self,
        joint_readings_deg: np.ndarray,
        gain_db: float = acoustics.REFERENCE_GAIN_DB,
        t_s: float = 0.0,
        motion_sign: np.ndarray | None = None,
    ) -> tuple[float, float]:
        """Noise-free reading ``(amplitude, tof_ns)``: no noise, jitter or gain error, the rest
        as ``echo`` (delay, detection, quantisation); amplitude 0 without a face, TOF NaN below
        the threshold."""
        found = self._echoing_hit(*self.true_beam(joint_readings_deg, motion_sign, t_s))
        if found is None:
            return 0.0, float("nan")
        h, share = found
        scale = acoustics.REFERENCE_AMPLITUDE * acoustics.gain_factor(gain_db) * share
        amp, tof = self._detect(h, self.sound_speed_m_s(t_s), scale, 0.0, 0.0)
        reading = self._report(amp)
        if reading <= 0.0 or amp < self.threshold:
            return reading, float("nan")
        return reading, tof

    def echo(
        self,
        joint_readings_deg: np.ndarray,
        averages: int = 1,
        gain_db: float = acoustics.REFERENCE_GAIN_DB,
        t_s: float = 0.0,
        motion_sign: np.ndarray | None = None,
        *,
        gate_us: tuple[float, float] | None = None,
    ) -> tuple[float, float]:
        """One pulser acquisition ``(amplitude, tof_ns)`` with the world's noise and errors.

        ``averages`` (≥ 1) divides every noise sigma by √averages; ``gain_db`` is the requested
        gain (amplitude × 10^((gain + error − 20)/20), saturating at 1.0; a new error is drawn
        when it differs from the previous call's); ``t_s`` is the simulated time (s) since the
        cell started (water drift); ``motion_sign`` the sign (−1, 0, +1) of each joint's last
        motion (backlash; None = no shift); ``gate_us`` = (start, width) of the round-trip gate
        in µs: an echo outside it is not seen. Without an echo above the threshold the TOF is
        NaN and the amplitude is the noise floor.
        """
        n_avg = max(int(averages), 1)
        root_n = math.sqrt(n_avg)
        noise = self.world.noise
        found = self._echoing_hit(*self.true_beam(joint_readings_deg, motion_sign, t_s))
        n = self._receiver.n
        with self._lock:
            gain_error_db = self._gain_error_db(float(gain_db))
            z_floor = float(self._rng[_Stream.NOISE_FLOOR].standard_normal())
            if found is not None:
                z_tof = float(self._rng[_Stream.TOF_JITTER].standard_normal())
                z_amp = float(self._rng[_Stream.AMPLITUDE].standard_normal())
                z_rx = self._rng[_Stream.RECEIVER_NOISE].standard_normal(2 * n)
        g = acoustics.gain_factor(float(gain_db) + gain_error_db)
        floor = self.noise_floor * g * abs(1.0 + _NOISE_FLOOR_SPREAD * z_floor / root_n)
        floor = min(floor, 1.0)
        if found is None:
            return self._report(floor), float("nan")
        h, share = found
        c_m_s = self.sound_speed_m_s(t_s)
        if gate_us is not None:
            arrival_ns = self._arrival_ns(h.distance_mm, c_m_s)
            start_ns, width_ns = gate_us[0] * 1e3, gate_us[1] * 1e3
            if not start_ns <= arrival_ns <= start_ns + width_ns:
                return self._report(floor), float("nan")
        scale = (
            acoustics.REFERENCE_AMPLITUDE
            * g
            * share
            * max(1.0 + noise.amplitude * z_amp / root_n, 0.0)
        )
        # receiver noise per quadrature component, scaled like the echo by the applied gain
        sigma = self.noise_floor * g / _FLOOR_PEAK_PER_SIGMA / root_n
        amp, tof = self._detect(h, c_m_s, scale, noise.tof_ns * z_tof / root_n, sigma, z_rx)
        reading = self._report(max(amp, floor))
        if reading <= 0.0 or amp < max(self.threshold, floor):  # lost in the noise
            return reading, float("nan")
        return reading, tof

    def _gain_error_db(self, gain_db: float) -> float:
        """Error (dB) of the gain applied for the requested ``gain_db``; call under the lock."""
        if self._gain_state is None or self._gain_state[0] != gain_db:
            z = float(self._rng[_Stream.GAIN_ERROR].standard_normal())
            self._gain_state = (gain_db, self.world.pulser.gain_error_db * z)
        return self._gain_state[1]

    def _arrival_ns(self, water_path_mm: float, c_m_s: float) -> float:
        """When the echo reaches the instrument: round trip in the water plus the delay (ns)."""
        return 2.0 * water_path_mm * 1e6 / c_m_s + self.world.pulser.delay_ns

    def _detect(
        self,
        h: FaceHit,
        c_m_s: float,
        scale: float,
        jitter_ns: float,
        sigma: float,
        z: np.ndarray | None = None,
    ) -> tuple[float, float]:
        """Synthesise the echo of ``h`` (with jitter and receiver noise) and gate it."""
        rx = self._receiver
        spectrum = rx.spectrum(h.tilt_deg, h.distance_mm, c_m_s)
        t0_ns, samples = rx.waveform(
            self._arrival_ns(h.distance_mm, c_m_s) + jitter_ns, scale, spectrum
        )
        if sigma > 0.0 and z is not None:
            samples = samples + sigma * (z[: rx.n] + 1j * z[rx.n :])
        return rx.detect(t0_ns, samples)

    def _report(self, amplitude: float) -> float:
        """What the amplitude register says: saturated at 1.0, truncated to 2^bits levels."""
        a = min(max(float(amplitude), 0.0), 1.0)
        bits = self.world.pulser.amplitude_bits
        if bits > 0:
            levels = float(1 << bits)
            a = math.floor(a * levels) / levels
        return a


def _mirror_overlap(offset_mm: float, band_mm: float, radius_mm: float) -> float:
    """Share of an element of ``radius_mm`` whose rays a corner returns onto the element: a
    ray ``r`` across the edge (in the beam's cross-section) that meets both faces, |r| ≤
    ``band_mm``, comes back at −r; the element's centre is ``offset_mm`` from the edge. The
    area of {p in the disc, its mirror in the disc, |r| ≤ band} over πa²:
    ``4·[F(o + w) − F(o)]/(πa²)``, F(u) = ∫√(a² − u²)du, w = min(band, a − o)."""
    a, o = float(radius_mm), abs(float(offset_mm))
    w = min(float(band_mm), a - o)
    if w <= 0.0:
        return 0.0

    def f(u: float) -> float:
        u = min(u, a)
        return 0.5 * (u * math.sqrt(max(a * a - u * u, 0.0)) + a * a * math.asin(u / a))

    return 4.0 * (f(o + w) - f(o)) / (math.pi * a * a)


def ideal_echo(
    world: WorldTruth, joint_readings_deg: np.ndarray, gain_db: float = acoustics.REFERENCE_GAIN_DB
) -> tuple[float, float]:
    """Noise-free ``(amplitude, tof_ns)`` of ``world`` at joint readings (see ``SimulatedCell``)."""
    return SimulatedCell(world).ideal_echo(joint_readings_deg, gain_db)
