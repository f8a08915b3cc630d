r"""Infeasible QP subproblems: rows no step can reach, and the elastic restoration QP.

At an infeasible iterate the linearised rows :math:`C d \ge \ell` may have
no solution in the box :math:`[\underline{b}, \overline{b}]`; ProxQP does not
detect this (:mod:`calib_oed.solver.qp`). :func:`unreachable_rows` finds the
obvious cases in :math:`O(\text{nnz})`, :func:`certified_violation` the others from the
multipliers of a failed solve (a Farkas certificate), and :func:`solve_elastic_qp` gives the
feasibility-restoration step of the SQP (:mod:`calib_oed.solver.sqp`, item 5);
:class:`_RestorationMixin` is that step inside :class:`calib_oed.solver.iteration._Run`.
"""

from __future__ import annotations

import time

import numpy as np
import scipy.sparse as sp

from calib_oed.solver.proxqp_build import proxsuite
from calib_oed.solver.qp import QPStep, QPSubproblem, _configure, _finish
from calib_oed.solver.result import SQPStatus


def _box_max(a, box_lower, box_upper):
    r""":math:`\max(a \underline{b}, a \overline{b})` elementwise, 0 where :math:`a = 0`: the
    largest :math:`a d` over the box, term by term (an infinite side with :math:`a = 0` counts 0)."""
    with np.errstate(invalid="ignore"):
        return np.where(a > 0, a * box_upper, np.where(a < 0, a * box_lower, 0.0))


def unreachable_rows(C, lower, box_lower, box_upper, tol: float) -> np.ndarray:
    r"""Rows that no :math:`d` in the box can satisfy: :math:`\max_{d \in \text{box}} C_i d < \ell_i - \text{tol}`.

    :math:`\max_{d} C_i d = \sum_j \max(C_{ij} \underline{b}_j, C_{ij} \overline{b}_j)`,
    one pass over the nonzeros. Any such row makes the QP infeasible; finding
    it here spares ProxQP, which does not detect infeasibility and would run
    to its iteration limit.
    """
    if sp.issparse(C):
        C = sp.csr_matrix(C)
        vals = _box_max(C.data, box_lower[C.indices], box_upper[C.indices])
        reach = np.asarray(sp.csr_matrix((vals, C.indices, C.indptr), shape=C.shape).sum(axis=1)).ravel()
    else:
        C = np.asarray(C, dtype=float)
        reach = (_box_max(C, box_lower[None, :], box_upper[None, :]).sum(axis=1) if C.size
                 else np.zeros(C.shape[0]))
    return np.flatnonzero(reach < lower - tol)


def certified_violation(C, lower, box_lower, box_upper, y) -> float:
    r"""The least violation every :math:`d` must have, by the Farkas certificate ``y``; <= 0: none.

    For :math:`y \ge 0` (on the rows of :math:`C d \ge \ell`), :math:`z = C^\top y` and
    :math:`\beta = \max_{d \in \text{box}} z^\top d = \sum_j \max(z_j \underline{b}_j,
    z_j \overline{b}_j)`, every :math:`d` in the box has
    :math:`\max_i (\ell_i - C_i d) \ge (y^\top \ell - \beta)/\|y\|_1 =: \gamma`. A :math:`d`
    outside the box by :math:`\epsilon` at most (∞-norm) meets the rows only :math:`L\epsilon`
    better, :math:`L = \|z\|_1/\|y\|_1`, so every :math:`d` violates a row or the box by at least
    :math:`\gamma/(1 + L)`, the value returned (Farkas' lemma: the QP is infeasible when it is
    positive; :func:`unreachable_rows` is the case of one row). ProxQP's multipliers of an
    infeasible QP grow along such a :math:`y`.
    """
    y = np.maximum(np.asarray(y, dtype=float), 0.0)
    total = float(y.sum())
    if not (np.isfinite(total) and total > 0.0):
        return -np.inf
    y = y / total
    z = np.asarray(C.T @ y).ravel()
    reach = float(np.sum(_box_max(z, box_lower, box_upper)))
    gap = float(y @ lower) - reach
    return gap / (1.0 + float(np.abs(z).sum())) if np.isfinite(gap) else -np.inf


