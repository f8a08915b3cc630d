r"""Sequential quadratic programming for inequality-constrained NLPs.

.. math::
    \min_{x \in \mathbb{R}^n} f(x) \quad \text{s.t.} \quad
    c(x) \ge 0 \;(m \text{ rows}), \qquad lb \le x \le ub.

Built for optimal experimental design: :math:`n \approx 360` joint angles
[rad], :math:`m \approx 3600` collision-distance and incidence rows with a
sparse block-diagonal Jacobian :math:`A = \partial c / \partial x`, most rows
far from active; :math:`f` scaled by the caller to O(1). One iteration at
:math:`x_k` (Nocedal & Wright, *Numerical Optimization*, 2nd ed., 2006,
"N&W" below, ch. 18):

1. **QP subproblem** with the trust region :math:`\|d\|_\infty \le \Delta_k`
   merged into the variable bounds as one box,

   .. math::
       \min_d \tfrac12 d^\top B_k d + \nabla f_k^\top d \quad \text{s.t.} \quad
       c_i + A_i d \ge 0 \;(i \in K_k), \qquad
       \max(lb - x_k, -\Delta_k) \le d \le \min(ub - x_k, \Delta_k),

   solved by ProxQP (:mod:`calib_oed.solver.qp`), warm-started from the previous
   multipliers, its residuals checked by us, small steps polished on their
   active set. Its multipliers :math:`\lambda_{k+1} \ge 0` (0 for dropped rows)
   are the multiplier estimates.
2. **Row selection**: :math:`i \in K_k` iff
   :math:`c_i - \|A_i\|_1 \Delta_k \le m_a` (``active_margin``). Inside the box
   :math:`|A_i d| \le \|A_i\|_1 \Delta_k`, so a dropped row cannot reach 0 under
   the linearisation: for :math:`m_a \ge 0` dropping it does not change the QP.
3. **Hessian**: damped BFGS (N&W §18.3, Procedure 18.2; Powell 1978) on the
   Lagrangian gradient difference
   :math:`y = \nabla_x L(x_{k+1}, \lambda_{k+1}) - \nabla_x L(x_k, \lambda_{k+1})`,
   from :math:`B_0 = \beta I`, rescaled before the first update to
   :math:`(y^\top y / s^\top y) I` (Shanno–Phua; N&W eq. 6.20).
4. **Globalisation**: the :math:`\ell_1` merit (N&W §15.4 and §18.3, "Merit functions")

   .. math::
       \phi_\mu(x) = f(x) + \mu \Big(\sum_i \max(0, -c_i(x))
       + \sum_j \max(0, lb_j - x_j) + \max(0, x_j - ub_j)\Big),

   :math:`\mu_k = \max(\mu_{k-1}, \|\lambda_{k+1}\|_\infty + \mu_m)`, nondecreasing, so
   that :math:`d` is a descent direction (N&W Theorem 18.2). Armijo backtracking
   (:meth:`_Run._line_search`) on
   :math:`\phi(x + \alpha d) \le \phi(x) + \eta \alpha D` with the directional
   derivative :math:`D = \nabla f^\top d - \mu \sum_i \max(0, -c_i)` (same
   theorem). Trust region: after a backtrack
   :math:`\Delta \leftarrow \max(\Delta_\min, \tfrac12 \|\alpha d\|_\infty)`; after a
   full step that reached the edge, :math:`\Delta \leftarrow \min(2\Delta, \Delta_\max)`;
   after any other accepted step :math:`\Delta \leftarrow \min(\Delta, \kappa \|\alpha d\|_\infty)`
   (``step_bound_ratio``), so the box, and the rows kept, shrink with the steps.
   When the full step is rejected, a second-order correction is tried first
   (:meth:`_Run._second_order_correction`, against the Maratos effect of
   curved active constraints). A step rejected after ``max_backtracks``
   leaves :math:`x_k` and cuts :math:`\Delta` tenfold.
5. **Infeasible QP** (only possible at an infeasible :math:`x_k`: at a feasible
   one :math:`d = 0` is feasible). A row no :math:`d` in the box can satisfy is
   found in :math:`O(\text{nnz})` (:func:`calib_oed.solver.qp.unreachable_rows`)
   before ProxQP is called, which does not detect infeasibility and would run
   to its iteration limit. Retry with :math:`\Delta_\max` (a smaller box
   only shrinks the feasible set), then take a restoration step from the
   elastic QP (:func:`calib_oed.solver.qp.solve_elastic_qp`) with backtracking on
   the violation (:meth:`_Run._restore`); if that cannot reduce the violation,
   stop with :attr:`SQPStatus.INFEASIBLE` (:attr:`SQPStatus.STALLED` if the
   violation is already within ``tol_feasibility``: then the linearisation is
   inconsistent, e.g. degenerate active rows, not the problem). A QP that fails at a feasible
   :math:`x_k` (numerical trouble) is retried with :math:`\Delta / 10`, then
   :attr:`SQPStatus.FAILED`.
6. **Stop**: :attr:`SQPStatus.CONVERGED` when :math:`r_p \le` ``tol_feasibility``
   and :math:`r_d, r_c \le` ``tol_optimality`` at :math:`x_k` with
   :math:`\lambda_{k+1}` (:mod:`calib_oed.solver.result` for the residuals);
   :attr:`SQPStatus.STALLED` when :math:`\|d\|_\infty \le` ``tol_step`` or the
   line search fails with :math:`\Delta = \Delta_\min`.

Bounds are kept exactly: :math:`x_0` is projected onto them and every step
stays inside, so their merit term is zero in practice.
"""

