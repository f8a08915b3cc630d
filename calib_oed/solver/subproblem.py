r"""The QP subproblem of one SQP iteration: rows, Hessian, backend, and failures as data.

:class:`QPSolver` picks the ProxQP workspace for a :class:`~calib_oed.solver.qp.QPSubproblem`
and never lets it raise:

* a :class:`~calib_oed.solver.result.StructuredHessian` goes to the lifted
  sparse QP (:mod:`calib_oed.solver.lifted`), or with ``structured_qp="block"``
  (``"auto"``, the default: from ``block_qp_min_size`` variables on) to the
  interior point method of :mod:`calib_oed.solver.block_qp` (warm-started by the
  active set the duals name, verified, else its own cold start, so no cold retry
  here; no dense polish: it polishes its own active set in O(n));
* a dense Hessian goes to the dense backend (``qp_backend="dense"``) only
  while :math:`n + K \le` ``max_dense_qp_size`` (:math:`K` its row capacity,
  at most that bound minus :math:`n`); otherwise to the sparse backend;
* every workspace refuses a QP beyond its size bound before ProxQP allocates
  (ProxQP aborts the process when an allocation fails, :mod:`calib_oed.solver.qp`);
* an exception (ProxQP's, ``MemoryError``, ``LinAlgError``, ...) or a
  non-finite result becomes a failed :class:`~calib_oed.solver.qp.QPStep`
  with status ``"error"``, ``"too_large"`` or ``"non_finite"`` and a message,
  which the iteration treats like any unsolved QP and, if it persists,
  reports as :attr:`~calib_oed.solver.result.SQPStatus.QP_FAILED`.

:class:`_SubproblemMixin` is the part of :class:`calib_oed.solver.iteration._Run`
that builds and solves the QP at :math:`x_k`: row selection with the
``max_qp_rows`` bound (:mod:`calib_oed.solver.rows`) and the re-solve with the
dropped rows a step violates, the Hessian (the caller's exact one made positive
definite, :mod:`calib_oed.solver.hessian`, with the BFGS matrices as fallback),
and the second-order correction with the same Hessian.
"""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np
import scipy.sparse as sp

from calib_oed.solver.block_qp import BlockQPWorkspace
from calib_oed.solver.hessian import active_normals, check_structured, positive_definite
from calib_oed.solver.lifted import LiftedQPWorkspace
from calib_oed.solver.polish import from_active_set, polish
from calib_oed.solver.qp import (
    DenseQPWorkspace,
    QPSizeError,
    QPStep,
    QPSubproblem,
    SparseQPWorkspace,
)
from calib_oed.solver.restoration import certified_violation, unreachable_rows
from calib_oed.solver.result import QPUse, StructuredHessian
from calib_oed.solver.rows import missed_rows, select_rows
from calib_oed.solver.settings import SQPSettings

# Every QP step within the dense size bound is polished (:func:`calib_oed.solver.polish.polish`),
# not only the small ones: besides ProxQP's ~1e-9 error, its last bits depend on where its
# buffers lie in memory (the same QP twice in one process can differ by 1e-16), and the SQP
# amplifies that into another design. The polish solves the KKT system of ProxQP's active set
# with LAPACK, the same bits in every process (issue 31). On the lifted path it is about a quarter
# of the SQP's CPU at 60 poses of fms_kr16 (1.53 of 6.38 s, bench/bench_design_qp_paths.py); the
# block QP (from block_qp_min_size on) polishes its own active set.

CRASHED = ("error", "too_large", "non_finite")
"""QP statuses of a solver that did not return a usable answer (not ProxQP's own)."""

BOUND_TOL = 1e-10
"""A variable within this of a bound (units of x) counts as on it, for the tangent rule of the
Hessian's modification (:func:`~calib_oed.solver.hessian.active_normals`); a step the QP takes
to a bound lands on it to rounding."""

