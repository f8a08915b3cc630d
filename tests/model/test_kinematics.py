"""Second-order tool kinematics: configuration derivatives of the regressor and Jacobian."""

from __future__ import annotations

import pytest
from conftest import central_difference, relative_error

from calib_oed.model.kinematics import (
    compute_tool_kinematics,
    jacobian_config_derivative,
    regressor_config_derivative,
)


def _kin(robot, q):
    return compute_tool_kinematics(robot.model, robot.tool_frame_id, q[None, :])


def test_regressor_and_jacobian_derivatives(robot):
    q = robot.random_configurations(2, 21)
    for qk in q:
        kin = _kin(robot, qk)
        num_k = central_difference(lambda x: _kin(robot, x).regressor[0], qk)
        num_j = central_difference(lambda x: _kin(robot, x).jacobian[0], qk)
        assert relative_error(regressor_config_derivative(kin)[0], num_k) < 1e-7
        assert relative_error(jacobian_config_derivative(kin)[0], num_j) < 1e-7


def test_second_order_needs_both(robot):
    q = robot.random_configurations(1, 0)
    kin = compute_tool_kinematics(robot.model, robot.tool_frame_id, q, jacobian=False)
    with pytest.raises(ValueError, match="regressor and the Jacobian"):
        regressor_config_derivative(kin)
