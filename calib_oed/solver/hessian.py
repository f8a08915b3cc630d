r"""The exact Hessian of the Lagrangian, made positive definite for the QP.

The caller's ``lagrangian_hessian(x, lam)`` returns
:math:`\nabla^2_{xx} L(x, \lambda)` of :math:`L = f - \lambda^\top c` as a
:class:`~calib_oed.solver.result.StructuredHessian`

.. math::
    \nabla^2_{xx} L = D + U U^\top, \qquad D = \mathrm{blkdiag}(D_1, \dots, D_b),\;
    D_j = D_j^\top \in \mathbb{R}^{s \times s},\; U \in \mathbb{R}^{n \times r},

in units of :math:`f / x^2`. The blocks may be indefinite (the criterion's
curvature and :math:`-\sum_i \lambda_i \nabla^2 c_i` of the curved collision
rows, per pose); the QP needs a positive definite matrix. An eigenvalue
modification (Nocedal & Wright, *Numerical Optimization*, 2nd ed., 2006,
§3.4; Gill, Murray & Wright, *Practical Optimization*, 1981, §4.4.2) replaces
each eigenvalue :math:`\theta` of :math:`Q \Theta Q^\top` by

.. math::
    \tilde\theta = \max(|\theta|, \epsilon), \qquad
    \epsilon = \epsilon_r \max(1, \max|\theta|),

with :math:`\epsilon_r` = ``hessian_eigenvalue_floor`` and the max over every
eigenvalue modified (all blocks together), so one scale holds for the whole
matrix. The absolute value keeps the size of the curvature and flips its sign,
so a step along a direction of negative curvature is as long as along positive
curvature of the same size.

Each :math:`D_j` is modified on its own, :math:`O(b s^3)`;
:math:`\tilde D + U U^\top \succ 0` since :math:`U U^\top \succeq 0`. The
result stays a :class:`StructuredHessian` and goes to the lifted sparse QP
(:mod:`calib_oed.solver.lifted`). It modifies more than needed where the
coupling would have made :math:`D + U U^\top` definite anyway.

A coupling of many columns, :math:`r > n/3` (:data:`LIFTED_MAX_RANK_RATIO`), is
not lifted: :math:`\tilde D + U U^\top` goes to the QP as a dense matrix. The
lifted QP's time grows with :math:`r` and the dense one's does not (ProxQP,
:math:`n = 360`, 400 rows: lifted 40, 104, 208, 531 ms for :math:`r` = 20,
120, 240, 480; dense 110-220 ms, sparse 100-125 ms).
"""

from __future__ import annotations

import numpy as np

from calib_oed.solver.result import StructuredHessian

LIFTED_MAX_RANK_RATIO = 1.0 / 3.0
r"""Largest :math:`r / n` of the coupling kept factored (module docstring)."""


def _floor(theta, rel_floor: float) -> float:
    return rel_floor * max(1.0, float(np.max(np.abs(theta), initial=0.0)))


def modify_blocks(blocks, rel_floor: float = 1e-8) -> tuple[np.ndarray, int]:
    r"""Positive definite :math:`\tilde D_j` from symmetric (b, s, s) ``blocks``; ``(blocks, n_modified)``.

    Blocks whose eigenvalues all satisfy :math:`\theta \ge \epsilon` are
    returned as given (symmetrised); ``n_modified`` counts the eigenvalues changed.
    """
    blocks = np.asarray(blocks, dtype=float)
    blocks = 0.5 * (blocks + blocks.transpose(0, 2, 1))
    theta, q = np.linalg.eigh(blocks)
    eps = _floor(theta, rel_floor)
    new = np.maximum(np.abs(theta), eps)
    changed = new != theta
    bad = np.flatnonzero(changed.any(axis=1))
    if bad.size:
        blocks = blocks.copy()
        qb = q[bad]
        blocks[bad] = np.einsum("jab,jb,jcb->jac", qb, new[bad], qb)
    return blocks, int(changed.sum())


def check_structured(h, n: int) -> StructuredHessian:
    r"""``h`` as a :class:`StructuredHessian` of size :math:`n`, or ``ValueError`` saying what is wrong.

    Accepts a :class:`StructuredHessian` or a ``(blocks, low_rank)`` pair:
    ``blocks`` (b, s, s) with :math:`b s = n`, ``low_rank`` (n, r) or None,
    all finite.
    """
    try:
        blocks, low_rank = h
    except (TypeError, ValueError):
        raise ValueError(f"expected a StructuredHessian (blocks, low_rank), got {type(h).__name__}") from None
    blocks = np.asarray(blocks, dtype=float)
    if blocks.ndim != 3 or blocks.shape[1] != blocks.shape[2] or blocks.shape[0] * blocks.shape[1] != n:
        raise ValueError(f"blocks must have shape (b, s, s) with b * s = n = {n}, got {blocks.shape}")
    if not np.all(np.isfinite(blocks)):
        raise ValueError("blocks hold non-finite values")
    if low_rank is not None:
        low_rank = np.asarray(low_rank, dtype=float)
        if low_rank.ndim != 2 or low_rank.shape[0] != n:
            raise ValueError(f"low_rank must have shape (n, r) with n = {n}, got {low_rank.shape}")
        if not np.all(np.isfinite(low_rank)):
            raise ValueError("low_rank holds non-finite values")
        if low_rank.shape[1] == 0:
            low_rank = None
    return StructuredHessian(blocks, low_rank)


def positive_definite(h: StructuredHessian, rel_floor: float) -> tuple[StructuredHessian | np.ndarray, int]:
    r"""The QP Hessian from the exact one: ``(H, n_modified)`` (module docstring).

    A :class:`StructuredHessian` :math:`\mathrm{blkdiag}(\tilde D_j) + U U^\top`,
    or its dense matrix when :math:`r > n/3`.
    """
    blocks, n_mod = modify_blocks(h.blocks, rel_floor)
    out = StructuredHessian(blocks, h.low_rank)
    if h.low_rank is not None and h.low_rank.shape[1] > LIFTED_MAX_RANK_RATIO * h.low_rank.shape[0]:
        return out.dense(), n_mod
    return out, n_mod