CERTIFIED_MARGIN = 10.0
"""A QP counts as infeasible when its Farkas certificate shows every step violating a row or the
box by more than this times the primal tolerance of the residual test
(:func:`~calib_oed.solver.restoration.certified_violation`)."""

_CERTIFIED = "infeasible by the Farkas certificate of a failed solve at this iterate"

_MISSED_ROUNDS = 2
"""Re-solves per QP with the dropped rows its step violates (:mod:`calib_oed.solver.rows`)."""


def _proves_infeasible(sub, y, tol_p) -> bool:
    """Whether ``y`` (multipliers of ``sub``'s rows) shows every step violating a row or the box by
    more than :data:`CERTIFIED_MARGIN` times ``tol_p`` (:func:`~calib_oed.solver.restoration.certified_violation`)."""
    return certified_violation(sub.C, sub.lower, sub.box_lower, sub.box_upper, y) > CERTIFIED_MARGIN * tol_p


def failed_step(n: int, k: int, status: str, message: str = "") -> QPStep:
    """A QP step that carries only a failure: NaN step, infinite residuals."""
    nan = np.full(n, np.nan)
    return QPStep(nan, np.zeros(k), nan, status, 0, np.inf, np.inf, np.inf, message=message)


def _stack(a_rows, gradients):
    """The QP's row matrix: the kept rows of :math:`A` over the pieces' gradients."""
    if not gradients.shape[0]:
        return a_rows
    if sp.issparse(a_rows):
        return sp.vstack([a_rows, gradients], format="csr")
    return np.vstack([np.asarray(a_rows), gradients.toarray()])


class QPSolver:
    """The workspaces of one SQP run and the choice among them (module docstring)."""

    def __init__(self, n: int, settings: SQPSettings):
        self.n, self.s = n, settings
        self._ws: dict[str, object] = {}
        self.last_backend = ""

    def dense_ok(self, k: int) -> bool:
        """Whether a QP of ``k`` rows with a dense Hessian goes to the dense backend."""
        return self.s.qp_backend == "dense" and self.n + k <= self.s.max_dense_qp_size

    def backend(self, sub: QPSubproblem) -> str:
        """The workspace ``sub`` goes to: ``"block"``, ``"lifted"``, ``"dense"`` or ``"sparse"``."""
        s = self.s
        if isinstance(sub.H, StructuredHessian):
            if s.structured_qp == "auto":
                return "block" if self.n >= s.block_qp_min_size else "lifted"
            return s.structured_qp
        return "dense" if self.dense_ok(sub.lower.size) else "sparse"

    def _workspace(self, sub: QPSubproblem):
        s, n = self.s, self.n
        name = self.backend(sub)
        if name not in self._ws:
            if name == "block":
                self._ws[name] = BlockQPWorkspace(n, s.qp_eps_abs, s.qp_max_iterations)
            elif name == "lifted":
                self._ws[name] = LiftedQPWorkspace(n, s.qp_eps_abs, s.qp_max_iterations, s.max_qp_nonzeros)
            elif name == "dense":
                self._ws[name] = DenseQPWorkspace(n, s.qp_eps_abs, s.qp_max_iterations,
                                                  max_capacity=max(1, s.max_dense_qp_size - n))
            else:
                self._ws[name] = SparseQPWorkspace(n, s.qp_eps_abs, s.qp_max_iterations, s.max_qp_nonzeros)
        return name, self._ws[name]

    def solve(self, sub: QPSubproblem, lam0=None, nu0=None, refresh: bool = False) -> QPStep:
        """Solve ``sub`` warm-started from the duals; failures come back as a failed step.
        ``refresh``: a reused ProxQP object recomputes its equilibration first."""
        n, k = self.n, sub.lower.size
        name = ""
        try:
            name, ws = self._workspace(sub)
            step = ws.solve(sub, None, lam0, nu0, refresh=True) if refresh else ws.solve(sub, None, lam0, nu0)
        except QPSizeError as exc:
            step = failed_step(n, k, "too_large", str(exc))
        except Exception as exc:  # noqa: BLE001 (ProxQP raises RuntimeError, ValueError, MemoryError, ...)
            self._ws.pop(name, None)  # its state is unknown: the next QP builds a new one
            step = failed_step(n, k, "error", f"{name or 'QP'} solver raised {type(exc).__name__}: {exc}")
        else:
            if not (np.all(np.isfinite(step.d)) and np.all(np.isfinite(step.lam))
                    and np.all(np.isfinite(step.nu))):
                self._ws.pop(name, None)
                step = failed_step(n, k, "non_finite", f"{name} QP solver returned non-finite values "
                                   f"(ProxQP status {step.status!r})")
        self.last_backend = name
        return step


