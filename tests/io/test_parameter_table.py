"""Parameter table files: written and read back exactly; as a URDF, the same kinematics."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pinocchio as pin
import pytest
from conftest import random_parameters

from calib_oed import load_robot
from calib_oed.exceptions import ParameterTableError
from calib_oed.io.parameter_table import (
    parse_parameter_table,
    read_parameter_table,
    write_parameter_table,
)
from calib_oed.model.dh import CONVENTIONS, compute_table
from calib_oed.model.dh_urdf import table_urdf_text
from calib_oed.model.parameters import ParameterSpace


def _calibrated(name):
    robot = load_robot(name)
    space = ParameterSpace(robot, pin.SE3.Identity(), np.zeros((1, 3)))
    return replace(robot, model=space.perturbed_model(random_parameters(space, 3)))


@pytest.mark.parametrize("convention", CONVENTIONS)
def test_file_round_trip_is_bit_exact_and_the_urdf_reproduces_the_model(tmp_path, convention):
    robot = _calibrated("kr16")
    table = compute_table(robot, convention)
    path = write_parameter_table(tmp_path / "t.yaml", table)
    back = read_parameter_table(path)
    assert back == table                                    # every float bit for bit
    urdf = tmp_path / "t.urdf"
    urdf.write_text(table_urdf_text(back))
    loaded = load_robot(urdf, tool_frame=table.tool_frame)
    assert loaded.joint_names == robot.joint_names
    assert np.array_equal(loaded.lower, robot.lower) and np.array_equal(loaded.upper, robot.upper)
    q = robot.random_configurations(40, 2)
    data_a, data_b = robot.model.createData(), loaded.model.createData()
    for row in q:   # model -> table -> file -> URDF -> model, within the table's named residual
        pin.framesForwardKinematics(robot.model, data_a, row)
        pin.framesForwardKinematics(loaded.model, data_b, row)
        diff = data_a.oMf[robot.tool_frame_id].actInv(data_b.oMf[loaded.tool_frame_id])
        assert np.linalg.norm(diff.translation) < max(1e-9, 10 * table.residual_m)
        assert np.linalg.norm(pin.log3(diff.rotation)) < max(1e-9, 10 * table.residual_rad)


def test_vendor_sheet_in_mm_and_degrees():
    """A UR5 as Universal Robots publish it (classic DH, "DH parameters for calculations of
    kinematics and dynamics", UR support article): d1 = 89.159, a2 = -425, a3 = -392.25,
    d4 = 109.15, d5 = 94.65, d6 = 82.3 mm; alpha1 = alpha4 = 90, alpha5 = -90 deg."""
    text = """
convention: classic_dh
robot: ur5_sheet
units: {length: mm, angle: deg}
joints:
  - {name: j1, alpha: 90, a: 0, d: 89.159, theta: 0}
  - {name: j2, alpha: 0, a: -425, d: 0, theta: 0}
  - {name: j3, alpha: 0, a: -392.25, d: 0, theta: 0}
  - {name: j4, alpha: 90, a: 0, d: 109.15, theta: 0}
  - {name: j5, alpha: -90, a: 0, d: 94.65, theta: 0}
  - {name: j6, alpha: 0, a: 0, d: 82.3, theta: 0}
"""
    table = parse_parameter_table(text)
    pose = table.compute_pose(np.zeros(6))
    # at q = 0 (UR's documented zero): the flange at x = a2 + a3, y = -(d4 + d6), z = d1 - d5
    assert np.allclose(pose.translation, [-0.81725, -0.19145, -0.005491], atol=1e-12)


@pytest.mark.parametrize("bad, message", [
    ("convention: dh\njoints: [{name: a}]", "valid: classic_dh"),
    ("convention: classic_dh\njoints: [{name: a, kind: hayati}]", "hayati table"),
    ("convention: classic_dh\nunits: {length: inch}\njoints: [{name: a}]", "valid: length m or mm"),
    ("convention: classic_dh\njoints: [{name: a, alpha: x}]", "not a finite number"),
    ("convention: classic_dh\njoints: [{name: a, gamma: 1}]", "unknown keys"),
    ("convention: classic_dh\njoints: []", "one row per joint"),
])
def test_bad_tables_name_the_field(bad, message):
    with pytest.raises(ParameterTableError, match=message):
        parse_parameter_table(bad)


_BOMB = ("x0: &a0 [1, 1, 1, 1, 1, 1, 1, 1, 1, 1]\n"
         + "".join(f"x{i}: &a{i} [{', '.join([f'*a{i - 1}'] * 10)}]\n" for i in range(1, 8)))


@pytest.mark.parametrize("text, message", [
    ("convention: classic_dh\nconvention: hayati\njoints: [{name: a}]", "duplicate key 'convention'"),
    (_BOMB + "convention: classic_dh\njoints: [{name: a}]", "expand to more than"),
], ids=["duplicate-key", "alias-bomb"])
def test_tables_are_read_with_the_bounded_yaml_reader(text, message):
    """A key given twice is refused (not the last one kept), as are aliases that expand to millions."""
    with pytest.raises(ParameterTableError, match=message):
        parse_parameter_table(text)


def test_a_table_file_beyond_the_size_bound_is_refused(tmp_path):
    path = tmp_path / "t.yaml"
    path.write_text("convention: classic_dh\njoints: [{name: a}]\n" + "#" * (2 * 2**20) + "\n")
    with pytest.raises(ParameterTableError, match="cannot read the parameter table .*MiB"):
        read_parameter_table(path)
