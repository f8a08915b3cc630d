"""calib_oed.solver.polish: the QP's solution from a guessed active set (from_active_set).

A strictly convex QP with a box and general rows, solved by ProxQP (dense workspace) and polished:
the reference. The active set the reference's multipliers name gives that point in one KKT solve;
a guess with a row too many, a row too few and a wrong bound is repaired in a few rounds (rows it
violates join, wrong-signed multipliers leave), and refused (``None``) when the rounds run out.
In the SQP the start leaves the optimum where it was and spares ProxQP most calls.
"""

from __future__ import annotations

import numpy as np
import pytest

from calib_oed.solver.polish import from_active_set, polish
from calib_oed.solver.qp import DenseQPWorkspace, QPSubproblem
from calib_oed.solver.sqp import SQPSettings, SQPStatus, solve_sqp

TOL = 1e-9


def _qp(seed=0, blocks=10, size=6, rows=3, coupled=False):
    """Per-pose structure as in the design SQP: a block-diagonal :math:`H`, each row on one block;
    ``coupled``: every row on every variable instead (a dense random QP)."""
    rng = np.random.default_rng(seed)
    n, k = blocks * size, blocks * rows
    H = np.zeros((n, n))
    C = np.zeros((k, n))
    for b in range(blocks):
        a = rng.standard_normal((size, size))
        H[b * size:(b + 1) * size, b * size:(b + 1) * size] = a @ a.T / size + np.eye(size)
        C[b * rows:(b + 1) * rows, b * size:(b + 1) * size] = rng.standard_normal((rows, size))
    if coupled:
        C = rng.standard_normal((k, n))
    g = rng.standard_normal(n)
    lower = -np.abs(rng.standard_normal(k)) * 0.2  # d = 0 feasible
    box = np.full(n, 1.0)
    return QPSubproblem(H, g, C, lower, -box, box)


def _reference(sub):
    step = DenseQPWorkspace(sub.g.size, TOL, 1000, capacity=2 * sub.lower.size).solve(sub)
    exact = polish(sub, step, 10 * TOL)
    assert exact is not None
    act, lo, up = exact.lam > 0, exact.nu > 0, exact.nu < 0
    assert act.sum() >= 3 and (lo | up).sum() >= 3 and (~(lo | up)).sum() >= 3  # a QP with all three kinds
    return exact


def test_the_active_set_of_the_solution_gives_the_solution_in_one_solve():
    sub = _qp(1)
    ref = _reference(sub)
    step = from_active_set(sub, ref.lam, ref.nu, 10 * TOL, rounds=1)
    assert step is not None and step.polished and step.iterations == 0 and step.status == "solved"
    assert step.is_solved(10 * TOL, 10 * TOL)
    np.testing.assert_allclose(step.d, ref.d, atol=1e-10)
    np.testing.assert_allclose(step.lam, ref.lam, atol=1e-8)
    np.testing.assert_allclose(step.nu, ref.nu, atol=1e-8)


@pytest.mark.parametrize("seed", [1, 2, 3, 4])
def test_a_wrong_guess_is_repaired_in_a_few_rounds(seed):
    sub = _qp(seed)
    ref = _reference(sub)
    lam, nu = ref.lam.copy(), ref.nu.copy()
    lam[np.flatnonzero(lam > 0)[0]] = 0.0  # an active row left out
    lam[np.flatnonzero(ref.lam == 0)[-1]] = 1.0  # an inactive row put in
    nu[np.flatnonzero(ref.nu == 0)[1]] = 1.0  # a free component put on its lower bound
    assert from_active_set(sub, lam, nu, 10 * TOL, rounds=1) is None  # one round cannot fix it
    step = from_active_set(sub, lam, nu, 10 * TOL, rounds=5)
    assert step is not None and step.is_solved(10 * TOL, 10 * TOL)
    np.testing.assert_allclose(step.d, ref.d, atol=1e-10)


def test_a_guess_it_cannot_repair_is_refused_not_answered():
    """Every row on every variable: one wrong row moves the whole point. Within its rounds the
    repair gives the solution or nothing, never another point."""
    answers = []
    for seed in range(4):
        sub = _qp(seed, coupled=True)
        sub = sub._replace(g=2.0 * sub.g)
        ref = _reference(sub)
        lam, nu = ref.lam.copy(), ref.nu.copy()
        lam[np.flatnonzero(lam > 0)[0]] = 0.0
        lam[np.flatnonzero(ref.lam == 0)[0]] = 1.0
        nu[np.flatnonzero(ref.nu == 0)[0]] = 1.0
        for rounds in (3, 5, 8):
            step = from_active_set(sub, lam, nu, 10 * TOL, rounds=rounds)
            answers.append(step is not None)
            if step is not None:
                np.testing.assert_allclose(step.d, ref.d, atol=1e-10)
        assert from_active_set(sub, ref.lam, ref.nu, 10 * TOL) is not None
    assert 0 < sum(answers) < len(answers)  # both outcomes occur


def test_the_empty_guess_is_the_unconstrained_minimiser_when_that_is_feasible():
    sub = _qp(1)
    far = sub._replace(lower=np.full(sub.lower.size, -1e3), box_lower=np.full(sub.g.size, -1e3),
                       box_upper=np.full(sub.g.size, 1e3))
    step = from_active_set(far, np.zeros(far.lower.size), None, 10 * TOL)
    np.testing.assert_allclose(step.d, np.linalg.solve(far.H, -far.g), atol=1e-10)
    assert not step.lam.any() and not step.nu.any()


def _hs76():
    """Hock-Schittkowski 76: a convex quadratic with three linear rows; f* = -4.681818..."""
    Q = np.array([[2.0, 0, -1, 0], [0, 1, 0, 0], [-1, 0, 2, 1], [0, 0, 1, 1]])
    q = np.array([-1.0, -3, 1, -1])
    A = np.array([[-1.0, -2, -1, -1], [-3, -1, -2, 1], [0, 1, 4, 0]])
    b = np.array([-5.0, -4, 1.5])

    def objective(x):
        return 0.5 * x @ Q @ x + q @ x, Q @ x + q

    def constraints(x):
        return A @ x - b, A

    return objective, constraints


def test_the_sqp_reaches_the_same_optimum_with_fewer_proxqp_calls(monkeypatch):
    calls = []
    solve = DenseQPWorkspace.solve

    def counted(self, *a, **kw):
        calls.append(1)
        return solve(self, *a, **kw)

    monkeypatch.setattr(DenseQPWorkspace, "solve", counted)
    objective, constraints = _hs76()
    runs = {}
    for on in (False, True):
        calls.clear()
        res = solve_sqp(objective, np.full(4, 0.5), bounds=(np.zeros(4), np.full(4, np.inf)),
                        constraints=constraints, settings=SQPSettings(qp_active_set_start=on))
        assert res.status is SQPStatus.CONVERGED and res.check(), res.summary()
        runs[on] = (res, len(calls))
    np.testing.assert_allclose(runs[True][0].x, runs[False][0].x, atol=1e-7)
    assert runs[True][0].fun == pytest.approx(-4.681818181, abs=1e-7)
    assert runs[True][1] < runs[False][1], (runs[True][1], runs[False][1])


def test_the_setting_must_be_a_bool():
    from calib_oed.solver.sqp import SQPSettingsError
    with pytest.raises(SQPSettingsError, match="qp_active_set_start"):
        SQPSettings(qp_active_set_start=1)
