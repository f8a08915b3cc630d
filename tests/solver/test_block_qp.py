"""The interior-point QP of a structured Hessian (calib_oed.solver.block_qp) against ProxQP on the same QP."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import scipy.sparse as sp

from calib_oed.solver.block_qp import BlockQPWorkspace
from calib_oed.solver.lifted import LiftedQPWorkspace
from calib_oed.solver.qp import DenseQPWorkspace, QPSubproblem
from calib_oed.solver.result import StructuredHessian
from calib_oed.solver.settings import SQPSettings
from calib_oed.solver.sqp import SQPStatus, solve_sqp

DATA = Path(__file__).parent / "data"


def _instance(rng, b=10, s=6, r=4, per_pose=4, cross=0):
    """Random PD blocks, coupling U (or none), rows on one pose each (and ``cross`` spanning poses), a box."""
    n = b * s
    g0 = rng.standard_normal((b, s, s))
    blocks = np.einsum("jab,jcb->jac", g0, g0) / s + 0.05 * np.eye(s)
    u = rng.standard_normal((n, r)) * 0.5 if r else None
    rows = []
    for j in range(b):
        for _ in range(per_pose):
            v = np.zeros(n)
            v[j * s:(j + 1) * s] = rng.standard_normal(s)
            rows.append(v)
    for _ in range(cross):
        v = np.zeros(n)
        v[rng.choice(n, 8, replace=False)] = rng.standard_normal(8)
        rows.append(v)
    c = np.array(rows)
    h = StructuredHessian(blocks, u)
    sub = QPSubproblem(h, 2 * rng.standard_normal(n), sp.csr_matrix(c), -rng.uniform(-0.02, 0.2, len(rows)),
                       np.full(n, -0.1), np.full(n, 0.1))
    return sub, sub._replace(H=h.dense(), C=c)


def _kkt(sub, step, tol):
    r"""The QP's KKT conditions at ``step`` (module calib_oed.solver.qp): :math:`H d + g - C^\top\lambda - \nu = 0`,
    :math:`C d \ge \ell`, :math:`\lambda \ge 0` with :math:`\lambda_i (C_i d - \ell_i) = 0`, the box
    and :math:`\nu` of the side's sign, zero between the sides; all to ``tol``."""
    d, lam, nu = step.d, step.lam, step.nu
    np.testing.assert_allclose(sub.H @ d + sub.g - sub.C.T @ lam - nu, 0.0, atol=tol)
    slack = sub.C @ d - sub.lower
    assert slack.min() >= -tol and lam.min() >= -tol
    assert np.max(np.abs(lam * slack)) <= tol
    assert np.all(d >= sub.box_lower - tol) and np.all(d <= sub.box_upper + tol)
    at_lo, at_hi = d <= sub.box_lower + tol, d >= sub.box_upper - tol
    assert np.all(nu[~at_lo] <= tol) and np.all(nu[~at_hi] >= -tol)


def _active(step, tol=1e-7):
    return np.flatnonzero(step.lam > tol), np.flatnonzero(np.abs(step.nu) > tol)


def _same_solution(block, reference, tol=1e-8):
    assert block.is_solved(tol, tol), block
    assert reference.is_solved(tol, tol)
    assert np.max(np.abs(block.d - reference.d)) <= 1e3 * tol
    assert np.max(np.abs(block.lam - reference.lam)) <= 1e3 * tol
    rows_b, box_b = _active(block)
    rows_r, box_r = _active(reference)
    np.testing.assert_array_equal(rows_b, rows_r)
    np.testing.assert_array_equal(box_b, box_r)
    assert rows_b.size + box_b.size >= 3  # rows and box both matter


@pytest.mark.parametrize(("b", "r", "cross"), [(3, 0, 0), (10, 4, 0), (30, 20, 0), (10, 4, 3)])
def test_block_qp_gives_proxqps_solution_and_active_set(b, r, cross):
    rng = np.random.default_rng(100 * b + r + cross)
    sub, dense_sub = _instance(rng, b=b, r=r, cross=cross)
    n = sub.g.size
    block = BlockQPWorkspace(n, 1e-9, 100).solve(sub)
    reference = DenseQPWorkspace(n, 1e-11, 1000).solve(dense_sub)
    _same_solution(block, reference)
    _kkt(sub, block, 1e-9)


def _design_qp():
    z = np.load(DATA / "design_qp_fms_kr16_n60.npz")
    C = sp.csr_matrix((z["C_data"], z["C_indices"], z["C_indptr"]), shape=tuple(z["C_shape"]))
    return QPSubproblem(StructuredHessian(z["blocks"], z["low_rank"]), z["g"], C, z["lower"],
                        z["box_lower"], z["box_upper"])


def _value(sub, d):
    return 0.5 * d @ (sub.H @ d) + sub.g @ d


