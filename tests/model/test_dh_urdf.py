"""A parameter table as a URDF: Pinocchio's model of the text is the table's kinematics."""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from calib_oed import load_robot
from calib_oed.model.dh import CONVENTIONS, compute_table
from calib_oed.model.dh_urdf import table_urdf_text


def test_urdf_text_reproduces_the_table():
    robot = load_robot("panda")
    for convention in CONVENTIONS:
        table = compute_table(robot, convention)
        model = pin.buildModelFromXML(table_urdf_text(table))
        data = model.createData()
        frame = model.getFrameId(table.tool_frame)
        assert list(model.names[1:]) == list(robot.joint_names)
        assert np.array_equal(model.lowerPositionLimit, robot.lower)
        for q in robot.random_configurations(10, 3):
            pin.framesForwardKinematics(model, data, q)
            assert np.allclose(data.oMf[frame].homogeneous, table.compute_pose(q).homogeneous, atol=1e-12)


def test_names_are_quoted():
    table = compute_table(load_robot("kr16"), "classic_dh")
    text = table_urdf_text(type(table)(table.convention, 'a "quoted" & <robot>', table.tool_frame, table.base,
                                       table.tool, table.rows))
    assert pin.buildModelFromXML(text).name == 'a "quoted" & <robot>'
