"""The pool enriched by the approximate design's column generation, the rounded start from it,
and its use by the design (start, replicates, record) and by the certificate."""

from __future__ import annotations

import numpy as np
import pytest

from calib_oed.exceptions import DesignError
from calib_oed.feasibility.constraints import FEASIBILITY_TOL
from calib_oed.feasibility.sampling import sample_feasible
from calib_oed.oed import certificate as cert
from calib_oed.oed.approximate import solve_approximate
from calib_oed.oed.approximate_pool import (
    START_LOCAL_HESSIAN,
    approximate_pool,
    approximate_start,
    rounded_start,
)
from calib_oed.oed.design import evaluate_design
from calib_oed.oed.objective import DesignObjective

N = 12


@pytest.fixture(scope="module")
def objective(kr16):
    return DesignObjective(kr16.problem, "kpi")


@pytest.fixture(scope="module")
def pool(kr16):
    return sample_feasible(kr16.feasibility, 300, 5)


@pytest.fixture(scope="module")
def enriched(kr16, objective, pool):
    return approximate_pool(kr16, objective, pool, starts=4, rounds=2, local_iterations=40)


def test_enrichment_keeps_the_pool_adds_feasible_maxima_and_lowers_the_value(kr16, objective, pool,
                                                                          enriched):
    ap = enriched
    assert np.array_equal(ap.q[:300], pool) and ap.n_pool == 300 and ap.n_added > 0
    added = ap.q[300:]
    assert kr16.feasibility.compute(added, jacobian=False).values.min() >= -FEASIBILITY_TOL
    assert np.allclose(ap.blocks[300:], objective.compute_blocks(added))
    pool_only = solve_approximate(objective.compute_blocks(pool), objective.criterion)
    assert ap.approx.value < pool_only.value  # the maxima were worth adding
    assert ap.approx.converged and ap.approx.weights.size == len(ap.q)
    rec = ap.to_dict()
    assert rec["candidates"] == len(ap.q) and rec["local_maxima_added"] == ap.n_added


@pytest.mark.parametrize("replicates", [1, 2, 3])
def test_rounded_start_respects_n_and_replicates(enriched, replicates):
    idx = rounded_start(enriched, N, replicates)
    n_cand = len(enriched.q)
    assert idx.size == N and np.unique(idx).size == N  # distinct indices into the repeated pool
    counts = np.bincount(idx % n_cand, minlength=n_cand)
    assert counts.max() <= replicates
    sup = enriched.approx.support
    if sup.size * replicates >= N:  # the support alone carries the n measurements
        assert set(np.flatnonzero(counts)) <= set(sup.tolist())


def test_approximate_start_never_worse_than_its_rounding(objective, enriched):
    for replicates in (1, 3):
        q, result = approximate_start(objective, enriched, N, None, replicates)
        idx = rounded_start(enriched, N, replicates)
        rounded = objective.compute_value(enriched.q[idx % len(enriched.q)])
        assert result.initial_value == pytest.approx(rounded, rel=1e-9)
        assert objective.compute_value(q) == pytest.approx(result.value, rel=1e-9)
        assert result.value <= rounded
        _, counts = np.unique(q, axis=0, return_counts=True)
        assert counts.sum() == N and counts.max() <= replicates


def test_certificate_continues_the_column_generation(kr16, objective, enriched):
    q, _ = approximate_start(objective, enriched, N)
    c = cert.certify(kr16, q, "kpi", approximate=enriched, local_starts=4, verify_starts=8,
                     local_rounds=2, local_iterations=40)
    assert c.holds() and c.pool_size >= len(enriched.q) + N
    assert c.n_local_added >= enriched.n_added
    assert c.bound <= objective.compute_value(q)


def test_start_searches_with_bfgs_and_the_certificate_with_the_exact_hessian(kr16, objective, pool,
                                                                             monkeypatch):
    """The start's maximisations keep per-pose BFGS without row pieces (START_LOCAL_HESSIAN: the designs
    stay what they were), the certificate's continuation takes the exact Hessian and the row pieces;
    both as asked when told."""
    from calib_oed.oed import sensitivity_maxima as sm

    used = []
    real = sm.solve_sqp

    def spy(*args, **kwargs):
        exact, pieces = (kwargs.get(k) is not None for k in ("lagrangian_hessian", "row_pieces"))
        assert exact == pieces
        used.append(exact)
        return real(*args, **kwargs)

    monkeypatch.setattr(sm, "solve_sqp", spy)
    assert START_LOCAL_HESSIAN == "bfgs"
    ap = approximate_pool(kr16, objective, pool, starts=4, rounds=1, local_iterations=20)
    assert used and not any(used)
    used.clear()
    q, _ = approximate_start(objective, ap, N)
    cert.certify(kr16, q, "kpi", approximate=ap, local_starts=4, verify_starts=4, local_rounds=1,
                 local_iterations=20)
    assert used and all(used)
    used.clear()
    approximate_pool(kr16, objective, pool, starts=4, rounds=1, local_iterations=20, local_hessian="exact")
    assert used and all(used)
    with pytest.raises(DesignError, match="local_hessian.*valid choices are: exact, bfgs"):
        approximate_pool(kr16, objective, pool, local_hessian="newton")


def test_replicated_start_and_the_record_of_its_multiplicity(kr16, objective, enriched):
    n = 2 * enriched.approx.support.size  # more than the support carries once each: poses repeat
    q, _ = approximate_start(objective, enriched, n, None, 3)
    rows, counts = np.unique(q, axis=0, return_counts=True)  # the start's copies are exact
    assert counts.sum() == n and 1 < counts.max() <= 3
    d = evaluate_design(kr16, q, "kpi")
    assert sorted(d.multiplicity) == sorted(counts.tolist())
    data = d.to_dict()
    assert data["distinct_poses"] == len(rows) < n and data["multiplicity"] == d.multiplicity
