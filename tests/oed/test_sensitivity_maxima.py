"""The column generation's local maximisation: its curvature, its end values, its starts, and why a round
may reuse one."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from conftest import central_difference, relative_error

from calib_oed.feasibility.sampling import sample_feasible
from calib_oed.oed import sensitivity_maxima as sm
from calib_oed.oed.approximate import information, solve_approximate
from calib_oed.oed.objective import DesignObjective
from calib_oed.oed.problem import DesignProblem


@pytest.fixture(scope="module")
def objective(kr16):
    return DesignObjective(kr16.problem, "kpi")


@pytest.fixture(scope="module")
def search_start(kr16, objective):
    pool = sample_feasible(kr16.feasibility, 200, 7)
    blocks = objective.compute_blocks(pool)
    return pool, blocks, solve_approximate(blocks, objective.criterion)


def four_starts(objective, search_start):
    """The approximate design of the search start, its sensitivity's gradient and four spread starts."""
    pool, blocks, approx = search_start
    gamma = objective.criterion.compute_gradient(information(blocks, approx.weights))
    return approx, gamma, pool[sm.spread_starts(pool, approx.sensitivities, 4)]


def test_end_values_are_those_at_the_end_points(kr16, objective, search_start):
    """The values the SQP saw last are reused only at exactly its end point: recomputed, they agree."""
    pool, blocks, approx = search_start
    gamma = objective.criterion.compute_gradient(information(blocks, approx.weights))
    idx = sm.spread_starts(pool, approx.sensitivities, 3)
    loc = sm.maximise_sensitivity(kr16, objective, gamma, pool[idx], approx.mean_sensitivity,
                                  max_iterations=15)
    d, _ = sm.sensitivity_field(objective, gamma, loc.q)
    np.testing.assert_allclose(loc.values, d, rtol=1e-12)
    np.testing.assert_allclose(loc.start_values, approx.sensitivities[idx], rtol=1e-9)
    nlp = DesignProblem(objective, kr16.feasibility, len(idx))
    rows, _ = nlp.compute_constraint_rows(loc.q.ravel(), jacobian=False)
    lo, hi = nlp.bounds
    x = loc.q.ravel()
    viol = np.maximum.reduce([np.zeros(len(idx)), -rows.min(axis=1),
                              (lo - x).reshape(len(idx), -1).max(axis=1),
                              (x - hi).reshape(len(idx), -1).max(axis=1)])
    np.testing.assert_allclose(loc.violation, viol, rtol=0, atol=1e-15)


def test_greedy_starts_are_separated_and_extend_each_other(search_start):
    """``spread_starts``: the largest values, pairwise at least START_SEPARATION apart, each skipped candidate
    too close to a chosen one of larger value; the 2k starts of a verification begin with the k of the
    round before it (what lets that round reuse the maxima from them)."""
    pool, _, approx = search_start
    v = approx.sensitivities
    k = 6
    few, many = sm.spread_starts(pool, v, k), sm.spread_starts(pool, v, 2 * k)
    assert few.size == k and many.size == 2 * k
    np.testing.assert_array_equal(many[:k], few)
    assert np.all(np.diff(v[many]) <= 0)
    gaps = np.max(np.abs(pool[many][:, None] - pool[many][None]), axis=2)
    assert np.all(gaps[~np.eye(2 * k, dtype=bool)] >= sm.START_SEPARATION)
    for i in np.flatnonzero(v > v[many[-1]]):
        if i not in many:  # skipped: a chosen start of larger value lies within the separation
            near = many[v[many] >= v[i]]
            assert np.min(np.max(np.abs(pool[near] - pool[i]), axis=1)) < sm.START_SEPARATION


