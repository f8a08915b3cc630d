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

**Where the step can move** (``hessian_modification="tangent"``; ``"auto"``, the default, up to
``tangent_max_size`` variables). The QP's step
keeps its active constraints, so what decides it is the curvature on their tangent space, the
reduced Hessian :math:`Z^\top H Z` (Nocedal & Wright 2006, §18.1 and §16.2). Flipping an
eigenvalue of :math:`D_j` whose eigenvector mixes constrained and free directions adds curvature
along the free ones too. Measured on ``fms_kr16``, 60 poses, ``kpi``: along the steps of a
170-iteration linear tail the flipped model's curvature :math:`d^\top\tilde H d` was 20-400 times
the true :math:`d^\top H d`, each step that much too short. The design's rows and bounds each
belong to one pose, so the active set splits by block: :math:`N_j` the normals of pose
:math:`j`'s active rows (multiplier > 0) and bounds (:math:`x` on them), :math:`Y_j` an orthonormal
basis of their span and :math:`Z_j` of its complement. In the basis :math:`[Z_j\;Y_j]`,

.. math::
    D_j = \begin{pmatrix} R & C \\ C^\top & S \end{pmatrix}, \qquad
    \tilde D_j = \begin{pmatrix} |R| & C \\ C^\top & W + |S - W| \end{pmatrix},
    \quad W = C^\top |R|^{-1} C,

