"""Curvature along the active rows before the eigenvalue modification (calib_oed.solver.hessian.augment_active).

The point of the augmentation: where the Lagrangian's Hessian curves down only
across the active constraints (its reduced Hessian on their null space is
positive definite), adding curvature along the active rows makes the block
positive definite without changing the QP's solution on that active set, so
no eigenvalue is flipped and the SQP takes Newton steps on the constraint
surface.
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from calib_oed.solver.hessian import augment_active, modify_blocks
from calib_oed.solver.result import StructuredHessian
from calib_oed.solver.sqp import SQPSettings, SQPSettingsError, SQPStatus, solve_sqp


def _equality_qp(h, g, a, b):
    """Solution d of min 1/2 d'Hd + g'd s.t. a d = b (KKT system)."""
    n, m = h.shape[0], a.shape[0]
    kkt = np.block([[h, a.T], [a, np.zeros((m, m))]])
    return np.linalg.solve(kkt, np.concatenate([-g, b]))[:n]


def test_augmented_block_is_definite_and_keeps_the_active_set_step():
    rng = np.random.default_rng(3)
    s = 4
    a = rng.standard_normal((2, s))  # two active rows of one block
    z = np.linalg.svd(a)[2][2:].T  # null space (s, 2)
    # indefinite block whose reduced Hessian z' h z is positive definite
    h = rng.standard_normal((s, s))
    h = 0.5 * (h + h.T)
    h += z @ (np.diag([2.0, 3.0]) - z.T @ h @ z) @ z.T
    assert np.linalg.eigvalsh(h)[0] < 0
    assert np.linalg.eigvalsh(z.T @ h @ z)[0] > 0
    blocks = np.stack([h, np.eye(s)])
    a_full = sp.csr_matrix(np.hstack([a, np.zeros((2, s))]))
    out, added = augment_active(blocks, a_full, np.array([True, True]), np.zeros(2 * s, bool), 10.0)
    assert added == 2
    assert np.linalg.eigvalsh(out[0])[0] > 0  # no modification needed any more
    np.testing.assert_array_equal(out[1], np.eye(s))  # a block without active rows is untouched
    assert modify_blocks(out)[1] == 0
    g, b = rng.standard_normal(s), rng.standard_normal(2)
    np.testing.assert_allclose(_equality_qp(out[0], g, a, b), _equality_qp(h, g, a, b), atol=1e-9)


def test_rows_spanning_blocks_and_inactive_rows_are_left_out_bounds_added():
    blocks = np.stack([np.eye(2), np.eye(2)])
    a = sp.csr_matrix(np.array([[1.0, 0.0, 1.0, 0.0],    # spans both blocks
                                [0.0, 2.0, 0.0, 0.0],    # block 0, inactive
                                [0.0, 0.0, 0.0, 3.0]]))  # block 1, active
    out, added = augment_active(blocks, a, np.array([True, False, True]),
                                np.array([True, False, False, False]), 1.0)
    assert added == 2  # the row of block 1 and the bound of variable 0
    rho = np.sqrt(2.0)  # ||I_2||_F
    np.testing.assert_allclose(out[0], np.diag([1.0 + rho, 1.0]))
    np.testing.assert_allclose(out[1], np.diag([1.0, 1.0 + rho]))


def _problem():
    r"""min 1/2 x1^2 + 3 x1 x2 + 1/2 x2^2 + x2^4/4 - 20 x1 s.t. c = 1 - x1 >= 0, x2 in [-5, 5].

    At the only minimiser x1 = 1 (c active) and 3 + x2 + x2^3 = 0; the
    Lagrangian's Hessian [[1, 3], [3, 1 + 3 x2^2]] is indefinite there, its
    reduced Hessian 1 + 3 x2^2 > 0.
    """
    def f(x):
        x1, x2 = x
        val = 0.5 * x1 ** 2 + 3 * x1 * x2 + 0.5 * x2 ** 2 + 0.25 * x2 ** 4 - 20 * x1
        return val, np.array([x1 + 3 * x2 - 20, 3 * x1 + x2 + x2 ** 3])

    def c(x):
        return np.array([1.0 - x[0]]), sp.csr_matrix(np.array([[-1.0, 0.0]]))

    def hess(x, lam):
        return StructuredHessian(np.array([[[1.0, 3.0], [3.0, 1.0 + 3 * x[1] ** 2]]]), None)

    return f, c, hess


def _solve(weight):
    f, c, hess = _problem()
    res = solve_sqp(f, np.array([0.0, 2.0]), constraints=c, bounds=([-5, -5], [5, 5]),
                    lagrangian_hessian=hess, block_size=2,
                    settings=SQPSettings(active_curvature=weight, tol_optimality=1e-9))
    # not 1e-10: the plain run converges linearly, and its last line searches are decided by
    # merit differences of 1e-15 (relative), i.e. by the QP's last bits
    return res


def test_augmentation_gives_newton_steps_on_the_constraint_surface():
    x2 = np.roots([1.0, 0.0, 1.0, 3.0])
    x2 = float(x2[np.abs(x2.imag) < 1e-12].real[0])
    plain, augmented = _solve(0.0), _solve(1.0)
    for res in (plain, augmented):
        assert res.status is SQPStatus.CONVERGED
        np.testing.assert_allclose(res.x, [1.0, x2], atol=1e-7)
    # flipping the negative eigenvalue over-estimates the curvature along x2: linear convergence
    assert augmented.iterations < plain.iterations
    tail = [r.hessian_modified for r in augmented.history[-3:]]
    assert tail == [0, 0, 0]


def test_weight_is_validated():
    with pytest.raises(SQPSettingsError, match="active_curvature"):
        SQPSettings(active_curvature=-1.0)
