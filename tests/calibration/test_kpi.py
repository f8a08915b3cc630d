"""KPI values and Jacobian G against central finite differences."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest
from conftest import central_difference, random_parameters, relative_error

from calib_oed.calibration.kpi import TcpKpi
from calib_oed.exceptions import ShapeError
from calib_oed.model.kinematics import compute_tool_kinematics


@pytest.mark.parametrize("frame", ["world", "tracker"])
@pytest.mark.parametrize("at", ["nominal", "perturbed"])
@pytest.mark.parametrize("reflector", [None, 1])
def test_kpi_jacobian(space, frame, at, reflector):
    q = space.robot.random_configurations(2, 21)
    kpi = TcpKpi(q, point=np.array([0.01, -0.02, 0.1]), frame=frame, reflector=reflector)
    p = space.zeros() if at == "nominal" else random_parameters(space, 3, 5e-3, 5e-3)
    g = kpi.compute_param_jacobian(space, p)
    numeric = central_difference(lambda x: kpi.compute_values(space, x).ravel(), p)
    assert g.shape == (6, space.size)
    assert relative_error(g, numeric) < 1e-6
    if frame == "world":  # a world-frame KPI does not depend on the tracker
        assert not np.any(g[:, :6])
    if reflector is None:  # nor a fixed tool point on the reflector offsets
        assert not np.any(g[:, 6: 6 + 3 * space.n_reflectors])


def test_kpi_value_is_the_tool_point(space):
    q = space.robot.random_configurations(1, 2)
    kin = compute_tool_kinematics(space.robot.model, space.robot.tool_frame_id, q)
    point = np.array([0.0, 0.0, 0.2])
    world = TcpKpi(q, point).compute_values(space)
    tool = pin.SE3(kin.rotation[0], kin.translation[0])
    assert np.allclose(world[0], tool.act(point), atol=1e-14)
    tracker = TcpKpi(q, point, frame="tracker").compute_values(space)
    assert np.allclose(tracker[0], space.tracker_placement0.actInv(tool.act(point)), atol=1e-14)


def test_bad_kpi_input():
    with pytest.raises(ShapeError):
        TcpKpi(np.zeros((1, 6)), point=np.zeros(2))
    with pytest.raises(ValueError, match="world"):
        TcpKpi(np.zeros((1, 6)), frame="base")
    with pytest.raises(ShapeError):
        TcpKpi(np.zeros((2, 6)), names=["only_one"])


def test_joint_path_sampling():
    from calib_oed.model.joint_path import sample_joint_path

    way = np.array([[0.0, 0.0], [3.0, 0.0], [3.0, 1.0]])  # joint-space length 4
    q = sample_joint_path(way, 5)
    assert q.shape == (5, 2)
    assert np.array_equal(q[0], way[0]) and np.array_equal(q[-1], way[-1])  # endpoints, exactly
    np.testing.assert_allclose(q, [[0, 0], [1, 0], [2, 0], [3, 0], [3, 1]], atol=1e-15)  # equal arc length
    np.testing.assert_allclose(sample_joint_path(way[:2], 2), way[:2])
    mid = sample_joint_path(way, 9)[7]  # 3.5 along: halfway up the second segment
    np.testing.assert_allclose(mid, [3.0, 0.5], atol=1e-15)
    with pytest.raises(ValueError, match="samples"):
        sample_joint_path(way, 1)
    with pytest.raises(ShapeError):
        sample_joint_path(way[:1], 3)
    with pytest.raises(ValueError, match="zero length"):
        sample_joint_path(np.zeros((3, 2)), 3)


def test_kpi_weights_are_checked():
    q = np.zeros((2, 6))
    assert np.array_equal(TcpKpi(q).weights, [1.0, 1.0])
    assert np.array_equal(TcpKpi(q, weights=[0.5, 2]).weights, [0.5, 2.0])
    with pytest.raises(ShapeError):
        TcpKpi(q, weights=[1.0])
    with pytest.raises(ValueError, match="weights"):
        TcpKpi(q, weights=[0.0, 0.0])