from __future__ import annotations

import time
from typing import NamedTuple

import numpy as np
import scipy.sparse as sp

from calib_oed.exceptions import NonFiniteError, ShapeError
from calib_oed.solver.qp import (
    QPStep,
    QPSubproblem,
    make_workspace,
    matvec,
    polish,
    solve_elastic_qp,
    unreachable_rows,
)
from calib_oed.solver.result import (
    IterationRecord,
    SQPProblemError,
    SQPResult,
    SQPSettings,
    SQPSettingsError,
    SQPStatus,
    kkt_residuals,
)

__all__ = ["SQPSettings", "SQPSettingsError", "SQPProblemError", "SQPStatus", "SQPResult",
           "IterationRecord", "solve_sqp", "damped_bfgs_update"]


class _Point(NamedTuple):
    r"""Everything known at one iterate: :math:`f, \nabla f, c, A`, violations, row norms."""

    x: np.ndarray
    f: float
    g: np.ndarray
    c: np.ndarray
    A: np.ndarray | sp.csr_matrix
    row_l1: np.ndarray  # ||A_i||_1
    violation_l1: float  # sum_i max(0, -c_i) + bound violation
    violation_max: float


class _Problem:
    """The caller's functions with shape checks, evaluation counts and timers."""

    def __init__(self, objective, constraints, n, lb, ub, times):
        self.objective, self.constraints = objective, constraints
        self.n, self.lb, self.ub, self.times = n, lb, ub, times
        self.m = None
        self.n_obj = self.n_con = 0

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


def damped_bfgs_update(B, s, y, damping=0.2, scale_first=False):
    r"""Damped BFGS update of :math:`B \succ 0` (N&W Procedure 18.2, Powell 1978).

    .. math::
        \theta = \begin{cases} 1 & s^\top y \ge \delta\, s^\top B s \\
        \dfrac{(1 - \delta)\, s^\top B s}{s^\top B s - s^\top y} & \text{otherwise,}\end{cases}
        \qquad r = \theta y + (1 - \theta) B s,

        B^+ = B - \frac{B s s^\top B}{s^\top B s} + \frac{r r^\top}{s^\top r},

    so that :math:`s^\top r \ge \delta\, s^\top B s > 0` and :math:`B^+ \succ 0`.
    With ``scale_first`` (first step), :math:`B` is first replaced by
    :math:`(y^\top y / s^\top y) I` when :math:`s^\top y > 0` (Shanno–Phua).
    Returns a new array; :math:`B` is unchanged if :math:`s^\top B s` is not positive.
    """
    sy = float(s @ y)
    if scale_first and sy > 0:
        B = np.eye(B.shape[0]) * float(np.clip(y @ y / sy, 1e-8, 1e8))
    Bs = matvec(B, s)
    sBs = float(s @ Bs)
    if not sBs > 0:
        return B
    theta = 1.0 if sy >= damping * sBs else (1.0 - damping) * sBs / (sBs - sy)
    r = theta * y + (1.0 - theta) * Bs
    B = B - np.outer(Bs, Bs) / sBs + np.outer(r, r) / float(s @ r)
    return 0.5 * (B + B.T)


