"""Robot loading: by name, by path, our URDFs; clear errors for bad input."""

from __future__ import annotations

import numpy as np
import pytest

from calib_oed import load_robot
from calib_oed.exceptions import (
    JointLimitError,
    NonFiniteError,
    RobotLoadError,
    ShapeError,
    UnknownFrameError,
    UnknownJointError,
    UnknownRobotError,
    UnsupportedModelError,
)
from calib_oed.model.registry import EXAMPLE_ROBOTS, own_urdf_path

CHAIN = """<robot name="r">
  <link name="base"/><link name="l1"/><link name="l2"/>
  <joint name="j1" type="{t1}"><parent link="base"/><child link="l1"/>
    <origin xyz="0 0 0.3"/><axis xyz="0 0 1"/>{limit}</joint>
  <joint name="j2" type="revolute"><parent link="l1"/><child link="l2"/>
    <origin xyz="0.4 0 0"/><axis xyz="0 1 0"/>
    <limit lower="-1" upper="1" effort="1" velocity="1"/>{mimic}</joint>
  {extra}
</robot>"""
LIMIT = '<limit lower="-2" upper="2" effort="1" velocity="1"/>'
BRANCH = """<link name="l3"/><joint name="j3" type="revolute"><parent link="l1"/>
  <child link="l3"/><axis xyz="1 0 0"/><limit lower="-1" upper="1" effort="1" velocity="1"/>
  </joint>"""


def write(tmp_path, text, name="arm.urdf"):
    path = tmp_path / name
    path.write_text(text)
    return path


@pytest.mark.parametrize("name", sorted(EXAMPLE_ROBOTS) + ["kr16", "kr300", "kr500"])
def test_named_robots_load_as_serial_chains(name):
    robot = load_robot(name)
    assert robot.nq == robot.model.nv >= 6
    assert list(robot.model.parents[1:]) == list(range(robot.nq))
    assert np.all(robot.lower < robot.upper)
    assert robot.tool_joint == robot.nq


def test_panda_fingers_are_locked_and_reported():
    robot = load_robot("panda")
    assert robot.nq == 7
    assert set(robot.locked_joints) == {"panda_finger_joint1", "panda_finger_joint2"}


def test_notional_arm_by_name():
    robot = load_robot("notional_l700_m650")
    assert robot.nq == 6 and robot.tool_frame == "tool0"


def test_load_from_path_and_tool_frame(tmp_path):
    robot = load_robot(write(tmp_path, CHAIN.format(t1="revolute", limit=LIMIT, mimic="", extra="")),
                       tool_frame="l2")
    assert robot.name == "arm" and robot.joint_names == ("j1", "j2")
    assert robot.model.frames[robot.tool_frame_id].name == "l2"


def test_load_own_urdf_by_path():
    robot = load_robot(own_urdf_path("kr16"))
    assert robot.joint_names == tuple(f"joint_a{i}" for i in range(1, 7))


def test_joint_limit_override():
    robot = load_robot("kr16", joint_limits={"joint_a2": (-1.0, 0.5)})
    assert robot.lower[1] == -1.0 and robot.upper[1] == 0.5
    with pytest.raises(ValueError):
        robot.lower[0] = 0.0  # read-only


def test_unknown_robot_lists_names():
    with pytest.raises(UnknownRobotError) as err:
        load_robot("kr17")
    assert "kr16" in str(err.value) and "ur5" in str(err.value)


def test_missing_file():
    with pytest.raises(RobotLoadError, match="not found"):
        load_robot("/nonexistent/robot.urdf")


@pytest.mark.parametrize(
    "text, match",
    [
        ("<robot name='x'><link name='a'/><joint", "malformed XML"),
        ("<model/>", "expected <robot>"),
        ("<robot name='x'><link name='a'/><joint name='j' type='revolute'><parent link='a'/>"
         "<child link='zz'/></joint></robot>", "not a valid URDF"),
    ],
)
def test_malformed_urdf(tmp_path, text, match):
    with pytest.raises(RobotLoadError, match=match):
        load_robot(write(tmp_path, text))


def test_unknown_tool_frame_lists_frames():
    with pytest.raises(UnknownFrameError) as err:
        load_robot("ur5", tool_frame="flange_tip")
    assert "tool0" in str(err.value) and err.value.name == "flange_tip"


def test_branching_tree_is_rejected_then_loads_with_lock(tmp_path):
    path = write(tmp_path, CHAIN.format(t1="revolute", limit=LIMIT, mimic="", extra=BRANCH))
    with pytest.raises(UnsupportedModelError, match="not a serial chain"):
        load_robot(path, tool_frame="l2")
    robot = load_robot(path, tool_frame="l2", lock_joints={"j3": 0.0})
    assert robot.joint_names == ("j1", "j2")


def test_continuous_joint_is_rejected(tmp_path):
    path = write(tmp_path, CHAIN.format(t1="continuous", limit="", mimic="", extra=""))
    with pytest.raises(UnsupportedModelError, match="continuous"):
        load_robot(path)


def test_mimic_joint_on_chain_is_rejected(tmp_path):
    path = write(tmp_path, CHAIN.format(t1="revolute", limit=LIMIT,
                                        mimic='<mimic joint="j1"/>', extra=""))
    with pytest.raises(UnsupportedModelError, match="mimic"):
        load_robot(path)


@pytest.mark.parametrize(
    "kwargs, error",
    [
        ({"joint_limits": {"joint_a9": (0, 1)}}, UnknownJointError),
        ({"joint_limits": {"joint_a1": (1.0, -1.0)}}, JointLimitError),
        ({"joint_limits": {"joint_a1": (1.0,)}}, ShapeError),
        ({"joint_limits": {"joint_a1": (-np.inf, 1.0)}}, JointLimitError),
        ({"lock_joints": {"nope": 0.0}}, UnknownJointError),
    ],
)
def test_bad_overrides(kwargs, error):
    with pytest.raises(error):
        load_robot("kr16", **kwargs)


def test_check_configurations():
    robot = load_robot("kr16")
    assert robot.check_configurations(np.zeros(6)).shape == (1, 6)
    with pytest.raises(ShapeError, match=r"\(n, 6\)"):
        robot.check_configurations(np.zeros((3, 5)))
    with pytest.raises(NonFiniteError):
        robot.check_configurations(np.array([0, 0, np.nan, 0, 0, 0]))


def test_random_configurations_are_seeded_and_within_limits():
    robot = load_robot("kr16")
    a = robot.random_configurations(50, 3)
    assert np.array_equal(a, robot.random_configurations(50, np.random.default_rng(3)))
    assert np.all((a >= robot.lower) & (a <= robot.upper))
