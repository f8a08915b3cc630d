"""Second-order tool kinematics: configuration derivatives of the regressor and Jacobian, and of J_log."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest
from conftest import central_difference, relative_error

from calib_oed.model.kinematics import (
    ad_matrices,
    compute_tool_kinematics,
    cross,
    jacobian_config_derivative,
    log_jacobian,
    log_jacobian_derivative,
    log_jacobian_second_derivative,
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


def regressor_config_hessian(kin) -> np.ndarray:
    """The dense d2K/dq_k dq_l, (n, 6, 6 n_j, nv, nv): ad(J_max(k,l)) ad(J_min(k,l)) K_i for
    min(k, l) >= i, else 0 (docs/derivations.md §13), the reference for the factored form."""
    reg, jac = kin.regressor, kin.jacobian
    n, _, ncol = reg.shape
    nv = jac.shape[2]
    ad = ad_matrices(jac)  # (n, nv, 6, 6)
    out = np.zeros((n, 6, ncol, nv, nv))
    for k in range(nv):
        cols = slice(0, 6 * (k + 1))  # blocks i <= k = min(k, l)
        inner = ad[:, k] @ reg[:, :, cols]
        for m in range(k, nv):
            out[:, :, cols, k, m] = out[:, :, cols, m, k] = ad[:, m] @ inner
    return out


def test_regressor_second_derivative(robot):
    """d2K/dq_k dq_l = ad(J_max) ad(J_min) K against differences of the exact dK/dq; symmetric."""
    q = robot.random_configurations(2, 22)
    for qk in q:
        analytic = regressor_config_hessian(_kin(robot, qk))[0]
        numeric = central_difference(lambda x: regressor_config_derivative(_kin(robot, x))[0], qk)
        assert analytic.shape == (6, 6 * robot.nq, robot.nq, robot.nq)
        assert relative_error(analytic, numeric) < 1e-7
        assert np.array_equal(analytic, np.swapaxes(analytic, 2, 3))


def test_ad_matrices_are_pinocchio_motion_actions(robot):
    kin = _kin(robot, robot.random_configurations(1, 23)[0])
    ad = ad_matrices(kin.jacobian)
    for k in range(robot.nq):
        assert np.allclose(ad[0, k], pin.Motion(kin.jacobian[0, :, k]).action, rtol=0, atol=1e-15)


def test_second_order_needs_both(robot):
    q = robot.random_configurations(1, 0)
    kin = compute_tool_kinematics(robot.model, robot.tool_frame_id, q, jacobian=False)
    with pytest.raises(ValueError, match="regressor and the Jacobian"):
        regressor_config_derivative(kin)


#: Rotation angles from tiny to just below pi: the series of J_log covers all of log3's range.
ANGLES = (1e-9, 1e-3, 0.4, 1.7, 2.9, np.pi - 1e-4)


@pytest.mark.parametrize("angle", ANGLES)
def test_log_jacobian_is_pinocchio_jlog3(angle):
    rng = np.random.default_rng(3)
    axis = rng.normal(size=3)
    rot = pin.exp3(angle * axis / np.linalg.norm(axis))
    theta = pin.log3(rot)
    # Pinocchio switches to a Taylor form near 0 (7e-11 off at 1 mrad); ours is the exact series
    assert np.allclose(log_jacobian(theta), pin.Jlog3(rot), rtol=0, atol=1e-9)
    if angle > 0.1:  # pin.Hlog3 is nan at 1e-9 rad and 3e-8 off at 1 mrad
        w = rng.normal(size=3)
        hlog = log_jacobian_derivative(theta, log_jacobian(theta) @ w)
        assert np.allclose(hlog, pin.Hlog3(rot, w), rtol=0, atol=1e-12)


def test_log_jacobian_series_is_the_closed_form():
    """b(t^2) = 1/t^2 - (1 + cos t)/(2 t sin t), where the closed form has no cancellation."""
    for t in (0.5, 1.5, 2.5, 3.1):
        theta = np.array([0.0, 0.0, t])
        sk = np.array([[0, -t, 0], [t, 0, 0], [0, 0, 0]])
        b = 1 / t**2 - (1 + np.cos(t)) / (2 * t * np.sin(t))
        assert np.allclose(log_jacobian(theta), np.eye(3) + 0.5 * sk + b * sk @ sk, rtol=0, atol=1e-14)


@pytest.mark.parametrize("angle", ANGLES)
def test_log_jacobian_derivatives_match_differences(angle):
    rng = np.random.default_rng(4)
    axis = rng.normal(size=3)
    theta = angle * axis / np.linalg.norm(axis)
    u, v = rng.normal(size=(2, 3))
    eps = 1e-6

    def along(fun, direction):
        return (fun(theta + eps * direction) - fun(theta - eps * direction)) / (2 * eps)

    d1 = log_jacobian_derivative(theta, u)
    assert relative_error(d1, along(log_jacobian, u)) < 1e-8
    d2 = log_jacobian_second_derivative(theta, u, v)
    assert relative_error(d2, along(lambda t: log_jacobian_derivative(t, u), v)) < 1e-8
    assert np.allclose(d2, log_jacobian_second_derivative(theta, v, u), rtol=0, atol=1e-15)
    # batched: leading axes broadcast
    batch = log_jacobian_second_derivative(theta[None, None], np.stack([u, v])[:, None],
                                           np.stack([u, v])[None, :])
    assert batch.shape == (2, 2, 3, 3) and np.allclose(batch[0, 1], d2, rtol=0, atol=1e-15)


@pytest.mark.parametrize("shape_a, shape_b, axis", [
    ((5, 7, 3), (5, 7, 3), -1),  # points and directions of bodies.directional_jacobian
    ((1, 3, 1), (4, 3, 9), 1),  # a lever against columns (kinematics.point_sensitivity)
    ((4, 3, 12, 1, 1), (1, 3, 1, 1), 1),  # regressor derivative columns (measurement.base)
    ((4, 3, 1, 6), (4, 3, 12, 1), 1),
    ((3,), (3,), -1),  # two vectors
])
def test_cross_is_numpy_cross_bit_for_bit_and_in_layout(shape_a, shape_b, axis):
    rng = np.random.default_rng(7)
    a, b = rng.normal(size=shape_a), rng.normal(size=shape_b)
    mine, numpy_cross = cross(a, b, axis=axis), np.cross(a, b, axis=axis)
    assert mine.shape == numpy_cross.shape and mine.strides == numpy_cross.strides
    assert mine.tobytes() == numpy_cross.tobytes()  # every bit, in memory order
    if a.ndim == 1:  # a list as the second vector (hull_curvature's frame completion)
        assert cross(a, [0.0, 1.0, 0.0]).tobytes() == np.cross(a, [0.0, 1.0, 0.0]).tobytes()
