"""The QP size bound of solve_sqp (row selection, calib_oed.solver.rows): bounded QPs, the same optimum."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from calib_oed.solver.sqp import SQPSettings, SQPSettingsError, SQPStatus, solve_sqp


def test_max_qp_rows_setting_is_validated():
    assert SQPSettings().qp_row_limit(10) == 200 and SQPSettings().qp_row_limit(360) == 1440
    assert SQPSettings(max_qp_rows=7).qp_row_limit(360) == 7
    for bad in (0, 2.5, True):
        with pytest.raises(SQPSettingsError, match="max_qp_rows"):
            SQPSettings(max_qp_rows=bad)


def _many_rows(n=12, m_lin=3000, m_ball=200, seed=0):
    """Thousands of linear rows and ball rows around x = 0, mostly far from active; optimum pulled far away.

    min 1/2 |x - p|^2 with p = 4 (1, ..., 1): from x0 = 0 the full step hits the
    trust region's edge (0.5) and it doubles to max_step_bound (1), where 2400
    of the 3200 rows pass the margin test.
    """
    rng = np.random.default_rng(seed)
    a = rng.standard_normal((m_lin, n)) * 0.25
    b = rng.uniform(0.5, 3.0, m_lin)
    centres = rng.standard_normal((m_ball, n)) * 0.1
    radii2 = rng.uniform(4.0, 9.0, m_ball)
    p = np.full(n, 4.0)

    def objective(x):
        return 0.5 * (x - p) @ (x - p), x - p

    def constraints(x):
        diff = x - centres
        c = np.concatenate([b + a @ x, radii2 - np.sum(diff**2, axis=1)])
        jac = sp.vstack([sp.csr_matrix(a), sp.csr_matrix(-2 * diff)], format="csr")
        return c, jac

    return objective, constraints, np.zeros(n)


@pytest.mark.parametrize("limit", [None, 40])
def test_qp_rows_stay_bounded_and_the_optimum_is_unchanged(limit):
    objective, constraints, x0 = _many_rows()
    n = x0.size
    bound = SQPSettings(max_qp_rows=limit).qp_row_limit(n)
    res = solve_sqp(objective, x0, constraints=constraints,
                    settings=SQPSettings(max_qp_rows=limit, step_bound=0.5))
    free = solve_sqp(objective, x0, constraints=constraints,
                     settings=SQPSettings(max_qp_rows=10**6, step_bound=0.5))
    assert res.status is SQPStatus.CONVERGED and res.check(), res.summary()
    assert free.status is SQPStatus.CONVERGED and free.check()
    assert all(r.n_rows_kept <= bound for r in res.history)
    assert any(r.n_rows_dropped > 0 for r in res.history)  # the bound did bind
    assert max(r.n_rows_kept for r in free.history) > 1000  # what an unbounded QP would take
    assert max(r.step_bound for r in res.history) == SQPSettings().max_step_bound
    np.testing.assert_allclose(res.x, free.x, atol=1e-6)
    assert res.fun == pytest.approx(free.fun, rel=1e-9)
    c, _ = constraints(res.x)
    assert c.min() >= -1e-7  # every row, kept or not, holds at the end


def test_infeasible_start_with_many_rows_stays_bounded():
    """An infeasible start makes the QP retry at max_step_bound (the Panda abort); still bounded."""
    objective, constraints, _ = _many_rows(seed=1)
    x0 = np.full(12, -3.0)  # violates many linear and ball rows
    c0, _ = constraints(x0)
    assert np.count_nonzero(c0 < 0) > 100
    res = solve_sqp(objective, x0, constraints=constraints, settings=SQPSettings(max_qp_rows=60))
    assert res.status is SQPStatus.CONVERGED and res.check(), res.summary()
    assert all(r.n_rows_kept <= 60 for r in res.history)


@pytest.mark.parametrize("size", [12 + 30, 12 + 10**4])
def test_the_dense_qp_size_bound_leaves_the_optimum_unchanged(size):
    """Below and above ``max_dense_qp_size`` (dense or sparse ProxQP): the same optimum and multipliers."""
    objective, constraints, x0 = _many_rows(m_lin=600, m_ball=50)
    res = solve_sqp(objective, x0, constraints=constraints, settings=SQPSettings(max_dense_qp_size=size))
    ref = solve_sqp(objective, x0, constraints=constraints, settings=SQPSettings(max_qp_rows=10**6))
    assert res.status is SQPStatus.CONVERGED and res.check(), res.summary()
    assert ref.status is SQPStatus.CONVERGED and ref.check()
    np.testing.assert_allclose(res.x, ref.x, atol=1e-6)
    np.testing.assert_allclose(res.multipliers, ref.multipliers, atol=1e-5)


def test_violated_rows_outnumbering_the_bound_are_all_restored():
    """Eight rows violated at the start, four allowed per QP, two active at the optimum: none is lost.

    min 1/2 |x - p|^2 s.t. x_i >= 1 + i/10 from x0 = 0, p = (0, 0, lo_2 + 1, ..., lo_7 + 1):
    x* = (lo_0, lo_1, p_2, ..., p_7), lambda* = (lo_0, lo_1, 0, ..., 0).
    """
    lo = 1.0 + np.arange(8) / 10
    p = np.concatenate([[0.0, 0.0], lo[2:] + 1.0])

    def constraints(x):
        return x - lo, np.eye(8)

    res = solve_sqp(lambda x: (0.5 * (x - p) @ (x - p), x - p), np.zeros(8), constraints=constraints,
                    settings=SQPSettings(max_qp_rows=4))
    assert res.status is SQPStatus.CONVERGED and res.check(), res.summary()
    np.testing.assert_allclose(res.x, np.concatenate([lo[:2], p[2:]]), atol=1e-8)
    np.testing.assert_allclose(res.multipliers, np.concatenate([lo[:2], np.zeros(6)]), atol=1e-6)
    assert all(r.n_rows_kept <= 4 for r in res.history)


def test_dropped_row_violated_by_the_step_enters_the_qp():
    """One row allowed: the nearest row (x2 <= 0.5) is kept, the blocking one (x1 <= 0.8) dropped.

    The QP step towards p = (3, 0) violates the dropped row's linearisation, so
    it replaces the other in a second solve: x* = (0.8, 0), lambda = 2.2, and
    no step ever crosses the dropped row.
    """
    p = np.array([3.0, 0.0])

    def constraints(x):
        return np.array([0.5 - x[1], 0.8 - x[0]]), np.array([[0.0, -1.0], [-1.0, 0.0]])

    steps = []
    res = solve_sqp(lambda x: (0.5 * (x - p) @ (x - p), x - p), np.zeros(2), constraints=constraints,
                    settings=SQPSettings(max_qp_rows=1, step_bound=1.0), callback=steps.append)
    assert res.status is SQPStatus.CONVERGED and res.check(), res.summary()
    np.testing.assert_allclose(res.x, [0.8, 0.0], atol=1e-9)
    np.testing.assert_allclose(res.multipliers, [0.0, 2.2], atol=1e-8)
    assert all(r.n_rows_kept == 1 for r in res.history) and res.history[0].n_rows_dropped == 1
    assert all(r.violation <= 1e-9 for r in steps) and sum(r.backtracks for r in steps) == 0
