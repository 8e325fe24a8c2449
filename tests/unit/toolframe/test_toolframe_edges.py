"""Tool-frame's edge scans on synthetic readings of a fresh cell (no processes): a tool on a
20° holder turned 180° puts joint 5 a dozen degrees from the wrist's singularity, where the
correction to normal incidence takes several degrees on joints 4 and 5."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
import tomlkit
from scipy.special import ndtr

from ucal.acoustics import directivity_half_angle_deg
from ucal.cell import CellProfile
from ucal.kinematics.dh import transform
from ucal.kinematics.rotations import angle_between_deg, rpy_to_matrix
from ucal.model.geometry import CellGeometry, beam_and_tcp
from ucal.model.wrist import aim_wrist
from ucal.profile import default_profile_text, profile_from_data
from ucal.toolframe.measure import PlateRig
from ucal.toolframe.plan import EdgePlan, ToolFramePlan, reference_joints
from ucal.toolframe.plane import fit_plane

from doubles import FakeController

#: The cell's truth: joint offsets never calibrated (the profile says 0) and the tool off its
#: drawing (a 20° holder), as ``benchmarks/drift.py``'s seed 8, world 5.
TRUE_OFFSETS = np.array([-1.76, -1.77, -1.33, 0.77, -0.59, 1.24])
TRUE_TOOL = transform(np.array([41.94, -0.76, 104.97]), rpy_to_matrix([0.63, 19.61, 0.37]))
#: Where the plate's edge crosses the scan line (mm from the plate centre along it).
EDGE_MM = 80.0
FOOTPRINT_SIGMA_MM = 1.5
#: The echo's half height off normal incidence (pulse-echo, deg): 25 MHz, 6 mm, 20 °C.
HALF_DEG = directivity_half_angle_deg(0.5, 25.0, 6.0, 20.0)


def holder_profile() -> CellProfile:
    """The template's profile with its tool drawn on a 20° holder."""
    profile = profile_from_data(tomlkit.parse(default_profile_text("tx90l")), "cell.toml")
    return profile.replace(
        tool_position_mm=np.array([40.374, -1.275, 105.063]),
        tool_rotation_deg=np.array([0.0, 20.0, 0.0]),
    )


class PlateCell:
    """The rig of a cell whose plate is the touched plane with a straight edge across the
    scan line: the echo is the footprint's share on the plate times the piston's fall off
    normal incidence, at the true beam of the readings."""

    def __init__(
        self, profile: CellProfile, plan: ToolFramePlan, direction: np.ndarray, q: np.ndarray
    ):
        self.geom = CellGeometry(profile.model, TRUE_TOOL, np.eye(3))
        self.normal = plan.plane.normal
        self.height = float(self.normal @ plan.centre_mm)
        self.direction = direction
        self.edge = float(direction @ plan.centre_mm) + EDGE_MM
        self.approach = np.ones(6)
        self.joint_min_deg = np.full(6, -270.0)
        self.joint_max_deg = np.full(6, 270.0)
        self.speed, self.move_timeout_s = 0.3, 10.0
        self.controller = FakeController(q)
        self.pulser = SimpleNamespace(endpoint="modbus-tcp://127.0.0.1:1502")
        self.tilts: list[float] = []

    @property
    def q(self) -> np.ndarray:
        """Where the arm is (deg): the controller's joints."""
        return self.controller.q

    @q.setter
    def q(self, q: np.ndarray) -> None:
        self.controller.q = np.asarray(q, float).copy()

    def read_joints(self) -> np.ndarray:
        return self.controller.read_joints()

    def move(self, q: np.ndarray, speed: float | None = None) -> np.ndarray:
        return self.controller.move_joints(q, speed or self.speed, self.move_timeout_s)

    def moved_to(self, target: np.ndarray, start: np.ndarray | None = None) -> None:
        pass

    def minutes(self) -> float:
        return 0.0

    def level_gain(self, averages: int = 1) -> None:
        pass

    def hit(self, q: np.ndarray) -> tuple[np.ndarray, float]:
        """The true beam axis's hit on the plate at readings ``q`` and its tilt (deg)."""
        beam, tcp = beam_and_tcp(self.geom, q, TRUE_OFFSETS)
        path = (self.height - self.normal @ tcp) / (self.normal @ beam)
        return tcp + path * beam, float(angle_between_deg(beam, -self.normal))

    def normalised_amplitude(self, averages: int = 1) -> float:
        point, tilt = self.hit(self.q)
        self.tilts.append(tilt)
        share = ndtr((self.edge - self.direction @ point) / FOOTPRINT_SIGMA_MM)
        return float(0.8 * share * 2.0 ** (-((tilt / HALF_DEG) ** 2)))


class CentringPlateRig(PlateRig):
    """``PlateRig`` whose centring finds the true normal incidence with joints 4 and 5, as
    the plate's peak search turns them."""

    def normal_near(self, q_pred, label, quick, radius_deg=0.0):
        cell = self.rig._rig
        self.q = aim_wrist(cell.geom, q_pred, -cell.normal, TRUE_OFFSETS)
        return None, self.q


def edge_plan(profile: CellProfile) -> ToolFramePlan:
    """The plan's scans across the plate's +e1 edge (``plan_tool_frame`` plans them so for
    this profile, with the tool turned 0 and 180° about the beam)."""
    plane = fit_plane(profile.reflector_points_mm)
    along = np.cross(plane.normal, plane.e1)
    ep = EdgePlan(0, "+e1", plane.e1, along, (-20.0, 20.0), 27.0, 300.0)
    centre = plane.project(plane.centroid_mm)
    return ToolFramePlan("exact", plane, centre, reference_joints(profile), 0.0, (), (ep,), ())


def test_an_edge_line_near_the_wrists_singularity_stays_at_normal_incidence() -> None:
    profile = holder_profile()
    plan = edge_plan(profile)
    ep = plan.edges[0]
    phi = plan.phi0_deg + 180.0
    cell = PlateCell(profile, plan, ep.direction, plan.reference_deg)
    rig = CentringPlateRig(profile, plan, cell, None)
    line = plan.centre_mm + ep.lateral_mm[0] * ep.along
    planned = rig.joints(line + EDGE_MM * ep.direction, 50.0, phi, "edge")
    assert abs(planned[4]) < 16.0  # joint 5 near the wrist's singularity
    _, fit, t_c, crossing = rig.edge_scan(ep, ep.lateral_mm[0], phi, None)
    # the edge's fall is the footprint's, where the correction held as joint increments
    # turned the beam 0.017°/mm off normal: the echo fell to half 20 mm short of the edge,
    # over 5.8 mm
    assert fit.width_mm == pytest.approx(FOOTPRINT_SIGMA_MM, abs=0.05)
    assert max(cell.tilts[-21:]) < 0.25 * HALF_DEG
    assert t_c == pytest.approx(fit.crossing, abs=1.5)
    point, _ = cell.hit(crossing.joints_deg)
    assert ep.direction @ (point + crossing.shift_mm) == pytest.approx(cell.edge, abs=0.02)
