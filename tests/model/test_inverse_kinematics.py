"""Inverse kinematics: the TCP Jacobian against finite differences, convergence, the singularity measure."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from calib_oed import load_robot
from calib_oed.model.inverse_kinematics import (
    IkSettings,
    TcpKinematics,
    characteristic_length,
    solve_ik,
)
from tests.conftest import central_difference, relative_error

TOOL = pin.SE3(pin.rpy.rpyToMatrix(0.1, -0.2, 0.3), np.array([0.02, -0.01, 0.15]))


@pytest.mark.parametrize("name", ["kr16", "ur5", "panda"])
def test_tcp_jacobian_matches_finite_differences(name):
    robot = load_robot(name)
    kin = TcpKinematics(robot, TOOL)
    q = robot.random_configurations(1, 3)[0]
    pose, jac = kin.compute_jacobian(q)

    def local_twist(x):  # log6(T(q)^-1 T(x)): the LOCAL twist of the TCP frame
        return pin.log6(pose.actInv(kin.compute_pose(x))).vector

    num = central_difference(local_twist, q)
    assert relative_error(jac, num) < 1e-7
    assert np.allclose(pose.homogeneous, kin.compute_pose(q).homogeneous)


@pytest.mark.parametrize("name", ["kr16", "ur5", "panda"])
def test_error_jacobian_matches_finite_differences(name):
    """The Newton step solves D J dq = D e: J is minus the derivative of e(q) = log6(T(q)^-1 T*)."""
    robot = load_robot(name)
    kin = TcpKinematics(robot, TOOL)
    q, q_star = robot.random_configurations(2, 4)
    target = kin.compute_pose(q_star)
    _, jac = kin.compute_error_jacobian(q, target)
    num = central_difference(lambda x: kin.compute_error(x, target), q)
    assert relative_error(-jac / kin.scale[:, None], num) < 1e-7


@pytest.mark.parametrize("name", ["kr16", "ur5", "panda"])
def test_ik_recovers_a_reachable_pose_from_a_nearby_seed(name):
    robot = load_robot(name)
    kin = TcpKinematics(robot, TOOL)
    q_true = robot.random_configurations(20, 5)
    seeds = q_true + np.random.default_rng(6).normal(scale=0.02, size=q_true.shape)
    sol = solve_ik(kin, [kin.compute_pose(q) for q in q_true], seeds)
    ok = sol.sigma_min > 0.02
    assert ok.sum() >= 10
    assert np.all(sol.converged[ok])
    assert np.all(sol.iterations[ok] <= 8)                 # quadratic convergence
    assert sol.position_error[ok].max() < 1e-10
    if robot.nq == 6:                                       # same branch: the configuration itself
        assert np.abs(sol.q[ok] - q_true[ok]).max() < 1e-8


def test_singularity_measure_vanishes_at_the_kuka_wrist_singularity():
    robot = load_robot("kr16")
    kin = TcpKinematics(robot)
    q = np.radians([10.0, -80.0, 90.0, 30.0, 40.0, 20.0])

    def sigma_min(q):  # at the solution of its own pose, started there
        return solve_ik(kin, [kin.compute_pose(q)], q[None]).sigma_min[0]

    assert sigma_min(q) > 0.02
    q[4] = 0.0                                              # A5 = 0: A4 and A6 aligned
    assert sigma_min(q) < 1e-12


def test_unreachable_target_is_not_converged():
    robot = load_robot("ur5")
    kin = TcpKinematics(robot)
    far = pin.SE3(np.eye(3), np.array([5.0, 0.0, 0.0]))    # beyond the reach
    sol = solve_ik(kin, [far], robot.random_configurations(1, 0), IkSettings(max_iterations=30))
    assert not sol.converged[0]
    assert sol.error[0] > 1.0


def test_characteristic_length_is_the_stretched_arm():
    robot = load_robot("ur5")
    length = characteristic_length(robot)
    kin = TcpKinematics(robot)
    reach = max(np.linalg.norm(kin.compute_pose(q).translation) for q in robot.random_configurations(200, 0))
    assert reach <= length <= 2.0 * reach
