"""The running estimate: measure a face, refit the cell, predict the next posture, trust it.

Every command that measures the block's faces (``calibrate`` at both levels, ``check``,
``verify``) measures them in one loop: the posture of the next face is predicted with the cell
as the faces measured so far see it (``estimate_cell``: the offsets, the block corner, the
tool and block orientations), checked before the robot moves there (``check_prediction``),
searched as hard as the prediction deserves (``Trust``), and the new face refits the cell.
At the end the early faces' recorded probes are fitted again with the final estimate
(``refit_peaks``), without motion. ``RunningEstimate`` holds that loop's state; the
procedures say only which face to measure next and from where.

The trust policy (``Trust``) is one for every command (the tool-frame plate's differs only
in what pins its prediction down, ``PLATE_TRUST``): the first face is acquired within 16°;
every later one is centred on its main lobe first, from the prediction (a quick centre that
finds no main lobe, or a fit that lands on a side lobe, falls back to the acquisition within
8°, so a poor prediction costs a few moves, never a wrong peak); after three faces, or as soon
as a prediction landed inside the direct fit's first grid (``LANDED_DEG``: the cell as
estimated is right, as a calibrated profile's is), the face is fitted at once — unless the last
prediction missed by more than the main lobe's half-width (``MAIN_LOBE_HALF_DEG``), which
says the faces so far do not pin the model down yet (postures far apart, as the full level's).
(Acquiring the second face as well, whatever its prediction, cost a region check of three
postures 230 moves instead of 129, and saved none on calibrate's demo: 182 against 180.)
A face whose peak came out uncertain (tilt σ above ``UNCERTAIN_TILT_DEG``) is left out of the
prediction.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field, replace

import numpy as np

from ucal.cell import CellProfile
from ucal.devices.rig import Rig
from ucal.errors import SafetyError
from ucal.kinematics.rotations import angle_between_deg, rotation_angle_deg
from ucal.measure.acquire import BLOCK_FACES, noise_floor
from ucal.measure.approach import FinalApproachRig, approaching
from ucal.measure.face import FaceRequest, FaceResult, FaceSetup, SearchMode, make_search, measure
from ucal.measure.search import ka_of, read_distance
from ucal.model.fit import (
    BETA,
    BLOCK,
    DH,
    OFFSETS,
    TOOL,
    CellPrior,
    cell_geometry,
    prior_from_profile,
    solve_cell,
)
from ucal.model.geometry import (
    CellGeometry,
    Face,
    FaceMeasurement,
    beam_and_tcp,
    distance_joints,
)
from ucal.model.safety import (
    MIN_WATER_PATH_MM,
    TOLERANCE_SIGMAS,
    check_joints,
    offsets_std_deg,
)
from ucal.model.wrist import aim_wrist

log = logging.getLogger(__name__)

#: Half-width (deg of beam tilt) of the main lobe at −6 dB (25 MHz, 6 mm element): a prediction
#: that missed by more than this is not trusted for a direct fit next.
MAIN_LOBE_HALF_DEG = 0.2
#: A prediction that landed within this of the peak (deg of tilt, inside the direct fit's
#: first grid) says the cell as estimated is right wherever the arm goes: the next face,
#: however few were measured, is fitted at once (a calibrated cell's own offsets).
LANDED_DEG = 0.02
#: A face whose peak posture is less certain than this (deg of tilt) is left out of the
#: prediction (a good one is a few thousandths).
UNCERTAIN_TILT_DEG = 0.01
#: The tilt σ (deg) of a water path read again without a search (``read_path_again``): a
#: thousand times a fitted peak's, so that its posture, the one measured before, is not
#: counted twice.
PATH_ONLY_TILT_STD_DEG = 1.0


@dataclass(frozen=True)
class Trust:
    """How far a predicted posture is trusted, from the faces measured so far (module
    docstring): ``quick_after`` faces, or the same face measured before, for a quick centring;
    ``direct_after`` faces (None: never) for a direct fit, while the last prediction missed by
    at most ``direct_miss_deg``; the acquisition radius (deg of beam tilt) of the first face
    and of the later ones."""

    quick_after: int = 1
    direct_after: int | None = 3
    direct_miss_deg: float = MAIN_LOBE_HALF_DEG
    first_radius_deg: float = 16.0
    radius_deg: float = 8.0

    def mode(self, measured: int, seen: bool, last_miss_deg: float = np.inf) -> SearchMode:
        """The search mode after ``measured`` faces (``seen``: this face among them), the last
        prediction off by ``last_miss_deg`` (deg of tilt)."""
        if self.direct_after is not None and measured >= 1:
            # landed inside the fit's first grid: the model is good wherever the arm goes
            if last_miss_deg <= LANDED_DEG:
                return SearchMode.DIRECT
            if measured >= self.direct_after and last_miss_deg <= self.direct_miss_deg:
                return SearchMode.DIRECT
        if measured >= self.quick_after or seen:
            return SearchMode.QUICK
        return SearchMode.ACQUIRE

    def radius(self, measured: int) -> float:
        return self.first_radius_deg if measured == 0 else self.radius_deg


#: The block's faces (module docstring).
BLOCK_TRUST = Trust()
#: The tool-frame plate, one face measured again and again (centred from the second posture
#: on), but never fitted without centring: the joint offsets, not yet calibrated, turn the beam
#: differently at each orientation by tenths of a degree, which no posture's fit pins down.
#: The plate is met at the planned water path, the profile's tool and plate known to a degree
#: or so: the raster starts 4° wide (``acquire.PLATE``).
PLATE_TRUST = Trust(direct_after=None, first_radius_deg=4.0, radius_deg=4.0)


@dataclass(frozen=True)
class CellEstimate:
    """What the measurements so far say about the cell, to predict the next posture."""

    offsets_deg: np.ndarray  # (6,)
    corner_mm: np.ndarray  # (3,) block corner
    vector: np.ndarray  # the fit's full parameter vector (start of the next fit)
    geometry: CellGeometry  # tool and block orientation as fitted


def estimate_cell(
    prior: CellPrior, meas: list[FaceMeasurement], start: np.ndarray | None = None
) -> CellEstimate:
    """The cell as the measurements so far see it (``start``: the previous vector).

    The prior-augmented fit of ``ucal.model.fit``: with fewer than the full set the
    priors (broad on the offsets, the declared tolerances on the rest) hold the directions the
    data do not see yet, and the sound speed is fitted as soon as a step shows it. The DH
    table and the tool position are held (their tolerances move a prediction by micrometres).
    The fitted tool and block orientations are part of the prediction: a block tilted by a
    tenth of a degree moves the next face's normal-incidence posture by as much, which is
    most of a fit grid.
    """
    cell = solve_cell(prior, meas, fixed=DH + BETA + TOOL[:3], start=start, tol=1e-7)
    return CellEstimate(
        np.array([cell.value(n) for n in OFFSETS]),
        np.array([cell.value(n) for n in BLOCK[:3]]),
        cell.estimate,
        cell_geometry(cell.table, cell.estimate, prior.model),
    )


def refit_peaks(
    rig: Rig,
    profile: CellProfile,
    meas: list[FaceMeasurement],
    ka: float,
    prior: CellPrior,
    vector: np.ndarray | None = None,
    rounds: int = 1,
) -> list[FaceMeasurement]:
    """Fit every face's recorded probes again with the offsets of a full solution.

    The first faces were fitted with kinematics whose offsets could be degrees off, which
    distorts the fit model (beam direction and water path against the wrist joints) at the
    1e-4 degree level. No motion: only the recorded probes are used.
    """
    for _ in range(rounds):
        cell = estimate_cell(prior, meas, vector)
        vector, est, geom = cell.vector, cell.offsets_deg, cell.geometry
        new = []
        for m in meas:
            if m.probes is None:
                new.append(m)
                continue
            search = make_search(rig, geom, profile, m.joints_deg, m.face, est, ka, m.search_joints)
            peak = search.refit(m.probes)
            new.append(
                replace(m, joints_deg=peak.joints_deg, tilt_std_deg=max(peak.tilt_std_deg, 1e-4))
            )
        meas = new
    return meas


def check_prediction(
    profile: CellProfile,
    geom: CellGeometry,
    joints_deg: np.ndarray,
    face: int,
    offsets_deg: np.ndarray,
    plane_mm: np.ndarray,
    label: str,
) -> np.ndarray:
    """The posture predicted for ``face`` from ``joints_deg`` (the wrist aimed with the cell as
    estimated), checked before moving there (``SafetyError``, exit 4): joint ranges with room
    for the wrist search, the singularity margin, and a water path of at least
    ``MIN_WATER_PATH_MM`` to the face's plane through ``plane_mm``."""
    q = aim_wrist(geom, joints_deg, -geom.normal(face), offsets_deg)
    try:
        check_joints(profile, q, label)
    except SafetyError as e:
        raise SafetyError(f"{e}; {outside_tolerance(profile, geom, offsets_deg)}") from None
    _, tcp = beam_and_tcp(geom, q, offsets_deg)
    path = float(geom.normal(face) @ (tcp - plane_mm))
    if path < MIN_WATER_PATH_MM:
        raise SafetyError(
            f"{label}: with the cell as measured so far the tool centre would be "
            f"{path:.1f} mm from the face (minimum {MIN_WATER_PATH_MM:g} mm)"
        )
    return q


