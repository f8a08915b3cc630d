r"""Which constraint rows enter the QP subproblem: the near-active ones, at most ``max_qp_rows``.

Inside the box :math:`\|d\|_\infty \le \Delta` the linearised row
:math:`c_i + A_i d` differs from :math:`c_i` by at most :math:`\|A_i\|_1 \Delta`,
so a row with :math:`c_i - \|A_i\|_1 \Delta > m_a \ge 0` (``active_margin``)
cannot reach 0 and leaving it out does not change the QP. Those left are the
*candidates*. Their number grows with :math:`\Delta` (15,800 of the rows of a
Panda cell at :math:`\Delta = 1` rad), so at most :math:`K` (``max_qp_rows``)
of them are kept, ordered by

.. math::
    r_i = c_i / \|A_i\|_1 \quad [\text{units of } x],

the ∞-norm step at which the linearisation of row :math:`i` reaches 0 (the
nearest to activity first; scale-free, unlike :math:`c_i` itself). Rows that
must stay come first whatever their :math:`r_i`: violated rows
(:math:`c_i < 0`), rows active at the last multipliers (:math:`\lambda_i > 0`)
and rows the caller marks (those a previous QP step violated). Every dropped
candidate has :math:`r_i \ge r_K`, so any QP step with
:math:`\|d\|_\infty < r_K` satisfies it; a step that does not is caught by
:func:`missed_rows` (one pass over the dropped rows' nonzeros) and the rows
it violates enter the QP (:mod:`calib_oed.solver.subproblem`). The merit
function and the line search see every row in any case: :math:`f` and
:math:`c` are always evaluated in full.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np


class RowSelection(NamedTuple):
    """Rows of one QP.

    Attributes:
        rows: Kept row indices, sorted.
        dropped: Candidate rows left out by the limit, sorted (check them with :func:`missed_rows`).
        n_candidates: Rows that pass the margin test.
    """

    rows: np.ndarray
    dropped: np.ndarray
    n_candidates: int


def row_distance(c, row_l1) -> np.ndarray:
    r""":math:`r_i = c_i / \|A_i\|_1`; :math:`\pm\infty` for a zero row (the sign of :math:`c_i`)."""
    c = np.asarray(c, dtype=float)
    out = np.where(c < 0, -np.inf, np.inf)
    nz = row_l1 > 0
    out[nz] = c[nz] / row_l1[nz]
    return out


def select_rows(c, row_l1, delta: float, margin: float, max_rows: int, must=None) -> RowSelection:
    r"""Candidates :math:`c_i - \|A_i\|_1 \Delta \le m_a`, at most ``max_rows`` of them.

    Args:
        c: :math:`c(x) \in \mathbb{R}^m`.
        row_l1: :math:`\|A_i\|_1 \in \mathbb{R}^m`.
        delta: Trust region :math:`\Delta` (∞-norm, units of :math:`x`).
        margin: :math:`m_a \ge 0` (units of :math:`c`).
        max_rows: :math:`K \ge 1`.
        must: Optional boolean mask (m,) of rows kept before the others
            (with :math:`c_i < 0`); among themselves, and among the rest, by
            :math:`r_i` ascending.

    Returns:
        :class:`RowSelection`; with at most ``max_rows`` candidates it keeps them
        all, as the plain margin rule does.
    """
    cand = np.flatnonzero(c - row_l1 * delta <= margin)
    if cand.size <= max_rows:
        return RowSelection(cand, cand[:0], int(cand.size))
    key = row_distance(c[cand], row_l1[cand])
    forced = c[cand] < 0
    if must is not None:
        forced |= must[cand]
    order = np.lexsort((key, ~forced))  # forced rows first, each group nearest first
    return RowSelection(np.sort(cand[order[:max_rows]]), np.sort(cand[order[max_rows:]]), int(cand.size))


def missed_rows(c, A, d, dropped, tol: float) -> np.ndarray:
    r"""Dropped rows the step violates under the linearisation: :math:`c_i + A_i d < -\text{tol}`.

    ``A`` is the full Jacobian (ndarray or scipy sparse); only the ``dropped``
    rows are multiplied (their nonzeros once).
    """
    if not dropped.size:
        return dropped
    lin = c[dropped] + np.asarray(A[dropped] @ d).reshape(-1)
    return dropped[lin < -tol]
