"""Compensation on simulated truths: the true robot at the compensated joints reaches the targets."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from calib_oed import load_robot
from calib_oed.calibration.compensation import (
    CalibrationUncertainty,
    calibrated_kinematics,
    calibrated_robot,
    compensate_joints,
    compensate_pose,
)
from calib_oed.calibration.identification import identify
from calib_oed.calibration.problem import CalibrationProblem
from calib_oed.calibration.simulation import draw_true_parameters, simulate_observations
from calib_oed.exceptions import CompensationError
from calib_oed.model.compliance import Compliance
from calib_oed.model.deflected_kinematics import JointDeflection
from calib_oed.model.inverse_kinematics import TcpKinematics
from calib_oed.model.joint_map import JointGains
from calib_oed.scene.reader import load_scene
from calib_oed.scene.records import ComplianceSpec

TRUTHS = (1, 2, 3)


def _rms(a) -> float:
    return float(np.sqrt(np.mean(np.square(a))))


def _truth_errors(scene_name, n_design: int = 60, n_targets: int = 120):
    """Per truth: compensated and uncompensated TCP errors [mm], the predicted residual [mm], the
    compensation, and the TCP errors [mm] of compensating the joint placements alone.

    ``scene_name``: a name, path or Scene; with joint compliance or gains the truth and the
    compensation have them (the last item ignores them)."""
    problem = CalibrationProblem.from_scene(scene_name if not isinstance(scene_name, str) else load_scene(scene_name))
    space = problem.space
    robot = space.robot
    q_design = robot.random_configurations(n_design, 0)   # a calibration design (feasibility not needed)
    out = []
    for seed in TRUTHS:
        rng = np.random.default_rng(seed)
        p_true = draw_true_parameters(space, problem.identifiability.free_indices, rng)
        result = identify(space, simulate_observations(space, problem.models, q_design, p_true, rng),
                          problem.identifiability)
        unc = CalibrationUncertainty(space, result.p, result.free_indices, result.covariance)
        targets = robot.random_configurations(n_targets, 100 + seed)
        deflection = JointDeflection.from_space(space, result.p)
        comp = compensate_joints(robot, calibrated_robot(space, result.p), targets, uncertainty=unc,
                                 deflection=deflection)
        true = calibrated_kinematics(calibrated_robot(space, p_true), JointDeflection.from_space(space, p_true))
        nominal = TcpKinematics(robot)
        goal = np.array([nominal.compute_pose(q).translation for q in targets])

        def error(q, goal=goal, true=true):
            return 1e3 * np.linalg.norm(np.array([true.compute_pose(row).translation for row in q]) - goal, axis=1)

        after = error(comp.q)
        rigid = after if deflection is None else error(
            compensate_joints(robot, calibrated_robot(space, result.p), targets).q)
        ok = comp.converged & comp.in_range & ~comp.near_singular
        out.append((after[ok], error(targets)[ok], comp.predicted_mm[ok], comp, rigid[ok]))
    return out


@pytest.mark.parametrize("scene_name", ["fms_kr16", "ur5_table", "fms_kr300", "fms_kr500"])
def test_true_robot_reaches_the_compensated_targets(scene_name):
    _check_truths(_truth_errors(scene_name))


def test_a_large_arm_from_a_ros_industrial_xacro(tmp_path):
    """KUKA KR 120 R2500 pro from ROS-Industrial's kr120r2500pro.xacro (rtb-data), in the fms_kr300 cell."""
    from tests.model.ros_industrial import kr120_scene_file

    scene = kr120_scene_file(tmp_path)
    robot, kr300 = load_scene(scene).robot, load_robot("kr300")
    assert robot.name == "kr120r2500pro" and robot.joint_names == kr300.joint_names
    for i in range(1, robot.model.njoints):     # the KR 300 R2500's link lengths: the cell fits
        assert robot.model.jointPlacements[i].isApprox(kr300.model.jointPlacements[i], 1e-12)
    _check_truths(_truth_errors(str(scene)))


def deflecting_scene(name: str = "fms_kr16", payload_kg: float = 16.0):
    """``name`` with joint compliance (``payload_kg`` 0.1 m out on the tool) and every joint's gain."""
    import dataclasses

    scene = load_scene(name)
    return dataclasses.replace(scene, compliance=ComplianceSpec(True, Compliance(payload_kg, [0.0, 0.0, 0.1])),
                               joint_gains=JointGains.all_joints(scene.robot.nq))


def test_compliance_and_gains_are_compensated():
    """A calibration with joint compliance and gains (simulated truths that have them): the commanded
    joints from the deflected model's inverse kinematics reach the targets to the predicted accuracy;
    compensating the joint placements alone leaves the deflection (here >= 5x more)."""
    trials = _truth_errors(deflecting_scene(), n_targets=60)
    _check_truths(trials)
    for after, *_, after_rigid in trials:
        assert _rms(after_rigid) >= 5 * _rms(after)


