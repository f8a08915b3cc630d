"""The lifted QP of a structured Hessian (calib_oed.solver.lifted) against the dense QP with H = D + U U^T."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from calib_oed.solver.lifted import LiftedQPWorkspace
from calib_oed.solver.polish import polish
from calib_oed.solver.qp import DenseQPWorkspace, QPSubproblem
from calib_oed.solver.result import StructuredHessian


def _instance(rng, b=8, s=6, r=4, k=30):
    """Random PD blocks, coupling U (or none), k rows of 6 nonzeros on one block each, a box."""
    n = b * s
    g0 = rng.standard_normal((b, s, s))
    blocks = np.einsum("jab,jcb->jac", g0, g0) / s + 0.05 * np.eye(s)
    u = rng.standard_normal((n, r)) * 0.7 if r else None
    c = np.zeros((k, n))
    for i in range(k):
        j = rng.integers(0, b) * s
        c[i, j:j + s] = rng.standard_normal(s)
    h = StructuredHessian(blocks, u)
    sub = QPSubproblem(h, 2 * rng.standard_normal(n), sp.csr_matrix(c), -rng.uniform(0.0, 0.3, k),
                       np.full(n, -0.25), np.full(n, 0.25))
    return sub, sub._replace(H=h.dense(), C=c)


@pytest.mark.parametrize("r", [0, 1, 4, 20])
def test_lifted_qp_gives_the_dense_qp_step(r):
    rng = np.random.default_rng(10 + r)
    lifted_sub, dense_sub = _instance(rng, r=r)
    n = lifted_sub.g.size
    lifted = LiftedQPWorkspace(n, 1e-11, 1000).solve(lifted_sub)
    dense = DenseQPWorkspace(n, 1e-11, 1000).solve(dense_sub)
    assert lifted.is_solved(1e-9, 1e-9) and dense.is_solved(1e-9, 1e-9)
    active = int(np.count_nonzero(lifted.lam > 1e-8) + np.count_nonzero(np.abs(lifted.nu) > 1e-8))
    assert active >= 3  # rows and box both matter
    np.testing.assert_allclose(lifted.d, dense.d, atol=1e-8)
    np.testing.assert_allclose(lifted.lam, dense.lam, atol=1e-8)
    np.testing.assert_allclose(lifted.nu, dense.nu, atol=1e-8)
    # the same step is the exact KKT point of either form
    exact = polish(lifted_sub, lifted, 1e-10)
    assert exact is not None
    np.testing.assert_allclose(exact.d, polish(dense_sub, dense, 1e-10).d, atol=1e-12)


def test_one_workspace_solves_a_sequence_of_qps_as_fresh_ones_do():
    """The SQP solves QP after QP in one workspace: a warm start from the solution needs at most
    one iteration; new values on the same rows (the second-order correction's QP) and other rows
    give the step a fresh workspace gives."""
    rng = np.random.default_rng(3)
    sub, _ = _instance(rng)
    n = sub.g.size
    ws = LiftedQPWorkspace(n, 1e-9, 1000)
    cold = ws.solve(sub)
    warm = ws.solve(sub, cold.d, cold.lam, cold.nu)
    assert warm.is_solved(1e-8, 1e-7) and warm.iterations <= 1
    np.testing.assert_allclose(warm.d, cold.d, atol=1e-7)
    h = sub.H
    moved = sub._replace(H=StructuredHessian(h.blocks * 1.5, h.low_rank * 0.5), lower=sub.lower - 0.05)
    fewer = sub._replace(C=sub.C[:10], lower=sub.lower[:10])
    for qp, guess in ((moved, (None, cold.lam, cold.nu)), (fewer, ())):
        step = ws.solve(qp, *guess)
        fresh = LiftedQPWorkspace(n, 1e-9, 1000).solve(qp)
        ref = DenseQPWorkspace(n, 1e-9, 1000).solve(qp._replace(H=qp.H.dense()))
        assert step.is_solved(1e-8, 1e-7)
        np.testing.assert_allclose(step.d, fresh.d, atol=1e-7)
        np.testing.assert_allclose(step.d, ref.d, atol=1e-7)
