"""calib_oed.oed.starts: an exchange already computed in the process is not computed again.

A study's designs with and without collisions of one criterion start from the same pool, so from
the same exchange. The second call returns the first's design (a copy) without running the
exchange; any different input (criterion, seed, n, pool) runs it, and a Generator (whose state is
an input the digest cannot see) is never taken from the memo.
"""

from __future__ import annotations

import numpy as np
import pytest

import calib_oed.oed.starts as starts
from calib_oed.oed.objective import DesignObjective

N = 12


@pytest.fixture
def counted(monkeypatch):
    calls = []
    exchange = starts.exchange_design

    def wrapper(*a, **kw):
        calls.append(1)
        return exchange(*a, **kw)

    monkeypatch.setattr(starts, "exchange_design", wrapper)
    monkeypatch.setattr(starts, "_EXCHANGES", {})
    return calls


def test_the_same_exchange_is_computed_once(kr16, counted):
    kpi = DesignObjective(kr16.problem, "kpi")
    pool = starts.candidate_pool(kr16, 120, 4)
    q1, r1 = starts.exchange_start(kpi, pool, N, seed=3)
    q2, r2 = starts.exchange_start(DesignObjective(kr16.problem, "kpi"), pool, N, seed=3)
    assert len(counted) == 1
    np.testing.assert_array_equal(q1, q2)
    assert r2.value == r1.value and np.array_equal(r2.indices, r1.indices)
    q2[0, 0] += 1.0  # a copy: changing it changes no later answer
    np.testing.assert_array_equal(starts.exchange_start(kpi, pool, N, seed=3)[0], q1)
    assert len(counted) == 1


def test_any_other_input_runs_the_exchange(kr16, counted):
    kpi, params = DesignObjective(kr16.problem, "kpi"), DesignObjective(kr16.problem, "params")
    pool = starts.candidate_pool(kr16, 120, 4)
    starts.exchange_start(kpi, pool, N, seed=3)
    fresh = starts.exchange_start(params, pool, N, seed=3)[1]
    assert len(counted) == 2 and fresh.criterion != "kpi"
    starts.exchange_start(kpi, pool, N, seed=4)
    starts.exchange_start(kpi, pool, N + 1, seed=3)
    starts.exchange_start(kpi, starts.candidate_pool(kr16, 121, 4), N, seed=3)
    assert len(counted) == 5
    rng = np.random.default_rng(3)
    starts.exchange_poses(kpi, pool.q, kpi.compute_blocks(pool.q), N, rng=rng)
    starts.exchange_poses(kpi, pool.q, kpi.compute_blocks(pool.q), N, rng=rng)
    assert len(counted) == 7


def test_the_memo_keeps_the_most_recent(kr16, counted):
    kpi = DesignObjective(kr16.problem, "kpi")
    pool = starts.candidate_pool(kr16, 120, 4)
    for seed in range(starts.EXCHANGES_KEPT + 2):
        starts.exchange_start(kpi, pool, N, seed=seed)
    assert len(starts._EXCHANGES) == starts.EXCHANGES_KEPT
    starts.exchange_start(kpi, pool, N, seed=0)  # the oldest left the memo: run again
    assert len(counted) == starts.EXCHANGES_KEPT + 3
