r"""Records in and out of :func:`calib_oed.solver.sqp.solve_sqp`: structured Hessian, status, history, result.

(The settings are :mod:`calib_oed.solver.settings`, re-exported here.)

The problem solved is

.. math::
    \min_{x \in \mathbb{R}^n} f(x) \quad \text{s.t.} \quad
    c(x) \ge 0 \;(c: \mathbb{R}^n \to \mathbb{R}^m), \qquad lb \le x \le ub,

with Lagrangian :math:`L(x, \lambda, \nu) = f(x) - \lambda^\top c(x) - \nu^\top x`,
:math:`\lambda \in \mathbb{R}^m_{\ge 0}` and :math:`\nu_j \ge 0` at a lower
bound, :math:`\nu_j \le 0` at an upper bound, :math:`\nu_j = 0` between them.
The residuals a :class:`SQPResult` reports about its final iterate are

.. math::
    r_p = \max\big(0,\; \max_i -c_i(x),\; \max_j (lb_j - x_j),\; \max_j (x_j - ub_j)\big),

    r_d = \frac{\|\nabla f(x) - A(x)^\top \lambda - \nu\|_\infty}{\max(1, \|\nabla f(x)\|_\infty)},
    \qquad r_c = \frac{\max_i |\lambda_i\, c_i(x)|}{\max(1, \|\nabla f(x)\|_\infty)},

with :math:`A = \partial c / \partial x \in \mathbb{R}^{m \times n}`. Units are
those of the caller's :math:`x`, :math:`c` and :math:`f`.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from enum import Enum
from typing import NamedTuple

import numpy as np

from calib_oed.exceptions import SQPProblemError, SQPSettingsError  # noqa: F401 (re-exported)
from calib_oed.solver.settings import SQPSettings  # noqa: F401 (re-exported)
from calib_oed.values import plain


class StructuredHessian(NamedTuple):
    r"""A Hessian in factored form: :math:`H = \mathrm{blkdiag}(H_1, \dots, H_b) + U U^\top`.

    The design problem's Lagrangian Hessian has this shape: one
    :math:`s \times s` block per pose (the criterion's curvature through that
    pose's sensitivities, and :math:`-\sum_i \lambda_i \nabla^2 c_i` of that
    pose's rows), plus the exact coupling between poses through :math:`M^{-1}`,
    which factors with few columns.

    Attributes:
        blocks: (b, s, s) symmetric diagonal blocks, :math:`b s = n`; they may be indefinite.
        low_rank: (n, r) factor :math:`U` of the positive semidefinite coupling, or None.
    """

    blocks: np.ndarray
    low_rank: np.ndarray | None = None

    @property
    def shape(self) -> tuple[int, int]:
        """:math:`(n, n)`."""
        b, s, _ = self.blocks.shape
        return b * s, b * s

    def dense(self) -> np.ndarray:
        """The (n, n) matrix (for tests and small problems)."""
        b, s, _ = self.blocks.shape
        h = np.zeros((b * s, b * s))
        for j in range(b):
            h[j * s:(j + 1) * s, j * s:(j + 1) * s] = self.blocks[j]
        if self.low_rank is not None:
            h += self.low_rank @ self.low_rank.T
        return h

    def __matmul__(self, v) -> np.ndarray:
        r""":math:`H v = \mathrm{blkdiag}(H_j)\, v + U (U^\top v)` for a vector :math:`v \in \mathbb{R}^n`."""
        b, s, _ = self.blocks.shape
        v = np.asarray(v, dtype=float)
        out = np.einsum("jab,jb->ja", self.blocks, v.reshape(b, s)).reshape(-1)
        if self.low_rank is not None and self.low_rank.shape[1]:
            out = out + np.einsum("ir,r->i", self.low_rank, np.einsum("ir,i->r", self.low_rank, v))
        return out


class SQPStatus(str, Enum):
    """Why :func:`~calib_oed.solver.sqp.solve_sqp` stopped."""

    CONVERGED = "converged"
    """KKT residuals below tolerance at a feasible point."""
    MAX_ITERATIONS = "max_iterations"
    """The iteration limit was reached first."""
    TIME_LIMIT = "time_limit"
    """The wall-clock limit (``SQPSettings.time_limit``) was reached first."""
    STALLED = "stalled"
    """The trust region or the step fell below its minimum without convergence, or a QP
    subproblem at a point feasible to tolerance was not solved (its linearised constraints
    inconsistent, or ProxQP not converging on it) and restoration could not help."""
    INFEASIBLE = "infeasible"
    """Feasibility restoration could not reduce a violation above ``tol_feasibility``."""
    FAILED = "failed"
    """The QP subproblem could not be solved at a feasible point (ProxQP returned, not to tolerance)."""
    QP_FAILED = "qp_failed"
    """The QP solver raised, returned non-finite values, or the QP was refused as too large
    (``SQPSettings.max_qp_nonzeros``); the message names the cause."""
    NUMERICAL_ERROR = "numerical_error"
    """A numerical failure outside the QP solver (``MemoryError``, ``LinAlgError``,
    floating-point error); the message names it."""
    INTERRUPTED = "interrupted"
    """A ``KeyboardInterrupt`` (Ctrl-C, or SIGTERM turned into one) arrived during an
    iteration; the result holds the last accepted iterate."""


def kkt_residuals(x, g, c, A, lam, lb, ub, bound_tol, pieces=None):
    r""":math:`(r_d, r_c, \nu)` at :math:`x` for multipliers :math:`\lambda` (module docstring).

    ``g`` is :math:`\nabla f(x)`, ``c`` and ``A`` (ndarray or scipy sparse)
    are :math:`c(x)` and its Jacobian.
    :math:`r = \nabla f - A^\top \lambda`; the bound multipliers are the parts
    of :math:`r` of the right sign at bounds within ``bound_tol``
    (:math:`\nu_j = \max(r_j, 0)` at a lower bound, :math:`\min(r_j, 0)` at an
    upper one). Returns :math:`(\|r - \nu\|_\infty / s,\ \max_i |\lambda_i c_i| / s,\ \nu)`
    with :math:`s = \max(1, \|\nabla f\|_\infty)`.

    ``pieces``: optional ``(v, G, mu)``, the smooth pieces of kinked rows at
    :math:`x` (values :math:`v`, gradients :math:`G` (k, n)) with multipliers
    :math:`\mu \ge 0` (:mod:`calib_oed.solver.pieces`): then
    :math:`r = \nabla f - A^\top\lambda - G^\top\mu` and :math:`r_c` includes
    :math:`|\mu_k v_k|`.
    """
    r = g - (A.T @ lam if lam.size else 0.0)  # A is sparse in the design problem
    comp_terms = lam * c
    if pieces is not None and len(pieces[0]):
        values, grads, mu = pieces
        r = r - np.asarray(grads.T @ mu).reshape(-1)
        comp_terms = np.concatenate([comp_terms, mu * values])
    at_lo, at_up = x - lb <= bound_tol, ub - x <= bound_tol
    nu = np.where(at_lo, np.maximum(r, 0.0), 0.0) + np.where(at_up, np.minimum(r, 0.0), 0.0)
    scale = max(1.0, float(np.max(np.abs(g), initial=0.0)))
    stat = float(np.max(np.abs(r - nu), initial=0.0)) / scale
    comp = float(np.max(np.abs(comp_terms), initial=0.0)) / scale
    return stat, comp, nu


@dataclass(frozen=True, kw_only=True)
class QPUse:
    r"""What the QP of one SQP iteration used (the QP's part of an :class:`IterationRecord`).

    Attributes:
        hessian: The QP's Hessian: ``"bfgs"`` (damped BFGS) or ``"exact"`` (the caller's
            ``lagrangian_hessian``, made positive definite).
        hessian_fallback: The exact Hessian was asked for but not used in this
            iteration (the callable returned None, raised or gave a bad value, or
            its QP failed): the BFGS one was.
        hessian_modified: Eigenvalues of the exact Hessian changed to make it
            positive definite (:mod:`calib_oed.solver.hessian`).
        qp_backend: ``"dense"``, ``"sparse"``, ``"lifted"`` (sparse, the
            coupling :math:`U U^\top` kept factored) or ``"block"`` (the interior point of
            :mod:`calib_oed.solver.block_qp`); ``""`` when no QP was solved.
        n_rows_dropped: Near-active rows left out by ``SQPSettings.max_qp_rows``
            (the farthest from activity).
        n_pieces: Extra QP rows: the smooth pieces of kinked rows at :math:`x_k`
            (:mod:`calib_oed.solver.pieces`).
    """

    hessian: str = "bfgs"
    hessian_fallback: bool = False
    hessian_modified: int = 0
    qp_backend: str = ""
    n_rows_dropped: int = 0
    n_pieces: int = 0


@dataclass(frozen=True)
class _Step:
    """The fields of :class:`IterationRecord` before those of :class:`QPUse` (documented there)."""

    iteration: int
    objective: float
    merit: float
    penalty: float
    violation: float
    stationarity: float
    step_norm: float
    step_bound: float
    n_rows_kept: int
    qp_status: str
    qp_iterations: int
    backtracks: int
    restoration: bool
    time: float
    second_order_correction: bool = False
    extrapolated: float = 1.0


@dataclass(frozen=True)
class IterationRecord(QPUse, _Step):
    r"""One SQP iteration: the QP solved at :math:`x_k` and the step to :math:`x_{k+1}`.

    Values at the point reached (``objective``, ``merit``, ``violation``) are
    at :math:`x_{k+1}`; ``stationarity`` is the scaled KKT residual
    :math:`r_d` at :math:`x_k` with the multipliers of that QP (it needs
    them). The last record of a converged run is the final KKT check: no step
    (``step_norm == 0``), values at the solution.

    Attributes:
        iteration: Index :math:`k`, from 0.
        objective: :math:`f(x_{k+1})`.
        merit: :math:`\phi_{\mu_k}(x_{k+1}) = f + \mu_k (\sum_i \max(0, -c_i) + \text{bound violation})`
            (with one weight per row, ``SQPSettings.penalty_weights="row"``, :math:`\mu_{i,k}` on row i).
        penalty: :math:`\mu_k` used in this iteration's line search (with one weight per
            row, the single penalty's update, at least every row's weight).
        violation: :math:`r_p(x_{k+1})`, max violation of :math:`c \ge 0` and the bounds.
        stationarity: :math:`r_d(x_k)` (see the module docstring).
        step_norm: :math:`\|x_{k+1} - x_k\|_\infty` (:math:`\alpha \|d\|_\infty`).
        step_bound: Trust-region radius :math:`\Delta_k` of the QP (∞-norm).
        n_rows_kept: Rows of :math:`c` passed to the QP.
        qp_status: Outcome of the QP: ProxQP's status (``"solved"``, ``"max_iter"``,
            ...), ``"unreachable_row"`` (infeasible, found before solving) or ``"infeasible"``
            (proved so by the Farkas certificate of a failed solve at the same iterate,
            :func:`~calib_oed.solver.restoration.certified_violation`). For a restoration step,
            that of the last QP that failed.
        qp_iterations: Inner iterations of the QP solver (all QPs of the iteration).
        backtracks: Halvings of :math:`\alpha` in the line search.
        restoration: The step came from the feasibility-restoration QP.
        time: Seconds since the start of :func:`~calib_oed.solver.sqp.solve_sqp` [s].
        second_order_correction: The accepted point is the second-order
            correction of the full step.
        extrapolated: :math:`\alpha \ge 2` of a step longer than the QP's
            (``SQPSettings.extrapolate``), else 1.

    and after them, keyword-only, what the QP used (:class:`QPUse`).
    """


@dataclass(frozen=True)
class SQPResult:
    r"""Outcome of :func:`~calib_oed.solver.sqp.solve_sqp`; checks its own KKT residuals.

    Attributes:
        x: Final iterate :math:`x \in \mathbb{R}^n` (read-only).
        fun: :math:`f(x)`.
        status: Why the solver stopped.
        message: The same in words.
        iterations: Number of QP subproblems solved (length of ``history``).
        history: One :class:`IterationRecord` per iteration.
        multipliers: :math:`\lambda \in \mathbb{R}^m_{\ge 0}` of :math:`c(x) \ge 0`
            from the last QP (rows left out of it get 0; read-only).
        bound_multipliers: :math:`\nu \in \mathbb{R}^n` of the bounds (read-only).
        max_violation: :math:`r_p(x)`.
        kkt_stationarity: :math:`r_d(x)` (relative, see the module docstring).
        kkt_complementarity: :math:`r_c(x)` (relative).
        times: Seconds spent per phase: ``"objective"``, ``"constraints"``,
            ``"values"`` (the ``values`` callable of trial points), ``"qp"``,
            ``"hessian"``, ``"total"`` [s].
        n_objective_evaluations: Calls of the objective.
        n_constraint_evaluations: Calls of the constraints.
        n_value_evaluations: Calls of ``values`` (trial points without derivatives).
        hessian: The Hessian asked for: ``"bfgs"`` or ``"exact"``.
        hessian_fallbacks: Iterations in which the exact Hessian was asked for
            but the BFGS one was used.
        hessian_message: Why the last fallback happened (``""`` if none).
        max_pieces: Most pieces of kinked rows in one QP
            (:mod:`calib_oed.solver.pieces`); their multipliers are added to
            their rows' in ``multipliers``, and counted in the KKT residuals.
    """

    x: np.ndarray
    fun: float
    status: SQPStatus
    message: str
    iterations: int
    history: tuple[IterationRecord, ...]
    multipliers: np.ndarray
    bound_multipliers: np.ndarray
    max_violation: float
    kkt_stationarity: float
    kkt_complementarity: float
    times: dict = field(default_factory=dict)
    n_objective_evaluations: int = 0
    n_constraint_evaluations: int = 0
    n_value_evaluations: int = 0
    hessian: str = "bfgs"
    hessian_fallbacks: int = 0
    hessian_message: str = ""
    max_pieces: int = 0

    def __post_init__(self):
        for name in ("x", "multipliers", "bound_multipliers"):
            arr = np.array(getattr(self, name), dtype=float)
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)

    @property
    def success(self) -> bool:
        """``status is SQPStatus.CONVERGED``."""
        return self.status is SQPStatus.CONVERGED

    def primal_residual(self) -> float:
        r""":math:`r_p`: largest violation of :math:`c(x) \ge 0` and of the bounds."""
        return self.max_violation

    def dual_residual(self) -> float:
        r""":math:`r_d`: scaled KKT stationarity :math:`\|\nabla_x L\|_\infty / \max(1, \|\nabla f\|_\infty)`."""
        return self.kkt_stationarity

    def check(self, tol_feasibility: float = 1e-7, tol_optimality: float = 1e-6) -> bool:
        r"""Whether the final iterate is a KKT point to these tolerances.

        True when :math:`r_p \le` ``tol_feasibility``, :math:`r_d \le`
        ``tol_optimality``, :math:`r_c \le` ``tol_optimality`` and
        :math:`\lambda \ge 0`. It looks at the residuals only, not at
        ``status``.
        """
        return bool(
            self.max_violation <= tol_feasibility
            and self.kkt_stationarity <= tol_optimality
            and self.kkt_complementarity <= tol_optimality
            and np.all(self.multipliers >= 0.0)
        )

    def to_dict(self) -> dict:
        """JSON-serialisable dict (arrays as lists, non-finite floats as ``None``)."""
        out = {
            "x": self.x,
            "fun": self.fun,
            "status": self.status,
            "message": self.message,
            "iterations": self.iterations,
            "history": [asdict(r) for r in self.history],
            "multipliers": self.multipliers,
            "bound_multipliers": self.bound_multipliers,
            "max_violation": self.max_violation,
            "kkt_stationarity": self.kkt_stationarity,
            "kkt_complementarity": self.kkt_complementarity,
            "times": dict(self.times),
            "n_objective_evaluations": self.n_objective_evaluations,
            "n_constraint_evaluations": self.n_constraint_evaluations,
            "n_value_evaluations": self.n_value_evaluations,
            "hessian": self.hessian,
            "hessian_fallbacks": self.hessian_fallbacks,
            "hessian_message": self.hessian_message,
            "max_pieces": self.max_pieces,
        }
        return plain(out)

    def summary(self) -> str:
        """A few lines for a log: status, objective, residuals, effort."""
        kept = [r.n_rows_kept for r in self.history]
        n_rest = sum(r.restoration for r in self.history)
        n_soc = sum(r.second_order_correction for r in self.history)
        n_ext = sum(r.extrapolated > 1.0 for r in self.history)
        t = self.times
        return "\n".join(
            [
                f"SQP {self.status.value}: {self.message}",
                f"  f = {self.fun:.10g} after {self.iterations} iterations "
                f"({self.n_objective_evaluations} objective, "
                f"{self.n_constraint_evaluations} constraint, {self.n_value_evaluations} value-only evaluations, "
                f"{n_rest} restoration steps, {n_soc} second-order corrections, {n_ext} longer steps)",
                f"  violation {self.max_violation:.2e}, stationarity "
                f"{self.kkt_stationarity:.2e}, complementarity {self.kkt_complementarity:.2e}",
                f"  QP rows kept: max {max(kept, default=0)} of {self.multipliers.size}"
                f" ({sum(r.n_rows_dropped > 0 for r in self.history)} QPs at max_qp_rows)",
                f"  Hessian: {self.hessian}" + (f", {self.hessian_fallbacks} BFGS fallbacks "
                                                 f"({self.hessian_message})" if self.hessian_fallbacks else ""),
                "  time [s]: "
                + ", ".join(f"{k} {t.get(k, 0.0):.3f}" for k in ("objective", "constraints", "values", "qp", "hessian", "total")),
            ]
        )
