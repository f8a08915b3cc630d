"""The design criterion as a function of the configurations: exact gradient against differences."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import central_difference, make_space, random_parameters, relative_error

from calib_oed.calibration.kpi import TcpKpi
from calib_oed.calibration.problem import CalibrationProblem
from calib_oed.measurement import PoseMeasurement, TrackerPosition
from calib_oed.measurement.sensitivity import weighted_jacobian
from calib_oed.oed.criteria import CRITERIA, ACriterion
from calib_oed.oed.objective import DesignObjective
from calib_oed.scene.records import GenericDesignSpec


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
                              GenericDesignSpec(n=60, seed=0))


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
    objective = DesignObjective(problem, "kpi", p=random_parameters(problem.space, 2, 1e-3, 1e-3), prior=prior)
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
    low = objective.compute_hessian(q).low_rank
    h1 = low @ low.T
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


# ------------------------------------------------------------------ exact Hessian
_MIXED: dict = {}


def _mixed_problem(robot):
    """Position and pose models on both reflectors, two KPI points (one problem per robot)."""
    if robot.name not in _MIXED:
        space = make_space(robot)
        kpi = TcpKpi(robot.random_configurations(2, 5), point=np.array([0.0, 0.0, 0.1]))
        models = [TrackerPosition(0), PoseMeasurement(1, sigma=2e-5, sigma_angle=3e-5),
                  TrackerPosition(1, sigma=1.5e-5)]
        _MIXED[robot.name] = CalibrationProblem(space, models, kpi, GenericDesignSpec(n=60, seed=0))
    return _MIXED[robot.name]


def _gradient_differences(objective, q, eps=1e-5):
    """Central differences of the exact gradient, (n nv, n nv), x = q.ravel()."""
    return central_difference(lambda x: objective.compute(x.reshape(q.shape)).gradient.ravel(),
                              q.ravel(), eps)


def test_row_hessians_match_differences_of_the_row_derivatives(robot):
    objective = DesignObjective(_mixed_problem(robot), "kpi")
    q = robot.random_configurations(3, 37)
    dd = objective.compute_row_hessians(q)
    rows, d_rows = objective.compute_row_derivatives(q)
    assert dd.shape == d_rows.shape + (q.shape[1],)
    for j in range(len(q)):

        def derivatives_of(x, j=j):
            qq = q.copy()
            qq[j] = x
            return objective.compute_row_derivatives(qq).derivatives[j]

        assert relative_error(dd[j], central_difference(derivatives_of, q[j], 1e-4)) < 1e-6


@pytest.mark.parametrize("criterion", ["kpi", "params", "D"])
def test_hessian_matches_differences_of_the_gradient(robot, criterion):
    """compute_hessian().dense() is the exact Hessian: central differences of the exact gradient."""
    objective = DesignObjective(_mixed_problem(robot), criterion)
    q = robot.random_configurations(8, 38)
    hess = objective.compute_hessian(q)
    n, nv = q.shape
    assert hess.blocks.shape == (n, nv, nv)
    assert np.allclose(hess.blocks, np.transpose(hess.blocks, (0, 2, 1)), rtol=0, atol=0)
    assert relative_error(hess.dense(), _gradient_differences(objective, q)) < 1e-6


def test_hessian_with_prior_weights_and_perturbed_parameters(robot):
    """Prior information, weighted KPI points and sensitivities at non-nominal p."""
    problem = _mixed_problem(robot)
    base = DesignObjective(problem, "kpi")
    prior = base.compute_information(robot.random_configurations(10, 3))
    crit = ACriterion.kpi(base.kpi_jacobian(), weights=[1.0, 3.0])
    objective = DesignObjective(problem, crit, p=random_parameters(problem.space, 2, 1e-3, 1e-3), prior=prior)
    q = robot.random_configurations(4, 39)  # fewer poses than parameters: the prior makes M regular
    hess = objective.compute_hessian(q)
    assert relative_error(hess.dense(), _gradient_differences(objective, q)) < 1e-6


@pytest.mark.parametrize("criterion", ["kpi", "params", "D"])
def test_hessian_low_rank_part_is_the_curvature_through_m(criterion):
    """U U^T is the coupling formed directly (PSD); U's columns: r_W n_f for A, n_f(n_f+1)/2 for D."""
    from calib_oed import load_robot

    robot = load_robot("kr16")
    objective = DesignObjective(_mixed_problem(robot), criterion)
    q = robot.random_configurations(8, 40)
    hess = objective.compute_hessian(q)
    low = hess.low_rank
    curvature = low @ low.T
    assert relative_error(curvature, _dense_curvature(objective, q)) < 1e-12
    nf = objective.n_free
    cols = {"kpi": 6 * nf, "params": nf * nf, "D": nf * (nf + 1) // 2}[criterion]  # 2 KPI points
    assert low.shape == (q.size, cols)
    eig = np.linalg.eigvalsh(low @ low.T)
    assert eig.min() >= -1e-12 * eig.max()
    # the pose blocks are the rest: dense Hessian minus the coupling, zero off the diagonal blocks
    rest = hess.dense() - curvature
    nv = q.shape[1]
    for j in range(len(q)):
        rest[j * nv:(j + 1) * nv, j * nv:(j + 1) * nv] -= hess.blocks[j]
    assert np.abs(rest).max() <= 1e-12 * np.abs(curvature).max()


def _dense_curvature(objective, q):
    """The coupling formed directly: (2/k) tr(P M_a C M_b) for A, tr(C M_a C M_b) for D."""
    rows, d_rows = objective.compute_row_derivatives(q)
    n, _, nf, nv = d_rows.shape
    c = np.linalg.inv(objective.compute_information(q))
    half = np.einsum("jdf,jdgk->jkfg", rows, d_rows).reshape(n * nv, nf, nf)
    v = c @ (half + np.transpose(half, (0, 2, 1)))  # C M_a
    crit = objective.criterion
    if isinstance(crit, ACriterion):
        x = (c @ crit.weight @ v).reshape(n * nv, -1) @ np.transpose(v, (0, 2, 1)).reshape(n * nv, -1).T
        return (x + x.T) / crit.dim
    return np.einsum("aij,bji->ab", v, v)


def test_hessian_of_a_singular_design_names_the_parameters():
    from calib_oed import load_robot
    from calib_oed.exceptions import NotIdentifiableError

    robot = load_robot("ur5")
    objective = DesignObjective(_problem(robot), "D")
    q = np.repeat(robot.random_configurations(1, 4), 20, axis=0)  # one pose, 20 times
    with pytest.raises(NotIdentifiableError) as err:
        objective.compute_hessian(q)
    assert set(err.value.names) <= set(objective.free_names)


@pytest.mark.parametrize("criterion", ["E", "O1", "O3"])
def test_no_hessian_for_eigenvalue_criteria(criterion):
    from calib_oed import load_robot

    robot = load_robot("ur5")
    objective = DesignObjective(_problem(robot), criterion)
    assert objective.compute_hessian(robot.random_configurations(8, 1)) is None


def test_no_hessian_with_compliance():
    """With joint compliance the rows' second derivative would need d2 tau_g/dq2: None (fall back)."""
    from calib_oed import load_robot
    from calib_oed.model.compliance import Compliance
    from calib_oed.model.parameters import ParameterSpace

    base = make_space(load_robot("ur5"))
    space = ParameterSpace(base.robot, base.tracker_placement(None), base.reflector_offsets(None),
                           compliance=Compliance(10.0, [0.0, 0.0, 0.1]))
    kpi = TcpKpi(base.robot.random_configurations(1, 5), point=np.array([0.0, 0.0, 0.1]))
    problem = CalibrationProblem(space, [TrackerPosition(0), TrackerPosition(1)], kpi,
                                 GenericDesignSpec(n=60, seed=0))
    objective = DesignObjective(problem, "kpi")
    q = base.robot.random_configurations(8, 2)
    assert objective.compute_row_hessians(q) is None
    assert objective.compute_hessian(q) is None
    assert objective.compute(q).gradient.shape == q.shape  # first order unaffected
