"""The simulated cell: the echo a transducer on the true robot receives from the true reflectors.

``SimulatedCell(world)`` turns joint readings into what the pulser reports, ``(amplitude,
tof_ns)``. Its truth is richer than the solvers' model (``ucal.calibration``), on purpose:

1. true joint angles = readings + ``world.joint_offsets_deg`` (SPEC.md: actual = reading +
   offset) − ``motion_sign`` · ``world.backlash_deg`` / 2 (the link lags the encoder by half
   the lost motion, against the direction of the joint's last motion; sign 0 or None = no
   shift), on the world's true DH table with Hayati's twist ``dh_beta_deg`` after each link
   (``A_i = Rz(θ)·Tz(d)·Tx(a)·Rx(α)·Ry(β)``), with the true tool frame → TCP and beam (tool +Z);
2. the echoing face is the nearest face whose plane the beam meets in front of the transducer,
   facing it, with some of the footprint on it (``ucal.sim.geometry``); a face met from behind
   does not reflect, and where the beam axis crosses it, it hides the faces behind it;
3. the echo arrives at ``2 L / c(T(t)) + delay`` with L the water path from the TCP to the axis
   hit point, ``T(t) = temperature_c + drift_c_per_min · t_s / 60`` (Marczak's c) at the
   simulated time ``t_s`` of the reading, and the pulser's fixed electronic ``delay_ns``;
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

import numpy as np
from scipy.spatial.transform import Rotation

from ucal import acoustics
from ucal.cell import WorldTruth
from ucal.sim.geometry import (
    Face,
    FaceHit,
    beam_ray,
    block_faces,
    bowed_hit,
    intersect,
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
            ry = np.eye(4)
            ry[:3, :3] = Rotation.from_euler("y", beta_deg, degrees=True).as_matrix()
            self._twists.append(ry)
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
        return th

    def true_flange(
        self, joint_readings_deg: np.ndarray, motion_sign: np.ndarray | None = None
    ) -> np.ndarray:
        """True flange frame (4, 4) in the base frame for joint readings (deg, (6,))."""
        th = np.radians(self.joint_angles_deg(joint_readings_deg, motion_sign))
        ct, st = np.cos(th), np.sin(th)
        # the six DH links at once: rows 3 and 4 are constant, rows 1 and 2 turn with θ
        links = self._links.copy()
        ca, sa, a = self._ca, self._sa, self._a_mm
        links[:, 0, 0] = ct
        links[:, 0, 1] = -st * ca
        links[:, 0, 2] = st * sa
        links[:, 0, 3] = a * ct
        links[:, 1, 0] = st
        links[:, 1, 1] = ct * ca
        links[:, 1, 2] = -ct * sa
        links[:, 1, 3] = a * st
        t = links[0]
        for i in range(6):
            if i:
                t = t @ links[i]
            twist = self._twists[i]
            if twist is not None:
                t = t @ twist
        return t

    def true_tcp(
        self, joint_readings_deg: np.ndarray, motion_sign: np.ndarray | None = None
    ) -> np.ndarray:
        """True tool-centre-point frame (4, 4) in the base frame for joint readings (deg)."""
        return self.true_flange(joint_readings_deg, motion_sign) @ self._tool

    def true_beam(
        self, joint_readings_deg: np.ndarray, motion_sign: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """True beam: origin (TCP, mm, (3,)) and unit direction (tool +Z, (3,)), base frame."""
        return beam_ray(self.true_tcp(joint_readings_deg, motion_sign))

    def hit(
        self, joint_readings_deg: np.ndarray, motion_sign: np.ndarray | None = None
    ) -> FaceHit | None:
        """The face that echoes at these readings (see module doc), or None."""
        found = self._echoing_hit(*self.true_beam(joint_readings_deg, motion_sign))
        return None if found is None else found[0]

    def water_temperature_c(self, t_s: float = 0.0) -> float:
        """Water temperature (°C) ``t_s`` seconds of simulated time after the cell started."""
        return self.world.water_temperature_c + self.world.water_drift_c_per_min * t_s / 60.0

    def sound_speed_m_s(self, t_s: float = 0.0) -> float:
        """Speed of sound in the tank (m/s, Marczak) ``t_s`` seconds after the cell started."""
        if self.world.water_drift_c_per_min == 0.0:
            return self._c_m_s
        c = 0.0
        for coeff in reversed(acoustics.MARCZAK_COEFFS_M_S):  # Horner on a float: fast
            c = c * self.water_temperature_c(t_s) + coeff
        return c

    def _echoing_hit(
        self, origin: np.ndarray, direction: np.ndarray
    ) -> tuple[FaceHit, float] | None:
        """The echoing face's hit and the footprint's share on it, or None."""
        hits = [h for f in self.faces if (h := intersect(origin, direction, f)) is not None]
        refl = self.world.reflector
        if refl is not None and refl.flatness_mm > 0.0:
            hits = [
                bowed_hit(h, direction, refl.flatness_mm, refl.size_mm)
                if h.face is self._plate
                else h
                for h in hits
            ]
        hits.sort(key=lambda h: h.distance_mm)
        for h in hits:
            if h.facing:
                share = self._share(h)
                if share > _MIN_SHARE:
                    return h, share
            elif h.inside:
                return None  # a face seen from behind blocks the beam and does not reflect
        return None

    def _share(self, h: FaceHit) -> float:
        # one hit's (4,) edge distances: a single share
        return float(acoustics.rectangle_share(h.edge_distances_mm, self._sigma_mm))

    # --- echoes -------------------------------------------------------------------------------
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
        found = self._echoing_hit(*self.true_beam(joint_readings_deg, motion_sign))
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
        found = self._echoing_hit(*self.true_beam(joint_readings_deg, motion_sign))
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


def ideal_echo(
    world: WorldTruth, joint_readings_deg: np.ndarray, gain_db: float = acoustics.REFERENCE_GAIN_DB
) -> tuple[float, float]:
    """Noise-free ``(amplitude, tof_ns)`` of ``world`` at joint readings (see ``SimulatedCell``)."""
    return SimulatedCell(world).ideal_echo(joint_readings_deg, gain_db)
