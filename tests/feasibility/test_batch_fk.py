"""Vectorised forward kinematics of the sampling against Pinocchio per configuration."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from calib_oed import load_robot
from calib_oed.feasibility.batch_fk import _joint_axes, batch_body_states
from calib_oed.feasibility.bodies import compute_body_states


def _assert_same(model, q):
    fast = batch_body_states(model, q)
    ref = compute_body_states(model, q, jacobian=False)
    assert fast.jacobian is None
    np.testing.assert_allclose(fast.rotation, ref.rotation, rtol=0, atol=1e-12)
    np.testing.assert_allclose(fast.translation, ref.translation, rtol=0, atol=1e-12)


@pytest.mark.parametrize("name", ["ur5", "panda", "kr16"])
def test_matches_pinocchio_on_the_derivative_robots(name):
    robot = load_robot(name)
    assert _joint_axes(robot.model) is not None  # the vectorised path, not the fallback
    q = np.random.default_rng(3).uniform(robot.lower, robot.upper, size=(50, robot.nq))
    _assert_same(robot.model, q)


def _branched_model():
    """Revolute and prismatic joints, aligned and unaligned, with a branch (two children of joint 1)."""
    model = pin.Model()
    rng = np.random.default_rng(0)

    def place():
        return pin.SE3(pin.rpy.rpyToMatrix(*rng.uniform(-1, 1, 3)), rng.uniform(-0.5, 0.5, 3))

    j1 = model.addJoint(0, pin.JointModelRZ(), place(), "rz")
    j2 = model.addJoint(j1, pin.JointModelRevoluteUnaligned(np.array([1.0, 2.0, -0.5])), place(), "ru")
    j3 = model.addJoint(j2, pin.JointModelPY(), place(), "py")
    model.addJoint(j3, pin.JointModelPrismaticUnaligned(np.array([0.3, -1.0, 0.2])), place(), "pu")
    model.addJoint(j1, pin.JointModelRX(), place(), "rx_branch")
    return model


def test_prismatic_unaligned_and_branches():
    model = _branched_model()
    assert _joint_axes(model) is not None
    q = np.random.default_rng(1).uniform(-3.0, 3.0, size=(20, model.nq))
    _assert_same(model, q)


def test_other_joint_types_fall_back_to_pinocchio():
    model = pin.Model()
    j1 = model.addJoint(0, pin.JointModelRY(), pin.SE3(np.eye(3), np.array([0.0, 0.0, 0.3])), "ry")
    model.addJoint(j1, pin.JointModelSpherical(), pin.SE3(np.eye(3), np.array([0.2, 0.0, 0.0])), "ball")
    assert _joint_axes(model) is None
    q = np.stack([pin.randomConfiguration(model, -np.ones(model.nq), np.ones(model.nq))
                  for _ in range(5)])
    _assert_same(model, q)
