"""Parameter layout and application; the regressor equals the explicit perturbation."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest
from conftest import central_difference, make_space, random_parameters, relative_error

from calib_oed.exceptions import NonFiniteError, ShapeError, UnknownParameterError
from calib_oed.model.kinematics import compute_tool_kinematics


def test_order_names_and_units(space):
    n = space.robot.nq
    assert space.size == 6 + 3 * 2 + 6 * n
    assert space.names[:6] == tuple(f"tracker.{c}" for c in ("tx", "ty", "tz", "rx", "ry", "rz"))
    assert space.names[6:12] == ("reflector0.x", "reflector0.y", "reflector0.z",
                                 "reflector1.x", "reflector1.y", "reflector1.z")
    assert space.names[12] == "joint1.tx" and space.names[-1] == f"joint{n}.rz"
    assert space.index("joint3.rz") == 12 + 6 * 2 + 5
    units = [p.unit for p in space.parameters]
    assert units[:6] == ["m"] * 3 + ["rad"] * 3 and units[6:12] == ["m"] * 6
    assert units[-6:] == ["m"] * 3 + ["rad"] * 3
    assert np.allclose(space.unit_scale, 1e-3)


def test_perturbation_never_mutates_nominal(space):
    before = [pin.SE3(m) for m in space.robot.model.jointPlacements]
    p = random_parameters(space, 0, 1e-2, 1e-2)
    model = space.perturbed_model(p)
    for i, m0 in enumerate(before):
        assert space.robot.model.jointPlacements[i].isApprox(m0)
    i = 2
    expected = before[i] * pin.exp6(p[space.joint_slice(i)])
    assert model.jointPlacements[i].isApprox(expected, 1e-12)
    assert space.perturbed_model(space.zeros()) is space.robot.model


def test_sensor_parameters(space):
    p = random_parameters(space, 1, 1e-2, 1e-2)
    t = space.tracker_placement(p)
    assert t.isApprox(space.tracker_placement0 * pin.exp6(p[:6]), 1e-12)
    assert np.allclose(space.reflector_offsets(p),
                       space.reflector_offsets0 + p[6:12].reshape(2, 3))


@pytest.mark.parametrize("at", ["nominal", "perturbed"])
def test_regressor_equals_explicit_perturbation(space, at):
    """LOCAL kinematic regressor (block i-1 for joint i) against perturbed models."""
    robot = space.robot
    p0 = space.zeros() if at == "nominal" else random_parameters(space, 2, 1e-2, 1e-2)
    model = space.perturbed_model(p0)
    q = robot.random_configurations(3, 7)
    kin = compute_tool_kinematics(model, robot.tool_frame_id, q)
    ref = compute_tool_kinematics(model, robot.tool_frame_id, q, regressor=False, jacobian=False)

    def local_twist(eps):
        pert = model.copy()
        for i in range(1, robot.nq + 1):
            pert.jointPlacements[i] = model.jointPlacements[i] * pin.exp6(eps[6 * (i - 1): 6 * i])
        k = compute_tool_kinematics(pert, robot.tool_frame_id, q, regressor=False, jacobian=False)
        return np.array([
            pin.log6(pin.SE3(ref.rotation[j], ref.translation[j]).inverse()
                     * pin.SE3(k.rotation[j], k.translation[j])).vector
            for j in range(len(q))
        ])

    numeric = central_difference(local_twist, np.zeros(6 * robot.nq))
    assert relative_error(kin.regressor, numeric) < 1e-6


@pytest.mark.parametrize(
    "bad, error",
    [(np.zeros(5), ShapeError), (np.full(48, np.nan), NonFiniteError)],
)
def test_bad_parameter_vectors(bad, error):
    from calib_oed import load_robot

    space = make_space(load_robot("kr16"))
    with pytest.raises(error):
        space.perturbed_model(bad)


def test_unknown_parameter_name(space):
    with pytest.raises(UnknownParameterError, match="joint1.tx"):
        space.index("joint0.tx")


def test_bad_reflector_offsets(robot):
    from calib_oed.model.parameters import ParameterSpace

    with pytest.raises(ShapeError):
        ParameterSpace(robot, pin.SE3.Identity(), np.zeros((2, 2)))
    with pytest.raises(NonFiniteError):
        ParameterSpace(robot, pin.SE3.Identity(), np.array([0.0, np.nan, 0.0]))
