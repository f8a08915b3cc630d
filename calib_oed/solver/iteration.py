r"""One SQP iteration and its globalisation (the algorithm of :mod:`calib_oed.solver.sqp`).

:class:`_Run` holds the state of one :func:`~calib_oed.solver.sqp.solve_sqp`
call (iterate, Hessian model :math:`B_k`, trust region :math:`\Delta_k`,
penalty :math:`\mu_k`, multipliers :math:`\lambda_k`) and makes one iteration:
the QP subproblem (items 1-3 of that module's docstring; built and solved by
:class:`calib_oed.solver.subproblem._SubproblemMixin`), the
:math:`\ell_1`-merit line search with second-order correction and the
trust-region update (item 4), feasibility restoration (item 5,
:class:`calib_oed.solver.restoration._RestorationMixin`) and the damped BFGS
update of the quasi-Newton part (item 3), kept up to date even when the exact
Hessian is used, as its fallback.
"""

from __future__ import annotations

import time
from dataclasses import asdict

import numpy as np

from calib_oed.exceptions import ShapeError
from calib_oed.solver.bfgs import damped_bfgs_update
from calib_oed.solver.nlp import _Point, _Problem
from calib_oed.solver.pieces import RowPieces, check_pieces
from calib_oed.solver.polish import polish
from calib_oed.solver.qp import matvec
from calib_oed.solver.restoration import _RestorationMixin
from calib_oed.solver.result import IterationRecord, QPUse, SQPSettings, SQPStatus, kkt_residuals
from calib_oed.solver.subproblem import CRASHED, QPSolver, _SubproblemMixin

_MESSAGES = {
    SQPStatus.CONVERGED: "KKT conditions satisfied to tolerance",
    SQPStatus.MAX_ITERATIONS: "iteration limit reached",
    SQPStatus.TIME_LIMIT: "wall-clock limit reached",
}