_POLISH_BELOW = 1e-4
r"""Polish QP steps with :math:`\|d\|_\infty` at most this (and any step whose line search
failed): only there is ProxQP's ~1e-9 error, summed over the active rows of the
:math:`\ell_1` merit, comparable to the merit decrease. Larger steps do not need it, and
the dense solve would cost time for nothing (the design problem takes hundreds of
steps of ~1e-3)."""

_MESSAGES = {
    SQPStatus.CONVERGED: "KKT conditions satisfied to tolerance",
    SQPStatus.MAX_ITERATIONS: "iteration limit reached",
    SQPStatus.TIME_LIMIT: "wall-clock limit reached",
}


class _Run:
    """State of one :func:`solve_sqp` call; the iteration is in :meth:`iterate`."""

    def __init__(self, problem: _Problem, pt: _Point, lb, ub, settings: SQPSettings, t0,
                 hessian_model=None, block_size=None):
        s = self.s = settings
        self.p, self.pt, self.lb, self.ub, self.t0 = problem, pt, lb, ub, t0
        n, m = pt.x.size, pt.c.size
        self.hessian_model = hessian_model
        self.block_size = int(block_size) if block_size else n
        if n % self.block_size:
            raise ShapeError("Hessian block size", f"a divisor of n = {n}", (self.block_size,))
        nb, bs = n // self.block_size, self.block_size
        # quasi-Newton remainder: one BFGS matrix per diagonal block
        self.R = np.tile(np.eye(bs) * s.initial_hessian_scale, (nb, 1, 1))
        self.H0 = self._known_hessian(pt.x)
        self.B = self._assemble()
        self.first_update = True
        self.delta = s.step_bound
        self.mu = s.penalty_margin
        self.lam = np.zeros(m)  # multipliers of all rows, 0 for rows not in the QP
        self.nu = np.zeros(n)  # box multipliers of the last QP (warm start)
        self.ws = make_workspace(s.qp_backend, n, s.qp_eps_abs, s.qp_max_iterations)
        self.history: list[IterationRecord] = []
        self.status = self.message = None
        self.restoration_run = 0  # consecutive restoration steps
        self.restoration_reference = np.inf  # violation l1 ten restoration steps ago

    # ------------------------------------------------------------- QP
    def _rows(self, delta):
        pt = self.pt
        return np.flatnonzero(pt.c - pt.row_l1 * delta <= self.s.active_margin)

    def _qp(self, delta):
        """Solve the QP subproblem with trust region ``delta``; ``(rows, step, ok)``.

        The subproblem and its tolerances are kept in ``self._sub`` for the
        second-order correction.
        """
        pt, s = self.pt, self.s
        rows = self._rows(delta)
        sub = QPSubproblem(self.B, pt.g, pt.A[rows], -pt.c[rows],
                           np.maximum(self.lb - pt.x, -delta), np.minimum(self.ub - pt.x, delta))
        scale = max(1.0, float(np.max(np.abs(pt.c[rows]), initial=0.0)))
        tol_p = 10 * s.qp_eps_abs * scale
        tol_d = 10 * s.qp_eps_abs * max(scale, float(np.max(np.abs(pt.g), initial=0.0)))
        self._sub = (sub, tol_p, tol_d)
        if np.any(pt.c[rows] < 0):
            bad = unreachable_rows(sub.C, sub.lower, sub.box_lower, sub.box_upper, tol_p)
            if bad.size:  # infeasible for sure: do not let ProxQP run to its limit
                nan = np.full(pt.x.size, np.nan)
                return rows, QPStep(nan, np.zeros(rows.size), nan, "unreachable_row", 0,
                                    np.inf, np.inf, np.inf), False
        t = time.perf_counter()
        step = self._solve(sub, self.lam[rows], self.nu, tol_d)
        ok = step.is_solved(tol_p, tol_d)
        if not ok:  # a stale warm start can mislead ProxQP: once more from scratch
            cold = self._solve(sub, None, None, tol_d)
            step, ok = cold._replace(iterations=cold.iterations + step.iterations), cold.is_solved(tol_p, tol_d)
        self.p.times["qp"] += time.perf_counter() - t
        return rows, step, ok

    def _solve(self, sub, lam0, nu0, tol):
        step = self.ws.solve(sub, None, lam0, nu0)
        if (self.s.qp_polish and step.primal_residual <= 1e3 * tol
                and np.max(np.abs(step.d), initial=0.0) <= _POLISH_BELOW):
            step = polish(sub, step, tol) or step
        return step

    def _second_order_correction(self, rows, step, trial):
        r"""Second-order correction after a rejected full step (Fletcher 1987, §14.4; N&W §18.3).

        The full step :math:`d` satisfies the linearised constraints, but the
        curvature of the active ones makes :math:`c(x + d)` violated and the
        :math:`\ell_1` merit rejects it (the Maratos effect). Re-solve the QP with
        the constraint constants taken at :math:`x + d`,

        .. math::
            c_i(x + d) + A_i (p - d) \ge 0 \quad (i \in K),

        same :math:`B`, :math:`\nabla f`, box and warm start, and return the
        evaluated :math:`x + p` (``None`` if the QP fails) and the QP iterations.
        """
        pt = self.pt
        sub, tol_p, tol_d = self._sub
        a_k = pt.A[rows]
        sub = sub._replace(lower=-(trial.c[rows] - a_k @ step.d))
        if unreachable_rows(sub.C, sub.lower, sub.box_lower, sub.box_upper, tol_p).size:
            return None, 0
        t = time.perf_counter()
        corr = self._solve(sub, step.lam, step.nu, tol_d)
        self.p.times["qp"] += time.perf_counter() - t
        if not corr.is_solved(tol_p, tol_d):
            return None, corr.iterations
        return self._trial(pt.x + corr.d), corr.iterations

    # ------------------------------------------------------------- steps
    def _merit(self, pt: _Point):
        return pt.f + self.mu * pt.violation_l1

    def _known_hessian(self, x):
        if self.hessian_model is None:
            return None
        t = time.perf_counter()
        h0 = np.asarray(self.hessian_model(x), dtype=float)
        self.p.times["hessian"] += time.perf_counter() - t
        if h0.shape != (x.size, x.size) or not np.all(np.isfinite(h0)):
            raise ShapeError("known Hessian part", f"finite ({x.size}, {x.size})", h0.shape)
        return 0.5 * (h0 + h0.T)

    def _assemble(self):
        r""":math:`B = H_0 + \mathrm{blkdiag}(R_1..R_b)` (structured) or the BFGS matrix itself."""
        nb, bs = self.R.shape[0], self.R.shape[1]
        if nb == 1 and self.H0 is None:
            return self.R[0]
        B = np.zeros((nb * bs, nb * bs)) if self.H0 is None else self.H0.copy()
        for j in range(nb):
            B[j * bs:(j + 1) * bs, j * bs:(j + 1) * bs] += self.R[j]
        return B

    def _accept(self, new: _Point, lam):
        r"""Move to ``new``; damped BFGS update of the quasi-Newton part with multipliers ``lam``.

        Structured (``hessian_model`` given): :math:`B = H_0(x) + \mathrm{blkdiag}(R_j)`,
        each block :math:`R_j` updated with the residual secant pair
        :math:`(s_j,\; (y - H_0(x_{k+1}) s)_j)` (Dennis & Moré's structured
        secant idea; Nocedal & Wright §18.3 for the damping). Without it, one
        dense BFGS matrix (one block of size n).
        """
        t = time.perf_counter()
        old = self.pt
        s = new.x - old.x
        if lam.size:
            y = (new.g - new.A.T @ lam) - (old.g - old.A.T @ lam)
        else:
            y = new.g - old.g
        self.p.times["hessian"] += time.perf_counter() - t
        self.H0 = self._known_hessian(new.x)
        t = time.perf_counter()
        if self.H0 is not None:
            y = y - self.H0 @ s
        bs = self.block_size
        for j in range(self.R.shape[0]):
            sl = slice(j * bs, (j + 1) * bs)
            self.R[j] = damped_bfgs_update(self.R[j], s[sl], y[sl], self.s.bfgs_damping, self.first_update)
        self.B = self._assemble()
        self.first_update = False
        self.p.times["hessian"] += time.perf_counter() - t
        self.pt = new

    def _trial(self, x):
        return self.p.evaluate(np.clip(x, self.lb, self.ub), strict=False)

    def _record(self, k, stat, step_norm, delta, n_rows, qp_status, qp_iter, backtracks, restoration,
                corrected=False):
        pt = self.pt
        rec = IterationRecord(k, pt.f, self._merit(pt), self.mu, pt.violation_max, stat, step_norm,
                              delta, int(n_rows), qp_status, int(qp_iter), int(backtracks),
                              bool(restoration), time.perf_counter() - self.t0, bool(corrected))
        self.history.append(rec)
        return rec

    def _stop(self, status, message=None):
        self.status, self.message = status, message or _MESSAGES[status]

    def iterate(self, k):
        """One iteration; returns its record."""
        s, pt = self.s, self.pt
        delta = self.delta
        rows, step, ok = self._qp(delta)
        qp_iter = step.iterations
        if not ok:
            if np.any(pt.c[rows] < 0):  # a larger box may make the linearisation feasible
                if delta < s.max_step_bound:
                    delta = s.max_step_bound
                    rows, step, ok = self._qp(delta)
                    qp_iter += step.iterations
                if not ok:
                    return self._restore(k, delta, step.status, qp_iter)
            else:  # d = 0 is feasible: a numerical failure; a smaller box is an easier QP
                delta = max(s.min_step_bound, 0.1 * delta)
                rows, step, ok = self._qp(delta)
                qp_iter += step.iterations
                if not ok:
                    self._stop(SQPStatus.FAILED, f"QP subproblem not solved at a feasible point "
                               f"(ProxQP status {step.status!r}, primal residual {step.primal_residual:.2e})")
                    return self._record(k, np.nan, 0.0, delta, rows.size, step.status, qp_iter, 0, False)
        self.delta = delta
        self.restoration_run = 0
        self.lam = np.zeros(pt.c.size)
        self.lam[rows] = step.lam
        self.nu = step.nu
        stat, comp, _ = kkt_residuals(pt.x, pt.g, pt.c, pt.A, self.lam, self.lb, self.ub, s.tol_feasibility)
        n_rows = rows.size
        if pt.violation_max <= s.tol_feasibility and stat <= s.tol_optimality and comp <= s.tol_optimality:
            self._stop(SQPStatus.CONVERGED)
            return self._record(k, stat, 0.0, delta, n_rows, step.status, qp_iter, 0, False)
        d_norm = float(np.max(np.abs(step.d), initial=0.0))
        if d_norm <= s.tol_step:
            self._stop(SQPStatus.STALLED, f"QP step {d_norm:.1e} below tol_step without convergence "
                       f"(violation {pt.violation_max:.1e}, stationarity {stat:.1e})")
            return self._record(k, stat, 0.0, delta, n_rows, step.status, qp_iter, 0, False)
        self.mu = max(self.mu, float(np.max(step.lam, initial=0.0)) + s.penalty_margin)
        new, backtracks, soc, its = self._line_search(rows, step)
        qp_iter += its
        if new is None and s.qp_polish and not step.polished:  # QP error may be the cause
            exact = polish(self._sub[0], step, self._sub[2])
            if exact is not None:
                step, d_norm = exact, float(np.max(np.abs(exact.d), initial=0.0))
                self.lam[rows], self.nu = exact.lam, exact.nu
                new, backtracks, soc, its = self._line_search(rows, step)
                qp_iter += its
        if new is None:  # no sufficient decrease: stay, shrink the box
            if delta <= s.min_step_bound:
                self._stop(SQPStatus.STALLED, "line search failed with the trust region at min_step_bound")
            self.delta = max(s.min_step_bound, 0.1 * min(delta, d_norm))
            return self._record(k, stat, 0.0, delta, n_rows, step.status, qp_iter, backtracks, False)
        step_norm = float(np.max(np.abs(new.x - pt.x), initial=0.0))
        self._accept(new, self.lam)
        if backtracks:
            self.delta = max(s.min_step_bound, 0.5 * step_norm)
        elif d_norm >= 0.99 * delta:
            self.delta = min(s.max_step_bound, 2.0 * delta)
        else:
            self.delta = max(s.min_step_bound, min(delta, s.step_bound_ratio * step_norm))
        return self._record(k, stat, step_norm, delta, n_rows, step.status, qp_iter, backtracks,
                            False, soc)

    def _line_search(self, rows, step):
        r"""Armijo backtracking on :math:`\phi_\mu` along the QP step, with one SOC try.

        Returns ``(point or None, backtracks, corrected, QP iterations)``. The
        test is :math:`\phi(x + \alpha d) \le \phi(x) + \eta \alpha D^- + 10 \varepsilon
        \max(1, |\phi(x)|)` with :math:`D^- = \min(D, 0)`: the last term accepts
        changes below rounding (as IPOPT does, Wächter & Biegler 2006, §3.9), and
        :math:`D \ge 0`, which only QP or rounding error can cause, then asks
        for no increase.
        """
        s, pt, d = self.s, self.pt, step.d
        phi0 = self._merit(pt)
        phi0 += 10 * np.finfo(float).eps * max(1.0, abs(phi0))
        slope = min(float(pt.g @ d) - self.mu * pt.violation_l1, 0.0)  # N&W Theorem 18.2
        alpha, its = 1.0, 0
        for backtracks in range(s.max_backtracks + 1):
            trial = self._trial(pt.x + alpha * d)
            if trial is not None and self._merit(trial) <= phi0 + s.armijo * alpha * slope:
                return trial, backtracks, False, its
            if backtracks == 0 and trial is not None and s.second_order_correction:
                corrected, its = self._second_order_correction(rows, step, trial)
                if corrected is not None and self._merit(corrected) <= phi0 + s.armijo * slope:
                    return corrected, 0, True, its
            alpha *= s.backtrack
        return None, s.max_backtracks, False, its

    def _restore(self, k, delta, qp_status, qp_iter):
        r"""Feasibility restoration: elastic QP, then backtracking on the violation :math:`h`.

        Accept :math:`x + \alpha d` when :math:`h(x + \alpha d) \le h(x) - \eta \alpha\, p`
        with :math:`p = h_K(x) - \sum_{i \in K} \max(0, -(c_i + A_i d))` the
        decrease the linearisation predicts (by convexity of the linearised
        :math:`h`, :math:`\alpha p` is its decrease along :math:`\alpha d`). On
        failure retry with a smaller box. Locally infeasible when :math:`p`
        vanishes, or when ten restoration steps in a row cut :math:`h` by
        less than 1 %.
        """
        s, pt = self.s, self.pt
        n_rows = 0
        for _ in range(4):
            rows = self._rows(delta)
            n_rows = rows.size
            c_k, a_k = pt.c[rows], pt.A[rows]
            t = time.perf_counter()
            step = solve_elastic_qp(a_k, -c_k, c_k < 0, np.maximum(self.lb - pt.x, -delta),
                                    np.minimum(self.ub - pt.x, delta), s.restoration_penalty,
                                    s.qp_eps_abs, s.qp_max_iterations)
            self.p.times["qp"] += time.perf_counter() - t
            qp_iter += step.iterations
            h_now = float(np.maximum(-c_k, 0.0).sum())
            if step.status != "solved" and step.primal_residual > 1e-6 * max(1.0, h_now):
                self._stop(SQPStatus.FAILED, f"restoration QP not solved (ProxQP status {step.status!r})")
                return self._record(k, np.nan, 0.0, delta, rows.size, qp_status, qp_iter, 0, True)
            d = step.d
            pred = h_now - float(np.maximum(-(c_k + a_k @ d), 0.0).sum())
            if pred <= 1e-8 * max(1.0, h_now):
                break
            alpha = 1.0
            for backtracks in range(s.max_backtracks + 1):
                trial = self._trial(pt.x + alpha * d)
                if trial is not None and trial.violation_l1 <= pt.violation_l1 - s.armijo * alpha * pred:
                    return self._restored(k, trial, delta, rows.size, qp_status, qp_iter, backtracks)
                alpha *= s.backtrack
            delta = 0.5 * alpha * float(np.max(np.abs(d)))
            if delta < s.min_step_bound:
                break
        if pt.violation_max <= s.tol_feasibility:  # feasible to tolerance: not an infeasibility
            self._stop(SQPStatus.STALLED, "the linearised constraints are inconsistent at a point "
                       f"feasible to tolerance (violation {pt.violation_max:.2e} <= tol_feasibility "
                       f"{s.tol_feasibility:.0e}) and restoration cannot reduce it further")
        else:
            self._stop(SQPStatus.INFEASIBLE, "the linearised constraints are infeasible and restoration "
                       f"cannot reduce the violation ({pt.violation_max:.2e}): locally infeasible")
        return self._record(k, np.nan, 0.0, delta, n_rows, qp_status, qp_iter, 0, True)

    def _restored(self, k, trial, delta, n_rows, qp_status, qp_iter, backtracks):
        """Accept a restoration step; watch the progress of a run of them."""
        s = self.s
        if self.restoration_run == 0:
            self.restoration_reference = self.pt.violation_l1
        self.restoration_run += 1
        step_norm = float(np.max(np.abs(trial.x - self.pt.x), initial=0.0))
        self._accept(trial, self.lam)
        self.delta = max(s.min_step_bound, min(s.max_step_bound, step_norm))
        if self.restoration_run % 10 == 0:
            if trial.violation_l1 > 0.99 * self.restoration_reference:
                self._stop(SQPStatus.INFEASIBLE, f"restoration stalled: {self.restoration_run} steps "
                           f"left the violation at {trial.violation_max:.2e}: locally infeasible")
            self.restoration_reference = trial.violation_l1
        return self._record(k, np.nan, step_norm, delta, n_rows, qp_status, qp_iter, backtracks, True)