def test_maximising_again_from_the_same_starts_finds_the_same_maxima(kr16, objective, search_start):
    """One approximate design, the same starts: the same maxima, so a round may reuse them."""
    pool, blocks, approx = search_start
    gamma = objective.criterion.compute_gradient(information(blocks, approx.weights))
    starts = pool[sm.spread_starts(pool, approx.sensitivities, 2)]
    first, again = (sm.maximise_sensitivity(kr16, objective, gamma, starts, approx.mean_sensitivity,
                                            max_iterations=15) for _ in range(2))
    np.testing.assert_allclose(again.q, first.q, rtol=0, atol=1e-9)
    np.testing.assert_allclose(again.values, first.values, rtol=1e-9)
    assert np.all(first.values >= first.start_values)  # a maximisation: no pose got worse


# ------------------------------------------------------------------ curvature
@pytest.mark.parametrize("name", ["kpi", "params", "D"])
def test_sensitivity_hessian_matches_central_differences(kr16, search_start, name):
    """Per pose, the Hessian of d is the central difference of its exact gradient, and symmetric."""
    pool, blocks, approx = search_start
    objective = DesignObjective(kr16.problem, name)
    gamma = objective.criterion.compute_gradient(objective.information(blocks[:40]))
    q = pool[100:103]
    hess = sm.sensitivity_hessian(objective, gamma, q)
    assert hess.shape == (3, q.shape[1], q.shape[1])
    np.testing.assert_allclose(hess, np.transpose(hess, (0, 2, 1)), rtol=0, atol=1e-12 * np.abs(hess).max())
    for j in range(q.shape[0]):
        def grad(x, j=j):
            qq = q.copy()
            qq[j] = x
            return sm.sensitivity_field(objective, gamma, qq)[1][j]

        assert relative_error(hess[j], central_difference(grad, q[j])) < 1e-6


def test_row_derivatives_and_hessians_at_one_point_share_one_evaluation(kr16, search_start):
    """The state kept for the last q gives the same bits as a fresh objective, whatever came before."""
    pool = search_start[0]
    a, b = pool[:4], pool[4:8]
    kept = DesignObjective(kr16.problem, "kpi")
    kept.compute_row_hessians(a)
    kept.compute_row_derivatives(b)
    for q in (a, b, a):
        fresh = DesignObjective(kr16.problem, "kpi")
        for got, want in zip(kept.compute_row_derivatives(q), fresh.compute_row_derivatives(q), strict=True):
            np.testing.assert_array_equal(got, want)
        np.testing.assert_array_equal(kept.compute_row_hessians(q), fresh.compute_row_hessians(q))


@pytest.mark.parametrize("exact", [True, False])
def test_trial_points_by_values_alone_give_the_same_maxima_bit_for_bit(kr16, objective, search_start, exact):
    """The line search's trial points are evaluated without derivatives (``values`` of the SQP):
    every iterate, and so every maximum, is that of the full evaluations."""
    pool, blocks, approx = search_start
    gamma = objective.criterion.compute_gradient(information(blocks, approx.weights))
    starts = pool[sm.spread_starts(pool, approx.sensitivities, 4)]
    runs = []
    real = sm.solve_sqp

    def spy(*args, drop=False, **kwargs):
        if drop:
            kwargs.pop("values")
        res = real(*args, **kwargs)
        runs.append(res)
        return res

    with pytest.MonkeyPatch.context() as mp:
        for drop in (True, False):
            mp.setattr(sm, "solve_sqp", lambda *a, drop=drop, **kw: spy(*a, drop=drop, **kw))
            runs.append(sm.maximise_sensitivity(kr16, objective, gamma, starts, approx.mean_sensitivity,
                                                exact=exact, max_iterations=25))
    full, full_loc, cheap, cheap_loc = runs
    assert full.n_value_evaluations == 0 and cheap.n_value_evaluations > 0
    assert cheap.n_objective_evaluations < full.n_objective_evaluations
    assert [(r.objective, r.step_norm) for r in full.history] == [(r.objective, r.step_norm) for r in cheap.history]
    for field in ("q", "values", "violation"):
        np.testing.assert_array_equal(getattr(full_loc, field), getattr(cheap_loc, field))


