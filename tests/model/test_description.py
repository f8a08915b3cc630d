"""Robot descriptions: xacro with arguments, ``$(find)`` and ``package://`` resolution.

The data is a tiny ROS-style package of our own, ``tests/model/data/calib_test_arm``:
``package.xml``, ``urdf/arm.urdf.xacro`` (arguments ``prefix`` and
``upper_length``, including ``urdf/arm_macro.xacro`` through
``$(find calib_test_arm)``) and ``meshes/block.stl``, a 120 x 100 x 200 mm box
written by trimesh, the collision mesh of ``link_1`` placed so that its bottom
face is the plane z = 0.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

from calib_oed import load_robot
from calib_oed.exceptions import RobotLoadError
from calib_oed.feasibility.capsules import load_collision_model
from calib_oed.feasibility.mesh_check import check_design_meshes
from calib_oed.feasibility.shapes import Cell, HalfSpace
from calib_oed.model.description import find_package, resolve_package_paths

DATA = Path(__file__).parent / "data"
PACKAGE = DATA / "calib_test_arm"
XACRO = PACKAGE / "urdf" / "arm.urdf.xacro"


@pytest.fixture(autouse=True)
def _no_ros_path(monkeypatch):
    monkeypatch.delenv("ROS_PACKAGE_PATH", raising=False)


def test_xacro_arguments_shape_the_model():
    short = load_robot(XACRO, xacro_args={"upper_length": 0.3})
    long = load_robot(XACRO, xacro_args={"upper_length": 0.7, "prefix": "a_"})
    assert short.joint_names == ("joint_1", "joint_2")
    assert long.joint_names == ("a_joint_1", "a_joint_2")
    assert long.xacro_args == {"upper_length": "0.7", "prefix": "a_"}
    for robot, length in ((short, 0.3), (long, 0.7)):
        tool = robot.model.frames[robot.tool_frame_id]
        assert tool.name.endswith("tool0")
        np.testing.assert_allclose(tool.placement.translation, [length, 0.0, 0.0], atol=1e-12)
    assert short.name == "arm" and short.urdf_path == XACRO.resolve()
    assert "<robot" in short.urdf_text and "xacro:" not in short.urdf_text


def test_package_mesh_is_found_and_used_by_the_mesh_check():
    """The package is found next to the xacro (no package_dirs given); the mesh
    check then measures the STL box: its bottom face is z = 0, so against a floor
    z >= 50 mm it penetrates by exactly 50 mm at any joint angle."""
    robot = load_robot(XACRO, xacro_args={"upper_length": 0.5})
    assert str(DATA) in robot.package_dirs
    geom = load_collision_model(robot)
    block = [g for g in geom.geometryObjects if g.meshPath.endswith("block.stl")]
    assert len(block) == 1 and Path(block[0].meshPath) == PACKAGE / "meshes" / "block.stl"
    assert block[0].geometry.num_vertices == 8
    floor = Cell(halfspaces=(HalfSpace(np.array([0.0, 0.0, 1.0]), 0.05, "floor"),))
    q = np.array([[0.3, 0.0], [-2.0, 0.5]])
    report = check_design_meshes(robot, q, floor)
    k = report.pairs.index(("link_1", "floor"))
    np.testing.assert_allclose(report.distances[:, k], -0.05, atol=1e-9)
    assert not report.feasible.any()


def test_ros_package_path_finds_a_package_elsewhere(tmp_path, monkeypatch):
    copy = tmp_path / "my_cell.urdf.xacro"
    copy.write_text(XACRO.read_text())
    with pytest.raises(RobotLoadError, match="'calib_test_arm' not found.*ROS_PACKAGE_PATH"):
        load_robot(copy)
    monkeypatch.setenv("ROS_PACKAGE_PATH", str(DATA))
    robot = load_robot(copy, xacro_args={"upper_length": 0.4})
    assert robot.name == "my_cell"
    assert any(g.meshPath.endswith("block.stl") for g in load_collision_model(robot).geometryObjects)


def test_package_named_by_its_manifest_in_a_differently_named_folder(tmp_path):
    """A workspace ``src/arms/test_arm_v2`` whose package.xml names calib_test_arm:
    found by its manifest below the search root, and package:// paths point into it."""
    folder = tmp_path / "src" / "arms" / "test_arm_v2"
    shutil.copytree(PACKAGE, folder)
    assert find_package("calib_test_arm", [tmp_path / "src"]) == folder
    assert find_package("calib_test_arm", [tmp_path / "elsewhere"]) is None
    text = '<robot name="r"><link name="a"><collision><geometry><mesh filename="' \
           'package://calib_test_arm/meshes/block.stl"/></geometry></collision></link></robot>'
    resolved, dirs = resolve_package_paths(text, [tmp_path / "src"])
    assert f'filename="{folder}/meshes/block.stl"' in resolved and "package://" not in resolved
    with pytest.raises(RobotLoadError, match="no such file"):
        resolve_package_paths(text.replace("block.stl", "nothing.stl"), [tmp_path / "src"])
    with pytest.raises(RobotLoadError, match="'calib_test_arm' not found"):
        resolve_package_paths(text, [tmp_path / "elsewhere"])


def test_xacro_errors_are_clear(tmp_path):
    bad = tmp_path / "bad.urdf.xacro"
    bad.write_text('<robot xmlns:xacro="http://www.ros.org/wiki/xacro" name="b">'
                   '<link name="$(arg missing_arg)"/></robot>')
    with pytest.raises(RobotLoadError, match="xacro failed.*missing_arg"):
        load_robot(bad)
    with pytest.raises(RobotLoadError, match="not a xacro file"):
        load_robot("kr16", xacro_args={"a": 1})
    with pytest.raises(RobotLoadError, match="xacro file not found"):
        load_robot(tmp_path / "absent.urdf.xacro")
