"""The column generation's local maximisation: its end values, and the maximisations it reuses."""

from __future__ import annotations

import numpy as np
import pytest

from calib_oed.calibration.workflow import setup
from calib_oed.feasibility.sampling import sample_feasible
from calib_oed.oed import sensitivity_maxima as sm
from calib_oed.oed.approximate import information, solve_approximate
from calib_oed.oed.objective import DesignObjective
from calib_oed.oed.problem import DesignProblem
from calib_oed.scene.reader import load_scene


@pytest.fixture(scope="module")
def kr16():
    return setup(load_scene("fms_kr16"))


@pytest.fixture(scope="module")
def objective(kr16):
    return DesignObjective(kr16.problem, "kpi")


@pytest.fixture(scope="module")
def search_start(kr16, objective):
    pool = sample_feasible(kr16.feasibility, 200, 7)
    blocks = objective.compute_blocks(pool)
    return pool, blocks, solve_approximate(blocks, objective.criterion)


def _fresh(search_start):
    pool, blocks, approx = search_start
    return sm._Search(pool.copy(), blocks.copy(), approx, approx.iterations)


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


def _round(approx, n_cand, starts):
    k = len(starts)
    dummy = sm.LocalMaxima(np.zeros((k, 6)), np.zeros(k), np.zeros(k), np.zeros(k), "converged", 1, 0.0)
    return sm._Round(approx, n_cand, np.asarray(starts, dtype=np.intp), dummy)


def test_reuse_only_for_the_same_design_candidates_and_leading_chunks(objective, search_start):
    search = _fresh(search_start)
    n = len(search.cand)
    idx = np.array([5, 9, 2, 7, 11, 3])
    assert sm._reusable(None, search, idx, 2) == 0
    assert sm._reusable(_round(search.approx, n, [5, 9]), search, idx, 2) == 2
    assert sm._reusable(_round(search.approx, n, [5, 9, 2, 7]), search, idx, 2) == 4
    # another approximate design (a re-solve: new Γ and d̄), even with equal weights
    other = solve_approximate(search.blocks, objective.criterion)
    assert sm._reusable(_round(other, n, [5, 9]), search, idx, 2) == 0
    assert sm._reusable(_round(search.approx, n + 1, [5, 9]), search, idx, 2) == 0  # candidates grew
    assert sm._reusable(_round(search.approx, n, [9, 5]), search, idx, 2) == 0  # other starts
    assert sm._reusable(_round(search.approx, n, [5]), search, idx, 2) == 0  # not a whole chunk
    assert sm._reusable(_round(search.approx, n, [5, 9, 2, 7, 11, 3, 1, 0]), search, idx, 2) == 0


def _counting(monkeypatch):
    calls = []
    real = sm.maximise_sensitivity

    def counted(setup_, objective_, gamma, starts, scale, **kwargs):
        calls.append(np.array(starts, copy=True))
        return real(setup_, objective_, gamma, starts, scale, **kwargs)

    monkeypatch.setattr(sm, "maximise_sensitivity", counted)
    return calls


def _search(kr16, objective, search, **kwargs):
    args = dict(starts=2, verify_starts=4, rounds=2, iterations=15, collisions=True, tol=1e-4,
                local_tol=1e-3, max_iterations=200)
    args.update(kwargs)
    return sm._local_search(kr16, objective, search, **args)


def test_verification_reuses_the_round_before_it(kr16, objective, search_start, monkeypatch):
    monkeypatch.setattr(sm, "LOCAL_CHUNK", 2)
    calls = _counting(monkeypatch)
    rounds = []
    real_round = sm._Round

    def recorded(*args):
        rounds.append(real_round(*args))
        return rounds[-1]

    monkeypatch.setattr(sm, "_Round", recorded)
    search = _search(kr16, objective, _fresh(search_start), rounds=30)
    starts_run = sum(len(c) for c in calls)
    starts_asked = sum(r.starts.size for r in rounds)
    verifications = [i for i, r in enumerate(rounds) if r.starts.size == 4]
    assert verifications, "the search should end with a verification round"
    for i in verifications:  # a verification right after a round without additions reuses it
        before = rounds[i - 1]
        if before.approx is rounds[i].approx:
            np.testing.assert_array_equal(rounds[i].starts[:2], before.starts)
            np.testing.assert_array_equal(rounds[i].maxima.q[:2], before.maxima.q)
    reused = sum(2 for i in verifications if rounds[i - 1].approx is rounds[i].approx)
    assert reused > 0 and starts_run == starts_asked - reused
    # the reused maxima are what a fresh maximisation from those starts finds
    last = rounds[verifications[-1]]
    gamma = objective.criterion.compute_gradient(information(search.blocks[:last.n_candidates],
                                                             last.approx.weights))
    again = sm._maximise_in_chunks(kr16, objective, gamma, search.cand[last.starts],
                                   last.approx.mean_sensitivity, 2, max_iterations=15)
    np.testing.assert_allclose(again.values, last.maxima.values, rtol=1e-6)
    assert search.d_local == rounds[-1].maxima.max_value  # the search's value is its last round's


def test_the_start_skips_the_maximisation_it_would_discard(kr16, objective, search_start, monkeypatch):
    calls = _counting(monkeypatch)
    full = _search(kr16, objective, _fresh(search_start), rounds=1, verify_starts=2)
    n_full = len(calls)
    calls.clear()
    short = _search(kr16, objective, _fresh(search_start), rounds=1, verify_starts=2,
                    final_maximisation=False)
    assert full.rounds == short.rounds == 1  # the round found maxima and re-solved
    assert n_full == 2 and len(calls) == 1  # ... and only the certificate needs the one after it
    np.testing.assert_allclose(short.cand, full.cand, rtol=0, atol=1e-7)  # ProxQP: not bit for bit
    assert short.approx.value == pytest.approx(full.approx.value, rel=1e-9)