class _SubproblemMixin:
    """Row selection, Hessian and QP solve of :class:`calib_oed.solver.iteration._Run`."""

    # ------------------------------------------------------------- rows
    def _select(self, delta):
        pt = self.pt
        must = self.sticky | (self.lam > 0)
        sel = select_rows(pt.c, pt.row_l1, delta, self.s.active_margin, self.max_rows, must)
        if sel.dropped.size:  # marked rows that are no longer candidates are forgotten
            near = np.zeros_like(self.sticky)
            near[sel.rows], near[sel.dropped] = True, True
            self.sticky &= near
        return sel

    def _rows(self, delta):
        return self._select(delta).rows

    # ------------------------------------------------------------- Hessian
    def _fallback(self, reason):
        self.fallback_reason = reason

    def _exact_hessian(self):
        r"""``(H, n_modified)`` from ``lagrangian_hessian`` at :math:`(x_k, \lambda_k)`, or None (reason kept);
        between every ``hessian_every``-th accepted point the last one computed."""
        key = (self._version, self.lam.tobytes())
        if key == self._exact_key or (self._exact is not None and self._version % self.s.hessian_every):
            return self._exact  # this point's, or the last one computed (SQPSettings.hessian_every)
        s, pt = self.s, self.pt
        t = time.perf_counter()
        self._exact, self._exact_key = None, key
        try:
            h = self.lagrangian_hessian(pt.x.copy(), self.lam.copy())
            if h is None:
                self._fallback("lagrangian_hessian returned None")
            else:
                h = check_structured(h, pt.x.size)
                self._init_bfgs(h.blocks.shape[1])
                self._exact = positive_definite(h, s.hessian_eigenvalue_floor, self._normals(h.blocks.shape))
        except Exception as exc:  # noqa: BLE001 (the caller's function: any failure means "use BFGS")
            self._fallback(f"lagrangian_hessian failed: {type(exc).__name__}: {exc}")
        self.p.times["hessian"] += time.perf_counter() - t
        return self._exact

    def _normals(self, shape):
        """The active constraints' normals per block for the tangent rule, else None (the block rule)."""
        x, rule = self.pt.x, self.s.hessian_modification
        if rule == "block" or (rule == "auto" and x.size > self.s.tangent_max_size):
            return None
        at_bound = (x - self.lb <= BOUND_TOL) | (self.ub - x <= BOUND_TOL)
        return active_normals(self.pt.A, np.flatnonzero(self.lam > 0), at_bound, shape[0], shape[1])

    def _dense_bfgs(self):
        r""":math:`B = \mathrm{blkdiag}(R_1..R_b)` (one block: the BFGS matrix itself), cached."""
        if self._B is None:
            nb, bs = self.R.shape[0], self.R.shape[1]
            if nb == 1:
                self._B = self.R[0]
            else:
                B = np.zeros((nb * bs, nb * bs))
                for j in range(nb):
                    B[j * bs:(j + 1) * bs, j * bs:(j + 1) * bs] += self.R[j]
                self._B = B
        return self._B

    def _qp_hessian(self, k):
        """The QP's Hessian for ``k`` rows and its record entries ``(H, label, fallback, modified)``."""
        want_exact = self.lagrangian_hessian is not None
        if want_exact and self._use_exact:
            exact = self._exact_hessian()
            if exact is not None:
                return exact[0], "exact", False, exact[1]
        self._init_bfgs(self.pt.x.size)  # no structure seen: one dense block
        if self.R.shape[0] > 1 and not self.qp.dense_ok(k):
            return StructuredHessian(self.R, None), "bfgs", want_exact, 0  # block-diagonal: sparse QP
        return self._dense_bfgs(), "bfgs", want_exact, 0

    # ------------------------------------------------------------- QP
    def _qp(self, delta):
        """Solve the QP subproblem with trust region ``delta``; ``(rows, step, ok)``.

        The subproblem and its tolerances are kept in ``self._sub`` for the
        second-order correction, what it used in ``self._info``. When rows were
        dropped by ``max_qp_rows`` and the step violates some of them
        (linearised), they join the QP (and stay preferred in later iterations)
        and it is solved again, up to twice.
        """
        pt, s = self.pt, self.s
        sel = self._select(delta)
        pieces = self._pieces()
        its = 0  # ProxQP iterations of the rounds before the last
        for rounds in range(_MISSED_ROUNDS + 1):
            rows = sel.rows
            H, label, fallback, modified = self._qp_hessian(rows.size + pieces.size)
            self._info = QPUse(hessian=label, hessian_fallback=bool(fallback), hessian_modified=int(modified),
                               n_rows_dropped=int(sel.dropped.size), n_pieces=int(pieces.size))
            qp_rows = np.concatenate([rows, pieces.rows])  # the row of c behind each QP row
            constants = np.concatenate([pt.c[rows], pieces.values])
            sub = QPSubproblem(H, pt.g, _stack(pt.A[rows], pieces.gradients), -constants,
                               np.maximum(self.lb - pt.x, -delta), np.minimum(self.ub - pt.x, delta))
            self._qp_rows = qp_rows
            scale = max(1.0, float(np.max(np.abs(constants), initial=0.0)))
            tol_p = 10 * s.qp_eps_abs * scale
            tol_d = 10 * s.qp_eps_abs * max(scale, float(np.max(np.abs(pt.g), initial=0.0)))
            self._sub = (sub, tol_p, tol_d)
            ids = np.concatenate([rows, pt.c.size + np.arange(pieces.size)])  # QP rows at x_k
            violated = bool(np.any(pt.c[rows] < 0))  # else d = 0 is feasible
            if violated:
                bad = unreachable_rows(sub.C, sub.lower, sub.box_lower, sub.box_upper, tol_p)
                if bad.size:  # infeasible for sure: do not let ProxQP run to its limit
                    return rows, failed_step(pt.x.size, qp_rows.size, "unreachable_row"), False
            t = time.perf_counter()
            if violated and self._certified(sub, ids, tol_p):
                step, ok = failed_step(pt.x.size, qp_rows.size, "infeasible", _CERTIFIED), False
            else:
                step = self._solve(sub, np.concatenate([self.lam_rows[rows], np.zeros(pieces.size)]), self.nu,
                                   tol_d)
                ok = step.is_solved(tol_p, tol_d)
                failed = not ok and step.status not in CRASHED
                proved = failed and violated and self._keep_certificate(sub, ids, step.lam, tol_p)
                if failed and not proved and self._info.qp_backend != "block":
                    # a stale warm start or a stale equilibration of the reused ProxQP object
                    # (:class:`~calib_oed.solver.qp.DenseQPWorkspace`) can mislead it: cold, rescaled;
                    # not a QP proved infeasible (the cold solve would fail as well)
                    cold = self._solve(sub, None, None, tol_d, refresh=True)
                    step, ok = (cold._replace(iterations=cold.iterations + step.iterations),
                                cold.is_solved(tol_p, tol_d))
                    if not ok and violated and cold.status not in CRASHED:
                        self._keep_certificate(sub, ids, cold.lam, tol_p)
            self.p.times["qp"] += time.perf_counter() - t
            if not ok or rounds == _MISSED_ROUNDS:
                break
            missed = missed_rows(pt.c, pt.A, step.d, sel.dropped, tol_p)
            if not missed.size:
                break
            self.sticky[missed] = True
            sel = self._select(delta)
            its += step.iterations
        return rows, step._replace(iterations=step.iterations + its), ok

    def _certified(self, sub, ids, tol_p) -> bool:
        r"""Whether the certificate kept at :math:`x_k` (:meth:`_keep_certificate`) proves ``sub``
        infeasible: its rows (``ids``: row of :math:`c`, or :math:`m` + piece) all in this QP, and
        every step violating a row or the box by more than ``CERTIFIED_MARGIN`` times ``tol_p``, so
        that no solver could return a step that passes the residual test."""
        kept = self._farkas
        if kept is None or kept[0] != self._version or not np.isin(kept[1], ids).all():
            return False
        y = np.zeros(ids.size)
        y[np.searchsorted(ids, kept[1])] = kept[2]  # ids: rows sorted, then pieces in order
        return _proves_infeasible(sub, y, tol_p)

    def _keep_certificate(self, sub, ids, lam, tol_p) -> bool:
        r"""Keep ``lam`` of a failed solve of ``sub`` as a Farkas certificate at :math:`x_k` if it
        proves ``sub`` infeasible (:func:`~calib_oed.solver.restoration.certified_violation`):
        the QPs of the same iteration (the BFGS fallback, a larger box) that hold its rows are
        then tested before ProxQP runs to its limit on them. Returns whether it was kept."""
        lam = np.asarray(lam, dtype=float)
        if lam.size != ids.size or not np.all(np.isfinite(lam)):
            return False
        if not _proves_infeasible(sub, lam, tol_p):
            return False
        on = lam > 0
        self._farkas = (self._version, ids[on], lam[on])
        return True

    def _polishes(self, backend: str) -> bool:
        """Whether the dense KKT solves (the polish, the active-set start) serve ``backend``'s QPs:
        not the block QP's (it polishes its own active set, O(n)), and only up to
        ``max_dense_qp_size`` variables."""
        return backend != "block" and self.pt.x.size <= self.s.max_dense_qp_size

    def _solve(self, sub, lam0, nu0, tol, refresh=False):
        if lam0 is not None and self.s.qp_active_set_start:  # the warm start's active set first
            name = self.qp.backend(sub)
            step = from_active_set(sub, lam0, nu0, tol) if self._polishes(name) else None
            if step is not None:
                self.qp.last_backend = name
                self._info = replace(self._info, qp_backend=name)
                return step
        step = self.qp.solve(sub, lam0, nu0, refresh)
        self._info = replace(self._info, qp_backend=self.qp.last_backend)
        if (self.s.qp_polish and step.status not in CRASHED and step.primal_residual <= 1e3 * tol
                and self._polishes(self.qp.last_backend)):
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

        same Hessian (exact or BFGS, as in the QP of :math:`d`), :math:`\nabla f`,
        box and warm start, and return the evaluated :math:`x + p` (its values only when the
        caller gave ``values``; ``None`` if the QP fails) and the QP iterations.
        """
        pt = self.pt
        sub, tol_p, tol_d = self._sub
        sub = sub._replace(lower=-(trial.c[self._qp_rows] - np.asarray(sub.C @ step.d).reshape(-1)))
        if unreachable_rows(sub.C, sub.lower, sub.box_lower, sub.box_upper, tol_p).size:
            return None, 0
        t = time.perf_counter()
        corr = self._solve(sub, step.lam, step.nu, tol_d)
        self.p.times["qp"] += time.perf_counter() - t
        if not corr.is_solved(tol_p, tol_d):
            return None, corr.iterations
        return self._trial(pt.x + corr.d), corr.iterations
