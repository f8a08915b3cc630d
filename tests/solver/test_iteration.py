"""One SQP iteration (:mod:`calib_oed.solver.iteration`): the longer step after a flipped model.

``SQPSettings.extrapolate``: after a full step from an exact Hessian whose eigenvalues were
modified, a step :math:`\\alpha d` (:math:`\\alpha \\ge 2`) to the minimiser of the merit's
quadratic along :math:`d`, within the box and the inactive rows' linearisations.
"""

from __future__ import annotations

import numpy as np
import pytest

from calib_oed.solver.result import StructuredHessian
from calib_oed.solver.sqp import SQPSettings, SQPSettingsError, SQPStatus, solve_sqp


def _tail_problem():
    r"""f = 0.005 (u - 2)^2 + u v - v^2/2 + v, v >= 0 (tests/solver/test_hessian.py's linear tail).

    The block [[0.01, 1], [1, -1]] is indefinite; the whole-block flip puts curvature 0.90 on
    u against the true 0.01, so each step is 1/90 of Newton's.
    """
    def objective(x):
        u, v = x
        return 0.005 * (u - 2) ** 2 + u * v - v**2 / 2 + v, np.array([0.01 * (u - 2) + v, u - v + 1])

    def hessian(x, lam):
        return StructuredHessian(np.array([[[0.01, 1.0], [1.0, -1.0]]]))

    return objective, hessian, np.array([0.0, 0.0]), ([-np.inf, 0.0], [np.inf, np.inf])


def test_a_longer_step_ends_the_linear_tail_of_a_flipped_eigenvalue():
    objective, hessian, x0, bounds = _tail_problem()
    runs = {ext: solve_sqp(objective, x0, bounds=bounds, lagrangian_hessian=hessian,
                           settings=SQPSettings(max_iterations=100, hessian_modification="block",
                                                extrapolate=ext))
            for ext in (False, True)}
    assert runs[False].status is SQPStatus.MAX_ITERATIONS and abs(runs[False].x[0] - 2.0) > 0.1
    res = runs[True]
    assert res.status is SQPStatus.CONVERGED and res.check(), res.summary()
    np.testing.assert_allclose(res.x, [2.0, 0.0], atol=1e-6)
    assert res.iterations <= 30
    longer = [r for r in res.history if r.extrapolated > 1.0]
    assert longer and all(r.extrapolated >= 2.0 and r.hessian_modified for r in longer)
    assert all(r.step_norm <= r.step_bound * (1 + 1e-12) for r in res.history)  # never past the box
    assert "longer steps" in res.summary()


def test_a_longer_step_stops_at_an_inactive_rows_linearisation():
    r"""f = \sum_i (x_i^4/4 - x_i^2), concave near 0; the row 0.35 - x_0 >= 0 (linear) binds at the end.

    From x_0 = 0.1 the flipped curvature makes the step towards \sqrt 2 short (0.101) and the
    merit's curvature along it is negative: the longer step would go to the box (0.3) but stops
    at the row's linearisation (exact here), 2.47 times the QP's step; every iterate is feasible.
    """
    def objective(x):
        return float(np.sum(x**4 / 4 - x**2)), x**3 - 2 * x

    def constraints(x):
        return np.array([0.35 - x[0]]), np.array([[-1.0, 0.0]])

    def hessian(x, lam):
        return StructuredHessian(np.diag(3 * x**2 - 2)[None])

    res = solve_sqp(objective, np.array([0.1, np.sqrt(2.0)]), constraints=constraints, lagrangian_hessian=hessian,
                    settings=SQPSettings(extrapolate=True))
    assert res.status is SQPStatus.CONVERGED and res.check(), res.summary()
    np.testing.assert_allclose(res.x, [0.35, np.sqrt(2.0)], atol=1e-6)
    assert res.multipliers[0] == pytest.approx(2 * 0.35 - 0.35**3, abs=1e-6)
    first = res.history[0]
    assert first.extrapolated == pytest.approx(0.25 / 0.10101522842639593, rel=1e-6)  # the row, not the box
    assert all(r.violation <= 1e-7 for r in res.history)


@pytest.mark.parametrize("exact", [False, True])
def test_no_longer_step_without_a_modified_exact_hessian(exact):
    """BFGS, or an exact Hessian that needed no change: the same run, bit for bit, with or without."""
    def objective(x):
        return float(np.sum((x - 1.0) ** 2) + x[0] * x[1]), 2 * (x - 1.0) + x[::-1]

    def constraints(x):
        return np.array([1.0 - x[0] ** 2 - x[1] ** 2]), -2 * x[None]

    def hessian(x, lam):
        return StructuredHessian(np.array([[[2 + 2 * lam[0], 1.0], [1.0, 2 + 2 * lam[0]]]]))

    runs = [solve_sqp(objective, np.array([0.1, -0.2]), constraints=constraints,
                      lagrangian_hessian=hessian if exact else None, settings=SQPSettings(extrapolate=ext))
            for ext in (False, True)]
    assert all(r.status is SQPStatus.CONVERGED for r in runs)
    assert all(r.extrapolated == 1.0 and not r.hessian_modified for r in runs[1].history)
    assert [(r.objective, r.step_norm) for r in runs[0].history] == \
        [(r.objective, r.step_norm) for r in runs[1].history]
    np.testing.assert_array_equal(runs[0].x, runs[1].x)


def test_extrapolate_must_be_a_bool():
    with pytest.raises(SQPSettingsError, match="extrapolate"):
        SQPSettings(extrapolate="yes")


def test_rows_the_qp_did_not_hold_are_charged_at_the_single_penalty():
    """``penalty_weights="row"``: a row with a multiplier is charged at its own weight, a row the
    QP did not hold (multiplier 0) at the single penalty mu, and a bound's violation at mu."""
    from collections import defaultdict

    from calib_oed.solver.iteration import _Run
    from calib_oed.solver.nlp import _Problem

    def objective(x):
        return float(x @ x), 2 * x

    def constraints(x):
        return np.array([x[0] - 1.1, x[1] - 1.2]), np.eye(2)

    lb, ub = np.array([-np.inf, -np.inf]), np.array([0.95, np.inf])
    problem = _Problem(objective, constraints, 2, lb, ub, defaultdict(float))
    pt = problem.evaluate(np.array([1.0, 1.0]), strict=True)  # c = (-0.1, -0.2), x_0 above its bound by 0.05
    run = _Run(problem, pt, lb, ub, SQPSettings(penalty_weights="row"), 0.0)
    run.lam, run.mu, run.mu_rows = np.array([0.5, 0.0]), 2.0, np.array([0.6, 0.001])
    assert run._penalty(pt) == pytest.approx(0.6 * 0.1 + 2.0 * 0.2 + 2.0 * 0.05, rel=1e-12)
    assert run._merit(pt) == pytest.approx(2.0 + run._penalty(pt), rel=1e-12)
    single = _Run(problem, pt, lb, ub, SQPSettings(), 0.0)
    single.mu = 2.0
    assert single._penalty(pt) == pytest.approx(2.0 * (0.1 + 0.2 + 0.05), rel=1e-12)