class _Run(_SubproblemMixin, _RestorationMixin):
    """State of one :func:`~calib_oed.solver.sqp.solve_sqp` call; the iteration is in :meth:`iterate`."""

    def __init__(self, problem: _Problem, pt: _Point, lb, ub, settings: SQPSettings, t0,
                 block_size=None, lagrangian_hessian=None, row_pieces=None):
        s = self.s = settings
        self.p, self.pt, self.lb, self.ub, self.t0 = problem, pt, lb, ub, t0
        n, m = pt.x.size, pt.c.size
        self.lagrangian_hessian = lagrangian_hessian
        if block_size and n % int(block_size):
            raise ShapeError("Hessian block size", f"a divisor of n = {n}", (int(block_size),))
        # quasi-Newton remainder: one BFGS matrix per diagonal block. With an exact Hessian and
        # no block_size they take the blocks of the first one returned (_SubproblemMixin._exact_hessian):
        # a dense n x n fallback would cost O(n^2) memory for a matrix rarely used
        self.R = None
        if block_size or lagrangian_hessian is None:
            self._init_bfgs(int(block_size) if block_size else n)
        self._B = None  # dense B, assembled when a QP needs it (_SubproblemMixin._dense_bfgs)
        self.first_update = True
        self.delta = s.step_bound
        self.mu = s.penalty_margin
        self.mu_rows = np.full(m, s.penalty_margin) if s.penalty_weights == "row" else None
        self.lam = np.zeros(m)  # multipliers of all rows, 0 for rows not in the QP (+ their pieces')
        self.lam_rows = self.lam  # the same without the pieces' (for the KKT test)
        self.row_pieces = row_pieces  # the caller's pieces of kinked rows (calib_oed.solver.pieces)
        self.n_pieces = 0  # most pieces in one QP
        self._pieces_at = (-1, RowPieces.none(n))  # (point version, pieces there)
        self.pieces = RowPieces.none(n)  # those of the last QP solved, with
        self.lam_pieces = np.zeros(0)  # their multipliers, and the point version they belong to
        self.pieces_version = -1
        self._qp_rows = np.zeros(0, dtype=int)  # row of c behind each row of the last QP
        self.nu = np.zeros(n)  # box multipliers of the last QP (warm start)
        self.qp = QPSolver(n, s)
        self.max_rows = s.qp_row_limit(n)
        self._farkas = None  # (point version, QP row ids, y): a failed QP's Farkas certificate
        self.sticky = np.zeros(m, dtype=bool)  # dropped rows a QP step violated: preferred later
        self._version = 0  # counts accepted points (the exact Hessian is cached per point and lam)
        self._exact = self._exact_key = None
        self._use_exact = True
        self._info = QPUse()
        self._crash_message = ""  # of the QP that sent the iteration to restoration, if it crashed
        self.n_fallbacks, self.fallback_reason = 0, ""
        self.history: list[IterationRecord] = []
        self.status = self.message = None
        self.restoration_run = 0  # consecutive restoration steps
        self.restoration_reference = np.inf  # violation l1 ten restoration steps ago
        self.extrapolated = 1.0  # alpha of this iteration's step longer than the QP's (_extrapolate)

    @property
    def hessian_label(self) -> str:
        """The Hessian asked for (:attr:`calib_oed.solver.result.SQPResult.hessian`)."""
        return "bfgs" if self.lagrangian_hessian is None else "exact"

    def _init_bfgs(self, bs):
        """The BFGS blocks :math:`R_j = \beta I` of size ``bs``, if not there yet."""
        if self.R is None:
            n = self.pt.x.size
            self.R = np.tile(np.eye(bs) * self.s.initial_hessian_scale, (n // bs, 1, 1))

    # ------------------------------------------------------------- steps
    def _merit(self, pt: _Point):
        return pt.f + self._penalty(pt)

    def _penalty(self, pt: _Point) -> float:
        r"""The merit's penalty term at ``pt``: :math:`\mu v_1`, or with ``penalty_weights="row"``
        :math:`\sum_i w_i \max(0, -c_i) + \mu\,` (bound violation), :math:`w_i = \mu_i` on the rows
        the last QP held (:math:`\lambda_i > 0`), :math:`\mu \ge \max_i \mu_i` on the others:
        a row the step did not expect to bind is charged as with one penalty."""
        if self.mu_rows is None:
            return self.mu * pt.violation_l1
        rows = np.maximum(-pt.c, 0.0)
        weights = np.where(self.lam > 0, self.mu_rows, self.mu)
        return float(weights @ rows) + self.mu * max(pt.violation_l1 - float(rows.sum()), 0.0)

    def _accept(self, new: _Point, lam):
        r"""Move to ``new``; damped BFGS update of the quasi-Newton part with multipliers ``lam``.

        :math:`B = \mathrm{blkdiag}(R_j)`, each block :math:`R_j` updated with
        its part :math:`(s_j, y_j)` of the secant pair (Nocedal & Wright §18.3
        for the damping); without ``block_size``, one dense BFGS matrix (one
        block of size n).
        """
        t = time.perf_counter()
        old = self.pt
        s = new.x - old.x
        if lam.size:
            y = (new.g - new.A.T @ lam) - (old.g - old.A.T @ lam)
        else:
            y = new.g - old.g
        self._init_bfgs(new.x.size)
        bs = self.R.shape[1]
        for j in range(self.R.shape[0]):
            sl = slice(j * bs, (j + 1) * bs)
            r_j = damped_bfgs_update(self.R[j], s[sl], y[sl], self.s.bfgs_damping, self.first_update)
            self.R[j] = r_j if np.all(np.isfinite(r_j)) else np.eye(bs) * self.s.initial_hessian_scale
        self._B = None
        self.first_update = False
        self.p.times["hessian"] += time.perf_counter() - t
        self.pt = new
        self._version += 1

    def _trial(self, x):
        """The point ``x`` (clipped to the bounds) with values only when the caller gave ``values``."""
        return self.p.evaluate_values(np.clip(x, self.lb, self.ub))

    def _pieces(self) -> RowPieces:
        """The pieces of the kinked rows near activity at :math:`x_k` (:mod:`calib_oed.solver.pieces`), cached."""
        if self.row_pieces is None:
            return self._pieces_at[1]
        if self._pieces_at[0] != self._version:
            pt = self.pt
            near = np.flatnonzero(pt.c <= self.s.row_pieces_margin)
            t = time.perf_counter()
            pieces = (check_pieces(self.row_pieces(pt.x.copy(), near), pt.x.size, pt.c.size)
                      if near.size else RowPieces.none(pt.x.size))
            self.p.times["constraints"] += time.perf_counter() - t
            self._pieces_at = (self._version, pieces)
            self.n_pieces = max(self.n_pieces, pieces.size)
        return self._pieces_at[1]

    def _set_multipliers(self, rows, lam, nu):
        r"""Store a QP's multipliers: rows, pieces (also summed into their rows), box."""
        m = self.pt.c.size
        self.lam_rows = np.zeros(m)
        self.lam_rows[rows] = lam[:rows.size]
        self.pieces, self.lam_pieces = self._pieces(), lam[rows.size:]  # those of x_k's QP
        self.pieces_version = self._version
        self.lam = self.lam_rows + np.bincount(self.pieces.rows, self.lam_pieces, minlength=m)
        self.nu = nu

    def kkt(self):
        r""":math:`(r_d, r_c, \nu)` at :math:`x_k` with the last multipliers (:func:`kkt_residuals`).

        The pieces of kinked rows count with their multipliers when they were
        evaluated at :math:`x_k` (:mod:`calib_oed.solver.pieces`).
        """
        pt = self.pt
        pieces = None
        if self.pieces.size and self.pieces_version == self._version:
            pieces = (self.pieces.values, self.pieces.gradients, self.lam_pieces)
        return kkt_residuals(pt.x, pt.g, pt.c, pt.A, self.lam_rows, self.lb, self.ub,
                             self.s.tol_feasibility, pieces)

    def _record(self, k, stat, step_norm, delta, n_rows, qp_status, qp_iter, backtracks, restoration,
                corrected=False):
        pt, info = self.pt, self._info
        self.n_fallbacks += info.hessian_fallback
        rec = IterationRecord(k, pt.f, self._merit(pt), self.mu, pt.violation_max, stat, step_norm,
                              delta, int(n_rows), qp_status, int(qp_iter), int(backtracks),
                              bool(restoration), time.perf_counter() - self.t0, bool(corrected),
                              float(self.extrapolated), **asdict(info))
        self.history.append(rec)
        return rec

    def _stop(self, status, message=None):
        self.status, self.message = status, message or _MESSAGES[status]

    def _qp_failed(self, k, delta, rows, step, qp_iter):
        """Stop after a QP that failed at a feasible point; its record."""
        if step.status in CRASHED:
            self._stop(SQPStatus.QP_FAILED, f"QP subproblem failed ({step.status}): {step.message}")
        else:
            self._stop(SQPStatus.FAILED, f"QP subproblem not solved at a feasible point "
                       f"(ProxQP status {step.status!r}, primal residual {step.primal_residual:.2e})")
        return self._record(k, np.nan, 0.0, delta, rows.size, step.status, qp_iter, 0, False)

    def iterate(self, k):
        """One iteration; returns its record."""
        s, pt = self.s, self.pt
        delta = self.delta
        self._use_exact = True
        self._info = QPUse()
        self.extrapolated = 1.0
        rows, step, ok = self._qp(delta)
        qp_iter = step.iterations
        if not ok and self._info.hessian == "exact" and step.status != "unreachable_row":
            self._fallback(f"QP with the exact Hessian failed ({step.status}"
                           + (f": {step.message})" if step.message else ")"))
            self._use_exact = False  # the BFGS matrices for the rest of this iteration
            rows, step, ok = self._qp(delta)
            qp_iter += step.iterations
        if not ok:
            crashed = step.status in CRASHED
            self._crash_message = step.message if crashed else ""
            if np.any(pt.c[rows] < 0) and not (crashed and pt.violation_max <= s.tol_feasibility):
                # a larger box may make the linearisation feasible: just large enough for
                # every violated row to reach 0 under its linearisation (|A_i d| <= ||A_i||_1 D),
                # with a factor 2 to spare, not the largest box (a long step through curved
                # rows is then cut by many backtracks)
                if delta < s.max_step_bound and not crashed:
                    bad = pt.c < 0
                    need = float(np.max(-pt.c[bad] / np.maximum(pt.row_l1[bad], 1e-300),
                                        initial=0.0))
                    delta = min(s.max_step_bound, max(4.0 * delta, 2.0 * need))
                    rows, step, ok = self._qp(delta)
                    qp_iter += step.iterations
                    if not ok and delta < s.max_step_bound:
                        delta = s.max_step_bound
                        rows, step, ok = self._qp(delta)
                        qp_iter += step.iterations
                if not ok:
                    return self._restore(k, delta, step.status, qp_iter)
            else:  # d = 0 is feasible (to tolerance): a numerical failure; a smaller box is an easier QP
                delta = max(s.min_step_bound, 0.1 * delta)
                rows, step, ok = self._qp(delta)
                qp_iter += step.iterations
                if not ok:
                    return self._qp_failed(k, delta, rows, step, qp_iter)
        self.delta = delta
        self.restoration_run = 0
        self._set_multipliers(rows, step.lam, step.nu)
        stat, comp, _ = self.kkt()
        n_rows = rows.size
        if pt.violation_max <= s.tol_feasibility and stat <= s.tol_optimality and comp <= s.tol_optimality:
            self._stop(SQPStatus.CONVERGED)
            return self._record(k, stat, 0.0, delta, n_rows, step.status, qp_iter, 0, False)
        d_norm = float(np.max(np.abs(step.d), initial=0.0))
        if d_norm <= s.tol_step:
            self._stop(SQPStatus.STALLED, f"QP step {d_norm:.1e} below tol_step without convergence "
                       f"(violation {pt.violation_max:.1e}, stationarity {stat:.1e})")
            return self._record(k, stat, 0.0, delta, n_rows, step.status, qp_iter, 0, False)
        need = float(np.max(self.lam, initial=0.0)) + s.penalty_margin
        self.mu = max(need, 0.5 * (self.mu + need))  # Powell (1978): may fall back after a spike
        if self.mu_rows is not None:  # Powell's (1978) update per row; the QP's active rows are
            # charged at theirs, a row the QP did not hold (lambda_i = 0) at mu (_penalty)
            need_rows = self.lam + s.penalty_margin
            self.mu_rows = np.maximum(need_rows, 0.5 * (self.mu_rows + need_rows))
        new, backtracks, soc, its = self._line_search(rows, step)
        qp_iter += its
        if (new is None and s.qp_polish and not step.polished  # QP error may be the cause
                and pt.x.size <= s.max_dense_qp_size):
            exact = polish(self._sub[0], step, self._sub[2])
            if exact is not None:
                step, d_norm = exact, float(np.max(np.abs(exact.d), initial=0.0))
                self._set_multipliers(rows, exact.lam, exact.nu)
                new, backtracks, soc, its = self._line_search(rows, step)
                qp_iter += its
        if new is None:  # no sufficient decrease: stay, shrink the box
            if delta <= s.min_step_bound:
                self._stop(SQPStatus.STALLED, "line search failed with the trust region at min_step_bound")
            self.delta = max(s.min_step_bound, 0.1 * min(delta, d_norm))
            return self._record(k, stat, 0.0, delta, n_rows, step.status, qp_iter, backtracks, False)
        step_norm = float(np.max(np.abs(new.x - pt.x), initial=0.0))
        self._accept(new, self.lam)
        if self.extrapolated > 1.0:  # the model was too pessimistic: a longer step that reached the box doubles it
            self.delta = min(s.max_step_bound, 2.0 * delta) if step_norm >= 0.99 * delta else delta
        elif s.trust_update == "ratio":
            self.delta = self._ratio_update(pt, new, step.d, delta, d_norm, backtracks)
        elif backtracks:  # the model failed at this radius: shrink it as a failed search does,
            # but not below the step accepted (halving the cut step instead collapsed the box
            # to 1e-4 rad on curved collision rows, and regrowing it cost ~7 iterations a time)
            self.delta = max(s.min_step_bound, 0.5 * step_norm, 0.1 * min(delta, d_norm))
        elif d_norm >= 0.99 * delta:
            self.delta = min(s.max_step_bound, 2.0 * delta)
        else:
            self.delta = max(s.min_step_bound, min(delta, s.step_bound_ratio * step_norm))
        return self._record(k, stat, step_norm, delta, n_rows, step.status, qp_iter, backtracks,
                            False, soc)

    def _ratio_update(self, old: _Point, new: _Point, d, delta, d_norm, backtracks) -> float:
        r""":math:`\Delta_{k+1}` of ``trust_update="ratio"`` after the accepted point ``new``.

        :math:`\rho = (\phi_\mu(x_k) - \phi_\mu(x_{k+1})) / (-g^\top d - \tfrac12 d^\top B d
        + \mu v_1(x_k))`, the merit's actual over the QP model's predicted reduction
        (:math:`v_1` the :math:`\ell_1` violation, which the QP's linearisation removes);
        a backtracked step counts as :math:`\rho < 0`. :math:`\rho < \tfrac14`:
        :math:`\tfrac12\|d\|_\infty`; :math:`\rho > \tfrac34` with :math:`\|d\|_\infty \ge
        0.99\Delta`: :math:`2\Delta`; else :math:`\Delta` (Nocedal & Wright 2006, Algorithm 4.1,
        in the :math:`\infty`-norm of the box)."""
        s = self.s
        rho = -1.0 if backtracks else self._agreement(old, new, d)
        if rho < 0.25:
            return max(s.min_step_bound, 0.5 * d_norm)
        if rho > 0.75 and d_norm >= 0.99 * delta:
            return min(s.max_step_bound, 2.0 * delta)
        return delta

    def _agreement(self, old: _Point, new: _Point, d) -> float:
        r""":math:`\rho` of :meth:`_ratio_update` for a full step (-1 when the model predicts no decrease)."""
        predicted = -(float(old.g @ d) + 0.5 * float(d @ matvec(self._sub[0].H, d))) + self._penalty(old)
        return (self._merit(old) - self._merit(new)) / predicted if predicted > 0 else -1.0

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
        merit0 = self._merit(pt)
        phi0 = merit0 + 10 * np.finfo(float).eps * max(1.0, abs(merit0))
        derivative = float(pt.g @ d) - self._penalty(pt)  # N&W Theorem 18.2
        slope = min(derivative, 0.0)
        alpha, its = 1.0, 0
        for backtracks in range(s.max_backtracks + 1):
            trial = self._trial(pt.x + alpha * d)
            if trial is not None and self._merit(trial) <= phi0 + s.armijo * alpha * slope:
                if backtracks == 0 and s.extrapolate:
                    trial = self._extrapolate(trial, d, merit0, derivative)
                trial = self.p.complete(trial)  # derivatives only where the step is taken
                if trial is not None:
                    return trial, backtracks, False, its
            if backtracks == 0 and trial is not None and s.second_order_correction:
                corrected, its = self._second_order_correction(rows, step, trial)
                if corrected is not None and self._merit(corrected) <= phi0 + s.armijo * slope:
                    corrected = self.p.complete(corrected)
                    if corrected is not None:
                        return corrected, 0, True, its
            alpha *= s.backtrack
        return None, s.max_backtracks, False, its

    def _extrapolate(self, trial: _Point, d, merit0: float, slope: float) -> _Point:
        r"""A longer step :math:`\alpha d`, :math:`\alpha \ge 2`, when the merit curves less along ``d`` than the model.

        Only after a full step from the exact Hessian whose eigenvalues were modified
        (:mod:`calib_oed.solver.hessian`): a flipped negative eigenvalue adds model curvature
        the function does not have, and the step is that much too short. The quadratic through
        :math:`\phi(0)`, the slope :math:`D = \nabla f^\top d - \mu v_1(x_k)` and
        :math:`\phi(1)` (the accepted full step; ``merit0`` and ``slope`` from the line search) has the curvature
        :math:`\kappa = 2(\phi(1) - \phi(0) - D)` along :math:`d` and its minimiser at
        :math:`\alpha = -D/\kappa` (Nocedal & Wright 2006, §3.5, eq. 3.57, here beyond 1;
        :math:`\kappa \le 0`: no minimiser), taken at most to the box
        (:math:`\alpha\|d\|_\infty \le \Delta`) and to every inactive row's linearisation
        (:math:`c_i + \alpha A_i d \ge -` ``tol_feasibility``; an active row's curvature is the
        merit's to judge). Tried when :math:`\alpha \ge 2`, kept when its merit is below
        :math:`\phi(1)`; the point is clipped to the bounds, as every trial.
        """
        pt, s = self.pt, self.s
        if self._info.hessian != "exact" or not self._info.hessian_modified or slope >= 0:
            return trial
        phi1 = self._merit(trial)
        kappa = 2.0 * (phi1 - merit0 - slope)
        ad = np.asarray(pt.A @ d).ravel()
        fall = (ad < 0) & (self.lam <= 0)
        alpha = min(self.delta / float(np.max(np.abs(d))),
                    float(np.min((pt.c[fall] + s.tol_feasibility) / -ad[fall], initial=np.inf)))
        if kappa > 0:
            alpha = min(alpha, -slope / kappa)
        if alpha < 2.0:
            return trial
        longer = self._trial(pt.x + alpha * d)
        if longer is None or not self._merit(longer) < phi1:
            return trial
        self.extrapolated = alpha
        return longer