def outside_tolerance(profile: CellProfile, geom: CellGeometry, offsets_deg: np.ndarray) -> str:
    """Why a posture the plan checked with room for the declared tolerances fails as the cell
    is measured: the measured quantity farthest outside its tolerance, in words (the joint
    offsets against ``offsets_std_deg``, the beam's and the block's turn against ``[tool]``
    and ``[sample] rotation_std_deg``, in sigma)."""
    std = offsets_std_deg(profile)
    z = np.abs(np.asarray(offsets_deg) - profile.joint_offsets_deg) / std
    j = int(np.argmax(z))
    found = [
        (
            float(z[j]),
            f"joint {j + 1}'s offset is measured "
            f"{offsets_deg[j] - profile.joint_offsets_deg[j]:+.2f} deg from the profile's, "
            f"{z[j]:.1f} sigma of the ±{std[j]:.3g} deg a plan allows it",
        )
    ]
    for what, key, turn, tol in (
        (
            "the beam",
            "[tool] rotation_std_deg",
            angle_between_deg(geom.beam_flange, profile.tool_matrix[:3, 2]),
            np.max(profile.tool_rotation_std_deg),
        ),
        (
            "the block",
            "[sample] rotation_std_deg",
            rotation_angle_deg(geom.block_rotation, profile.sample_matrix[:3, :3]),
            np.max(profile.sample_rotation_std_deg),
        ),
    ):
        if tol > 0:
            found.append(
                (
                    float(turn / tol),
                    f"{what} is measured turned {float(turn):.2f} deg from the profile's, "
                    f"{float(turn / tol):.1f} sigma of {key} ±{tol:g} deg",
                )
            )
    z_max, words = max(found)
    if z_max > TOLERANCE_SIGMAS:
        return f"the plan kept room for the declared tolerances, and {words}: outside them"
    return f"the cell as measured so far is within the declared tolerances ({words})"


