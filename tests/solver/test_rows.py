"""Row selection of the SQP (calib_oed.solver.rows) and the QP size bound inside solve_sqp."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from calib_oed.solver.rows import missed_rows, row_distance, select_rows
from calib_oed.solver.sqp import SQPSettings, SQPSettingsError, SQPStatus, solve_sqp


def test_select_rows_keeps_all_candidates_below_the_limit():
    c = np.array([0.0, 0.1, 1.0, 5.0, -0.2])
    l1 = np.array([1.0, 1.0, 1.0, 1.0, 1.0])
    sel = select_rows(c, l1, 0.5, 0.05, 10)
    assert sel.rows.tolist() == [0, 1, 4]  # c - 0.5 <= 0.05
    assert sel.dropped.size == 0 and sel.n_candidates == 3


def test_select_rows_keeps_the_nearest_and_the_forced_rows():
    # distances c / ||A||_1: 0.5, 0.1, 0.05, 0.9, -1 (violated), 0.3 (active multiplier)
    c = np.array([1.0, 0.1, 0.1, 0.9, -0.5, 0.6])
    l1 = np.array([2.0, 1.0, 2.0, 1.0, 0.5, 2.0])
    must = np.array([False, False, False, False, False, True])
    sel = select_rows(c, l1, 1.0, 0.05, 3, must)
    assert sel.n_candidates == 6
    assert sel.rows.tolist() == [2, 4, 5]  # violated, active, then the nearest (0.05)
    assert sel.dropped.tolist() == [0, 1, 3]
    np.testing.assert_allclose(row_distance(c, l1), [0.5, 0.1, 0.05, 0.9, -1.0, 0.3])
    # forced rows beyond the limit: the most violated first
    sel = select_rows(np.array([-0.1, -1.0, -0.5]), np.ones(3), 1.0, 0.0, 2)
    assert sel.rows.tolist() == [1, 2]
    assert row_distance(np.array([1.0, -1.0]), np.zeros(2)).tolist() == [np.inf, -np.inf]


def test_missed_rows_are_the_dropped_rows_the_step_violates():
    a = sp.csr_matrix(np.array([[1.0, 0.0], [0.0, 1.0], [1.0, 1.0]]))
    c = np.array([0.5, 0.5, 0.5])
    d = np.array([-1.0, 0.0])
    assert missed_rows(c, a, d, np.array([0, 1]), 1e-12).tolist() == [0]
    assert missed_rows(c, a.toarray(), d, np.array([1, 2]), 1e-12).tolist() == [2]
    assert missed_rows(c, a, d, np.array([], dtype=int), 0.0).size == 0


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


def test_dense_backend_is_not_used_above_its_size_bound():
    objective, constraints, x0 = _many_rows(m_lin=600, m_ball=50)
    settings = SQPSettings(max_dense_qp_size=12 + 30)
    res = solve_sqp(objective, x0, constraints=constraints, settings=settings)
    assert res.status is SQPStatus.CONVERGED and res.check()
    backends = {(r.qp_backend, r.n_rows_kept + 12 <= 42) for r in res.history}
    assert ("sparse", False) in backends and ("dense", False) not in backends


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
