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
2. **Row selection** (:mod:`calib_oed.solver.rows`): the candidates are the rows with
   :math:`c_i - \|A_i\|_1 \Delta_k \le m_a` (``active_margin``). Inside the box
   :math:`|A_i d| \le \|A_i\|_1 \Delta_k`, so any other row cannot reach 0 under
   the linearisation: for :math:`m_a \ge 0` dropping it does not change the QP.
   At most ``max_qp_rows`` (default :math:`\max(200, 4n)`) candidates are kept,
   violated rows and rows with :math:`\lambda_i > 0` first, then the nearest
   to activity by :math:`c_i / \|A_i\|_1` [units of x]; a dropped row that the
   step violates (linearised) joins the QP, which is solved again. The QP's
   size is thus bounded whatever :math:`\Delta`; the dense ProxQP backend is
   used only up to ``max_dense_qp_size`` (variables + row capacity), larger
   QPs go to the sparse backend, and a QP the sparse backend could not hold
   (``max_qp_nonzeros``) is refused before ProxQP allocates
   (:mod:`calib_oed.solver.subproblem`).
3. **Hessian**: damped BFGS (N&W §18.3, Procedure 18.2; Powell 1978) on the
   Lagrangian gradient difference
   :math:`y = \nabla_x L(x_{k+1}, \lambda_{k+1}) - \nabla_x L(x_k, \lambda_{k+1})`,
   from :math:`B_0 = \beta I`, rescaled before the first update to
   :math:`(y^\top y / s^\top y) I` (Shanno–Phua; N&W eq. 6.20). With
   ``lagrangian_hessian``, the exact :math:`\nabla^2_{xx} L(x_k, \lambda_k) = D + U U^\top`
   instead, its diagonal blocks made positive definite by an eigenvalue
   modification (:mod:`calib_oed.solver.hessian`) and the coupling kept
   factored in a lifted sparse QP (:mod:`calib_oed.solver.lifted`); the BFGS
   matrices are still updated and used whenever the exact Hessian is not
   available (the callable returns None or fails) or its QP fails.
4. **Globalisation**: the :math:`\ell_1` merit (N&W §15.4 and §18.3, "Merit functions")

   .. math::
       \phi_\mu(x) = f(x) + \mu \Big(\sum_i \max(0, -c_i(x))
       + \sum_j \max(0, lb_j - x_j) + \max(0, x_j - ub_j)\Big),

   :math:`\mu_k = \max(\nu_k, \tfrac12(\mu_{k-1} + \nu_k))` with
   :math:`\nu_k = \|\lambda_{k+1}\|_\infty + \mu_m` (Powell's update, Powell 1978,
   "A fast algorithm for nonlinearly constrained optimization calculations"), so
   that :math:`d` is a descent direction (N&W Theorem 18.2) and a penalty raised by
   one QP's spurious multipliers (a degenerate active set) falls back by half per
   iteration: a nondecreasing one stayed at 5e4 against multipliers of 0.03 on
   ``fms_kr16_program``, where the QP's 1e-9 error times :math:`\mu` then outweighed
   every gain and the run stalled. With ``penalty_weights="row"`` each row has its own weight,
   :math:`\mu_{i,k} = \max(\nu_{i,k}, \tfrac12(\mu_{i,k-1} + \nu_{i,k}))`,
   :math:`\nu_{i,k} = \lambda_{i,k+1} + \mu_m`, and the merit is
   :math:`f + \sum_i w_i \max(0, -c_i) + \mu` (bound violation) with :math:`w_i = \mu_i` on the
   rows the QP held (:math:`\lambda_i > 0`) and :math:`\mu` on the others (Powell 1978's weights;
   :math:`w_i \ge \lambda_i` keeps :math:`d` a descent direction): an active row with a small
   multiplier is not charged at the largest one. Armijo backtracking
   (:meth:`~calib_oed.solver.iteration._Run._line_search`) on
   :math:`\phi(x + \alpha d) \le \phi(x) + \eta \alpha D` with the directional
   derivative :math:`D = \nabla f^\top d - \mu \sum_i \max(0, -c_i)` (:math:`\mu_i` per row; same
   theorem). Trust region: after a backtrack
   :math:`\Delta \leftarrow \max(\Delta_\min, \tfrac12 \|\alpha d\|_\infty,
   \tfrac1{10} \min(\Delta, \|d\|_\infty))` (the tenfold cut of a failed search, but
   never below half the step accepted); after a
   full step that reached the edge, :math:`\Delta \leftarrow \min(2\Delta, \Delta_\max)`;
   after any other accepted step :math:`\Delta \leftarrow \min(\Delta, \kappa \|\alpha d\|_\infty)`
   (``step_bound_ratio``), so the box, and the rows kept, shrink with the steps.
   That is ``trust_update="edge"`` (the default, ``None``); ``"ratio"`` follows the agreement of the
   merit's actual and predicted reduction instead
   (:meth:`~calib_oed.solver.iteration._Run._ratio_update`). When the full step is rejected, a second-order correction is tried first
   (:meth:`~calib_oed.solver.iteration._Run._second_order_correction`, against the Maratos effect of
   curved active constraints). With ``extrapolate``, an accepted full step from a modified exact
   Hessian is taken further when the merit curves less along it than the model
   (:meth:`~calib_oed.solver.iteration._Run._extrapolate`); such a step that reaches the edge
   doubles :math:`\Delta`. A step rejected after ``max_backtracks``
   leaves :math:`x_k` and cuts :math:`\Delta` tenfold. With the caller's
   ``values`` the trial points are evaluated without derivatives, and
   :math:`\nabla f`, :math:`A` only at the point accepted.
