"""Efficient rounding of approximate designs (Pukelsheim & Rieder 1992)."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from calib_oed.exceptions import DesignError
from calib_oed.oed.criteria import ACriterion
from calib_oed.oed.rounding import efficient_rounding


def _compositions(n: int, parts: int, cap: int):
    """Every (n_1..n_parts) with 0 <= n_i <= cap summing to n."""
    for c in itertools.product(range(min(n, cap) + 1), repeat=parts):
        if sum(c) == n:
            yield np.array(c)


def rounding_efficiency(weights, counts) -> float:
    r""":math:`\varepsilon = \min_i n_i/(n w_i)`: the rounded design's information is at least
    :math:`\varepsilon\,n\,M(w)` (Pukelsheim & Rieder 1992)."""
    w = np.asarray(weights, dtype=float)
    c = np.asarray(counts, dtype=float)
    return float(np.min(c / (c.sum() * (w / w.sum()))))


def test_known_small_cases():
    # (n - l/2) w = 8.5 (0.5, 0.3, 0.2) = (4.25, 2.55, 1.7): the ceilings already sum to 10
    assert efficient_rounding([0.5, 0.3, 0.2], 10).tolist() == [5, 3, 2]
    # equal weights, n = 4: ceilings (1, 1, 1), one increment to the first of the tied poses
    assert efficient_rounding([1, 1, 1], 4).tolist() == [2, 1, 1]
    # too many: ceil(3.5 * (0.55, 0.45)) = (2, 2) for n = 3: take one from the largest (n_k - 1)/w_k
    assert efficient_rounding([0.55, 0.45], 3).tolist() == [2, 1]
    # a cap moves the excess to the next poses
    assert efficient_rounding([0.7, 0.2, 0.1], 6, cap=3).tolist() == [3, 2, 1]


@pytest.mark.parametrize("seed", range(6))
def test_maximises_the_efficiency_bound_over_every_apportionment(seed):
    rng = np.random.default_rng(seed)
    parts = int(rng.integers(2, 5))
    w = rng.dirichlet(np.full(parts, 0.7))
    n = int(rng.integers(parts, 12))
    cap = None if seed % 2 == 0 else int(np.ceil(n / parts)) + 1
    counts = efficient_rounding(w, n, cap)
    assert counts.sum() == n and counts.min() >= 0
    assert cap is None or counts.max() <= cap
    best = max(rounding_efficiency(w, c) for c in _compositions(n, parts, cap or n))
    assert rounding_efficiency(w, counts) == pytest.approx(best, rel=1e-12)


def test_rounded_information_dominates_the_scaled_approximate_design():
    # M_n >= eps n M(w) in the Loewner order, so an A-criterion loses at most the factor eps
    rng = np.random.default_rng(3)
    blocks = rng.normal(size=(7, 3, 5))
    w = rng.dirichlet(np.ones(7))
    n = 11
    counts = efficient_rounding(w, n, cap=3)
    m_w = np.einsum("i,idp,idq->pq", w, blocks, blocks)
    m_n = np.einsum("i,idp,idq->pq", counts.astype(float), blocks, blocks)
    eps = rounding_efficiency(w, counts)
    assert np.linalg.eigvalsh(m_n - eps * n * m_w).min() >= -1e-10
    crit = ACriterion(np.eye(5), 5)
    assert crit.compute_value(m_n) <= crit.compute_value(m_w) / (eps * n) * (1 + 1e-12)


@pytest.mark.parametrize("args, what", [
    (([0.5, -0.5], 3), "weights"), (([0.5, 0.5], 0), "n"), (([0.5, 0.5], 3, 0), "cap"),
    (([0.5, 0.5], 5, 2), "n"), (([[0.5, 0.5]], 2), "weights"),
])
def test_bad_input_names_the_problem(args, what):
    with pytest.raises(DesignError) as err:
        efficient_rounding(*args)
    assert err.value.what == what