def _check_truths(trials):
    after = np.concatenate([t[0] for t in trials])
    predicted = np.concatenate([t[2] for t in trials])
    assert all(len(t[0]) >= t[3].n // 2 for t in trials)       # most random targets are regular
    # the RMS error over 3 truths is the calibration's predicted accuracy (within 20 %) ...
    assert _rms(after) <= 1.2 * _rms(predicted)
    assert _rms(after) >= 0.6 * _rms(predicted)                # ... and the prediction is not loose
    # ... and at least 5x smaller than without compensation, per truth
    for a, b, *_ in trials:
        assert 5.0 * _rms(a) <= _rms(b)
    # flagged targets are named, the others not
    comp = trials[0][3]
    issues = comp.issues()
    flagged = ~(comp.converged & comp.in_range & ~comp.near_singular)
    assert len(issues) == flagged.sum()


def test_pose_compensation_round_trip():
    robot = load_robot("kr16")
    rng = np.random.default_rng(4)
    from calib_oed.model.parameters import ParameterSpace

    space = ParameterSpace(robot, pin.SE3.Identity(), np.zeros((1, 3)))
    p = np.zeros(space.size)
    p[space.joints_slice] = rng.normal(scale=5e-4, size=6 * robot.nq)
    cal = calibrated_robot(space, p)
    tool = pin.SE3(np.eye(3), np.array([0.0, 0.05, 0.2]))
    base = pin.SE3(pin.rpy.rpyToMatrix(0.0, 0.0, 0.3), np.array([0.5, -0.2, 0.1]))
    q0 = np.radians([[20.0, -70.0, 100.0, 15.0, 50.0, -30.0], [-35.0, -100.0, 80.0, -40.0, -60.0, 90.0]])
    nom = TcpKinematics(robot, tool)
    poses = [base.inverse() * nom.compute_pose(q) for q in q0]
    comp = compensate_pose(robot, cal, poses, q0 + 0.05, tool=tool, base=base)
    assert np.all(comp.converged) and np.allclose(comp.q_nominal, q0, atol=1e-9)
    calk = TcpKinematics(cal, tool)
    for i in range(2):   # the calibrated robot at q-hat is at the target; the commanded pose is nominal FK there
        assert np.allclose((base * poses[i]).homogeneous, calk.compute_pose(comp.q[i]).homogeneous, atol=1e-10)
        assert np.allclose((base * comp.commanded[i]).homogeneous, nom.compute_pose(comp.q[i]).homogeneous,
                           atol=1e-12)
    # the same joints through compensate_joints
    joints = compensate_joints(robot, cal, q0, tool=tool, base=base)
    assert np.allclose(joints.q, comp.q, atol=1e-9)


def test_mismatched_robots_are_refused():
    with pytest.raises(CompensationError, match="joints"):
        compensate_joints(load_robot("kr16"), load_robot("ur5"), np.zeros(6))


def test_model_error_hook_adds_to_the_prediction():
    problem = CalibrationProblem.from_scene(load_scene("fms_kr16"))
    space = problem.space
    free = problem.identifiability.free_indices
    cov = np.eye(len(free)) * 1e-10
    q = space.robot.random_configurations(5, 1)
    base = CalibrationUncertainty(space, space.zeros(), free, cov)
    extra = CalibrationUncertainty(space, space.zeros(), free, cov,
                                   model_error=lambda q, point: np.tile(np.eye(3) * 1e-8, (len(q), 1, 1)))
    c0 = base.compute_covariance(q, np.zeros(3))
    c1 = extra.compute_covariance(q, np.zeros(3))
    assert np.allclose(c1 - c0, np.eye(3) * 1e-8)


def test_pose_compensation_with_a_deflection():
    """Cartesian targets with joint compliance and gains: the deflected calibrated model reaches the
    target at the compensated (commanded) joints; the commanded pose is the nominal one there."""
    space = CalibrationProblem.from_scene(deflecting_scene()).space
    robot = space.robot
    rng = np.random.default_rng(8)
    p = space.zeros()
    p[space.joints_slice] = rng.normal(scale=5e-4, size=6 * robot.nq)
    p[space.compliance_slice] = 3e-6
    p[space.gain_slice] = rng.normal(scale=1e-3, size=robot.nq)
    deflection = JointDeflection.from_space(space, p)
    tool = pin.SE3(np.eye(3), np.array([0.0, 0.05, 0.2]))
    q0 = np.radians([[20.0, -70.0, 100.0, 15.0, 50.0, -30.0], [-35.0, -100.0, 80.0, -40.0, -60.0, 90.0]])
    nom = TcpKinematics(robot, tool)
    poses = [nom.compute_pose(q) for q in q0]
    comp = compensate_pose(robot, calibrated_robot(space, p), poses, q0 + 0.05, tool=tool, deflection=deflection)
    cal = calibrated_kinematics(calibrated_robot(space, p), deflection, tool)
    assert np.all(comp.converged)
    for i in range(2):
        assert np.allclose(cal.compute_pose(comp.q[i]).homogeneous, poses[i].homogeneous, atol=1e-10)
        assert np.allclose(comp.commanded[i].homogeneous, nom.compute_pose(comp.q[i]).homogeneous, atol=1e-12)
    rigid = compensate_pose(robot, calibrated_robot(space, p), poses, q0 + 0.05, tool=tool)
    assert np.abs(rigid.q - comp.q).max() > 1e-4                   # the deflection is compensated too