5. **Infeasible QP** (only possible at an infeasible :math:`x_k`: at a feasible
   one :math:`d = 0` is feasible). A row no :math:`d` in the box can satisfy is
   found in :math:`O(\text{nnz})` (:func:`calib_oed.solver.restoration.unreachable_rows`)
   before ProxQP is called, which does not detect infeasibility and would run
   to its iteration limit. Retry with :math:`\Delta_\max` (a smaller box
   only shrinks the feasible set), then take a restoration step from the
   elastic QP (:func:`calib_oed.solver.restoration.solve_elastic_qp`) with backtracking on
   the violation (:meth:`~calib_oed.solver.iteration._Run._restore`); if that cannot reduce the violation,
   stop with :attr:`SQPStatus.INFEASIBLE` (:attr:`SQPStatus.STALLED` if the
   violation is already within ``tol_feasibility``: then the linearisation is
   inconsistent, e.g. degenerate active rows, or ProxQP did not converge on the QP, not the
   problem). Every QP ProxQP did not solve is retried cold with a recomputed equilibration
   (:mod:`calib_oed.solver.qp`, :class:`~calib_oed.solver.qp.DenseQPWorkspace`), before any of
   this, unless its multipliers prove it infeasible: ProxQP's multipliers of an infeasible QP grow
   along a Farkas certificate :math:`y \ge 0`, and when :math:`y` shows every step violating a row or
   the box by more than ten times the primal tolerance
   (:func:`calib_oed.solver.restoration.certified_violation`), the retries of that iteration whose
   QPs hold the same rows are tested with it and not solved (``qp_status`` ``"infeasible"``): the
   same steps and multipliers, without ProxQP's iteration limit on each. A QP that fails at a feasible
   :math:`x_k` (numerical trouble) is retried with :math:`\Delta / 10`, then
   :attr:`SQPStatus.FAILED` (:attr:`SQPStatus.QP_FAILED` when the QP solver
   raised, returned non-finite values or the QP was too large).
6. **Stop**: :attr:`SQPStatus.CONVERGED` when :math:`r_p \le` ``tol_feasibility``
   and :math:`r_d, r_c \le` ``tol_optimality`` at :math:`x_k` with
   :math:`\lambda_{k+1}` (:mod:`calib_oed.solver.result` for the residuals);
   :attr:`SQPStatus.STALLED` when :math:`\|d\|_\infty \le` ``tol_step`` or the
   line search fails with :math:`\Delta = \Delta_\min`.

Bounds are kept exactly: :math:`x_0` is projected onto them and every step
stays inside, so their merit term is zero in practice.