@dataclass
class RunningEstimate:
    """The loop's state (module docstring): the faces measured, the cell they give, how far
    the last prediction missed. ``rig`` reaches every static posture the same way (the
    procedures give a ``FinalApproachRig``)."""

    profile: CellProfile
    rig: Rig
    setup: FaceSetup
    prior: CellPrior
    geometry: CellGeometry  # tool and block orientation as estimated so far
    trust: Trust = BLOCK_TRUST
    offsets_deg: np.ndarray = field(init=False)
    corner_mm: np.ndarray = field(init=False)
    vector: np.ndarray | None = None
    measurements: list[FaceMeasurement] = field(default_factory=list)
    last_miss_deg: float = np.inf

    def __post_init__(self) -> None:
        self.offsets_deg = np.array(self.profile.joint_offsets_deg, float)
        self.corner_mm = np.array(self.profile.sample_position_mm, float)

    @classmethod
    def start(
        cls,
        profile: CellProfile,
        rig: Rig,
        geom: CellGeometry,
        first_deg: np.ndarray,
        joint: int,
        keep_still: bool = False,
    ) -> RunningEstimate:
        """The noise floor read off the first posture ``first_deg`` (``joint`` turned: the beam
        in open water), then the estimate at the profile's cell, measuring through a
        ``FinalApproachRig`` of ``rig`` (``keep_still``: its)."""
        ka = ka_of(profile.frequency_mhz, profile.element_diameter_mm, profile.water_temperature_c)
        gain = noise_floor(rig, first_deg, joint, BLOCK_FACES)
        setup = FaceSetup(profile, ka, gain)
        approach = FinalApproachRig(rig, keep_still=keep_still)
        return cls(profile, approach, setup, prior_from_profile(profile), geom)

    def converting_at(self, temperature_c: float) -> None:
        """Convert the water paths measured from now on at ``temperature_c`` (the tank's
        sound speed as read since the run began, as Marczak's temperature)."""
        self.profile = self.profile.replace(water_temperature_c=temperature_c)
        self.setup = replace(self.setup, profile=self.profile)

    def measure(
        self,
        face: Face,
        start_deg: np.ndarray,
        label: str,
        config: str,
        above_mm: float = 0.0,
        mode: SearchMode | None = None,
        keep: bool = True,
        direction: int = 1,
    ) -> FaceResult:
        """Measure ``face`` from ``start_deg`` (arm as planned, wrist where the last search
        of the face ended), its posture predicted and checked with the cell as estimated;
        ``above_mm``: the surface measured lies that far above the face (a step on it).
        ``mode``: the policy's unless given (a face measured again). ``keep``: the face
        refits the estimate (a water path over a step does not). ``direction``: every static
        posture of the search reached from below (+1) or from above (−1, a reading of the
        lost motion: ``ucal.measure.approach``)."""
        n = len(self.measurements)
        plane = self.corner_mm + above_mm * self.geometry.normal(Face.XY)
        check_prediction(
            self.profile, self.geometry, start_deg, face, self.offsets_deg, plane, label
        )
        request = FaceRequest(
            face,
            start_deg,
            self.geometry,
            self.offsets_deg,
            label,
            config,
            mode or self.trust.mode(n, face in self.faces_seen, self.last_miss_deg),
            self.trust.radius(n),
        )
        rig = self.rig if direction == 1 else approaching(self.rig, direction)
        found = measure(rig, self.setup, request)
        self.last_miss_deg = found.prediction_error_deg
        if keep:
            self.measurements.append(found.measurement)
            self.refit()
        return found

    def read_path_again(self, i: int, config: str) -> FaceMeasurement:
        """The water path of measurement ``i`` read again where it was read (its readings, its
        gain, its approach), without a search: what changed since is the tank (its drift), not
        the arm. The posture is not measured again: its tilt rows carry no weight
        (``PATH_ONLY_TILT_STD_DEG``). One move, the readings of one water path."""
        return read_path_at(self.rig, self.profile, self.measurements[i], config)

    @property
    def faces_seen(self) -> set[Face]:
        return {Face(m.face) for m in self.measurements}

    def replace(self, i: int, m: FaceMeasurement) -> None:
        """Put ``m`` (a face measured again) in place of measurement ``i`` and refit."""
        self.measurements[i] = m
        self.refit()

    def refit(self) -> None:
        """The cell from the faces measured so far, leaving out the uncertain ones."""
        meas = self.measurements
        good = [m for m in meas if m.tilt_std_deg <= UNCERTAIN_TILT_DEG] or meas
        cell = estimate_cell(self.prior, good, self.vector)
        self.offsets_deg, self.corner_mm = cell.offsets_deg, cell.corner_mm
        self.vector, self.geometry = cell.vector, cell.geometry

    def refit_peaks(self) -> list[FaceMeasurement]:
        """Every face's probes fitted again with the final estimate (no motion)."""
        return refit_peaks(
            self.rig, self.profile, self.measurements, self.setup.ka, self.prior, self.vector
        )


