r"""A small dense QP with one equality row and a box, solved deterministically.

.. math::
    \min_{s \in \mathbb{R}^m} \tfrac12 s^\top H s + g^\top s \quad \text{s.t.} \quad
    a^\top s = b, \qquad \ell \le s \le u,

with :math:`H` symmetric positive definite: the step of the approximate
design's Newton iteration on the simplex (:mod:`calib_oed.oed.approximate`).

**Why not ProxQP.** ProxQP's dense solver returns solutions that differ in the
last bit for bit-identical inputs, depending on where its buffers are allocated
(Eigen's vectorised reductions start at an aligned address); the SQP that
starts from the approximate design amplifies that into another design. This
solver does every step through numpy/LAPACK on arrays of its own, in a fixed
order, so the same input gives the same bits in any process.

**Method**: the primal active-set method for convex QPs (Nocedal & Wright,
*Numerical Optimization*, 2nd ed., Algorithm 16.3). The working set :math:`W`
holds the bounds held fixed; with :math:`F` the free indices and
:math:`r = Hs + g`, each iteration solves the equality-constrained step

.. math::
    \begin{pmatrix} H_{FF} & a_F \\ a_F^\top & 0 \end{pmatrix}
    \begin{pmatrix} p_F \\ -\lambda \end{pmatrix} =
    \begin{pmatrix} -r_F \\ 0 \end{pmatrix}, \qquad p_W = 0,

moves along :math:`p` to the first bound it meets (adding it to :math:`W`), and
when :math:`p = 0` checks the bound multipliers :math:`\nu_i = r_i - \lambda a_i`
(:math:`\nu_i \ge 0` at a lower bound, :math:`\le 0` at an upper one), releasing
the most violated one (the first in index order on a tie). It starts from a
feasible point the caller gives. Finite for positive definite :math:`H` barring
degenerate cycling, which an iteration cap turns into a failure (``None``).
"""

from __future__ import annotations

import numpy as np

__all__ = ["solve_simplex_qp"]

#: Step norm below which the working set's minimiser is taken as reached (relative to 1 + |s|).
_STEP_TOL = 1e-14


def _equality_step(h, r, a, free):
    """Step ``p`` on the free indices and the equality multiplier ``lam`` (module docstring)."""
    f = np.flatnonzero(free)
    m = h.shape[0]
    p = np.zeros(m)
    if f.size == 0:
        return p, None
    kkt = np.zeros((f.size + 1, f.size + 1))
    kkt[:-1, :-1] = h[np.ix_(f, f)]
    kkt[:-1, -1] = a[f]
    kkt[-1, :-1] = a[f]
    sol = np.linalg.solve(kkt, np.concatenate([-r[f], [0.0]]))
    p[f] = sol[:-1]
    return p, -sol[-1]


def _release(r, a, lam, at_lower, at_upper) -> int | None:
    """The bound whose multiplier has the wrong sign by most, or ``None`` at the optimum."""
    fixed = at_lower | at_upper
    if lam is None:  # nothing free: lam is any value making the multipliers feasible, if one exists
        idx = np.flatnonzero(fixed)
        ratio = r[idx] / np.where(a[idx] != 0, a[idx], 1.0)
        lam = float(np.min(ratio[at_lower[idx]])) if at_lower[idx].any() else float(np.max(ratio))
    nu = r - lam * a
    wrong = np.where(at_lower, np.maximum(-nu, 0.0), 0.0) + np.where(at_upper, np.maximum(nu, 0.0), 0.0)
    scale = 1e-12 * (1.0 + float(np.max(np.abs(r))))
    k = int(np.argmax(wrong))
    return k if wrong[k] > scale else None


def solve_simplex_qp(h, g, a, lower, upper, start, max_iterations: int | None = None) -> np.ndarray | None:
    r"""The minimiser :math:`s` of the QP in the module docstring, or ``None`` if not found.

    Args:
        h: :math:`H`, (m, m), symmetric positive definite.
        g: :math:`g`, (m,).
        a: The equality row :math:`a`, (m,); :math:`b = a^\top` ``start``.
        lower, upper: The box, (m,), ``lower <= start <= upper``.
        start: A feasible point (m,).
        max_iterations: Active-set changes before giving up (default ``10 m + 20``).

    Returns:
        :math:`s` (m,) with the bounds it meets set exactly to the bound, or
        ``None`` (iteration cap, singular KKT matrix, non-finite values).
    """
    # own C-ordered copies: a Fortran-ordered H would take another BLAS path (other last bits)
    h, g, a = (np.array(x, dtype=float, order="C") for x in (h, g, a))
    lower, upper = np.array(lower, dtype=float), np.array(upper, dtype=float)
    s = np.clip(np.array(start, dtype=float), lower, upper)
    m = s.size
    # warm start: the bounds the start already meets form the working set (the approximate
    # design's step starts at s = 0, where every candidate of weight 0 is at its bound), so the
    # iterations scale with the support, not with the number of candidates
    at_lower = s <= lower
    at_upper = (s >= upper) & ~at_lower
    cap = 10 * m + 20 if max_iterations is None else int(max_iterations)
    for _ in range(cap):
        r = h @ s + g
        try:
            p, lam = _equality_step(h, r, a, ~(at_lower | at_upper))
        except np.linalg.LinAlgError:
            return None
        if not np.all(np.isfinite(p)):
            return None
        if np.linalg.norm(p) <= _STEP_TOL * (1.0 + np.linalg.norm(s)):
            k = _release(r, a, lam, at_lower, at_upper)
            if k is None:
                return s
            at_lower[k] = at_upper[k] = False
            continue
        alpha, block = 1.0, None
        with np.errstate(divide="ignore", invalid="ignore"):
            to_bound = np.where(p < 0, (lower - s) / p, np.where(p > 0, (upper - s) / p, np.inf))
        to_bound = np.maximum(to_bound, 0.0)
        k = int(np.argmin(to_bound))
        if to_bound[k] < 1.0:
            alpha, block = float(to_bound[k]), k
        s = s + alpha * p
        if block is not None:
            lo = p[block] < 0
            s[block] = lower[block] if lo else upper[block]
            at_lower[block], at_upper[block] = lo, not lo
    return None
