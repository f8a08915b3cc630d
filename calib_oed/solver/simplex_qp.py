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
order, with one BLAS thread, so the same input gives the same bits in any process;
approximate designs solved with it take 0.9-1.3x the CPU they take with ProxQP
(``bench/bench_simplex_qp.py``, ``docs/benchmarks.md``).

**Method.** Both phases solve, for a working set :math:`W` of bounds held
fixed at their values :math:`s_W = \ell_W` or :math:`u_W` (:math:`F` the free
indices), the working set's minimiser

.. math::
    \begin{pmatrix} H_{FF} & a_F \\ a_F^\top & 0 \end{pmatrix}
    \begin{pmatrix} x_F \\ \mu \end{pmatrix} =
    \begin{pmatrix} -g_F - H_{FW} s_W \\ b - a_W^\top s_W \end{pmatrix},
    \qquad x_W = s_W,

by LAPACK (LU, partial pivoting), with the bound multipliers
:math:`\nu_i = (Hx + g)_i + \mu a_i` (:math:`\nu_i \ge 0` at a lower bound,
:math:`\le 0` at an upper one). :math:`x` is the optimum when it is inside the
box and every :math:`\nu_i` has its sign (to rounding).

1. *Block principal pivoting* (Júdice & Pires, *Comput. Oper. Res.* 21, 1994;
   Kim & Park, *SIAM J. Sci. Comput.* 33, 2011, for NNLS): every free index
   outside its bound and every fixed one whose multiplier has the wrong sign
   changes side at once; when that does not lower the number of such indices,
   only the worst half of the last block changes (scored by violation relative
   to the largest), down to one. Few solves where the active set changes a lot
   (a Newton step that drops half the support).
2. If that has not converged after :data:`_PRIMAL_DUAL_CAP` solves, the primal
   active-set method (Nocedal & Wright, *Numerical Optimization*, 2nd ed.,
   Algorithm 16.3) from ``start``: move towards :math:`x` to the first bound met
   (first index on a tie), which joins :math:`W`; at :math:`x` release the most
   wrong multiplier (first index on a tie). Finite barring degenerate cycling,
   which its cap turns into a failure (``None``).

**Same bits.** The answer is the solution of the one linear system fixed by
the final working set and the input, whatever path led there; every choice
(ties, block sizes) is made by index order, no time or thread count enters,
and BLAS runs on one thread inside (a threaded LU or GEMV may sum in another
order). A free component within a rounding error outside its bound (a weakly
active bound) is set to it rather than exchanged.
"""

from __future__ import annotations

import numpy as np
from threadpoolctl import ThreadpoolController

__all__ = ["solve_simplex_qp"]

#: Bound violation of a working-set minimiser taken as rounding (relative to 1 + |x|).
_FEASIBILITY_TOL = 1e-13
#: Multiplier of the wrong sign taken as rounding (relative to the size of H x and g).
_MULTIPLIER_TOL = 1e-12

#: Iterations of block principal pivoting before the primal active-set method takes over.
_PRIMAL_DUAL_CAP = 100

_THREADS: list[ThreadpoolController] = []


def _one_blas_thread():
    """A context holding BLAS to one thread (a threaded LU or GEMV may sum in another order)."""
    if not _THREADS:
        _THREADS.append(ThreadpoolController())
    return _THREADS[0].limit(limits=1, user_api="blas")


def _minimiser(h, g, a, b, s_fixed, free):
    """The working set's minimiser ``x`` and equality multiplier ``mu`` (module docstring)."""
    f = np.flatnonzero(free)
    x = s_fixed.copy()
    if f.size == 0:
        return x, None
    hf = h[f]
    kkt = np.empty((f.size + 1, f.size + 1))
    kkt[:-1, :-1] = hf[:, f]
    kkt[:-1, -1] = a[f]
    kkt[-1, :-1] = a[f]
    kkt[-1, -1] = 0.0
    rhs = np.empty(f.size + 1)
    rhs[:-1] = -g[f] - hf @ s_fixed  # s_fixed is 0 on the free indices
    rhs[-1] = b - a @ s_fixed
    sol = np.linalg.solve(kkt, rhs)
    x[f] = sol[:-1]
    return x, float(sol[-1])


def _wrong_signs(h, g, a, x, mu, at_lower, at_upper):
    """How far each fixed bound's multiplier has the wrong sign (0 if right), and the rounding scale."""
    r = h @ x + g
    fixed = at_lower | at_upper
    if mu is None:  # nothing free: mu is any value making the multipliers feasible, if one exists
        idx = np.flatnonzero(fixed)
        ratio = -r[idx] / np.where(a[idx] != 0, a[idx], 1.0)
        mu = float(np.max(ratio[at_lower[idx]])) if at_lower[idx].any() else float(np.min(ratio))
    nu = r + mu * a
    wrong = np.where(at_lower, np.maximum(-nu, 0.0), 0.0) + np.where(at_upper, np.maximum(nu, 0.0), 0.0)
    return wrong, _MULTIPLIER_TOL * (1.0 + float(np.max(np.abs(r))) + float(np.max(np.abs(g))))


