"""Rows with a kink: the SQP with the linearisations of their smooth pieces (solver/pieces.py)."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from calib_oed.exceptions import ShapeError
from calib_oed.solver.pieces import RowPieces, check_pieces
from calib_oed.solver.result import kkt_residuals
from calib_oed.solver.sqp import SQPStatus, solve_sqp

#: Two half-planes, c = min(1 - x0 - x1/2, 1 - x0/2 - x1) >= 0: one row with a concave kink on x0 = x1.
G = np.array([[-1.0, -0.5], [-0.5, -1.0]])


def _objective(x):
    return float(((x - 2.0) ** 2).sum()), 2.0 * (x - 2.0)


def _kinked_row(x):
    c = 1.0 + G @ x
    k = int(np.argmin(c))  # the gradient of the piece x is on (of the first at a tie)
    return np.array([c[k]]), G[k:k + 1].copy()


def _pieces(x, rows):
    if not len(rows):
        return None
    return np.zeros(2, dtype=int), 1.0 + G @ x, sp.csr_matrix(G)


def test_the_optimum_on_a_kink_converges_with_the_pieces():
    """The nearest feasible point to (2, 2) is the corner (2/3, 2/3), on the kink, where both pieces
    are active with multipliers 16/9 (KKT by hand: -(2/3 - 2)·2 = 8/3 = 16/9 · 3/2). With the pieces
    the SQP converges there in a few iterations; with the one gradient of the row it cannot: at the
    corner no multiple of one piece's gradient is the objective's, so it stops without convergence."""
    with_pieces = solve_sqp(_objective, np.zeros(2), constraints=_kinked_row, row_pieces=_pieces)
    assert with_pieces.status is SQPStatus.CONVERGED, with_pieces.summary()
    assert np.allclose(with_pieces.x, [2 / 3, 2 / 3], atol=1e-7)
    assert np.isclose(with_pieces.multipliers[0], 32 / 9, rtol=1e-6)  # both pieces' together
    assert with_pieces.kkt_stationarity <= 1e-6 and with_pieces.max_pieces == 2
    assert with_pieces.iterations <= 10
    without = solve_sqp(_objective, np.zeros(2), constraints=_kinked_row)
    assert without.status is not SQPStatus.CONVERGED and without.kkt_stationarity > 0.1


def test_a_smooth_problem_is_unchanged_by_an_empty_answer():
    """row_pieces that finds no kink (returns None) leaves the iterates as without it."""
    def row(x):
        return np.array([1.0 - x[0] - 0.5 * x[1]]), G[:1].copy()

    a = solve_sqp(_objective, np.zeros(2), constraints=row, row_pieces=lambda x, rows: None)
    b = solve_sqp(_objective, np.zeros(2), constraints=row)
    assert a.status is b.status is SQPStatus.CONVERGED and a.iterations == b.iterations
    assert np.array_equal(a.x, b.x) and a.max_pieces == 0


def test_kkt_residuals_count_the_pieces():
    """r = g - A^T lam - G^T mu; complementarity includes mu · value."""
    x, g = np.array([2 / 3, 2 / 3]), np.array([-8 / 3, -8 / 3])
    c, A = np.zeros(1), sp.csr_matrix(G[:1])
    lb, ub = np.full(2, -np.inf), np.full(2, np.inf)
    stat, _, _ = kkt_residuals(x, g, c, A, np.array([0.0]), lb, ub, 1e-9,
                               (np.zeros(2), sp.csr_matrix(G), np.array([16 / 9, 16 / 9])))
    assert stat < 1e-12
    stat_row_only, _, _ = kkt_residuals(x, g, c, A, np.array([32 / 9]), lb, ub, 1e-9)
    assert stat_row_only > 0.1
    _, comp, _ = kkt_residuals(x, g, c, A, np.array([0.0]), lb, ub, 1e-9,
                               (np.array([0.0, 0.5]), sp.csr_matrix(G), np.array([1.0, 2.0])))
    assert np.isclose(comp, 1.0 / 8 * 3)  # |2 · 0.5| / max(1, |g|_inf = 8/3)


def test_bad_pieces_are_refused():
    assert check_pieces(None, 3, 5).size == 0 and RowPieces.none(3).gradients.shape == (0, 3)
    with pytest.raises(ShapeError, match="row pieces"):
        check_pieces(([0, 1], [0.0], np.zeros((2, 3))), 3, 5)
    with pytest.raises(ShapeError, match="rows"):
        check_pieces(([7], [0.0], np.zeros((1, 3))), 3, 5)