def test_block_qp_on_a_design_qp_same_value_and_active_set():
    """A QP of the fms_kr16 design SQP at n = 60 (exact Hessian, r = 75, 261 rows), captured from a run:
    the same QP value (to 1e-10 relative), the same step, the same box sides, the same row force
    :math:`C^T \\lambda`, feasible. Where a kinked row and its piece are both active (dependent rows,
    their multipliers not unique) ProxQP splits the multiplier between them, the block QP may give it
    to one: its active rows are among ProxQP's and cover every pose ProxQP's do."""
    sub = _design_qp()
    n = sub.g.size
    assert sub.H.low_rank.shape[1] > 50 and sub.lower.size > 100
    block = BlockQPWorkspace(n, 1e-9, 100).solve(sub)
    reference = LiftedQPWorkspace(n, 1e-11, 1000).solve(sub)
    assert reference.is_solved(1e-9, 1e-9)
    assert abs(_value(sub, block.d) - _value(sub, reference.d)) <= 1e-10 * abs(_value(sub, reference.d))
    np.testing.assert_allclose(block.d, reference.d, atol=1e-6)
    np.testing.assert_allclose(sub.C.T @ block.lam, sub.C.T @ reference.lam, atol=1e-8)
    (rows_b, box_b), (rows_r, box_r) = _active(block), _active(reference)
    np.testing.assert_array_equal(box_b, box_r)
    assert set(rows_b) <= set(rows_r)
    C = sub.C.tocsr()
    pose = C.indices[C.indptr[:-1]] // 6  # each row's pose: its first column's
    assert set(pose[rows_b]) == set(pose[rows_r])
    assert block.is_solved(1e-9, 1e-9)


def test_block_qp_on_a_design_qp_meets_the_sqp_tolerance():
    """The same QP: its curvature floor (1e-8) once stopped the interior point's dual residual near 4e-8;
    the polish on the active set meets the SQP's 1e-8 test and ProxQP's own accuracy."""
    sub = _design_qp()
    block = BlockQPWorkspace(sub.g.size, 1e-9, 100).solve(sub)
    assert block.status == "solved"
    assert block.is_solved(1e-9, 1e-9)
    assert max(block.primal_residual, block.dual_residual, block.complementarity) <= 1e-12
    _kkt(sub, block, 1e-9)


def test_infeasible_qp_is_not_solved_by_either():
    """Two rows of one pose that no step in the box satisfies: neither solver reports it solved."""
    rng = np.random.default_rng(7)
    sub, dense_sub = _instance(rng, b=4, r=2)
    n = sub.g.size
    e = np.zeros(n)
    e[0] = 1.0
    C = sp.vstack([sub.C, sp.csr_matrix(e), sp.csr_matrix(-e)], format="csr")
    lower = np.concatenate([sub.lower, [0.05, 0.0]])  # d_0 >= 0.05 and -d_0 >= 0
    bad, bad_dense = sub._replace(C=C, lower=lower), dense_sub._replace(C=C.toarray(), lower=lower)
    block = BlockQPWorkspace(n, 1e-9, 100).solve(bad)
    reference = DenseQPWorkspace(n, 1e-9, 100).solve(bad_dense)
    assert not block.is_solved(1e-8, 1e-8) and not reference.is_solved(1e-8, 1e-8)
    assert block.status != "solved" and reference.status != "solved"


@pytest.mark.parametrize(("settings", "backend"), [
    (SQPSettings(structured_qp="lifted"), "lifted"), (SQPSettings(structured_qp="block"), "block"),
    (SQPSettings(block_qp_min_size=60), "block"), (SQPSettings(block_qp_min_size=61), "lifted"),
    (SQPSettings(), "block" if 60 >= SQPSettings().block_qp_min_size else "lifted"),
], ids=["lifted", "block", "auto-block", "auto-lifted", "default"])
def test_every_structured_qp_setting_gives_the_sqp_the_same_optimum(settings, backend):
    """The SQP on a QP (f = d^T H d / 2 + g^T d, rows C d >= l, the box; n = 60 variables) with its exact
    structured Hessian: whichever QP ``structured_qp`` and ``block_qp_min_size`` choose (every QP goes to
    that one), the SQP's point and multipliers are the QP's KKT point, ProxQP's dense answer."""
    rng = np.random.default_rng(3)
    sub, dense_sub = _instance(rng)
    reference = DenseQPWorkspace(sub.g.size, 1e-11, 1000).solve(dense_sub)
    C = sub.C.toarray()

    res = solve_sqp(lambda d: (0.5 * d @ (sub.H @ d) + sub.g @ d, sub.H @ d + sub.g), np.zeros(sub.g.size),
                    bounds=(sub.box_lower, sub.box_upper),
                    constraints=lambda d: (C @ d - sub.lower, C),
                    lagrangian_hessian=lambda d, lam: sub.H, settings=settings)
    assert res.status is SQPStatus.CONVERGED and res.check(), res.summary()
    assert res.hessian_fallbacks == 0
    assert {r.qp_backend for r in res.history if r.qp_backend} == {backend}
    np.testing.assert_allclose(res.x, reference.d, atol=1e-7)
    np.testing.assert_allclose(res.multipliers, reference.lam, atol=1e-6)