def read_path_at(
    rig: Rig, profile: CellProfile, m: FaceMeasurement, config: str
) -> FaceMeasurement:
    """The water path of ``m`` read again where it was read (its readings, its gain, each
    joint reached from the side it was), without a search, converted at the profile's
    ``[water] temperature_c``: ``m`` with that path, its time and ``config``. One move, the
    readings of one water path; the posture is not measured again (its tilt rows carry no
    weight, ``PATH_ONLY_TILT_STD_DEG``)."""
    above = m.approach is not None and bool(np.all(np.asarray(m.approach) < 0))
    rig = approaching(rig, -1 if above else 1)
    settled = rig.move(distance_joints(m))
    if m.gain_db is not None:
        rig.configure(gain_db=m.gain_db)
    averages = max(profile.procedure.tof_averages, 1)
    path, path_std = read_distance(rig, profile.water_temperature_c, averages)
    log.info("%s again (%s): water path %.4f ± %.4f mm", config, m.config, path, path_std)
    return replace(
        m,
        config=config,
        distance_mm=path,
        distance_std_mm=max(path_std, 1e-4),
        tilt_std_deg=PATH_ONLY_TILT_STD_DEG,
        distance_joints_deg=np.asarray(settled, float),
        probes=None,
        time_min=rig.minutes(),
        approach=rig.approach.copy(),
    )
