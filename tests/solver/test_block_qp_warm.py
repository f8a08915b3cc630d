"""The block QP's warm start by the active set its duals name (calib_oed.solver.block_qp): the same
answer as the cold interior point, with no interior-point iteration when the guess is right."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import scipy.sparse as sp

from calib_oed.solver.block_qp import BlockQPWorkspace
from calib_oed.solver.qp import QPSubproblem
from calib_oed.solver.result import StructuredHessian

DATA = Path(__file__).parent / "data"
TOL = 1e-9


def _random_qp(seed, b=20, s=6, r=5, per_pose=4):
    """Random PD blocks, coupling U, rows on one pose each, a box: a QP of the design's shape."""
    rng = np.random.default_rng(seed)
    n = b * s
    g0 = rng.standard_normal((b, s, s))
    blocks = np.einsum("jab,jcb->jac", g0, g0) / s + 0.05 * np.eye(s)
    C = sp.block_diag([rng.standard_normal((per_pose, s)) for _ in range(b)], format="csr")
    return QPSubproblem(StructuredHessian(blocks, 0.5 * rng.standard_normal((n, r))),
                        2 * rng.standard_normal(n), C, -rng.uniform(-0.02, 0.2, b * per_pose),
                        np.full(n, -0.1), np.full(n, 0.1))


def _design_qp():
    z = np.load(DATA / "design_qp_fms_kr16_n60.npz")
    C = sp.csr_matrix((z["C_data"], z["C_indices"], z["C_indptr"]), shape=tuple(z["C_shape"]))
    return QPSubproblem(StructuredHessian(z["blocks"], z["low_rank"]), z["g"], C, z["lower"],
                        z["box_lower"], z["box_upper"])


def _solve(sub, lam0=None, nu0=None):
    return BlockQPWorkspace(sub.g.size, TOL, 100).solve(sub, None, lam0, nu0)


def _same_point(sub, a, b):
    """Same step; the same force of the constraints (the multipliers themselves are not unique where
    rows are dependent: a kinked row and its piece in the design QP)."""
    assert a.status == b.status == "solved"
    assert np.max(np.abs(a.d - b.d)) <= 1e-7
    force_a, force_b = sub.C.T @ a.lam + a.nu, sub.C.T @ b.lam + b.nu
    assert np.max(np.abs(force_a - force_b)) <= 1e-7 * max(1.0, float(np.max(np.abs(force_b))))


@pytest.mark.parametrize("make", [lambda: _random_qp(1), lambda: _random_qp(2, b=40, r=0), _design_qp],
                         ids=["random", "no_coupling", "fms_kr16_n60"])
def test_the_answers_duals_give_the_answer_without_interior_point_iterations(make):
    sub = make()
    cold = _solve(sub)
    assert cold.iterations > 5  # the interior point did work
    warm = _solve(sub, cold.lam, cold.nu)
    assert warm.iterations == 0
    _same_point(sub, warm, cold)
    assert np.count_nonzero(cold.lam) + np.count_nonzero(cold.nu) >= 3  # an active set to guess


@pytest.mark.parametrize("guess", ["every_row", "none_but_one_wrong_box_side", "random"])
def test_a_wrong_guess_falls_back_to_the_same_answer(guess):
    sub = _random_qp(3)
    cold = _solve(sub)
    k, n = sub.lower.size, sub.g.size
    rng = np.random.default_rng(4)
    lam0, nu0 = {"every_row": (np.ones(k), np.zeros(n)),
                 "none_but_one_wrong_box_side": (np.zeros(k), -np.sign(cold.nu + 1e-30) * (np.arange(n) == 0)),
                 "random": (rng.uniform(-1, 1, k), rng.uniform(-1, 1, n))}[guess]
    warm = _solve(sub, lam0, nu0)
    assert warm.iterations > 0  # the guess was not taken
    _same_point(sub, warm, cold)


def test_second_order_correction_shape_shifted_constants_keep_the_active_set():
    """The SOC re-solves with the constants moved by O(|d|^2): the step's duals answer it (here the
    rows moved by C e, a small translation that keeps a kinked row and its piece consistent)."""
    sub = _design_qp()
    step = _solve(sub)
    e = 1e-6 * np.random.default_rng(5).uniform(-1, 1, sub.g.size)
    shifted = sub._replace(lower=sub.lower + sub.C @ e)
    cold = _solve(shifted)
    assert np.max(np.abs(cold.d - step.d)) > 1e-7  # another QP, another answer
    warm = _solve(shifted, step.lam, step.nu)
    assert warm.iterations == 0
    _same_point(shifted, warm, cold)
    primal, dual, comp = shifted.residuals(warm.d, warm.lam, warm.nu)
    assert max(primal, comp) <= TOL and dual <= TOL * max(1.0, float(np.max(np.abs(shifted.g))))


def test_a_block_semidefinite_in_rounding_is_solved_as_proxqp_solves_it():
    """A BFGS block with an eigenvalue of -1e-15 (rounding) made the Cholesky factor raise at n = 500."""
    from calib_oed.solver.qp import DenseQPWorkspace

    sub = _random_qp(6)
    sub = sub._replace(H=StructuredHessian(sub.H.blocks, None))
    blocks = sub.H.blocks.copy()
    lam, q = np.linalg.eigh(blocks[3])
    lam[0] = -1e-15
    blocks[3] = (q * lam) @ q.T
    with pytest.raises(np.linalg.LinAlgError):
        np.linalg.cholesky(blocks[3])
    sub = sub._replace(H=StructuredHessian(blocks, None))
    block = _solve(sub)
    n = sub.g.size
    reference = DenseQPWorkspace(n, 1e-11, 1000).solve(sub._replace(H=sub.H.dense(), C=sub.C.toarray()))
    assert block.status == "solved"
    assert np.max(np.abs(block.d - reference.d)) <= 1e-6
