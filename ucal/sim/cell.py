"""The simulated cell: the echo a transducer on the true robot receives from the true reflectors.

``SimulatedCell(world)`` turns joint readings into ``(amplitude, tof_ns)``:

1. true joint angles = readings + ``world.joint_offsets_deg`` (SPEC.md: actual = reading +
   offset) on the world's true DH table, with the true tool frame → TCP and beam (tool +Z);
2. the echoing face is the nearest face whose plane the beam meets in front of the transducer,
   facing it, with some of the footprint on it (``ucal.sim.geometry``); a face met from behind
   does not reflect, and where the beam axis crosses it, it hides the faces behind it;
3. ``tof_ns = 2 L / c(T)`` with L the water path from the TCP to the axis hit point;
   the amplitude is ``ucal.acoustics.echo_amplitude`` (0.8 of full screen at normal
   incidence, 50 mm path, 20 dB gain; × 10^(Δg/20); clipped at 1.0 = saturation);
4. noise as the world says, divided by √averages, from a ``numpy.random.Generator`` seeded with
   ``world.noise.seed``.

Below the gate threshold (``threshold``, fraction of full screen) or the receiver's noise floor
no TOF is reported (NaN) and the amplitude is at least the noise floor. A pulser that applies its
own gate and threshold (``drivers.pulser.simulator``) gets the raw echo with ``threshold=0``. ``echo`` is called from the pulser server thread at
every acquisition: constant matrices are built once, and the generator is guarded by a lock.
"""

from __future__ import annotations

import threading

import numpy as np

from ucal import acoustics
from ucal.cell import WorldTruth
from ucal.sim.geometry import Face, FaceHit, beam_ray, block_faces, intersect, reflector_face

#: Default gate threshold (fraction of full screen): weaker echoes give no time of flight.
DEFAULT_THRESHOLD = 0.02
#: Peak of the receiver's electronic noise in the gate at the reference gain (fraction of FS):
#: 78 dB below the reference echo, the dynamic range of a good 25 MHz pulser-receiver with a
#: flat reflector in its near field.
DEFAULT_NOISE_FLOOR = 0.0001
#: Relative one-sigma fluctuation of the noise-floor peak of a single acquisition.
_NOISE_FLOOR_SPREAD = 0.25
#: Footprint share below which a face is considered missed.
_MIN_SHARE = 1e-9


