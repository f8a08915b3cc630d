"""Infeasible QP subproblems: the Farkas certificate of a failed solve (calib_oed.solver.restoration)."""

from __future__ import annotations

import numpy as np
import scipy.optimize
import scipy.sparse as sp

from calib_oed.solver.restoration import certified_violation


def _least_violation(C, lower, bl, bu, slack: float) -> float:
    r""":math:`\min_d \max(\max_i(\ell_i - C_i d), \text{box violation})` over a box widened by ``slack``, by LP."""
    k, n = C.shape
    # variables (d, t): min t s.t. l - C d <= t, bl - d <= t, d - bu <= t
    a = np.vstack([np.hstack([-C, -np.ones((k, 1))]),
                   np.hstack([-np.eye(n), -np.ones((n, 1))]),
                   np.hstack([np.eye(n), -np.ones((n, 1))])])
    b = np.concatenate([-lower, -bl, bu])
    res = scipy.optimize.linprog(np.r_[np.zeros(n), 1.0], A_ub=a, b_ub=b,
                                 bounds=[(lo - slack, hi + slack) for lo, hi in zip(bl, bu, strict=True)]
                                 + [(None, None)], method="highs")
    assert res.status == 0
    return float(res.fun)


def _infeasible_qp(rng, n=4, k=7):
    """Random rows with two that contradict each other in the box [-1, 1]^n."""
    C = rng.normal(size=(k, n))
    C[1] = -C[0]
    lower = rng.normal(size=k) - 3.0  # the others hold near d = 0
    lower[0], lower[1] = 0.8 * np.abs(C[0]).sum(), -0.2 * np.abs(C[0]).sum()  # C_0 d >= 0.8 |C_0|, <= 0.2 |C_0|
    return C, lower, -np.ones(n), np.ones(n)


def test_certified_violation_is_a_lower_bound_on_every_step():
    """The certificate's bound never exceeds the least violation of any step (box sides included,
    by LP), and random steps in and around the box (Monte Carlo) all violate by at least that much."""
    rng = np.random.default_rng(0)
    for _ in range(20):
        C, lower, bl, bu = _infeasible_qp(rng)
        y = np.zeros(len(lower))
        y[:2] = rng.uniform(0.5, 2.0) * np.array([1.0, 1.0 + rng.uniform(0.0, 0.3)])  # near the ray (1, 1)
        bound = certified_violation(C, lower, bl, bu, y)
        assert bound > 0.0
        assert bound <= _least_violation(C, lower, bl, bu, slack=10.0) + 1e-12
        d = rng.uniform(-1.5, 1.5, size=(20000, C.shape[1]))
        viol = np.maximum.reduce([(lower - d @ C.T).max(axis=1), (bl - d).max(axis=1), (d - bu).max(axis=1)])
        assert viol.min() >= bound - 1e-12
        # scale-free, and the same for a sparse C
        assert np.isclose(certified_violation(C, lower, bl, bu, 1e6 * y), bound, rtol=1e-12)
        assert np.isclose(certified_violation(sp.csr_matrix(C), lower, bl, bu, y), bound, rtol=1e-12)


def test_no_certificate_for_a_feasible_qp():
    """Farkas: where some step meets every row in the box, no y >= 0 shows a positive violation."""
    rng = np.random.default_rng(1)
    for _ in range(20):
        C = rng.normal(size=(7, 4))
        d_ok = rng.uniform(-1, 1, size=4)
        lower = C @ d_ok - rng.uniform(0, 0.1, size=7)
        for y in rng.exponential(size=(50, 7)) * (rng.random((50, 7)) < 0.5):
            assert certified_violation(C, lower, -np.ones(4), np.ones(4), y) <= 1e-12


def test_no_certificate_without_multipliers():
    C, lower, bl, bu = _infeasible_qp(np.random.default_rng(2))
    for y in (np.zeros(len(lower)), np.full(len(lower), np.nan), -np.ones(len(lower))):
        assert certified_violation(C, lower, bl, bu, y) == -np.inf
    # an infinite box side the certificate leans on proves nothing
    y = np.r_[1.0, 1.0, np.zeros(len(lower) - 2)]
    inf = np.full(4, np.inf)
    assert certified_violation(C, lower, -inf, inf, y) > 0  # z = C^T y = 0: the box is not used
    y[2] = 1.0
    assert certified_violation(C, lower, -inf, inf, y) == -np.inf
