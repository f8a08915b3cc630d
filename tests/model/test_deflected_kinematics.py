"""The kinematics of the commanded joints of a deflecting arm (compliance under gravity, joint gains)."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from calib_oed import load_robot
from calib_oed.measurement.base import evaluate_setup
from calib_oed.model.compliance import Compliance
from calib_oed.model.deflected_kinematics import DeflectedTcpKinematics, JointDeflection
from calib_oed.model.inverse_kinematics import IkSettings, TcpKinematics, solve_ik
from calib_oed.model.joint_map import JointGains
from calib_oed.model.parameters import ParameterSpace
from tests.conftest import central_difference


def effective(deflection: JointDeflection, q) -> np.ndarray:
    """:math:`q_{eff}` at every row of ``q`` (n, nq) [rad or m]."""
    return np.array([deflection.compute_effective_one(row) for row in np.atleast_2d(q)])

PAYLOAD = Compliance(60.0, np.array([0.0, 0.05, 0.15]))


def _space_and_p(seed=0, gains=True):
    robot = load_robot("kr16")
    space = ParameterSpace(robot, pin.SE3.Identity(), np.zeros((1, 3)), compliance=PAYLOAD,
                           joint_gains=JointGains.all_joints(robot.nq) if gains else None)
    rng = np.random.default_rng(seed)
    p = space.zeros()
    p[space.joints_slice] = rng.normal(scale=5e-4, size=space.joints_slice.stop - space.joints_slice.start)
    p[space.compliance_slice] = rng.uniform(1e-6, 5e-6, size=robot.nq)      # stiffness 2e5..1e6 N m/rad
    if gains:
        p[space.gain_slice] = rng.normal(scale=1e-3, size=space.gain_slice.stop - space.gain_slice.start)
    return space, p


def _kinematics(space, p, payload=None):
    from calib_oed.calibration.compensation import calibrated_robot

    return DeflectedTcpKinematics(calibrated_robot(space, p), JointDeflection.from_space(space, p, payload),
                                  pin.SE3(np.eye(3), np.array([0.0, 0.0, 0.2])))


def test_chain_matches_finite_differences():
    space, p = _space_and_p()
    deflection = JointDeflection.from_space(space, p)
    q = space.robot.random_configurations(3, 1)
    d = [deflection.compute_chain_one(row) for row in q]
    for k in range(3):
        fd = central_difference(deflection.compute_effective_one, q[k])
        assert np.allclose(d[k], fd, atol=1e-8)
        assert np.abs(d[k] - np.eye(space.robot.nq)).max() > 1e-4     # the deflection is felt


def test_jacobian_matches_finite_differences():
    space, p = _space_and_p()
    kin = _kinematics(space, p)
    for q in space.robot.random_configurations(3, 2):
        pose, jac = kin.compute_jacobian(q)
        fd = central_difference(lambda x, pose=pose: pin.log6(pose.actInv(kin.compute_pose(x))).vector, q)
        assert np.allclose(jac, fd, atol=1e-7)
        rigid = TcpKinematics(kin.robot, kin.tool).compute_jacobian(q)[1]
        assert np.abs(jac - rigid).max() > 1e-4                        # not the rigid Jacobian


def test_pose_is_the_identification_model():
    """The TCP of the deflected kinematics is the one the identification fits (evaluate_setup)."""
    space, p = _space_and_p()
    q = space.robot.random_configurations(5, 3)
    kin = DeflectedTcpKinematics(_kinematics(space, p).robot, JointDeflection.from_space(space, p))
    ours = np.array([kin.compute_pose(row).translation for row in q])
    assert np.allclose(ours, evaluate_setup(space, p, q, jacobian=False).kin.translation, atol=1e-12)
    rigid = np.array([TcpKinematics(kin.robot).compute_pose(row).translation for row in q])
    assert np.abs(ours - rigid).max() > 1e-4                           # > 0.1 mm: the deflection matters


@pytest.mark.parametrize("gains", [True, False])
def test_inverse_kinematics_reaches_the_target_with_the_deflection(gains):
    space, p = _space_and_p(4, gains)
    kin = _kinematics(space, p)
    nominal = TcpKinematics(space.robot, kin.tool)
    q = space.robot.random_configurations(8, 5)
    targets = [nominal.compute_pose(row) for row in q]
    sol = solve_ik(kin, targets, q, IkSettings())
    assert np.all(sol.converged) and np.all(sol.iterations <= 6)       # Newton: a few iterations
    for row, target in zip(sol.q, targets, strict=True):
        assert np.allclose(kin.compute_pose(row).homogeneous, target.homogeneous, atol=1e-10)


def test_payload_changes_only_the_gravity():
    space, p = _space_and_p(gains=False)
    q = space.robot.random_configurations(4, 6)
    same = JointDeflection.from_space(space, p, PAYLOAD)
    assert np.allclose(effective(same, q), effective(JointDeflection.from_space(space, p), q))
    empty = JointDeflection.from_space(space, p, Compliance(0.0))
    assert "0 kg" in empty.payload
    dq = effective(JointDeflection.from_space(space, p), q) - effective(empty, q)
    assert np.abs(dq).max() > 1e-5                                     # 60 kg deflects the joints
    rigid = ParameterSpace(space.robot, pin.SE3.Identity(), np.zeros((1, 3)))
    assert JointDeflection.from_space(rigid, rigid.zeros()) is None
