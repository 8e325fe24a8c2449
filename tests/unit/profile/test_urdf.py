"""A robot model from a URDF (``ucal profile init --from-urdf``), against the shipped table.

The TX90L URDF here is written by the test from the published layout of the ROS-Industrial
description (``staubli_tx90_support`` / ``staubli_tx2-90_support``, ``tx90l_macro.xacro``):
joint 1 0.478 m above ``base_link``, joint 2 0.05 m in front, joint 3 0.05 m across and
0.5 m up, joint 5 0.55 m up, joint 6 0.1 m up, axes z y y z y z, the ``base`` frame at
shoulder height and ``tool0`` on ``link_6``; each joint's origin carries an rpy turn undone by
its axis and its child's next origin, so that no origin is a DH row. It is not derived from
the shipped DH table, and its forward kinematics is yourdfpy's, not ucal's.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yourdfpy
from urdf_files import TX90L_JOINTS, urdf_text

from ucal.errors import InputError
from ucal.kinematics.dh import fk
from ucal.profile import load_profile
from ucal.profile.models import load_model
from ucal.profile.urdf import model_from_urdf, read_urdf

from doubles import ucal_here


def write(tmp_path: Path, text: str, name: str = "arm.urdf") -> Path:
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path


def yourdfpy_flange_mm(robot: yourdfpy.URDF, q_deg: np.ndarray) -> np.ndarray:
    """``tool0`` in ``base`` (4×4, mm) at readings ``q_deg``, by yourdfpy's kinematics."""
    robot.update_cfg(np.radians(q_deg))
    t = robot.get_transform("tool0", "base").copy()
    t[:3, 3] *= 1000.0
    return t


@pytest.mark.parametrize("turned", [False, True])
def test_a_tx90l_urdf_gives_the_shipped_tables_kinematics_within_a_micrometre(
    tmp_path, turned
) -> None:
    path = write(tmp_path, urdf_text(turned=turned))
    model = model_from_urdf(read_urdf(path), "tx90l-urdf")
    shipped = load_model("tx90l")
    robot = yourdfpy.URDF.load(str(path), load_meshes=False, build_scene_graph=True)
    rng = np.random.default_rng(11)
    q = rng.uniform(shipped.joint_min_deg, shipped.joint_max_deg, (300, 6))
    ours, theirs = fk(model, q), fk(shipped, q)
    urdf = np.array([yourdfpy_flange_mm(robot, qi) for qi in q])
    worst_shipped_um = 1000 * np.max(np.linalg.norm(ours[:, :3, 3] - theirs[:, :3, 3], axis=1))
    worst_urdf_um = 1000 * np.max(np.linalg.norm(ours[:, :3, 3] - urdf[:, :3, 3], axis=1))
    assert worst_shipped_um < 1.0 and worst_urdf_um < 1.0, (worst_shipped_um, worst_urdf_um)
    np.testing.assert_allclose(ours[:, :3, :3], urdf[:, :3, :3], atol=1e-9)
    np.testing.assert_allclose(model.joint_min_deg, shipped.joint_min_deg, atol=1e-9)
    np.testing.assert_allclose(model.joint_max_deg, shipped.joint_max_deg, atol=1e-9)
    np.testing.assert_allclose(model.speed_deg_s, [400, 390, 420, 540, 475, 760], atol=1e-9)
    if not turned:  # the plain layout is the shipped table itself, row by row
        np.testing.assert_allclose(model.dh, shipped.dh, atol=1e-9)


def test_profile_init_from_urdf_writes_a_profile_of_that_arm(tmp_path) -> None:
    urdf = write(tmp_path, urdf_text())
    done = ucal_here("profile", "init", "--from-urdf", str(urdf), str(tmp_path / "cell.toml"))
    assert done.returncode == 0, done.stderr
    profile = load_profile(tmp_path / "cell.toml")
    assert profile.model.name == "staubli_tx90l"
    q = np.random.default_rng(3).uniform(-90, 90, (100, 6))
    worst = np.max(np.abs(fk(profile.model, q) - fk(load_model("tx90l"), q))[:, :3, 3])
    assert worst < 1e-3
    np.testing.assert_allclose(profile.model.speed_deg_s, [400, 390, 420, 540, 475, 760])
    named = ucal_here(
        "profile", "init", "--from-urdf", str(urdf), str(tmp_path / "b.toml"), "--name", "cell_arm"
    )
    assert named.returncode == 0 and load_profile(tmp_path / "b.toml").model.name == "cell_arm"


def _moved(joint: str, xyz) -> tuple:
    return tuple((n, xyz if n == joint else o, *rest) for n, o, *rest in TX90L_JOINTS)


@pytest.mark.parametrize(
    ("text", "words"),
    [
        (urdf_text(kinds={"joint_3": "prismatic"}), "joint joint_3: a prismatic joint"),
        (urdf_text(TX90L_JOINTS[:5]), "5 revolute joints"),
        (urdf_text(tool="0 0.02 0"), "joint joint_6: the flange frame (tool0)"),
        (urdf_text(_moved("joint_1", (0.1, 0, 0.478)), turned=False), "joint joint_1"),
        (urdf_text(_moved("joint_5", (0.03, 0, 0.55)), turned=False), "wrist"),
    ],
    ids=["prismatic", "five-joints", "flange-off-axis", "base-off-axis", "wrist-offset"],
)
def test_what_a_model_cannot_express_is_refused_naming_the_file(tmp_path, text, words) -> None:
    path = write(tmp_path, text)
    with pytest.raises(InputError, match=r"arm\.urdf") as e:
        model_from_urdf(read_urdf(path))
    assert words in str(e.value)
    done = ucal_here("profile", "init", "--from-urdf", str(path), str(tmp_path / "cell.toml"))
    assert done.returncode == 2 and "arm.urdf" in done.stderr, done.stderr
    assert not (tmp_path / "cell.toml").exists()