class SimulatedCell:
    """The physics of a cell's truth: echoes at joint readings, true TCP and beam."""

    def __init__(self, world: WorldTruth, threshold: float = DEFAULT_THRESHOLD,
                 noise_floor: float = DEFAULT_NOISE_FLOOR):
        self.world = world
        self.threshold = float(threshold)
        self.noise_floor = float(noise_floor)
        model = world.model
        # constant parts of the DH chain
        self._angle_offset_deg = (np.asarray(model.theta_offset_deg, float)
                                  + np.asarray(world.joint_offsets_deg, float))
        alpha = np.radians(model.alpha_deg)
        self._ca = np.cos(alpha)
        self._sa = np.sin(alpha)
        self._d_mm = np.asarray(model.d_mm, float).copy()
        self._a_mm = np.asarray(model.a_mm, float).copy()
        self._tool = world.tool_matrix
        faces: list[Face] = list(block_faces(world.sample_matrix, world.sample_face_size_mm))
        if world.reflector is not None:
            faces.append(reflector_face(world.reflector))
        self.faces: tuple[Face, ...] = tuple(faces)
        self._sigma_mm = acoustics.footprint_sigma_mm(world.element_diameter_mm)
        self._c_m_s = acoustics.sound_speed_m_s(world.water_temperature_c)
        self._rng = np.random.default_rng(world.noise.seed)
        self._lock = threading.Lock()

    # --- truth --------------------------------------------------------------------------------
    def true_flange(self, joint_readings_deg: np.ndarray) -> np.ndarray:
        """True flange frame (4, 4) in the base frame for joint readings (deg, (6,))."""
        th = np.radians(np.asarray(joint_readings_deg, float) + self._angle_offset_deg)
        ct, st = np.cos(th), np.sin(th)
        t = np.eye(4)
        ca, sa, d, a = self._ca, self._sa, self._d_mm, self._a_mm
        for i in range(6):
            link = np.array([[ct[i], -st[i] * ca[i], st[i] * sa[i], a[i] * ct[i]],
                             [st[i], ct[i] * ca[i], -ct[i] * sa[i], a[i] * st[i]],
                             [0.0, sa[i], ca[i], d[i]],
                             [0.0, 0.0, 0.0, 1.0]])
            t = t @ link
        return t

    def true_tcp(self, joint_readings_deg: np.ndarray) -> np.ndarray:
        """True tool-centre-point frame (4, 4) in the base frame for joint readings (deg)."""
        return self.true_flange(joint_readings_deg) @ self._tool

    def true_beam(self, joint_readings_deg: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """True beam: origin (TCP, mm, (3,)) and unit direction (tool +Z, (3,)) in the base frame."""
        return beam_ray(self.true_tcp(joint_readings_deg))

    def hit(self, joint_readings_deg: np.ndarray) -> FaceHit | None:
        """The face that echoes at these readings (see module doc), or None."""
        origin, direction = self.true_beam(joint_readings_deg)
        return self._echoing_hit(origin, direction)

    def _echoing_hit(self, origin: np.ndarray, direction: np.ndarray) -> FaceHit | None:
        hits = [h for f in self.faces if (h := intersect(origin, direction, f)) is not None]
        hits.sort(key=lambda h: h.distance_mm)
        for h in hits:
            if h.facing:
                if self._share(h) > _MIN_SHARE:
                    return h
            elif h.inside:
                return None  # a face seen from behind blocks the beam and does not reflect
        return None

    def _share(self, h: FaceHit) -> float:
        return acoustics.rectangle_share(h.edge_distances_mm, self._sigma_mm)

    # --- echoes -------------------------------------------------------------------------------
    def ideal_echo(self, joint_readings_deg: np.ndarray,
                   gain_db: float = acoustics.REFERENCE_GAIN_DB) -> tuple[float, float]:
        """Noise-free ``(amplitude, tof_ns)``: amplitude 0 without a face, TOF NaN below threshold."""
        h = self.hit(joint_readings_deg)
        if h is None:
            return 0.0, float("nan")
        amp = self._amplitude(h, gain_db)
        tof = self._tof_ns(h.distance_mm) if amp >= self.threshold else float("nan")
        return amp, tof

    def echo(self, joint_readings_deg: np.ndarray, averages: int = 1,
             gain_db: float = acoustics.REFERENCE_GAIN_DB,
             gate_us: tuple[float, float] | None = None) -> tuple[float, float]:
        """One pulser acquisition ``(amplitude, tof_ns)`` with the world's noise.

        ``averages`` (≥ 1) divides both noise sigmas by √averages; ``gain_db`` scales the
        amplitude by 10^((gain − 20)/20), saturating at 1.0; ``gate_us`` = (start, width) of the
        round-trip gate in µs: an echo outside it is not seen. Without an echo above the
        threshold the TOF is NaN and the amplitude is the noise floor.
        """
        n_avg = max(int(averages), 1)
        root_n = np.sqrt(n_avg)
        noise = self.world.noise
        h = self.hit(joint_readings_deg)
        with self._lock:
            z_amp, z_tof, z_floor = self._rng.standard_normal(3)
        g = acoustics.gain_factor(gain_db)
        floor = self.noise_floor * g * abs(1.0 + _NOISE_FLOOR_SPREAD * z_floor / root_n)
        floor = min(floor, 1.0)
        if h is None:
            return floor, float("nan")
        tof = self._tof_ns(h.distance_mm)
        if gate_us is not None:
            start_ns, width_ns = gate_us[0] * 1e3, gate_us[1] * 1e3
            if not start_ns <= tof <= start_ns + width_ns:
                return floor, float("nan")
        # unclipped, so that noise acts on the echo before the screen saturates
        amp = self._amplitude(h, gain_db, clip=False)
        amp = amp * (1.0 + noise.amplitude * z_amp / root_n)
        amp = float(np.clip(amp, 0.0, 1.0))
        if amp < max(self.threshold, floor):  # below the threshold or lost in the noise
            return max(amp, floor), float("nan")
        return max(amp, floor), tof + noise.tof_ns * z_tof / root_n

    def _tof_ns(self, water_path_mm: float) -> float:
        return 2.0 * water_path_mm * 1e6 / self._c_m_s

    def _amplitude(self, h: FaceHit, gain_db: float, clip: bool = True) -> float:
        w = self.world
        a = (acoustics.REFERENCE_AMPLITUDE * acoustics.gain_factor(gain_db)
             * acoustics.water_attenuation(h.distance_mm, w.frequency_mhz)
             * acoustics.directivity(h.tilt_deg, w.frequency_mhz, w.element_diameter_mm,
                                     w.water_temperature_c)
             * self._share(h))
        return float(min(a, 1.0)) if clip else float(a)


def ideal_echo(world: WorldTruth, joint_readings_deg: np.ndarray,
               gain_db: float = acoustics.REFERENCE_GAIN_DB) -> tuple[float, float]:
    """Noise-free ``(amplitude, tof_ns)`` of ``world`` at joint readings (see ``SimulatedCell``)."""
    return SimulatedCell(world).ideal_echo(joint_readings_deg, gain_db)