def _solve_on(h, g, a, b, lower, upper, at_lower, at_upper):
    """The working set's minimiser, whether it is inside the box (to rounding), and its multiplier."""
    s_fixed = np.where(at_lower, lower, np.where(at_upper, upper, 0.0))
    x, mu = _minimiser(h, g, a, b, s_fixed, ~(at_lower | at_upper))
    if not np.all(np.isfinite(x)):
        raise np.linalg.LinAlgError("non-finite working-set minimiser")
    slack = _FEASIBILITY_TOL * (1.0 + np.abs(x))
    return x, x < lower - slack, x > upper + slack, mu


def _primal_dual(h, g, a, b, lower, upper, at_lower, at_upper, cap):
    """Block principal pivoting (module docstring): the optimum, or ``None`` at the cap."""
    best, block = np.inf, None
    for _ in range(cap):
        x, below, above, mu = _solve_on(h, g, a, b, lower, upper, at_lower, at_upper)
        wrong, scale = _wrong_signs(h, g, a, x, mu, at_lower, at_upper)
        outside = np.maximum(lower - x, 0.0) + np.maximum(x - upper, 0.0)
        change = below | above | (wrong > scale)
        count = int(np.count_nonzero(change))
        if count == 0:
            return np.clip(x, lower, upper)
        if count < best:
            best, block = count, count
        else:  # no fewer infeasibilities: exchange only the worst half of the last block's size
            block = max(1, block // 2)
            score = np.where(change, outside / max(float(outside.max()), 1e-300)
                             + wrong / max(float(wrong.max()), 1e-300), -1.0)
            keep = np.argsort(-score, kind="stable")[:block]
            change = np.zeros_like(change)
            change[keep] = True
        at_lower = np.where(change, below, at_lower)
        at_upper = np.where(change, above, at_upper)
    return None


def _primal(h, g, a, b, lower, upper, s, at_lower, at_upper, cap):
    """The primal active-set method from the feasible ``s`` (module docstring), or ``None`` at the cap."""
    for _ in range(cap):
        x, below, above, mu = _solve_on(h, g, a, b, lower, upper, at_lower, at_upper)
        if not (below.any() or above.any()):
            x = np.clip(x, lower, upper)
            wrong, scale = _wrong_signs(h, g, a, x, mu, at_lower, at_upper)
            k = int(np.argmax(wrong))
            if wrong[k] <= scale:
                return x
            s = x
            at_lower[k] = at_upper[k] = False
            continue
        p = x - s
        with np.errstate(divide="ignore", invalid="ignore"):
            to_bound = np.where(p < 0, (lower - s) / p, np.where(p > 0, (upper - s) / p, np.inf))
        to_bound = np.where(at_lower | at_upper, np.inf, np.maximum(to_bound, 0.0))
        k = int(np.argmin(to_bound))
        s = s + min(float(to_bound[k]), 1.0) * p
        lo = p[k] < 0
        s[k] = lower[k] if lo else upper[k]
        at_lower[k], at_upper[k] = lo, not lo
    return None


def solve_simplex_qp(h, g, a, lower, upper, start, max_iterations: int | None = None,
                     fixed=None) -> np.ndarray | None:
    r"""The minimiser :math:`s` of the QP in the module docstring, or ``None`` if not found.

    Args:
        h: :math:`H`, (m, m), symmetric positive definite.
        g: :math:`g`, (m,).
        a: The equality row :math:`a`, (m,); :math:`b = a^\top` ``start``.
        lower, upper: The box, (m,), ``lower <= start <= upper``.
        start: A feasible point (m,).
        max_iterations: Working-set changes of the primal method before giving up
            (default ``10 m + 20``).
        fixed: Bounds to start the working set with (bool (m,)); only those ``start``
            meets are taken. Default: every bound ``start`` meets.

    Returns:
        :math:`s` (m,), the minimiser on the final working set with its bounds set
        exactly, or ``None`` (iteration cap, singular KKT matrix, non-finite values).
    """
    # own C-ordered copies: a Fortran-ordered H would take another BLAS path (other last bits)
    h, g, a = (np.array(x, dtype=float, order="C") for x in (h, g, a))
    lower, upper = np.array(lower, dtype=float), np.array(upper, dtype=float)
    s = np.clip(np.array(start, dtype=float), lower, upper)
    b = float(a @ s)
    m = s.size
    # warm start: the bounds the start meets (the approximate design's step starts at s = 0,
    # where every candidate of weight 0 is at its bound), or those of them the caller names
    at_lower = s <= lower
    at_upper = (s >= upper) & ~at_lower
    if fixed is not None:
        keep = np.asarray(fixed, dtype=bool)
        at_lower &= keep
        at_upper &= keep
    cap = 10 * m + 20 if max_iterations is None else int(max_iterations)
    with _one_blas_thread():
        try:
            x = _primal_dual(h, g, a, b, lower, upper, at_lower.copy(), at_upper.copy(),
                             min(cap, _PRIMAL_DUAL_CAP))
            return x if x is not None else _primal(h, g, a, b, lower, upper, s, at_lower, at_upper, cap)
        except np.linalg.LinAlgError:
            return None
