"""KPI covariance: the explicit form, against Monte Carlo."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.optimize
import scipy.stats
from conftest import make_space, random_parameters

from calib_oed import load_robot
from calib_oed.calibration.covariance import (
    kpi_covariance,
    parameter_covariance,
)
from calib_oed.calibration.kpi import TcpKpi
from calib_oed.calibration.problem import CalibrationProblem
from calib_oed.exceptions import NotIdentifiableError
from calib_oed.measurement import TrackerPosition, evaluate_setup
from calib_oed.measurement.sensitivity import stacked_values


@pytest.fixture(scope="module")
def problem():
    robot = load_robot("kr16")
    space = make_space(robot, [(0.03, 0.01, 0.05)])
    kpi = TcpKpi(robot.random_configurations(2, 8), point=np.array([0.0, 0.0, 0.1]))
    return CalibrationProblem(space, [TrackerPosition(0, 1e-5)], kpi)


def test_explicit_equals_kkt_form(problem):
    """C_s = G C_p G^T equals the s-block of [I 0][[F1'F1, F2'],[F2, 0]]^-1[I; 0] (paper Thm. 1)."""
    free = problem.identifiability.free_indices
    q = problem.robot.random_configurations(40, 3)
    f1 = problem.weighted_jacobian(q)[:, free]
    g = problem.kpi_jacobian()[:, free]
    n_p, n_s = f1.shape[1], g.shape[0]
    # v = (p, s); f1 does not depend on s; f2 = TCP(p) - s, so F2 = [G, -I].
    f1v = np.hstack([f1, np.zeros((f1.shape[0], n_s))])
    f2v = np.hstack([g, -np.eye(n_s)])
    kkt = np.block([[f1v.T @ f1v, f2v.T], [f2v, np.zeros((n_s, n_s))]])
    sel = np.vstack([np.eye(n_p + n_s), np.zeros((n_s, n_p + n_s))])
    c_v = sel.T @ np.linalg.solve(kkt, sel)
    c_s = kpi_covariance(f1, g)
    assert np.allclose(c_v[n_p:, n_p:], c_s, rtol=1e-6, atol=1e-6 * np.abs(c_s).max())
    assert np.allclose(c_v[:n_p, :n_p], parameter_covariance(f1), rtol=1e-6,
                       atol=1e-6 * np.abs(c_s).max())


def test_singular_information_names_parameters(problem):
    q = problem.robot.random_configurations(40, 3)
    f1 = problem.weighted_jacobian(q)  # all parameters, gauge not removed
    with pytest.raises(NotIdentifiableError):
        parameter_covariance(f1, problem.space.names)


def test_kpi_covariance_against_monte_carlo(problem):
    """Simulated calibrations: nonlinear least squares on the free parameters.

    1000 seeded runs; the mean squared KPI error must match tr(C_s) within
    15 % and the 95 % ellipsoid must cover 92-98 % of the errors.
    """
    rng = np.random.default_rng(2026)
    space = problem.space
    model = problem.models[0]
    free = problem.identifiability.free_indices
    q = problem.robot.random_configurations(30, 5)
    p_true = np.zeros(space.size)
    p_true[free] = random_parameters(space, rng)[free]
    c_s = problem.kpi_covariance(q, p_true)
    s_true = problem.kpi.compute_values(space, p_true).ravel()
    h_true = stacked_values([model], evaluate_setup(space, p_true, q, jacobian=False))
    sigma = np.tile(model.sigma, len(q))

    def estimate(eta):
        def residual(x):
            p = np.zeros(space.size)
            p[free] = x
            return (eta - stacked_values([model], evaluate_setup(space, p, q, jacobian=False))) / sigma

        def jac(x):
            p = np.zeros(space.size)
            p[free] = x
            return -problem.weighted_jacobian(q, p)[:, free]

        sol = scipy.optimize.least_squares(residual, np.zeros(len(free)), jac=jac, method="lm",
                                           xtol=1e-12, ftol=1e-12)
        p = np.zeros(space.size)
        p[free] = sol.x
        return p

    n_runs = 1000
    errors = np.empty((n_runs, len(s_true)))
    for k in range(n_runs):
        eta = h_true + sigma * rng.normal(size=h_true.shape)
        errors[k] = problem.kpi.compute_values(space, estimate(eta)).ravel() - s_true
    ratio = np.mean(np.sum(errors**2, axis=1)) / np.trace(c_s)
    print(f"Monte Carlo: mean squared KPI error / tr(C_s) = {ratio:.3f}")
    assert 0.85 < ratio < 1.15
    c_inv = np.linalg.inv(c_s[:3, :3])
    d2 = np.einsum("ki,ij,kj->k", errors[:, :3], c_inv, errors[:, :3])
    coverage = np.mean(d2 <= scipy.stats.chi2.ppf(0.95, 3))
    print(f"Monte Carlo: coverage of the 95 % KPI ellipsoid = {coverage:.3f}")
    assert 0.92 <= coverage <= 0.98


def test_too_few_poses_is_a_clear_error(problem):
    q = problem.robot.random_configurations(5, 3)  # 15 values for 25+ free parameters
    with pytest.raises(NotIdentifiableError, match="measure more configurations"):
        problem.kpi_covariance(q)
