r"""Rows with a kink: the linearisations of their smooth pieces, as extra QP rows.

Some rows are only piecewise smooth. The distance of two convex polytopes is
:math:`c_i = \min_k c_i^{(k)}` over vertex-against-face distances where an edge
or a face rests on a face, and an optimum sits on such kinks as it sits on the
corners of a polytope. At a point on the kink the row's one gradient (that of
the piece its witness points happen to be on) overestimates
:math:`c_i(x + d)` *to first order* along every direction that crosses the
kink: the :math:`\ell_1` merit then rejects every step however small the trust
region, and the SQP stalls with a KKT residual no step can lower (the
`panda_cell` stall, docs/benchmarks.md).

So the caller may give the pieces: ``row_pieces(x, rows)`` returns, for rows
among ``rows`` that have a kink near :math:`x`, the values
:math:`c_i^{(k)}(x) \ge c_i(x)` and gradients :math:`\nabla c_i^{(k)}(x)` of
their smooth pieces, and the QP gets, besides :math:`c_i + A_i d \ge 0`,

.. math::
    c_i^{(k)}(x) + \nabla c_i^{(k)}(x)^\top d \ge 0 \quad \text{for every piece } k,

the linearisation of :math:`\min_k c_i^{(k)}` that a QP can hold (as the SQP
of Curtis & Overton, *SIAM J. Optim.* 22(2), 2012, 474–500, holds several
gradients of a nonsmooth constraint, here exact instead of sampled). The
pieces' multipliers :math:`\mu \ge 0` enter the KKT test
(:func:`calib_oed.solver.result.kkt_residuals`): at a kink

.. math::
    \nabla f = A^\top \lambda + \sum_{i,k} \mu_{ik} \nabla c_i^{(k)} + \nu,

stationarity with the gradients of the active pieces, i.e. in the sense of
Clarke for :math:`\min_k c_i^{(k)}` (Clarke, *Optimization and Nonsmooth
Analysis*, 1983, §2.3 and §6.1); for a row without a kink nothing changes.
The pieces' multipliers are also added to their rows' (``SQPResult.multipliers``
and the exact Hessian's :math:`\lambda`, where the row's curvature stands for
its pieces': a model approximation that the KKT test does not use).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import scipy.sparse as sp

from calib_oed.exceptions import ShapeError


class RowPieces(NamedTuple):
    r"""Linearisations of the smooth pieces of kinked rows, at one point :math:`x`.

    Attributes:
        rows: The row :math:`i` of each piece (k,).
        values: :math:`c_i^{(k)}(x)` (k,), units of :math:`c`.
        gradients: :math:`\nabla c_i^{(k)}(x)` (k, n), CSR.
    """

    rows: np.ndarray
    values: np.ndarray
    gradients: sp.csr_matrix

    @property
    def size(self) -> int:
        """Number of pieces."""
        return int(self.rows.size)

    @classmethod
    def none(cls, n: int) -> RowPieces:
        """No pieces, for ``n`` variables."""
        return cls(np.zeros(0, dtype=int), np.zeros(0), sp.csr_matrix((0, n)))


def check_pieces(value, n: int, m: int) -> RowPieces:
    """The caller's ``row_pieces`` answer as :class:`RowPieces`, shapes and values checked."""
    if value is None:
        return RowPieces.none(n)
    rows, values, grads = value
    rows = np.asarray(rows, dtype=int).reshape(-1)
    values = np.asarray(values, dtype=float).reshape(-1)
    grads = sp.csr_matrix(grads)
    k = rows.size
    if values.shape != (k,) or grads.shape != (k, n):
        raise ShapeError("row pieces", f"rows (k,), values (k,), gradients (k, {n})",
                         (rows.shape, values.shape, grads.shape))
    if k and (rows.min() < 0 or rows.max() >= m):
        raise ShapeError("row pieces' rows", f"indices in [0, {m})", (int(rows.min()), int(rows.max())))
    if not (np.all(np.isfinite(values)) and np.all(np.isfinite(grads.data))):
        raise FloatingPointError("row pieces: non-finite values or gradients")
    return RowPieces(rows, values, grads)
