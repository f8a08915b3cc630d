r"""One SQP iteration and its globalisation (the algorithm of :mod:`calib_oed.solver.sqp`).

:class:`_Run` holds the state of one :func:`~calib_oed.solver.sqp.solve_sqp`
call (iterate, Hessian model :math:`B_k`, trust region :math:`\Delta_k`,
penalty :math:`\mu_k`, multipliers :math:`\lambda_k`) and makes one iteration:
row selection and the QP subproblem (items 1-2 of that module's docstring),
the :math:`\ell_1`-merit line search with second-order correction and the
trust-region update (item 4), feasibility restoration (item 5) and the
damped BFGS update of the quasi-Newton part (item 3).
"""

from __future__ import annotations

import time

import numpy as np

from calib_oed.exceptions import ShapeError
from calib_oed.solver.bfgs import damped_bfgs_update
from calib_oed.solver.nlp import _Point, _Problem
from calib_oed.solver.polish import polish
from calib_oed.solver.qp import QPStep, QPSubproblem, make_workspace
from calib_oed.solver.restoration import solve_elastic_qp, unreachable_rows
from calib_oed.solver.result import IterationRecord, SQPSettings, SQPStatus, kkt_residuals

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
    """State of one :func:`~calib_oed.solver.sqp.solve_sqp` call; the iteration is in :meth:`iterate`."""

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