Failures are statuses, not exceptions: only bad input raises (shapes,
non-finite values at :math:`x_0`, ``lb > ub``, invalid settings, and errors
raised by the caller's ``objective`` or ``constraints``).
QP failures end in :attr:`SQPStatus.FAILED` or :attr:`SQPStatus.QP_FAILED`;
``MemoryError``, ``LinAlgError`` and floating-point errors anywhere else in
an iteration in :attr:`SQPStatus.NUMERICAL_ERROR`, with the last iterate.

This module owns the entry point :func:`solve_sqp` and its outer loop; one
iteration (items 1-5) is :class:`calib_oed.solver.iteration._Run`, the caller's
functions are wrapped by :mod:`calib_oed.solver.nlp`.
"""

from __future__ import annotations

import time

import numpy as np

from calib_oed.exceptions import NonFiniteError, ShapeError
from calib_oed.solver.iteration import _Run
from calib_oed.solver.nlp import _bounds, _Problem
from calib_oed.solver.result import (
    IterationRecord,
    SQPProblemError,
    SQPResult,
    SQPSettings,
    SQPSettingsError,
    SQPStatus,
    StructuredHessian,
)

__all__ = ["SQPSettings", "SQPSettingsError", "SQPProblemError", "SQPStatus", "SQPResult",
           "IterationRecord", "StructuredHessian", "solve_sqp"]

_NUMERICAL = (MemoryError, np.linalg.LinAlgError, FloatingPointError)
"""Errors an iteration turns into :attr:`SQPStatus.NUMERICAL_ERROR`."""


def solve_sqp(objective, x0, *, constraints=None, bounds=None, settings: SQPSettings | None = None,
              callback=None, block_size: int | None = None,
              lagrangian_hessian=None, row_pieces=None, values=None) -> SQPResult:
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
        block_size: Size of the diagonal blocks of the quasi-Newton matrix
            (e.g. the joints of one pose when every constraint and the unknown
            curvature are per pose); default one dense block.
        lagrangian_hessian: Optional ``(x, lam) -> StructuredHessian`` (or
            ``None``): the exact Hessian :math:`\nabla^2_{xx} L` of
            :math:`L = f - \lambda^\top c` at :math:`x` for the row multipliers
            ``lam`` (m,), :math:`\lambda \ge 0` (0 for rows not in the last QP),
            as diagonal blocks (b, s, s), possibly indefinite, plus a low-rank
            factor :math:`U` (n, r) of a positive semidefinite coupling
            :math:`U U^\top`. Used in place of BFGS (module docstring, item 3);
            returning ``None`` or raising falls back to BFGS for that
            iteration (counted in ``SQPResult.hessian_fallbacks``). Without
            ``block_size`` the fallback BFGS matrices take the block size of
            the first Hessian returned (one dense block if none ever is).
        row_pieces: Optional ``(x, rows) -> (rows_k, values, G)`` or ``None``: for
            rows among ``rows`` (those with :math:`c_i \le` ``row_pieces_margin``)
            that have a kink at :math:`x`, the values (k,) and gradients
            :math:`G` (k, n) of their smooth pieces (:mod:`calib_oed.solver.pieces`):
            extra QP rows, and their multipliers count in the KKT test.
        values: Optional ``x -> (f, c)``: :math:`f(x)` and :math:`c(x)` without
            derivatives, equal to those of ``objective`` and ``constraints``. The
            line searches then evaluate their trial points with it and call
            ``objective`` and ``constraints`` only at the point accepted: most
            trials are rejected, and the derivatives are most of the cost.

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
    times = dict.fromkeys(("objective", "constraints", "values", "qp", "hessian", "total"), 0.0)
    problem = _Problem(objective, constraints, n, lb, ub, times, values)
    pt0 = problem.evaluate(np.clip(x0, lb, ub), strict=True)
    try:
        run = _Run(problem, pt0, lb, ub, s, t0, block_size, lagrangian_hessian, row_pieces)
    except MemoryError as exc:  # e.g. one dense BFGS matrix for a very large n
        times["total"] = time.perf_counter() - t0
        return SQPResult(
            x=pt0.x, fun=pt0.f, status=SQPStatus.NUMERICAL_ERROR,
            message=f"MemoryError setting up the solver for n = {n}: {exc} (give block_size "
                    "or lagrangian_hessian instead of one dense Hessian)",
            iterations=0, history=(), multipliers=np.zeros(pt0.c.size), bound_multipliers=np.zeros(n),
            max_violation=pt0.violation_max, kkt_stationarity=np.nan, kkt_complementarity=np.nan,
            times=times, n_objective_evaluations=problem.n_obj, n_constraint_evaluations=problem.n_con,
            n_value_evaluations=problem.n_values)
    for k in range(s.max_iterations):
        try:
            record = run.iterate(k)
            if callback is not None:
                callback(record)
        except _NUMERICAL as exc:
            run._stop(SQPStatus.NUMERICAL_ERROR, f"iteration {k}: {type(exc).__name__}: {exc}")
            break
        except KeyboardInterrupt:  # the last accepted iterate is returned, not lost
            run._stop(SQPStatus.INTERRUPTED, f"interrupted in iteration {k}")
            break
        if run.status is not None:
            break
        if time.perf_counter() - t0 > s.time_limit:
            run._stop(SQPStatus.TIME_LIMIT)
            break
    else:
        run._stop(SQPStatus.MAX_ITERATIONS)
    pt = run.pt
    # residuals at the final point with the latest multipliers (those of its QP when converged)
    try:
        stat, comp, nu_bounds = run.kkt()
    except _NUMERICAL:  # already reported by the status; the residuals are unknown
        stat, comp, nu_bounds = np.nan, np.nan, np.zeros(n)
    times["total"] = time.perf_counter() - t0
    return SQPResult(
        x=pt.x, fun=pt.f, status=run.status, message=run.message, iterations=len(run.history),
        history=tuple(run.history), multipliers=run.lam, bound_multipliers=nu_bounds,
        max_violation=pt.violation_max, kkt_stationarity=stat, kkt_complementarity=comp, times=times,
        n_objective_evaluations=problem.n_obj, n_constraint_evaluations=problem.n_con,
        n_value_evaluations=problem.n_values, hessian=run.hessian_label, hessian_fallbacks=run.n_fallbacks, hessian_message=run.fallback_reason,
        max_pieces=run.n_pieces)
