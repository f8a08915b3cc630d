r"""The caller's nonlinear program as the SQP sees it: evaluated, checked and timed.

:class:`_Problem` wraps ``objective: x -> (f, \nabla f)`` and
``constraints: x -> (c, A)`` (:math:`c \in \mathbb{R}^m`, feasible where
:math:`c \ge 0`, :math:`A = \partial c / \partial x`) with shape and
finiteness checks, evaluation counts and timers [s]; one evaluation is a
:class:`_Point`, which also carries the row norms :math:`\|A_i\|_1` and the
:math:`\ell_1` and :math:`\infty` violations of the rows and of the bounds.
With the caller's optional ``values: x -> (f, c)``, a trial point of a line
search is first evaluated without derivatives (:meth:`_Problem.evaluate_values`:
``g``, ``A`` and ``row_l1`` None) and completed only if it is accepted
(:meth:`_Problem.complete`); most trials are rejected.
:func:`_bounds` checks ``(lb, ub)``.
"""

from __future__ import annotations

import time
from typing import NamedTuple

import numpy as np
import scipy.sparse as sp

from calib_oed.exceptions import NonFiniteError, ShapeError
from calib_oed.solver.result import SQPProblemError


class _Point(NamedTuple):
    r"""Everything known at one iterate: :math:`f, \nabla f, c, A`, violations, row norms.

    ``g``, ``A`` and ``row_l1`` are None at a trial point evaluated by ``values`` alone."""

    x: np.ndarray
    f: float
    g: np.ndarray | None
    c: np.ndarray
    A: np.ndarray | sp.csr_matrix | None
    row_l1: np.ndarray | None  # ||A_i||_1
    violation_l1: float  # sum_i max(0, -c_i) + bound violation
    violation_max: float


class _Problem:
    """The caller's functions with shape checks, evaluation counts and timers."""

    def __init__(self, objective, constraints, n, lb, ub, times, values=None):
        self.objective, self.constraints, self.values = objective, constraints, values
        self.n, self.lb, self.ub, self.times = n, lb, ub, times
        self.m = None
        self.n_obj = self.n_con = self.n_values = 0

    def evaluate_values(self, x) -> _Point | None:
        """:math:`f, c` at ``x`` without derivatives (``values``), or the full :meth:`evaluate`
        without ``values``; ``None`` if not finite."""
        if self.values is None:
            return self.evaluate(x, strict=False)
        t = time.perf_counter()
        f, c = self.values(x)
        self.times["values"] += time.perf_counter() - t
        self.n_values += 1
        f, c = float(f), np.asarray(c, dtype=float).reshape(-1)
        m = 0 if self.constraints is None else self.m
        if c.shape != (m,):
            raise ShapeError("constraint values of `values`", f"({m},)", c.shape)
        if not (np.isfinite(f) and np.all(np.isfinite(c))):
            return None
        return self._point(x, f, None, c, None, None)

    def complete(self, pt: _Point) -> _Point | None:
        r"""``pt`` with :math:`\nabla f` and :math:`A` (evaluated at ``pt.x`` if missing); ``None`` if not finite."""
        return pt if pt.g is not None else self.evaluate(pt.x, strict=False)

    def evaluate(self, x, strict: bool) -> _Point | None:
        """Evaluate at ``x``; non-finite values raise if ``strict``, else give ``None``."""
        t = time.perf_counter()
        f, g = self.objective(x)
        self.times["objective"] += time.perf_counter() - t
        self.n_obj += 1
        f, g = float(f), np.asarray(g, dtype=float).reshape(-1)
        if g.shape != (self.n,):
            raise ShapeError("objective gradient", f"({self.n},)", g.shape)
        if self.constraints is None:
            c, A = np.zeros(0), sp.csr_matrix((0, self.n))
        else:
            t = time.perf_counter()
            c, A = self.constraints(x)
            self.times["constraints"] += time.perf_counter() - t
            self.n_con += 1
            c = np.asarray(c, dtype=float).reshape(-1)
            A = sp.csr_matrix(A) if sp.issparse(A) else np.asarray(A, dtype=float)
            if self.m is None:
                self.m = c.size
            if c.shape != (self.m,):
                raise ShapeError("constraint values", f"({self.m},)", c.shape)
            if A.shape != (self.m, self.n):
                raise ShapeError("constraint Jacobian", f"({self.m}, {self.n})", A.shape)
        a_data = A.data if sp.issparse(A) else A
        if not (np.isfinite(f) and np.all(np.isfinite(g)) and np.all(np.isfinite(c))
                and np.all(np.isfinite(a_data))):
            if strict:
                raise NonFiniteError("objective or constraints at the initial point")
            return None
        row_l1 = (np.asarray(abs(A).sum(axis=1)).ravel() if sp.issparse(A)
                  else np.abs(A).sum(axis=1))
        return self._point(x, f, g, c, A, row_l1)

    def _point(self, x, f, g, c, A, row_l1) -> _Point:
        neg = np.maximum(-c, 0.0)
        bnd = np.maximum(self.lb - x, 0.0) + np.maximum(x - self.ub, 0.0)
        vmax = max(float(np.max(neg, initial=0.0)), float(np.max(bnd, initial=0.0)))
        return _Point(x, f, g, c, A, row_l1, float(neg.sum() + bnd.sum()), vmax)


def _bounds(bounds, n):
    """``(lb, ub)`` as float arrays of shape ``(n,)``, checked."""
    if bounds is None:
        return np.full(n, -np.inf), np.full(n, np.inf)
    out = []
    for name, b in zip(("lb", "ub"), bounds, strict=True):
        b = np.asarray(b, dtype=float)
        if b.ndim > 1 or b.size not in (1, n):
            raise ShapeError(f"bounds {name}", f"({n},) or a scalar", b.shape)
        out.append(np.broadcast_to(b.reshape(-1), (n,)).copy())
    lb, ub = out
    if np.any(np.isnan(lb)) or np.any(np.isnan(ub)):
        raise NonFiniteError("bounds", np.flatnonzero(np.isnan(lb) | np.isnan(ub)).tolist())
    if np.any(lb > ub):
        bad = np.flatnonzero(lb > ub)
        raise SQPProblemError(f"bounds: lb > ub at indices {bad[:10].tolist()}; "
                              "every lower bound must be at most its upper bound", bad)
    return lb, ub