def test_exact_curvature_reaches_the_maxima_in_fewer_iterations(kr16, objective, search_start):
    """With the exact Lagrangian Hessian the maximisation ends at a KKT point, feasible and no pose worse
    than its start, in fewer SQP iterations than with per-pose BFGS blocks; it never falls back to BFGS."""
    approx, gamma, starts = four_starts(objective, search_start)
    calls = []
    real = sm.solve_sqp

    def spy(*args, **kwargs):
        res = real(*args, **kwargs)
        calls.append(res)
        return res

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(sm, "solve_sqp", spy)
        exact, bfgs = (sm.maximise_sensitivity(kr16, objective, gamma, starts, approx.mean_sensitivity,
                                               exact=e) for e in (True, False))
    assert calls[0].hessian_fallbacks == 0
    for loc in (exact, bfgs):
        assert loc.status == "converged" and np.all(loc.feasible)
        assert np.all(loc.values >= loc.start_values)
    assert exact.iterations < bfgs.iterations


def test_a_chunk_that_could_not_move_is_run_again_one_start_at_a_time(kr16, objective, search_start,
                                                                     monkeypatch):
    """A chunk's SQP that stops at its starts without converging (its first QP failed) is split: each
    start alone finds its maximum, as it does on its own, instead of the round ending on the starts."""
    pool, blocks, approx = search_start
    gamma = objective.criterion.compute_gradient(information(blocks, approx.weights))
    starts = pool[sm.spread_starts(pool, approx.sensitivities, 3)]
    real = sm.solve_sqp

    def failing_first_qp(objective_fn, x0, **kwargs):  # several poses: stopped where it began
        if x0.size == starts.shape[1]:
            return real(objective_fn, x0, **kwargs)
        res = real(objective_fn, x0, **{**kwargs, "settings": sm.SQPSettings(max_iterations=1)})
        return dataclasses.replace(res, x=np.array(x0, dtype=float), status=sm.SQPStatus.STALLED)

    alone = [sm.maximise_sensitivity(kr16, objective, gamma, q[None], approx.mean_sensitivity) for q in starts]
    monkeypatch.setattr(sm, "solve_sqp", failing_first_qp)
    loc = sm._maximise_in_chunks(kr16, objective, gamma, starts, approx.mean_sensitivity, sm.LOCAL_CHUNK)
    assert loc.q.shape == starts.shape and not np.array_equal(loc.q, starts)
    for j, one in enumerate(alone):
        np.testing.assert_array_equal(loc.q[j], one.q[0])
        assert loc.values[j] == one.values[0] >= one.start_values[0]



def test_the_start_search_from_the_last_active_set_finds_the_maxima_of_proxqp_alone(kr16, objective, search_start,
                                                                                    monkeypatch):
    """The design's start (BFGS, ``exact=False``) solves its QPs from the last active set first
    (``qp_active_set_start``): the maxima are those the search finds with ProxQP alone."""
    from calib_oed.solver import subproblem
    from calib_oed.solver.sqp import SQPSettings

    approx, gamma, starts = four_starts(objective, search_start)
    used = []
    real = sm.solve_sqp

    def seen(*args, **kwargs):
        used.append(kwargs["settings"].qp_active_set_start)
        return real(*args, **kwargs)

    answered = []
    guess = subproblem.from_active_set

    def counted(*args, **kwargs):
        step = guess(*args, **kwargs)
        answered.append(step is not None)
        return step

    monkeypatch.setattr(sm, "solve_sqp", seen)
    monkeypatch.setattr(subproblem, "from_active_set", counted)
    kept = sm.maximise_sensitivity(kr16, objective, gamma, starts, approx.mean_sensitivity, exact=False)
    assert sum(answered) > 0  # some QPs answered from the last active set, without ProxQP
    monkeypatch.setattr(sm, "SQPSettings", lambda **kw: SQPSettings(**{**kw, "qp_active_set_start": False}))
    plain = sm.maximise_sensitivity(kr16, objective, gamma, starts, approx.mean_sensitivity, exact=False)
    assert used == [True, False]
    np.testing.assert_allclose(kept.q, plain.q, rtol=0, atol=1e-9)
    np.testing.assert_allclose(kept.values, plain.values, rtol=1e-9)
    assert kept.status == plain.status and kept.iterations == plain.iterations
