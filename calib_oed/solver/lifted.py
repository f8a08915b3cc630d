r"""The QP subproblem with a structured Hessian, the coupling kept factored (lifted variables).

With :math:`H = D + U U^\top` (:math:`D = \mathrm{blkdiag}(D_1, \dots, D_b) \succ 0`,
:math:`D_j \in \mathbb{R}^{s \times s}`, :math:`U \in \mathbb{R}^{n \times r}`,
:class:`~calib_oed.solver.result.StructuredHessian`), the subproblem of
:mod:`calib_oed.solver.qp` is solved in the lifted variables
:math:`(d, w) \in \mathbb{R}^{n + r}`, :math:`w = U^\top d`:

.. math::
    \min_{d, w}\ \tfrac12 d^\top D d + \tfrac12 w^\top w + g^\top d
    \quad \text{s.t.} \quad U^\top d - w = 0, \quad C d \ge \ell, \quad
    \underline{b} \le d \le \overline{b}.

Eliminating :math:`w` gives back :math:`\tfrac12 d^\top (D + U U^\top) d + g^\top d`:
the same :math:`d`, the same multipliers. Its Hessian
:math:`\mathrm{blkdiag}(D, I_r)` has :math:`b s (s+1)/2 + r` nonzeros (upper
triangle) instead of :math:`n(n+1)/2`, the :math:`r` equality rows
:math:`n r + r`: for :math:`n = 360`, :math:`s = 6`, :math:`r = 40` about
16,000 instead of 65,000, and the factorisation ProxQP's sparse backend
computes stays :math:`O(n r^2)`. The dual of the equality rows is
:math:`y = w` (stationarity in :math:`w`); it is warm-started with :math:`U^\top d_0`.

The same workspace takes :math:`U = 0` (``low_rank=None``): then it is the
sparse QP of a block-diagonal Hessian, used for per-block BFGS matrices when
a QP is too large for the dense backend.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from calib_oed.solver.proxqp_build import proxsuite
from calib_oed.solver.qp import (
    QPSizeError,
    QPStep,
    QPSubproblem,
    SparseWorkspace,
    _configure,
    _finish,
    warm_duals,
)
from calib_oed.solver.result import StructuredHessian


def _block_pattern(b: int, s: int, r: int):
    """Row indices, (block, i, j) entries and column pointers of the upper triangle of blkdiag(D, I_r), CSC."""
    ii, jj = np.triu_indices(s)
    order = np.lexsort((ii, jj))  # column-major within a block
    ii, jj = ii[order], jj[order]
    blk = np.repeat(np.arange(b), ii.size)
    rows = np.concatenate([(blk * s + np.tile(ii, b)), b * s + np.arange(r)]).astype(np.int32)
    counts = np.concatenate([np.tile(np.arange(1, s + 1), b), np.ones(r, dtype=int)])
    indptr = np.concatenate([[0], np.cumsum(counts)]).astype(np.int32)
    return rows, (blk, np.tile(ii, b), np.tile(jj, b)), indptr


class LiftedQPWorkspace(SparseWorkspace):
    r"""ProxQP sparse on the lifted QP of a :class:`StructuredHessian` (module docstring).

    The QP object is reused (``update``) while the block sizes, :math:`r` and
    the pattern of :math:`C` stay the same (e.g. the second-order correction
    QP after the QP of the same iteration); otherwise a new one is built.
    A QP of more than ``max_nonzeros`` nonzeros raises :class:`QPSizeError`
    before ProxQP allocates.
    """

    def __init__(self, n: int, eps_abs: float, max_iter: int, max_nonzeros: int | None = None):
        super().__init__(n, eps_abs, max_iter, max_nonzeros)
        self._key = None

    def _matrices(self, H: StructuredHessian, C):
        n = self.n
        b, s, _ = H.blocks.shape
        U = H.low_rank if H.low_rank is not None else np.zeros((n, 0))
        r = U.shape[1]
        k = C.shape[0]
        C = sp.csr_matrix(C) if k else sp.csr_matrix((0, n))
        nnz = b * s * (s + 1) // 2 + r + n * r + r + C.nnz + n
        if self.max_nonzeros is not None and nnz > self.max_nonzeros:
            raise QPSizeError(f"lifted QP with {nnz:.3g} nonzeros above max_qp_nonzeros = {self.max_nonzeros:.3g}")
        if self._pattern is None or self._pattern[0] != (b, s, r):
            self._pattern = ((b, s, r), _block_pattern(b, s, r))
        h_rows, (blk, ii, jj), h_ptr = self._pattern[1]
        h_data = np.concatenate([H.blocks[blk, ii, jj], np.ones(r)])
        Hz = sp.csc_matrix((h_data, h_rows, h_ptr), shape=(n + r, n + r))
        a_ptr = np.concatenate([np.arange(n + 1) * r, n * r + np.arange(1, r + 1)]).astype(np.int32)
        a_rows = np.concatenate([np.tile(np.arange(r), n), np.arange(r)]).astype(np.int32)
        Az = sp.csc_matrix((np.concatenate([U.ravel(), -np.ones(r)]), a_rows, a_ptr), shape=(r, n + r))
        M = sp.vstack([C, sp.identity(n, format="csr")], format="csc")
        M.sort_indices()
        Cz = sp.csc_matrix((M.data, M.indices, np.concatenate([M.indptr, np.full(r, M.indptr[-1])])),
                           shape=(k + n, n + r))
        return Hz, Az, Cz, U, r

    def solve(self, sub: QPSubproblem, d0=None, lam0=None, nu0=None, refresh: bool = False) -> QPStep:
        """Solve ``sub`` (``sub.H`` a :class:`StructuredHessian`), warm-started from ``(d0, lam0, nu0)``;
        ``refresh`` recomputes the equilibration of a reused object."""
        n, k = self.n, sub.lower.size
        Hz, Az, Cz, U, r = self._matrices(sub.H, sub.C)
        gz = np.concatenate([sub.g, np.zeros(r)])
        lower = np.concatenate([sub.lower, sub.box_lower])
        upper = np.concatenate([np.full(k, np.inf), sub.box_upper])
        key = ((n, r, k), Cz.indptr.tobytes(), Cz.indices.tobytes())
        pq = proxsuite.proxqp
        if self._qp is None or key != self._key:
            qp = pq.sparse.QP(n + r, r, k + n)
            _configure(qp, self.eps_abs, self.max_iter)
            qp.init(Hz, gz, Az, np.zeros(r), Cz, lower, upper)
            self._qp, self._key = qp, key
        else:
            qp = self._qp
            qp.update(Hz, gz, Az, np.zeros(r), Cz, lower, upper, update_preconditioner=refresh)
        if d0 is not None or lam0 is not None or nu0 is not None:
            d = np.zeros(n) if d0 is None else np.asarray(d0, dtype=float)
            w = U.T @ d
            qp.solve(np.concatenate([d, w]), w, warm_duals(lam0, nu0, k, n))
        else:
            qp.settings.initial_guess = pq.InitialGuess.NO_INITIAL_GUESS
            qp.solve()
        res = qp.results
        return _finish(sub, res.x[:n], res.z[:k], res.z[k:], res.info)
