"""The column generation's local maximisation: its end values, its starts, and why a round may reuse one."""

from __future__ import annotations

import numpy as np
import pytest

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