def solve_sqp(objective, x0, *, constraints=None, bounds=None, settings: SQPSettings | None = None,
              callback=None, hessian_model=None, block_size: int | None = None) -> SQPResult:
    r"""Minimise :math:`f(x)` s.t. :math:`c(x) \ge 0`, :math:`lb \le x \le ub` by SQP (module docstring).

    Args:
        objective: ``x -> (f, g)`` with :math:`f \in \mathbb{R}`, :math:`g = \nabla f(x) \in \mathbb{R}^n`.
        x0: Initial point :math:`\in \mathbb{R}^n`; projected onto the bounds.
        constraints: ``x -> (c, A)``, :math:`c \in \mathbb{R}^m` (feasible where
            :math:`c \ge 0`) and :math:`A = \partial c/\partial x \in \mathbb{R}^{m \times n}`
            as an ndarray or any scipy sparse matrix. ``None``: no constraints.
        bounds: ``(lb, ub)``, arrays of shape ``(n,)`` (or scalars), may hold ±inf.
        settings: :class:`SQPSettings`; defaults if ``None``.
        callback: Called with each :class:`IterationRecord`.
        hessian_model: Optional ``x -> H_0`` (n, n), a known positive
            semidefinite part of the Lagrangian's Hessian (e.g. the
            Gauss–Newton-like term of an OED criterion); the quasi-Newton
            matrices then only learn the remainder.
        block_size: Size of the diagonal blocks of the quasi-Newton remainder
            (e.g. the joints of one pose when every constraint and the unknown
            curvature are per pose); default one dense block.

    Returns:
        :class:`SQPResult`; call ``check()`` for the KKT residuals.

    Raises:
        ShapeError: ``x0``, the gradient, :math:`c` or :math:`A` has the wrong shape.
        NonFiniteError: ``x0`` or the functions' values at it are not finite.
        SQPProblemError: ``lb > ub`` somewhere.
    """
    t0 = time.perf_counter()
    s = settings if settings is not None else SQPSettings()
    x0 = np.asarray(x0, dtype=float)
    if x0.ndim != 1:
        raise ShapeError("x0", "(n,)", x0.shape)
    if not np.all(np.isfinite(x0)):
        raise NonFiniteError("x0", np.flatnonzero(~np.isfinite(x0)).tolist())
    n = x0.size
    lb, ub = _bounds(bounds, n)
    times = dict.fromkeys(("objective", "constraints", "qp", "hessian", "total"), 0.0)
    problem = _Problem(objective, constraints, n, lb, ub, times)
    run = _Run(problem, problem.evaluate(np.clip(x0, lb, ub), strict=True), lb, ub, s, t0,
               hessian_model, block_size)
    for k in range(s.max_iterations):
        record = run.iterate(k)
        if callback is not None:
            callback(record)
        if run.status is not None:
            break
        if time.perf_counter() - t0 > s.time_limit:
            run._stop(SQPStatus.TIME_LIMIT)
            break
    else:
        run._stop(SQPStatus.MAX_ITERATIONS)
    pt = run.pt
    # residuals at the final point with the latest multipliers (those of its QP when converged)
    stat, comp, nu_bounds = kkt_residuals(pt.x, pt.g, pt.c, pt.A, run.lam, lb, ub, s.tol_feasibility)
    times["total"] = time.perf_counter() - t0
    return SQPResult(
        x=pt.x, fun=pt.f, status=run.status, message=run.message, iterations=len(run.history),
        history=tuple(run.history), multipliers=run.lam, bound_multipliers=nu_bounds,
        max_violation=pt.violation_max, kkt_stationarity=stat, kkt_complementarity=comp, times=times,
        n_objective_evaluations=problem.n_obj, n_constraint_evaluations=problem.n_con)