with :math:`|\cdot|` the eigenvalue rule above: the tangent curvature :math:`R` is kept where it is
positive, the coupling :math:`C` kept, and the Schur complement in the constrained directions
made positive, so :math:`\tilde D_j \succ 0` and :math:`\tilde D_j = D_j` wherever :math:`R` and
:math:`S - W` are already positive definite. A block with no active constraint, or with its
directions all constrained, takes the whole-block rule. A row whose gradient spans two blocks
adds no normal (the rule then falls back towards the whole block's). ``"block"`` is the
whole-block rule for every block. Above 120 poses the tangent rule's steps follow flat
curvature further and took 37-48 % more SQP iterations on ``fms_kr16`` for a value
0.03-0.26 % lower, hence ``"auto"``.

A coupling of many columns, :math:`r > n/3` (:data:`LIFTED_MAX_RANK_RATIO`), is
not lifted: :math:`\tilde D + U U^\top` goes to the QP as a dense matrix. The
lifted QP's time grows with :math:`r` and the dense one's does not (ProxQP,
:math:`n = 360`, 400 rows: lifted 40, 104, 208, 531 ms for :math:`r` = 20,
120, 240, 480; dense 110-220 ms, sparse 100-125 ms).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from calib_oed.solver.result import StructuredHessian

LIFTED_MAX_RANK_RATIO = 1.0 / 3.0
r"""Largest :math:`r / n` of the coupling kept factored (module docstring)."""


def _floor(theta, rel_floor: float) -> float:
    return rel_floor * max(1.0, float(np.max(np.abs(theta), initial=0.0)))


def _recompose(q: np.ndarray, theta: np.ndarray) -> np.ndarray:
    r""":math:`Q\,\mathrm{diag}(\theta)\,Q^\top` per matrix of (k, p, p) ``q`` and (k, p) ``theta``."""
    return np.einsum("jab,jb,jcb->jac", q, theta, q)


def _abs_floor(m: np.ndarray, eps: float) -> tuple[np.ndarray, np.ndarray]:
    r""":math:`Q\max(|\Theta|, \epsilon)Q^\top` of symmetric (k, p, p) ``m``, and the eigenvalues changed per matrix."""
    theta, q = np.linalg.eigh(m)
    new = np.maximum(np.abs(theta), eps)
    return _recompose(q, new), (new != theta).sum(axis=1)


def modify_blocks(blocks, rel_floor: float = 1e-8, normals=None) -> tuple[np.ndarray, int]:
    r"""Positive definite :math:`\tilde D_j` from symmetric (b, s, s) ``blocks``; ``(blocks, n_modified)``.

    ``normals``: None, or (b, k, s) normals of each block's active constraints (zero rows
    for none), for the tangent rule (module docstring); None: the whole-block rule for
    every block. Blocks that need no change (whole block, or tangent part and Schur
    complement, with every eigenvalue :math:`\ge \epsilon`) are returned as given
    (symmetrised); ``n_modified`` counts the eigenvalues changed.
    """
    blocks = np.asarray(blocks, dtype=float)
    blocks = 0.5 * (blocks + blocks.transpose(0, 2, 1))
    theta, q = np.linalg.eigh(blocks)
    eps = _floor(theta, rel_floor)
    new = np.maximum(np.abs(theta), eps)
    changed = new != theta
    bad = np.flatnonzero(changed.any(axis=1))
    if not bad.size:
        return blocks, 0
    blocks = blocks.copy()
    s = blocks.shape[1]
    rank = np.zeros(bad.size, dtype=int)  # constrained directions of each block in bad
    if normals is not None and np.shape(normals)[1]:
        basis, rank = _active_bases(np.asarray(normals, dtype=float)[bad])
    whole = bad[(rank == 0) | (rank == s)]
    n_mod = int(changed[whole].sum())
    if whole.size:
        blocks[whole] = _recompose(q[whole], new[whole])
    for r in range(1, s):
        sel = np.flatnonzero(rank == r)
        if sel.size:
            n_mod += _modify_tangent(blocks, bad[sel], basis[sel], r, eps)
    return blocks, n_mod


def _active_bases(normals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per block, an orthonormal basis (s, s) whose first r columns span the normals, and r."""
    _, sv, vt = np.linalg.svd(normals, full_matrices=True)
    top = sv[:, :1] if sv.shape[1] else np.zeros((len(normals), 1))
    rank = (sv > 1e-10 * np.maximum(top, 1e-300)).sum(axis=1)
    return np.swapaxes(vt, 1, 2), rank


def _modify_tangent(blocks, idx, basis, r, eps) -> int:
    r"""The tangent rule in place on ``blocks[idx]``, r constrained directions (the basis's first r)."""
    d = np.einsum("jba,jbc,jcd->jad", basis, blocks[idx], basis)  # Q^T D Q: [S C^T; C R]
    sm, c, rr = d[:, :r, :r], d[:, r:, :r], d[:, r:, r:]
    r_new, k1 = _abs_floor(rr, eps)
    w = np.einsum("jza,jzb->jab", c, np.linalg.solve(r_new, c))
    schur = 0.5 * (sm - w + np.swapaxes(sm - w, 1, 2))
    s_new, k2 = _abs_floor(schur, eps)
    keep = (k1 == 0) & (k2 == 0)  # tangent part and Schur complement definite: D as given
    if np.all(keep):
        return 0
    m = d.copy()
    m[:, r:, r:] = r_new
    m[:, :r, :r] = w + s_new
    out = np.einsum("jab,jbc,jdc->jad", basis, m, basis)
    change = ~keep
    blocks[idx[change]] = 0.5 * (out[change] + np.swapaxes(out[change], 1, 2))
    return int(k1.sum() + k2.sum())


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


def positive_definite(h: StructuredHessian, rel_floor: float, normals=None) -> tuple[StructuredHessian | np.ndarray, int]:
    r"""The QP Hessian from the exact one: ``(H, n_modified)`` (module docstring).

    A :class:`StructuredHessian` :math:`\mathrm{blkdiag}(\tilde D_j) + U U^\top`,
    or its dense matrix when :math:`r > n/3`. ``normals``: as :func:`modify_blocks`.
    """
    blocks, n_mod = modify_blocks(h.blocks, rel_floor, normals)
    out = StructuredHessian(blocks, h.low_rank)
    if h.low_rank is not None and h.low_rank.shape[1] > LIFTED_MAX_RANK_RATIO * h.low_rank.shape[0]:
        return out.dense(), n_mod
    return out, n_mod


def active_normals(A, rows: np.ndarray, at_bound: np.ndarray, b: int, s: int) -> np.ndarray:
    r"""(b, k, s) normals of each block's active constraints for :func:`modify_blocks`.

    ``A`` the constraint Jacobian (m, b s), dense or scipy sparse; ``rows`` the active rows;
    ``at_bound`` (b s,) bool, the variables on a bound (a unit normal each). A row whose
    nonzeros span more than one block is left out. Zero rows pad the blocks with fewer
    than k normals.
    """
    blk, part = [], []
    if rows.size:
        a = sp.csr_matrix(A[rows]) if sp.issparse(A) else sp.csr_matrix(np.asarray(A)[rows])
        a.eliminate_zeros()
        counts = np.diff(a.indptr)
        owner = np.repeat(np.arange(len(rows)), counts)
        col_block = a.indices // s
        lo = np.full(len(rows), b)
        hi = np.full(len(rows), -1)
        np.minimum.at(lo, owner, col_block)
        np.maximum.at(hi, owner, col_block)
        ok = (counts > 0) & (lo == hi)
        dense = np.zeros((len(rows), s))
        np.add.at(dense, (owner, a.indices % s), a.data)
        blk.append(lo[ok])
        part.append(dense[ok])
    var = np.flatnonzero(at_bound)
    if var.size:
        unit = np.zeros((var.size, s))
        unit[np.arange(var.size), var % s] = 1.0
        blk.append(var // s)
        part.append(unit)
    if not blk:
        return np.zeros((b, 0, s))
    blk, part = np.concatenate(blk), np.concatenate(part)
    order = np.argsort(blk, kind="stable")
    blk, part = blk[order], part[order]
    count = np.bincount(blk, minlength=b)
    out = np.zeros((b, int(count.max(initial=0)), s))
    slot = np.arange(blk.size) - np.repeat(np.cumsum(count) - count, count)
    out[blk, slot] = part
    return out