def solve_elastic_qp(C, lower, violated, box_lower, box_upper, penalty: float,
                     eps_abs: float, max_iter: int) -> QPStep:
    r"""Feasibility-restoration step: the elastic QP.

    .. math::
        \min_{d, s} \tfrac12 \|d\|_2^2 + \rho \sum_{i \in V} s_i
        \quad \text{s.t.} \quad C_i d + s_i \ge \ell_i \;(i \in V), \quad
        C_i d \ge \ell_i \;(i \notin V), \quad s \ge 0, \quad
        \underline{b} \le d \le \overline{b},

    with :math:`V` the rows violated at the current point
    (:math:`\ell_i > 0`, i.e. :math:`c_i < 0`). It is always feasible
    (:math:`d = 0`, :math:`s_i = \ell_i`), and for large :math:`\rho` its
    :math:`d` is the shortest step minimising the linearised :math:`\ell_1`
    violation inside the box (the elastic mode of Nocedal & Wright,
    *Numerical Optimization*, 2nd ed., §18.3, with the proximal term
    :math:`\tfrac12\|d\|^2` in place of the Hessian model). A term
    :math:`10^{-8} \|s\|^2` keeps the Hessian definite. Its Hessian is
    diagonal and its rows sparse, so it goes to ProxQP's sparse backend (the
    box as identity rows). Returns :math:`d` (slacks dropped) and the
    multipliers of the rows.
    """
    C = sp.csr_matrix(C)
    k, n = C.shape
    idx = np.flatnonzero(violated)
    nv = idx.size
    E = sp.csr_matrix((np.ones(nv), (idx, np.arange(nv))), shape=(k, nv))
    H = sp.diags(np.concatenate([np.ones(n), np.full(nv, 1e-8)])).tocsc()
    g = np.concatenate([np.zeros(n), np.full(nv, penalty)])
    CC = sp.hstack([C, E], format="csr")
    bl = np.concatenate([box_lower, np.zeros(nv)])
    bu = np.concatenate([box_upper, np.full(nv, np.inf)])
    stacked = sp.vstack([CC, sp.identity(n + nv, format="csr")], format="csc")
    qp = proxsuite.proxqp.sparse.QP(n + nv, 0, k + n + nv)
    _configure(qp, eps_abs, max_iter)
    qp.init(H, g, None, None, stacked, np.concatenate([lower, bl]),
            np.concatenate([np.full(k, np.inf), bu]))
    qp.solve()
    r = qp.results
    sub = QPSubproblem(H, g, CC, np.asarray(lower, dtype=float), bl, bu)
    full = _finish(sub, r.x, r.z[:k], r.z[k:], r.info)
    return full._replace(d=full.d[:n], lam=full.lam[:k], nu=full.nu[:n])


class _RestorationMixin:
    """Feasibility restoration of :class:`calib_oed.solver.iteration._Run` (:mod:`calib_oed.solver.sqp`, item 5)."""

    def _restore(self, k, delta, qp_status, qp_iter):
        r"""Feasibility restoration: elastic QP, then backtracking on the violation :math:`h`.

        Accept :math:`x + \alpha d` when :math:`h(x + \alpha d) \le h(x) - \eta \alpha\, p`
        with :math:`p = h_K(x) - \sum_{i \in K} \max(0, -(c_i + A_i d))` the
        decrease the linearisation predicts (by convexity of the linearised
        :math:`h`, :math:`\alpha p` is its decrease along :math:`\alpha d`). On
        failure retry with a smaller box. Locally infeasible when :math:`p`
        vanishes, or when ten restoration steps in a row cut :math:`h` by
        less than 1 %. The rows :math:`K` are those of the QP (at most
        ``max_qp_rows``, the violated ones first); :math:`h` itself sums every row.
        """
        s, pt = self.s, self.pt
        n_rows = 0
        for _ in range(4):
            rows = self._rows(delta)
            n_rows = rows.size
            c_k, a_k = pt.c[rows], pt.A[rows]
            t = time.perf_counter()
            try:
                step = solve_elastic_qp(a_k, -c_k, c_k < 0, np.maximum(self.lb - pt.x, -delta),
                                        np.minimum(self.ub - pt.x, delta), s.restoration_penalty,
                                        s.qp_eps_abs, s.qp_max_iterations)
            except Exception as exc:  # noqa: BLE001 (ProxQP's errors become a status, never an abort)
                self.p.times["qp"] += time.perf_counter() - t
                self._stop(SQPStatus.QP_FAILED, f"restoration QP of {n_rows} rows raised "
                           f"{type(exc).__name__}: {exc}")
                return self._record(k, np.nan, 0.0, delta, n_rows, "error", qp_iter, 0, True)
            self.p.times["qp"] += time.perf_counter() - t
            qp_iter += step.iterations
            h_now = float(np.maximum(-c_k, 0.0).sum())
            if not np.all(np.isfinite(step.d)):
                self._stop(SQPStatus.QP_FAILED, "restoration QP returned non-finite values "
                           f"(ProxQP status {step.status!r})")
                return self._record(k, np.nan, 0.0, delta, rows.size, "non_finite", qp_iter, 0, True)
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
                    trial = self.p.complete(trial)
                    if trial is not None:
                        return self._restored(k, trial, delta, rows.size, qp_status, qp_iter, backtracks)
                alpha *= s.backtrack
            delta = 0.5 * alpha * float(np.max(np.abs(d)))
            if delta < s.min_step_bound:
                break
        if self._crash_message:  # the QP solver failed, not the problem: say so
            self._stop(SQPStatus.QP_FAILED, f"QP subproblem failed ({qp_status}): {self._crash_message}; "
                       f"restoration cannot reduce the violation ({pt.violation_max:.2e}) further")
        elif pt.violation_max <= s.tol_feasibility:  # feasible to tolerance: not an infeasibility
            # ProxQP does not detect infeasibility: a QP it did not solve may be inconsistent,
            # or ProxQP failed on it (the stale equilibration of issue 30): the status says which QP
            self._stop(SQPStatus.STALLED, f"the QP subproblem was not solved (status {qp_status!r}: "
                       "its linearised constraints are inconsistent, or ProxQP did not converge) at a point "
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
