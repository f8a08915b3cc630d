"""Behaviour tests of the SQP solver (calib_oed.solver.sqp, sqp_qp, sqp_result).

Known answers come from Hock & Schittkowski, *Test Examples for Nonlinear
Programming Codes* (Springer, 1981), problems 21, 35, 43 (Rosen–Suzuki), 76
and 100, and from problems whose optimum follows by hand. The assertions are
on KKT residuals recomputed here from the problem functions, not only on the
solver's own report.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
import scipy.optimize
import scipy.sparse as sp

from calib_oed.exceptions import NonFiniteError, ShapeError
from calib_oed.solver.bfgs import damped_bfgs_update
from calib_oed.solver.polish import polish
from calib_oed.solver.qp import DenseQPWorkspace, QPSubproblem, SparseQPWorkspace
from calib_oed.solver.restoration import unreachable_rows
from calib_oed.solver.result import StructuredHessian
from calib_oed.solver.sqp import (
    SQPProblemError,
    SQPSettings,
    SQPSettingsError,
    SQPStatus,
    solve_sqp,
)


# ------------------------------------------------------------ test problems
def _hs21():
    def obj(x):
        return 0.01 * x[0] ** 2 + x[1] ** 2 - 100, np.array([0.02 * x[0], 2 * x[1]])

    def con(x):
        return np.array([10 * x[0] - x[1] - 10]), np.array([[10.0, -1.0]])

    return obj, con, [-1.0, -1.0], ([2, -50], [50, 50]), [2.0, 0.0], -99.96


def _hs35():
    def obj(x):
        x1, x2, x3 = x
        f = 9 - 8 * x1 - 6 * x2 - 4 * x3 + 2 * x1**2 + 2 * x2**2 + x3**2 + 2 * x1 * x2 + 2 * x1 * x3
        return f, np.array([-8 + 4 * x1 + 2 * x2 + 2 * x3, -6 + 4 * x2 + 2 * x1, -4 + 2 * x3 + 2 * x1])

    def con(x):
        return np.array([3 - x[0] - x[1] - 2 * x[2]]), np.array([[-1.0, -1.0, -2.0]])

    return obj, con, [0.5] * 3, (0, np.inf), [4 / 3, 7 / 9, 4 / 9], 1 / 9


def _hs43():
    """Rosen–Suzuki."""
    def obj(x):
        x1, x2, x3, x4 = x
        f = x1**2 + x2**2 + 2 * x3**2 + x4**2 - 5 * x1 - 5 * x2 - 21 * x3 + 7 * x4
        return f, np.array([2 * x1 - 5, 2 * x2 - 5, 4 * x3 - 21, 2 * x4 + 7])

    def con(x):
        x1, x2, x3, x4 = x
        c = np.array([8 - x1**2 - x2**2 - x3**2 - x4**2 - x1 + x2 - x3 + x4,
                      10 - x1**2 - 2 * x2**2 - x3**2 - 2 * x4**2 + x1 + x4,
                      5 - 2 * x1**2 - x2**2 - x3**2 - 2 * x1 + x2 + x4])
        a = np.array([[-2 * x1 - 1, -2 * x2 + 1, -2 * x3 - 1, -2 * x4 + 1],
                      [-2 * x1 + 1, -4 * x2, -2 * x3, -4 * x4 + 1],
                      [-4 * x1 - 2, -2 * x2 + 1, -2 * x3, 1.0]])
        return c, a

    return obj, con, [0.0] * 4, None, [0.0, 1.0, 2.0, -1.0], -44.0


def _hs76():
    def obj(x):
        x1, x2, x3, x4 = x
        f = x1**2 + 0.5 * x2**2 + x3**2 + 0.5 * x4**2 - x1 * x3 + x3 * x4 - x1 - 3 * x2 + x3 - x4
        return f, np.array([2 * x1 - x3 - 1, x2 - 3, 2 * x3 - x1 + x4 + 1, x4 + x3 - 1])

    a = np.array([[-1.0, -2, -1, -1], [-3, -1, -2, 1], [0, 1, 4, 0]])

    def con(x):
        return np.array([5.0, 4.0, -1.5]) + a @ x, sp.csr_matrix(a)  # sparse Jacobian on purpose

    return obj, con, [0.5] * 4, (0, np.inf), [3 / 11, 23 / 11, 0.0, 6 / 11], -4.681818181


def _hs100():
    def obj(x):
        x1, x2, x3, x4, x5, x6, x7 = x
        f = ((x1 - 10) ** 2 + 5 * (x2 - 12) ** 2 + x3**4 + 3 * (x4 - 11) ** 2 + 10 * x5**6
             + 7 * x6**2 + x7**4 - 4 * x6 * x7 - 10 * x6 - 8 * x7)
        g = np.array([2 * (x1 - 10), 10 * (x2 - 12), 4 * x3**3, 6 * (x4 - 11), 60 * x5**5,
                      14 * x6 - 4 * x7 - 10, 4 * x7**3 - 4 * x6 - 8])
        return f, g

    def con(x):
        x1, x2, x3, x4, x5, x6, x7 = x
        c = np.array([127 - 2 * x1**2 - 3 * x2**4 - x3 - 4 * x4**2 - 5 * x5,
                      282 - 7 * x1 - 3 * x2 - 10 * x3**2 - x4 + x5,
                      196 - 23 * x1 - x2**2 - 6 * x6**2 + 8 * x7,
                      -4 * x1**2 - x2**2 + 3 * x1 * x2 - 2 * x3**2 - 5 * x6 + 11 * x7])
        a = np.array([[-4 * x1, -12 * x2**3, -1, -8 * x4, -5, 0, 0],
                      [-7, -3, -20 * x3, -1, 1, 0, 0],
                      [-23, -2 * x2, 0, 0, 0, -12 * x6, 8],
                      [-8 * x1 + 3 * x2, -2 * x2 + 3 * x1, -4 * x3, 0, 0, -5, 11.0]])
        return c, a

    x_star = [2.330499, 1.951372, -0.4775414, 4.365726, -0.6244870, 1.038131, 1.594227]
    return obj, con, [1.0, 2, 0, 4, 0, 1, 1], None, x_star, 680.6300573


HS = {"hs21": _hs21, "hs35": _hs35, "hs43": _hs43, "hs76": _hs76, "hs100": _hs100}


def _rosenbrock(x):
    f = 100 * (x[1] - x[0] ** 2) ** 2 + (1 - x[0]) ** 2
    return f, np.array([-400 * x[0] * (x[1] - x[0] ** 2) - 2 * (1 - x[0]), 200 * (x[1] - x[0] ** 2)])


def _kkt(objective, constraints, bounds, res):
    """Independent KKT residuals of ``res``: (max violation, max |grad L|, max |lam c|)."""
    x = res.x
    f, g = objective(x)
    viol, r, comp = 0.0, np.array(g, dtype=float), 0.0
    if constraints is not None:
        c, a = constraints(x)
        a = a.toarray() if sp.issparse(a) else np.asarray(a)
        viol = max(0.0, float(-c.min()))
        r = r - a.T @ res.multipliers
        comp = float(np.max(np.abs(res.multipliers * c)))
    if bounds is not None:
        lb, ub = (np.broadcast_to(np.asarray(b, dtype=float), x.shape) for b in bounds)
        viol = max(viol, float(np.max(lb - x)), float(np.max(x - ub)))
        nu = res.bound_multipliers
        r = r - nu
        lo, up = x - lb <= 1e-7, ub - x <= 1e-7
        assert np.all(nu[~(lo | up)] == 0.0)
        assert np.all(nu[lo & ~up] >= 0.0) and np.all(nu[up & ~lo] <= 0.0)
    return viol, float(np.max(np.abs(r))) / max(1.0, float(np.max(np.abs(g)))), comp


# ------------------------------------------------------------ known optima
@pytest.mark.parametrize("name", sorted(HS))
def test_hock_schittkowski_problems_reach_the_published_optimum(name):
    objective, constraints, x0, bounds, x_star, f_star = HS[name]()
    res = solve_sqp(objective, np.array(x0, dtype=float), constraints=constraints, bounds=bounds)
    assert res.status is SQPStatus.CONVERGED, res.summary()
    assert res.check()
    x_star = np.asarray(x_star)
    # published optima have ~7 significant digits
    np.testing.assert_allclose(res.x, x_star, atol=1e-5 * max(1.0, np.abs(x_star).max()))
    assert abs(res.fun - f_star) <= 1e-7 * max(1.0, abs(f_star))
    assert res.iterations <= 30
    viol, stat, comp = _kkt(objective, constraints, bounds, res)
    assert viol <= 1e-7 and stat <= 1e-6 and comp <= 1e-6
    assert np.all(res.multipliers >= 0)


def test_convex_projection_onto_a_ball_is_exact():
    """min ||x - p||^2 / 2 s.t. 1 - ||x||^2 >= 0 has x* = p / ||p|| and lambda* = (||p|| - 1) / 2."""
    p = np.array([3.0, -1.0, 2.0, 0.5, 1.0])
    res = solve_sqp(lambda x: (0.5 * (x - p) @ (x - p), x - p), np.zeros(5),
                    constraints=lambda x: (np.array([1.0 - x @ x]), (-2.0 * x)[None, :]),
                    settings=SQPSettings(tol_optimality=1e-10, tol_feasibility=1e-12, tol_step=1e-14))
    assert res.status is SQPStatus.CONVERGED and res.check(1e-12, 1e-10)
    norm = np.linalg.norm(p)
    np.testing.assert_allclose(res.x, p / norm, atol=1e-9)
    np.testing.assert_allclose(res.multipliers, [(norm - 1) / 2], rtol=1e-9)


# ------------------------------------------------------------ behaviour
@pytest.mark.parametrize("name", ["hs43", "hs100"])
def test_merit_never_increases_across_accepted_iterations(name):
    objective, constraints, x0, bounds, _, _ = HS[name]()
    res = solve_sqp(objective, np.array(x0, dtype=float), constraints=constraints, bounds=bounds)
    h = res.history
    compared = 0
    for prev, cur in zip(h[:-1], h[1:], strict=True):
        if cur.restoration or prev.restoration or cur.penalty > prev.penalty:
            continue  # a larger penalty is a different merit; a smaller one only lowers phi(x_k)
        assert cur.merit <= prev.merit + 1e-12 * max(1.0, abs(prev.merit))
        compared += 1
    assert compared >= len(h) // 2
    # Powell's update: mu falls at most by half per iteration (after a multiplier spike)
    assert all(b.penalty >= 0.5 * a.penalty for a, b in zip(h[:-1], h[1:], strict=True))


def test_second_order_correction_overcomes_the_maratos_effect():
    """N&W Example 15.4 as an inequality: min 2(|x|^2 - 1) - x1 s.t. |x|^2 >= 1, x* = (1, 0).

    Near x*, full SQP steps raise the l1 merit (the constraint's curvature);
    the corrected step is accepted instead and no backtracking is needed.
    """
    def objective(x):
        return 2 * (x @ x - 1) - x[0], np.array([4 * x[0] - 1, 4 * x[1]])

    def constraints(x):
        return np.array([x @ x - 1]), (2 * x)[None, :]

    x0 = np.array([np.cos(0.3), np.sin(0.3)])
    runs = {soc: solve_sqp(objective, x0, constraints=constraints,
                           settings=SQPSettings(second_order_correction=soc)) for soc in (True, False)}
    for res in runs.values():
        assert res.status is SQPStatus.CONVERGED and res.check()
        np.testing.assert_allclose(res.x, [1.0, 0.0], atol=2e-6)
        np.testing.assert_allclose(res.multipliers, [1.5], rtol=1e-5)
    with_soc, without = runs[True].history, runs[False].history
    assert any(r.second_order_correction for r in with_soc)
    assert sum(r.backtracks for r in with_soc) == 0 < sum(r.backtracks for r in without)
    assert len(with_soc) < len(without)


def test_result_checks_itself_and_serialises():
    objective, constraints, x0, bounds, _, _ = HS["hs43"]()
    seen = []
    res = solve_sqp(objective, np.array(x0), constraints=constraints, bounds=bounds, callback=seen.append)
    assert seen == list(res.history) and res.iterations == len(res.history)
    assert res.primal_residual() == res.max_violation <= 1e-7
    assert res.dual_residual() == res.kkt_stationarity <= 1e-6
    assert res.check() and not res.check(tol_optimality=0.0)
    assert not res.x.flags.writeable
    text = json.dumps(res.to_dict(), allow_nan=False)
    assert json.loads(text)["status"] == "converged"
    assert "converged" in res.summary() and res.n_objective_evaluations >= res.iterations
    assert set(res.times) == {"objective", "constraints", "values", "qp", "hessian", "total"}
    assert res.history[-1].step_norm == 0.0  # the last record is the final KKT check


def test_many_far_rows_are_left_out_of_the_qp():
    """2000 rows that never come near 0 (sparse Jacobian): the QP keeps only the one real row."""
    rng = np.random.default_rng(1)
    n, m_far = 6, 2000
    p = np.array([2.0, 2.0, 0, 0, 0, 0])
    a_far = sp.random(m_far, n, density=0.5, random_state=rng, format="csr") * 0.1
    a_real = sp.csr_matrix(np.array([[-1.0, -1, 0, 0, 0, 0]]))
    a = sp.vstack([a_real, a_far], format="csr")
    b = np.concatenate([[1.0], np.full(m_far, 5.0)])

    def constraints(x):
        return b + a @ x, a

    res = solve_sqp(lambda x: (0.5 * (x - p) @ (x - p), x - p), np.zeros(n), constraints=constraints)
    assert res.status is SQPStatus.CONVERGED and res.check()
    np.testing.assert_allclose(res.x, [0.5, 0.5, 0, 0, 0, 0], atol=1e-7)
    assert max(r.n_rows_kept for r in res.history) == 1
    assert np.count_nonzero(res.multipliers) == 1
    np.testing.assert_allclose(res.multipliers[0], 1.5, rtol=1e-6)


def test_infeasible_start_converges_through_restoration():
    """x1 x2 >= 25 from (1, 1): the linearisation is out of reach of the box; x* = (sqrt 50, sqrt 12.5)."""
    def objective(x):
        return x[0] ** 2 + 4 * x[1] ** 2, np.array([2 * x[0], 8 * x[1]])

    def constraints(x):
        return np.array([x[0] * x[1] - 25.0]), np.array([[x[1], x[0]]])

    res = solve_sqp(objective, np.array([1.0, 1.0]), constraints=constraints, bounds=(0, 100))
    assert res.status is SQPStatus.CONVERGED and res.check(), res.summary()
    assert any(r.restoration for r in res.history)
    np.testing.assert_allclose(res.x, [np.sqrt(50), np.sqrt(12.5)], rtol=1e-6)
    assert res.fun == pytest.approx(100.0, rel=1e-8)  # f* moves by lambda* x violation (<= 1e-7)
    json.dumps(res.to_dict(), allow_nan=False)  # NaN stationarity of restoration steps -> None


@pytest.mark.parametrize("case", ["annulus", "linear"])
def test_infeasible_problem_is_reported_infeasible(case):
    if case == "annulus":  # inside the unit disc and outside the radius-2 circle
        def constraints(x):
            r2 = x @ x
            return np.array([1 - r2, r2 - 4]), np.vstack([-2 * x, 2 * x])
        x0 = np.array([1.5, 0.0])
    else:  # x1 >= 1 and x1 <= 0
        def constraints(x):
            return np.array([x[0] - 1, -x[0]]), np.array([[1.0, 0], [-1, 0]])
        x0 = np.array([0.5, 0.5])
    res = solve_sqp(lambda x: (x @ x, 2 * x), x0, constraints=constraints)
    assert res.status is SQPStatus.INFEASIBLE, res.summary()
    assert not res.check() and res.max_violation > 0.1
    assert res.history[-1].restoration


def test_inconsistent_linearisation_within_tolerance_is_stalled_not_infeasible():
    """x >= 0 and x <= -5e-8: infeasible by 5e-8 only, below tol_feasibility 1e-7 (above the QP tolerance)."""
    def constraints(x):
        return np.array([x[0], -x[0] - 5e-8]), np.array([[1.0], [-1.0]])

    res = solve_sqp(lambda x: (float(x @ x), 2 * x), np.array([0.0]), constraints=constraints)
    assert res.status is SQPStatus.STALLED, res.summary()
    assert "feasible to tolerance" in res.message
    assert res.max_violation <= 1e-7


@pytest.mark.parametrize("bounds, x_star, nu", [
    ((-np.inf, [np.inf, np.inf]), [1.0, 1.0], [0.0, 0.0]),  # interior optimum
    (([-np.inf, -1.5], [0.5, np.inf]), [0.5, 0.25], [-1.0, 0.0]),  # upper bound on x1 active
])
def test_rosenbrock_with_bounds(bounds, x_star, nu):
    res = solve_sqp(_rosenbrock, np.array([-1.2, 1.0]), bounds=bounds,
                    settings=SQPSettings(max_iterations=200))
    assert res.status is SQPStatus.CONVERGED and res.check(), res.summary()
    np.testing.assert_allclose(res.x, x_star, atol=1e-6)
    np.testing.assert_allclose(res.bound_multipliers, nu, atol=1e-5)
    assert res.multipliers.shape == (0,)


@pytest.mark.parametrize("name", sorted(HS))
def test_ratio_trust_update_reaches_the_same_optimum(name):
    objective, constraints, x0, bounds, x_star, f_star = HS[name]()
    res = solve_sqp(objective, np.array(x0, dtype=float), constraints=constraints, bounds=bounds,
                    settings=SQPSettings(trust_update="ratio"))
    assert res.status is SQPStatus.CONVERGED and res.check(), res.summary()
    np.testing.assert_allclose(res.x, x_star, atol=1e-5 * max(1.0, np.abs(np.asarray(x_star)).max()))
    assert abs(res.fun - f_star) <= 1e-7 * max(1.0, abs(f_star))


def test_ratio_trust_update_follows_its_rule():
    """Rosenbrock (no rows, so the box is never enlarged within an iteration): after a
    backtracked step the box is at most half the last one, otherwise it is kept or doubled."""
    res = solve_sqp(_rosenbrock, np.array([-1.2, 1.0]),
                    settings=SQPSettings(max_iterations=200, trust_update="ratio", step_bound=1.0))
    assert res.status is SQPStatus.CONVERGED and res.check(), res.summary()
    np.testing.assert_allclose(res.x, [1.0, 1.0], atol=1e-6)
    h = [r for r in res.history if r.step_norm > 0]
    kinds = set()
    for a, b in zip(h[:-1], h[1:], strict=True):
        if a.backtracks:
            assert b.step_bound <= 0.5 * a.step_bound * (1 + 1e-12)
            kinds.add("halved")
        else:
            ratio = b.step_bound / a.step_bound
            assert ratio <= 0.5 * (1 + 1e-12) or ratio in (1.0, 2.0), ratio
            kinds.add({1.0: "kept", 2.0: "doubled"}.get(ratio, "halved"))
    assert {"halved", "kept"} <= kinds  # the rule was exercised, not only one branch


def test_ratio_trust_update_follows_the_agreement(monkeypatch):
    """Each accepted step's agreement rho decides the next box: half the step below 1/4 (a
    backtracked step counts as rho < 0), doubled above 3/4 when the step reached the box, else
    kept (HS problems with rows, each update as the SQP made it)."""
    from calib_oed.solver import iteration
    rhos, updates = [], []
    agreement, update = iteration._Run._agreement, iteration._Run._ratio_update

    def record_rho(self, *a):
        rhos.append(agreement(self, *a))
        return rhos[-1]

    def record_update(self, old, new, d, delta, d_norm, backtracks):
        n = len(rhos)
        out = update(self, old, new, d, delta, d_norm, backtracks)
        updates.append((rhos[-1] if len(rhos) > n else -1.0, delta, d_norm, bool(backtracks), out))
        return out

    monkeypatch.setattr(iteration._Run, "_agreement", record_rho)
    monkeypatch.setattr(iteration._Run, "_ratio_update", record_update)
    for name in sorted(HS):
        objective, constraints, x0, bounds, x_star, f_star = HS[name]()
        res = solve_sqp(objective, np.array(x0, dtype=float), constraints=constraints, bounds=bounds,
                        settings=SQPSettings(trust_update="ratio", step_bound=0.05))
        assert res.status is SQPStatus.CONVERGED and abs(res.fun - f_star) <= 1e-7 * max(1.0, abs(f_star))
    kinds = set()
    for rho, delta, d_norm, backtracked, out in updates:
        assert not backtracked or rho == -1.0
        if rho < 0.25:
            assert out == pytest.approx(max(1e-8, 0.5 * d_norm)), (rho, delta, d_norm)
            kinds.add("halved")
        elif rho > 0.75 and d_norm >= 0.99 * delta:
            assert out == pytest.approx(min(1.0, 2 * delta))
            kinds.add("doubled")
        else:
            assert out == delta
            kinds.add("kept at the box" if d_norm >= 0.99 * delta else "kept")
    # every branch was exercised, a step at the box with rho in [1/4, 3/4] among them
    assert {"halved", "doubled", "kept at the box"} <= kinds


def test_a_penalty_far_above_the_multipliers_makes_the_ratio_rule_creep():
    """Along the inside of the unit circle (an objective 1e-3 small pushing outward), each full
    step to the box leaves a violation of order box squared. The merit charges it at mu, the QP's
    Lagrangian Hessian at the multiplier (about 5e-3): with ``penalty_margin`` 0.1 the difference
    keeps rho below 3/4, the box at 0.003-0.006 and the run creeps along the 2.5 rad of arc to the
    iteration limit; with 1e-3 the box grows and the run converges in about 20 iterations."""
    def objective(x):
        return 1e-3 * (-x[0] - 5 * x @ x), 1e-3 * (np.array([-1.0, 0.0]) - 10 * x)

    def constraints(x):
        return np.array([1 - x @ x]), (-2 * x)[None, :]

    x0 = np.array([np.cos(2.5), np.sin(2.5)])
    runs = {margin: solve_sqp(objective, x0, constraints=constraints,
                              settings=SQPSettings(trust_update="ratio", step_bound=0.003,
                                                   penalty_margin=margin))
            for margin in (0.1, 1e-3)}
    creep, tight = runs[0.1], runs[1e-3]
    assert creep.status is SQPStatus.MAX_ITERATIONS
    assert max(r.step_bound for r in creep.history) <= 0.006
    assert tight.status is SQPStatus.CONVERGED and tight.iterations <= 30
    assert max(r.step_bound for r in tight.history) >= 0.1
    np.testing.assert_allclose(tight.x, [1.0, 0.0], atol=1e-6)
    np.testing.assert_allclose(tight.multipliers, [5.5e-3], rtol=1e-4)  # -df/dc at x*: (1 + 10)/2 * 1e-3


def test_one_penalty_weight_per_row_ends_the_creep_a_large_multiplier_elsewhere_causes():
    """The circle of the test above, with a second, linear row whose multiplier is 100 (f = 100 z,
    z >= 0). One penalty (Powell's mu >= max lambda + margin) charges the circle's second-order
    violation at 100 against its multiplier 5e-3: the ratio rule keeps the box small and the run
    crawls towards x* = (0, 1, 0). Powell's (1978) weights, one per row (mu_i >= lambda_i + margin),
    charge it at 6e-3 and the run converges in a few iterations, with or without the exact Hessian."""
    def objective(x):
        return -0.01 * x[1] + 100 * x[2], np.array([0.0, -0.01, 100.0])

    def constraints(x):
        return np.array([x[2], 1 - x[0] ** 2 - x[1] ** 2]), np.array([[0.0, 0.0, 1.0], [-2 * x[0], -2 * x[1], 0.0]])

    def hessian(x, lam):
        return StructuredHessian(np.diag([2 * lam[1], 2 * lam[1], 0.0])[None])

    runs = {(w, exact): solve_sqp(objective, np.array([1.0, 0.0, 0.0]), constraints=constraints,
                                  lagrangian_hessian=hessian if exact else None,
                                  settings=SQPSettings(trust_update="ratio", penalty_margin=1e-3,
                                                       penalty_weights=w))
            for w in ("single", "row") for exact in (False, True)}
    for exact in (False, True):
        res = runs["row", exact]
        assert res.status is SQPStatus.CONVERGED and res.check(), res.summary()
        assert res.iterations <= 15
        np.testing.assert_allclose(res.x, [0.0, 1.0, 0.0], atol=1e-6)
        np.testing.assert_allclose(res.multipliers, [100.0, 5e-3], rtol=1e-6)
        assert res.history[-1].penalty >= 100.0  # the record's penalty: the largest weight
    single = runs["single", True]
    assert single.iterations >= 4 * runs["row", True].iterations
    assert abs(single.x[0]) > 1e-3  # stopped by the scaled stationarity test short of x*


@pytest.mark.parametrize("name", sorted(HS))
def test_one_penalty_weight_per_row_reaches_the_same_optimum(name):
    objective, constraints, x0, bounds, x_star, f_star = HS[name]()
    res = solve_sqp(objective, np.array(x0, dtype=float), constraints=constraints, bounds=bounds,
                    settings=SQPSettings(trust_update="ratio", penalty_weights="row"))
    assert res.status is SQPStatus.CONVERGED and res.check(), res.summary()
    np.testing.assert_allclose(res.x, x_star, atol=1e-5 * max(1.0, np.abs(np.asarray(x_star)).max()))
    assert abs(res.fun - f_star) <= 1e-7 * max(1.0, abs(f_star))


def test_a_lagged_exact_hessian_is_computed_every_k_th_point_and_converges():
    """``hessian_every = k``: ``lagrangian_hessian`` is called at the start and at every k-th accepted
    point only (the QPs between take the last one); the run still reaches Rosenbrock's minimum."""
    def objective(x):
        return 100 * (x[1] - x[0] ** 2) ** 2 + (1 - x[0]) ** 2, np.array(
            [-400 * x[0] * (x[1] - x[0] ** 2) - 2 * (1 - x[0]), 200 * (x[1] - x[0] ** 2)])

    runs = {}
    for every in (1, 3):
        seen = []

        def hessian(x, lam, seen=seen):
            seen.append(x.copy())
            return StructuredHessian(np.array([[[1200 * x[0] ** 2 - 400 * x[1] + 2, -400 * x[0]],
                                                 [-400 * x[0], 200.0]]]))

        res = solve_sqp(objective, np.array([-1.2, 1.0]), lagrangian_hessian=hessian,
                        settings=SQPSettings(hessian_every=every, trust_update="ratio"))
        assert res.status is SQPStatus.CONVERGED and res.check(), res.summary()
        np.testing.assert_allclose(res.x, [1.0, 1.0], atol=1e-6)
        runs[every] = (res, seen)
    (res, seen), (lagged, seen3) = runs[1], runs[3]
    # points 0..A (A accepted steps; the last record, the KKT check, solves a QP at the last one)
    accepted = [sum(r.step_norm > 0 for r in run.history) for run in (res, lagged)]
    assert len(seen) == accepted[0] + 1  # every point
    assert len(seen3) == accepted[1] // 3 + 1 and np.array_equal(seen3[0], [-1.2, 1.0])  # 0, 3, 6, ...


def test_max_iterations_is_reported():
    res = solve_sqp(_rosenbrock, np.array([-1.2, 1.0]), settings=SQPSettings(max_iterations=3))
    assert res.status is SQPStatus.MAX_ITERATIONS and res.iterations == 3 and not res.check()


@pytest.mark.parametrize("name", ["hs43", "hs76"])
def test_dense_and_sparse_qp_backends_agree(name):
    objective, constraints, x0, bounds, _, _ = HS[name]()
    results = [solve_sqp(objective, np.array(x0), constraints=constraints, bounds=bounds,
                         settings=SQPSettings(qp_backend=b)) for b in ("dense", "sparse")]
    assert all(r.status is SQPStatus.CONVERGED for r in results)
    np.testing.assert_allclose(results[0].x, results[1].x, atol=1e-7)
    np.testing.assert_allclose(results[0].multipliers, results[1].multipliers, atol=1e-6)


def test_agrees_with_scipy_slsqp_on_a_random_smooth_problem():
    """Strictly convex objective, four ball constraints containing 0, bounds: one optimum."""
    rng = np.random.default_rng(7)
    n = 6
    g0 = rng.standard_normal((n, n))
    q_mat = g0 @ g0.T / n + 0.5 * np.eye(n)
    q = 3 * rng.standard_normal(n)
    centres = 0.3 * rng.standard_normal((4, n))
    radii = np.linalg.norm(centres, axis=1) + rng.uniform(0.8, 1.5, 4)
    lb, ub = np.full(n, -0.9), np.full(n, 0.9)

    def objective(x):
        return 0.5 * x @ q_mat @ x + q @ x + 0.1 * np.sum(x**4), q_mat @ x + q + 0.4 * x**3

    def constraints(x):
        diff = x - centres
        return radii**2 - np.sum(diff**2, axis=1), -2 * diff

    res = solve_sqp(objective, np.zeros(n), constraints=constraints, bounds=(lb, ub))
    ref = scipy.optimize.minimize(
        lambda x: objective(x)[0], np.zeros(n), jac=lambda x: objective(x)[1], method="SLSQP",
        bounds=list(zip(lb, ub, strict=True)),
        constraints=[{"type": "ineq", "fun": lambda x: constraints(x)[0],
                      "jac": lambda x: constraints(x)[1]}],
        options={"ftol": 1e-14, "maxiter": 500})
    assert ref.success and res.status is SQPStatus.CONVERGED and res.check()
    assert np.count_nonzero(res.multipliers) + np.count_nonzero(res.bound_multipliers) >= 2
    np.testing.assert_allclose(res.x, ref.x, atol=1e-6)
    assert res.fun == pytest.approx(ref.fun, abs=1e-9)


# ------------------------------------------------------------ errors
@pytest.mark.parametrize("field, value", [
    ("max_iterations", 0), ("max_iterations", 2.5), ("tol_optimality", -1.0),
    ("tol_feasibility", float("nan")), ("step_bound", 2.0), ("min_step_bound", 0.0),
    ("active_margin", -0.1), ("bfgs_damping", 1.0), ("armijo", 0.6), ("backtrack", 1.5),
    ("max_backtracks", -1), ("qp_polish", "yes"), ("step_bound_ratio", 0.5),
    ("qp_eps_abs", 0.0), ("qp_backend", "osqp"), ("trust_update", "nocedal"),
    ("penalty_weights", "each"), ("hessian_every", 0),
])
def test_bad_settings_raise_clear_errors(field, value):
    with pytest.raises(SQPSettingsError, match=field) as info:
        SQPSettings(**{field: value})
    assert isinstance(info.value, ValueError) and info.value.name == field
    if field in ("qp_backend", "trust_update", "penalty_weights"):
        assert info.value.valid and all(repr(v) in str(info.value) for v in info.value.valid)


def test_bad_problem_data_raise_clear_errors():
    quad = lambda x: (x @ x, 2 * x)  # noqa: E731
    with pytest.raises(ShapeError):
        solve_sqp(quad, np.zeros((2, 2)))
    with pytest.raises(NonFiniteError):
        solve_sqp(quad, np.array([np.nan, 0.0]))
    with pytest.raises(SQPProblemError, match="lb > ub"):
        solve_sqp(quad, np.zeros(2), bounds=([0, 1], [1, 0]))
    with pytest.raises(ShapeError):
        solve_sqp(quad, np.zeros(2), bounds=([0, 0, 0], 1))
    with pytest.raises(ShapeError, match="gradient"):
        solve_sqp(lambda x: (0.0, np.zeros(3)), np.zeros(2))
    with pytest.raises(ShapeError, match="Jacobian"):
        solve_sqp(quad, np.zeros(2), constraints=lambda x: (np.zeros(1), np.zeros((1, 3))))
    with pytest.raises(NonFiniteError):
        solve_sqp(lambda x: (np.inf, 2 * x), np.zeros(2))


# ------------------------------------------------------------ pieces
def test_damped_bfgs_keeps_positive_definite_and_meets_the_secant_condition():
    rng = np.random.default_rng(0)
    b = np.eye(4)
    s = rng.standard_normal(4)
    y = -s  # negative curvature: damping must step in
    b1 = damped_bfgs_update(b, s, y, 0.2)
    assert np.linalg.eigvalsh(b1).min() > 0
    y = 2 * s + 0.1 * rng.standard_normal(4)  # s^T y > 0.2 s^T B s: plain BFGS
    b2 = damped_bfgs_update(b, s, y, 0.2)
    np.testing.assert_allclose(b2 @ s, y, atol=1e-12)
    np.testing.assert_allclose(b2, b2.T)


def _random_qp(rng, n=12, k=8):
    g0 = rng.standard_normal((n, n))
    c = np.zeros((k, n))
    for i in range(k):  # block pattern: each row touches 3 consecutive variables
        j = rng.integers(0, n - 3)
        c[i, j:j + 3] = rng.standard_normal(3)
    return QPSubproblem(g0 @ g0.T / n + np.eye(n), rng.standard_normal(n), c,
                        -rng.uniform(0.0, 0.2, k), np.full(n, -0.3), np.full(n, 0.3))


@pytest.mark.parametrize("workspace", [DenseQPWorkspace, SparseQPWorkspace])
def test_qp_workspaces_solve_a_sequence_of_varying_size(workspace):
    """Reuse across QPs whose row count grows and shrinks; each is a KKT point of its QP."""
    rng = np.random.default_rng(3)
    ws = workspace(12, 1e-9, 1000)
    lam = None
    for k in (8, 2, 40, 3, 0, 9):
        sub = _random_qp(rng, k=k)
        step = ws.solve(sub, None, None if lam is None or lam.size != k else lam, None)
        lam = step.lam
        assert step.is_solved(1e-8, 1e-7), step
        assert np.all(step.lam >= 0)
        exact = polish(sub, step, 1e-9)
        assert exact is not None and exact.polished
        np.testing.assert_allclose(step.d, exact.d, atol=1e-7)


@pytest.mark.parametrize("workspace", [DenseQPWorkspace, SparseQPWorkspace])
def test_qp_warm_start_takes_effect(workspace):
    """Re-solving a QP from its own solution takes at most one ProxQP iteration."""
    sub = _random_qp(np.random.default_rng(11), n=30, k=25)
    ws = workspace(30, 1e-9, 1000)
    cold = ws.solve(sub)
    assert cold.iterations >= 5
    warm = ws.solve(sub, cold.d, cold.lam, cold.nu)
    assert warm.is_solved(1e-8, 1e-7) and warm.iterations <= 1
    duals_only = ws.solve(sub, None, cold.lam, cold.nu)  # what solve_sqp passes
    assert duals_only.is_solved(1e-8, 1e-7)
    np.testing.assert_allclose(duals_only.d, cold.d, atol=1e-7)


def test_dense_workspace_recovers_from_a_misleading_warm_start():
    """ProxQP can stop at once on wrong warm-start duals; the residual check sees it."""
    rng = np.random.default_rng(5)
    sub = _random_qp(rng)
    ws = DenseQPWorkspace(12, 1e-9, 1000)
    good = ws.solve(sub)
    bad = ws.solve(sub, None, np.full(8, 5.0), np.full(12, -3.0))
    if not bad.is_solved(1e-8, 1e-7):  # detected: a cold solve fixes it
        bad = ws.solve(sub)
    np.testing.assert_allclose(bad.d, good.d, atol=1e-7)


def test_unreachable_rows_are_found_without_solving():
    c = sp.csr_matrix(np.array([[1.0, -2.0], [1.0, 1.0], [0.0, 0.0]]))
    lower = np.array([0.5, 2.5, 0.0])  # row 0 reaches 0.9, row 1 reaches 0.6, row 2 holds
    bl, bu = np.array([-0.3, -0.3]), np.array([0.3, 0.3])
    assert unreachable_rows(c, lower, bl, bu, 1e-12).tolist() == [1]
    assert unreachable_rows(c.toarray(), lower, bl, bu, 1e-12).tolist() == [1]
    # infinite box sides: any row with a nonzero is reachable
    assert unreachable_rows(c, lower, np.full(2, -np.inf), np.full(2, np.inf), 0.0).size == 0


def test_time_limit_stops_with_its_status():
    def slow_rosenbrock(x):
        import time

        time.sleep(0.02)
        a, b = x
        f = (1 - a) ** 2 + 100 * (b - a**2) ** 2
        return f, np.array([-2 * (1 - a) - 400 * a * (b - a**2), 200 * (b - a**2)])

    res = solve_sqp(slow_rosenbrock, np.array([-1.2, 1.0]), settings=SQPSettings(time_limit=0.1))
    assert res.status == SQPStatus.TIME_LIMIT and res.iterations < 10
    assert "wall-clock" in res.message
    with pytest.raises(SQPSettingsError):
        SQPSettings(time_limit=0)


def test_ctrl_c_returns_the_last_accepted_iterate_with_status_interrupted():
    """A KeyboardInterrupt during an iteration (here raised by the callback at iteration 3)
    ends the run with status ``interrupted`` and the iterate the run had accepted."""
    seen = []

    def callback(record):
        seen.append(record)
        if record.iteration == 3:
            raise KeyboardInterrupt

    res = solve_sqp(_rosenbrock, np.array([-1.2, 1.0]), callback=callback)
    assert res.status is SQPStatus.INTERRUPTED and "iteration 3" in res.message
    assert res.iterations == 4 and len(seen) == 4
    assert res.fun == pytest.approx(_rosenbrock(res.x)[0])
    assert res.fun < _rosenbrock(np.array([-1.2, 1.0]))[0]  # progress so far is kept
