"""The design criterion as a function of the configurations: exact gradient against differences."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import central_difference, make_space, relative_error

from calib_oed.calibration.kpi import TcpKpi
from calib_oed.calibration.problem import CalibrationProblem, GenericDesign
from calib_oed.measurement import PoseMeasurement, TrackerPosition
from calib_oed.measurement.sensitivity import weighted_jacobian
from calib_oed.oed.criteria import CRITERIA, ACriterion
from calib_oed.oed.objective import DesignObjective


def _partial_differences(objective, q, poses, eps=1e-5):
    """Central differences of phi along every coordinate of the given poses, (len(poses), nv).

    eps = 1e-5 rad: M's eigenvalues span ~8 decades, so phi carries relative
    rounding ~1e-16 * cond; a smaller step amplifies it (E on Panda: 2.6e-5 at 1e-6).
    """

    def phi_of(x, j):
        qq = q.copy()
        qq[j] = x
        return objective.compute_value(qq)

    return np.stack([central_difference(lambda x, j=j: phi_of(x, j), q[j], eps) for j in poses])


_PROBLEMS: dict = {}


def _problem(robot, pose=False):
    """One problem per robot and model kind for the whole module (the gauge rule is the slow part)."""
    key = (robot.name, pose)
    if key not in _PROBLEMS:
        _PROBLEMS[key] = _build_problem(robot, pose)
    return _PROBLEMS[key]


def _build_problem(robot, pose):
    space = make_space(robot)
    model = PoseMeasurement if pose else TrackerPosition
    kpi = TcpKpi(robot.random_configurations(2, 5), point=np.array([0.0, 0.0, 0.1]))
    return CalibrationProblem(space, [model(0), model(1, sigma=2e-5)], kpi,
                              GenericDesign(n=60, seed=0))


@pytest.mark.parametrize("criterion", CRITERIA)
def test_gradient_matches_differences(robot, criterion):
    problem = _problem(robot)
    objective = DesignObjective(problem, criterion)
    q = robot.random_configurations(8, 31)
    ev = objective.compute(q)
    poses = [0, 5]
    numeric = _partial_differences(objective, q, poses)
    assert ev.gradient.shape == q.shape
    assert np.isclose(ev.value, objective.compute_value(q), rtol=1e-12)
    assert relative_error(ev.gradient[poses], numeric) < 1e-5


def test_gradient_with_pose_measurement_and_prior(robot):
    problem = _problem(robot, pose=True)
    base = DesignObjective(problem, "kpi")
    prior = base.compute_information(robot.random_configurations(10, 3))
    objective = DesignObjective(problem, "kpi", p=problem.space.random(2, 1e-3, 1e-3), prior=prior)
    q = robot.random_configurations(4, 32)
    numeric = _partial_differences(objective, q, [0, 1, 2, 3])
    assert relative_error(objective.compute(q).gradient, numeric) < 1e-5


def test_kpi_criterion_is_the_average_kpi_variance(robot):
    """The kpi criterion equals tr(C_s)/3t of the problem's KPI covariance, in mm²."""
    problem = _problem(robot)
    objective = DesignObjective(problem, "kpi")
    q = robot.random_configurations(12, 33)
    cs = problem.kpi_covariance(q)
    assert np.isclose(objective.compute_value(q), np.trace(cs) / cs.shape[0] * 1e6, rtol=1e-9)
    assert isinstance(objective.criterion, ACriterion)


def test_blocks_are_the_scaled_rows_of_f1(robot):
    problem = _problem(robot)
    objective = DesignObjective(problem, "params")
    q = robot.random_configurations(7, 34)
    f1 = weighted_jacobian(problem.space, problem.models, q)[:, objective.free] * objective.scale
    blocks = objective.compute_blocks(q)
    # sensitivity.py stacks model-major; the objective stacks pose-major
    d = 3
    for j in range(len(q)):
        expect = np.vstack([f1[m * len(q) * d + j * d: m * len(q) * d + (j + 1) * d] for m in range(2)])
        assert np.allclose(blocks[j], expect, rtol=1e-12, atol=0)
    info = objective.information(blocks)
    assert np.allclose(info, f1.T @ f1, rtol=1e-10)


@pytest.mark.parametrize("pose", [False, True], ids=["tracker", "pose"])
def test_row_derivatives_match_differences_of_the_rows(robot, pose):
    """compute_row_derivatives: the rows of compute_blocks and, per pose, their central differences.

    eps = 1e-4 rad: kr16's pose-measurement rows carry rounding that a smaller
    step amplifies (relative error 1.5e-6 at 1e-6, 3e-8 at 1e-4; truncation ~2e-9).
    """
    objective = DesignObjective(_problem(robot, pose), "kpi")
    q = robot.random_configurations(3, 36)  # no M is formed: any number of poses
    rows, derivatives = objective.compute_row_derivatives(q)
    blocks = objective.compute_blocks(q)
    assert rows.shape == blocks.shape and derivatives.shape == blocks.shape + (q.shape[1],)
    assert np.allclose(rows, blocks, rtol=1e-12, atol=1e-12 * np.abs(blocks).max())
    for j in range(len(q)):

        def rows_of(x, j=j):
            qq = q.copy()
            qq[j] = x
            return objective.compute_blocks(qq)[j]

        assert relative_error(derivatives[j], central_difference(rows_of, q[j], 1e-4)) < 1e-6


def test_too_few_poses_names_the_parameters(robot):
    from calib_oed.exceptions import NotIdentifiableError

    objective = DesignObjective(_problem(robot), "kpi")
    with pytest.raises(NotIdentifiableError, match="measure more configurations") as err:
        objective.compute_value(robot.random_configurations(2, 0))
    assert set(err.value.names) == set(objective.free_names)


@pytest.mark.parametrize("criterion", ["kpi", "params", "D"])
def test_curvature_is_the_criterion_hessian_along_dm(criterion):
    """H1[a, b] = d2/dta dtb Phi(M + ta Ma + tb Mb), with Ma = dM/dq_a by central differences."""
    from calib_oed import load_robot

    robot = load_robot("ur5")
    objective = DesignObjective(_problem(robot), criterion)
    q = robot.random_configurations(7, 35)
    h1 = objective.compute_curvature(q)
    assert h1.shape == (q.size, q.size) and np.allclose(h1, h1.T)
    assert np.linalg.eigvalsh(h1).min() >= -1e-9 * np.abs(h1).max()  # convex criteria: PSD
    info = objective.compute_information(q)
    picks = [0, 4, 9, 20, 41]

    def m_a(a):
        def info_at(x):
            qq = q.ravel().copy()
            qq[a] = x[0]
            return objective.compute_information(qq.reshape(q.shape))
        return central_difference(info_at, q.ravel()[a:a + 1])[..., 0]

    mats = {a: m_a(a) for a in picks}
    phi = objective.criterion.compute_value
    eps = 1e-4
    for a in picks:
        for b in picks:
            num = (phi(info + eps * mats[a] + eps * mats[b]) - phi(info + eps * mats[a] - eps * mats[b])
                   - phi(info - eps * mats[a] + eps * mats[b]) + phi(info - eps * mats[a] - eps * mats[b])
                   ) / (4 * eps**2)
            assert np.isclose(h1[a, b], num, rtol=1e-4, atol=1e-6 * np.abs(h1).max())


def test_no_curvature_for_eigenvalue_criteria(robot):
    objective = DesignObjective(_problem(robot), "E")
    assert objective.compute_curvature(robot.random_configurations(8, 1)) is None
