r"""QP subproblems of the SQP solver, solved with ProxQP (proxsuite).

The subproblem at an iterate :math:`x` is

.. math::
    \min_{d \in \mathbb{R}^n} \tfrac12 d^\top H d + g^\top d \quad \text{s.t.} \quad
    C d \ge \ell, \qquad \underline{b} \le d \le \overline{b},

with :math:`H \in \mathbb{R}^{n \times n}` symmetric positive definite,
:math:`C \in \mathbb{R}^{k \times n}` and the box
:math:`[\underline{b}, \overline{b}]` (variable bounds and trust region
combined). Its KKT conditions, in the sign convention used throughout,

.. math::
    H d + g - C^\top \lambda - \nu = 0, \qquad \lambda \ge 0, \quad
    \lambda_i (C_i d - \ell_i) = 0,

    \nu_j \ge 0 \text{ if } d_j = \underline{b}_j, \quad
    \nu_j \le 0 \text{ if } d_j = \overline{b}_j, \quad \nu_j = 0 \text{ otherwise}.

ProxQP writes :math:`H d + g + C^\top z + z_\text{box} = 0` for
:math:`\ell \le C d \le u`, so :math:`\lambda = -z` and :math:`\nu = -z_\text{box}`.

Traps of ProxQP (proxsuite 0.8.0) handled here:

* it does not flag an infeasible QP: it iterates to ``max_iter`` and returns a
  point that may violate even the box. :class:`QPStep` therefore carries our
  own primal, dual and complementarity residuals, and
  :func:`calib_oed.solver.restoration.unreachable_rows` catches the common
  case before ProxQP runs;
* with its default settings it stops with complementarity errors of ~1e-5
  even for ``eps_abs = 1e-9``: the duality-gap check is switched on;
* warm-started with stale duals it can report success after 0 iterations
  with complementarity violated (seen on HS21): the caller retries cold when
  our residuals disagree (:meth:`QPStep.is_solved`);
* ``solve(x, y, z)`` of a box-constrained dense QP rejects a dual of the size
  the solver itself returns (:class:`DenseQPWorkspace` writes the guess into
  the result vectors instead);
* sparse ``update`` silently keeps the old matrices when the new ones have
  another sparsity pattern (:class:`SparseQPWorkspace` rebuilds instead);
* its sparse ``Automatic`` backend picks an iterative (matrix-free) KKT solver
  when it expects fill, ~500x slower on the lifted QP: the Cholesky one is forced;
* it allocates with a library that calls ``std::terminate`` when memory runs
  out: a dense QP of 420 variables and 31,616 rows aborted the whole process
  ("terminate called without an active exception"). Sizes are therefore
  checked *before* a QP object is built (:class:`QPSizeError`);
* its AVX2 build answers one QP with other last bits depending on where the allocator put
  its buffers: ProxQP is imported from :mod:`calib_oed.solver.proxqp_build`, which loads the
  SSE2 build.

Two backends: :class:`DenseQPWorkspace` (ProxQP dense, native box constraints,
one QP object reused across iterations with a fixed row capacity, at most
``max_capacity`` rows) and :class:`SparseQPWorkspace` (ProxQP sparse, box as
identity rows, rebuilt whenever the kept rows change, at most ``max_nonzeros``
nonzeros). ``bench/bench_sqp_qp.py`` compares them: dense was 1.8-3.4x faster
on QPs shaped like the design problem's (400 rows) when the SQP was written;
re-measured for issue 16 (``--rows 400/1000/1600 --qps 5``, shared 2-core
machine) sparse took 0.4-0.9x the dense time at every size.
A third, :class:`calib_oed.solver.lifted.LiftedQPWorkspace`, takes a
:class:`~calib_oed.solver.result.StructuredHessian` in factored form.

This module owns the subproblem and step records and the two workspaces;
the active-set polish is :mod:`calib_oed.solver.polish`, the infeasible
subproblems (unreachable rows, elastic QP) are :mod:`calib_oed.solver.restoration`,
the choice of workspace and the capture of its failures :mod:`calib_oed.solver.subproblem`.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import scipy.sparse as sp

from calib_oed.solver.proxqp_build import proxsuite

_STATUS_NAMES = {
    "PROXQP_SOLVED": "solved",
    "PROXQP_MAX_ITER_REACHED": "max_iter",
    "PROXQP_PRIMAL_INFEASIBLE": "primal_infeasible",
    "PROXQP_DUAL_INFEASIBLE": "dual_infeasible",
    "PROXQP_SOLVED_CLOSEST_PRIMAL_FEASIBLE": "closest_primal_feasible",
    "PROXQP_NOT_RUN": "not_run",
}


class QPSizeError(RuntimeError):
    """A QP larger than the workspace's bound: refused before ProxQP allocates (module docstring)."""


def matvec(M, v) -> np.ndarray:
    """:math:`M v` without waking BLAS threads for a dense :math:`M` (scipy sparse and
    :class:`~calib_oed.solver.result.StructuredHessian` through their ``@``).

    OpenBLAS runs a 360 x 360 ``dgemv`` on all cores and its threads then spin
    for a while, competing with ProxQP (single-threaded) for the CPU: on two
    cores that cost the SQP ~30 % of its time. ``einsum`` without
    ``optimize`` is a plain single-threaded loop, fast enough here.
    """
    if not isinstance(M, np.ndarray):
        return M @ v
    return np.einsum("ij,j->i", M, v)


def as_dense(H) -> np.ndarray:
    """The (n, n) ndarray of a dense, scipy sparse or structured Hessian."""
    if isinstance(H, np.ndarray):
        return H
    return H.toarray() if sp.issparse(H) else H.dense()


class QPSubproblem(NamedTuple):
    r"""Data of :math:`\min \tfrac12 d^\top H d + g^\top d` s.t. :math:`C d \ge \ell`, :math:`\underline{b} \le d \le \overline{b}`.

    Attributes:
        H: :math:`H \in \mathbb{R}^{n \times n}`, symmetric positive definite; dense,
            a :class:`~calib_oed.solver.result.StructuredHessian` (lifted QP), or
            scipy sparse (restoration QP).
        g: :math:`g \in \mathbb{R}^n`.
        C: :math:`C \in \mathbb{R}^{k \times n}`, dense ndarray or scipy sparse.
        lower: :math:`\ell \in \mathbb{R}^k`.
        box_lower: :math:`\underline{b} \in \mathbb{R}^n` (may hold -inf).
        box_upper: :math:`\overline{b} \in \mathbb{R}^n` (may hold +inf).
    """

    H: np.ndarray
    g: np.ndarray
    C: np.ndarray | sp.csr_matrix
    lower: np.ndarray
    box_lower: np.ndarray
    box_upper: np.ndarray

    def residuals(self, d, lam, nu) -> tuple[float, float, float]:
        r"""``(primal, dual, complementarity)`` residuals of :math:`(d, \lambda, \nu)`, ∞-norms.

        Primal: largest violation of :math:`C d \ge \ell` and of the box.
        Dual: :math:`\|H d + g - C^\top \lambda - \nu\|_\infty`.
        Complementarity: :math:`\max_i |\lambda_i (C_i d - \ell_i)|` together
        with :math:`|\nu_j|` times the distance of :math:`d_j` to the bound its
        sign refers to.
        """
        slack = matvec(self.C, d) - self.lower
        primal = max(
            float(np.max(-slack, initial=0.0)),
            float(np.max(self.box_lower - d, initial=0.0)),
            float(np.max(d - self.box_upper, initial=0.0)),
        )
        dual = float(np.max(np.abs(matvec(self.H, d) + self.g - matvec(self.C.T, lam) - nu), initial=0.0))
        with np.errstate(invalid="ignore"):  # 0 * inf where a multiplier is 0 at an infinite bound
            gap_lo = np.where(nu > 0, nu * (d - self.box_lower), 0.0)
            gap_up = np.where(nu < 0, -nu * (self.box_upper - d), 0.0)
        comp = max(
            float(np.max(np.abs(lam * slack), initial=0.0)),
            float(np.max(np.abs(gap_lo), initial=0.0)),
            float(np.max(np.abs(gap_up), initial=0.0)),
        )
        return primal, dual, comp


class QPStep(NamedTuple):
    r"""Solution of a :class:`QPSubproblem` with its own residuals.

    Attributes:
        d: Step :math:`d \in \mathbb{R}^n`.
        lam: :math:`\lambda \in \mathbb{R}^k_{\ge 0}` of the rows.
        nu: :math:`\nu \in \mathbb{R}^n` of the box.
        status: ProxQP's status, short (``"solved"``, ``"max_iter"``, ...).
        iterations: ProxQP inner iterations.
        primal_residual: See :meth:`QPSubproblem.residuals`.
        dual_residual: See :meth:`QPSubproblem.residuals`.
        complementarity: See :meth:`QPSubproblem.residuals`.
        polished: :math:`(d, \lambda, \nu)` come from :func:`calib_oed.solver.polish.polish`.
        message: Why the QP failed, when it did not return (``status`` ``"error"``,
            ``"too_large"`` or ``"non_finite"``, :mod:`calib_oed.solver.subproblem`).
    """

    d: np.ndarray
    lam: np.ndarray
    nu: np.ndarray
    status: str
    iterations: int
    primal_residual: float
    dual_residual: float
    complementarity: float
    polished: bool = False
    message: str = ""

    def is_solved(self, primal_tolerance: float, dual_tolerance: float) -> bool:
        """Solved per ProxQP *and* per our residuals.

        ProxQP's word alone is not enough: warm-started with stale duals it
        can report success after 0 iterations with complementarity violated.
        Complementarity is held to ``dual_tolerance`` too.
        """
        return ((self.status == "solved" or self.polished) and self.primal_residual <= primal_tolerance
                and self.dual_residual <= dual_tolerance and self.complementarity <= dual_tolerance)


def _configure(qp, eps_abs: float, max_iter: int) -> None:
    """Tight absolute tolerances (ProxQP's default 1e-3 is lax) and the duality-gap check."""
    s = qp.settings
    s.eps_abs = eps_abs
    s.eps_rel = 0.0
    s.check_duality_gap = True
    s.eps_duality_gap_abs = eps_abs
    s.eps_duality_gap_rel = 0.0
    s.max_iter = max_iter
    # bounds the time of one QP: ProxQP's default 1500 inner iterations per outer one let a
    # degenerate QP of the design problem run for minutes (seen in bench/bench_oed.py)
    s.max_iter_in = 200
    # sparse QPs: ProxQP's "Automatic" backend switches to its iterative MatrixFree solver when it
    # expects much fill; on a lifted QP (n = 2400, r = 60 dense coupling rows) that took 181 s
    # instead of 0.35 s with the Cholesky factorisation
    s.sparse_backend = proxsuite.proxqp.SparseBackend.SparseCholesky
    s.verbose = False


def _finish(sub: QPSubproblem, x, z_rows, z_box, info) -> QPStep:
    """Convert ProxQP's :math:`(x, z)` to :class:`QPStep` and check it."""
    d = np.array(x, dtype=float)
    lam = np.maximum(-np.asarray(z_rows, dtype=float), 0.0)
    nu = -np.asarray(z_box, dtype=float)
    primal, dual, comp = sub.residuals(d, lam, nu)
    return QPStep(d, lam, nu, _STATUS_NAMES.get(info.status.name, info.status.name.lower()),
                  int(info.iter), primal, dual, comp)


class DenseQPWorkspace:
    r"""One ProxQP dense QP object reused across SQP iterations.

    The object has a row capacity :math:`K \ge k`; rows :math:`k..K-1` are
    padding (zero rows of :math:`C`, bounds :math:`-\infty \le 0 \le +\infty`),
    so the same object serves QPs with a varying number of kept rows through
    ``update``. It is rebuilt with :math:`K = 2k` when :math:`k > K` (growth)
    or :math:`k < K/4` (shrink; padding is not free: ProxQP works on all
    :math:`K` rows). The box is ProxQP's native box constraint; the
    factorisation is ``PrimalDualLDLT`` (fastest here, ``bench/bench_sqp_qp.py``).

    The Ruiz equilibration is computed when the object is built and kept
    through ``update`` (``update_preconditioner=False``): recomputing it costs
    more than the solve itself (45 ms vs 12 ms at :math:`K = 2048`,
    :math:`n = 360`), and a stale diagonal scaling of rows it has seen is
    still a valid one. Not so for a slot that was padding when it was
    computed: a QP with more rows than the equilibration saw
    (``scaled_rows``) recomputes it. ``ur5_table``'s ``kpi_model`` design
    (issue 30) built the object at 1235 rows; its QPs of 1442 rows then all
    stopped at ProxQP's iteration limit with residuals of 0.01-100, and the
    SQP stalled after 9 iterations; re-equilibrated, each was solved in 30-40
    ProxQP iterations (``tests/solver/test_qp.py``). ``refresh``
    recomputes it on demand (the retry of a failed QP,
    :mod:`calib_oed.solver.subproblem`).

    Warm start: ``initial_guess = WARM_START``, with the caller's guess for
    :math:`(d, \lambda, \nu)` written into the solver's result vectors after
    ``update`` (the ``solve(x, y, z)`` overload of 0.8.0 rejects a dual of
    size :math:`K + n` for box-constrained QPs). ProxQP starts from the active
    set of the nonzero duals, so passing the previous iteration's multipliers
    (mapped to the rows' new slots) saves active-set changes. ``WARM_START``
    resets the proximal parameters; ``WARM_START_WITH_PREVIOUS_RESULT`` keeps
    the small ones the previous solve converged with and needed 1.6x more
    ProxQP iterations over a 360-variable SQP run (1.4x the QP time).
    """

    def __init__(self, n: int, eps_abs: float, max_iter: int, capacity: int = 32,
                 update_preconditioner: bool = False, max_capacity: int | None = None):
        self.n = n
        self.eps_abs = eps_abs
        self.max_iter = max_iter
        self.max_capacity = max_capacity
        self.min_capacity = self.capacity = max(1, int(capacity))
        if max_capacity is not None:
            self.min_capacity = self.capacity = min(self.capacity, max(1, int(max_capacity)))
        self.update_preconditioner = update_preconditioner
        self.scaled_rows = 0  # rows of the QP the equilibration was computed on (slots above: padding)
        self._qp = None

    def _build(self, capacity: int):
        pq = proxsuite.proxqp
        qp = pq.dense.QP(self.n, 0, capacity, True, pq.dense.HessianType.Dense,
                         pq.dense.DenseBackend.PrimalDualLDLT)
        _configure(qp, self.eps_abs, self.max_iter)
        self.capacity = capacity
        self._qp = qp

    def solve(self, sub: QPSubproblem, d0=None, lam0=None, nu0=None, refresh: bool = False) -> QPStep:
        """Solve ``sub``, warm-started from ``(d0, lam0, nu0)`` when given; ``refresh``
        recomputes the equilibration (as does a QP with more rows than it saw)."""
        n, k = self.n, sub.lower.size
        if self.max_capacity is not None and k > self.max_capacity:
            raise QPSizeError(f"dense QP of {k} rows above its capacity bound {self.max_capacity}")
        fresh = self._qp is None or k > self.capacity or (
            4 * k < self.capacity and self.capacity > self.min_capacity)
        if fresh:
            cap = max(self.min_capacity, 2 * k)
            self._build(cap if self.max_capacity is None else min(cap, self.max_capacity))
        cap = self.capacity
        C = np.zeros((cap, n))
        if k:
            C[:k] = sub.C.toarray() if sp.issparse(sub.C) else sub.C
        lower = np.full(cap, -np.inf)
        lower[:k] = sub.lower
        upper = np.full(cap, np.inf)
        qp = self._qp
        pq = proxsuite.proxqp
        warm = d0 is not None or lam0 is not None or nu0 is not None
        qp.settings.initial_guess = (pq.InitialGuess.WARM_START if warm
                                     else pq.InitialGuess.NO_INITIAL_GUESS)
        if fresh:
            qp.init(sub.H, sub.g, None, None, C, lower, upper, sub.box_lower, sub.box_upper)
            self.scaled_rows = k
        else:
            rescale = self.update_preconditioner or refresh or k > self.scaled_rows
            qp.update(sub.H, sub.g, None, None, C, lower, upper, sub.box_lower, sub.box_upper,
                      update_preconditioner=rescale)
            if rescale:
                self.scaled_rows = k
        if warm:
            z = warm_duals(lam0, nu0, k, n, box_at=cap)
            # results.x / results.z are views of the solver's vectors: this is the warm start
            qp.results.x[:] = 0.0 if d0 is None else d0
            qp.results.z[:] = z
        qp.solve()
        r = qp.results
        return _finish(sub, r.x, r.z[:k], r.z[cap:], r.info)


class SparseWorkspace:
    """What the ProxQP sparse workspaces share: the size, the tolerances, the bound on the
    nonzeros, and the QP object kept while its pattern stays (``_pattern``)."""

    def __init__(self, n: int, eps_abs: float, max_iter: int, max_nonzeros: int | None = None):
        self.n = n
        self.eps_abs = eps_abs
        self.max_iter = max_iter
        self.max_nonzeros = max_nonzeros
        self._qp = None
        self._pattern = None


def warm_duals(lam0, nu0, k: int, n: int, box_at: int | None = None) -> np.ndarray:
    """ProxQP's dual guess: :math:`-\\lambda_0` on the ``k`` rows, :math:`-\nu_0` on the ``n``
    box rows from ``box_at`` (default ``k``), zero where no guess is given."""
    at = k if box_at is None else box_at
    z = np.zeros(at + n)
    if lam0 is not None and k:
        z[:k] = -np.asarray(lam0, dtype=float)
    if nu0 is not None:
        z[at:] = -np.asarray(nu0, dtype=float)
    return z


class SparseQPWorkspace(SparseWorkspace):
    r"""ProxQP sparse backend; the box becomes :math:`n` identity rows of :math:`C`.

    :math:`H` is passed with the full upper-triangular pattern (explicit zeros
    kept) so that its structure never changes. ProxQP sparse ``update`` keeps
    the symbolic factorisation and silently ignores a matrix whose sparsity
    pattern differs, so the object is reused only when the stacked constraint
    matrix has exactly the previous pattern; otherwise a new one is built.
    Warm start through ``solve(x, y, z)``. A QP with more than ``max_nonzeros``
    nonzeros (:math:`n(n+1)/2` of :math:`H`, those of :math:`C`, :math:`n` box
    rows) raises :class:`QPSizeError` before anything is allocated.
    """

    def __init__(self, n: int, eps_abs: float, max_iter: int, max_nonzeros: int | None = None):
        super().__init__(n, eps_abs, max_iter, max_nonzeros)
        self._h_rows = None  # the upper triangle's pattern, built on first use

    def _hessian(self, H) -> sp.csc_matrix:
        n = self.n
        if self._h_rows is None:
            rows, cols = np.triu_indices(n)
            order = np.lexsort((rows, cols))  # column-major order of the upper triangle
            self._h_rows, self._h_cols = rows[order], cols[order]
            self._h_indptr = np.concatenate([[0], np.cumsum(np.arange(1, n + 1))]).astype(np.int32)
        data = as_dense(H)[self._h_rows, self._h_cols]
        return sp.csc_matrix((data, self._h_rows.astype(np.int32), self._h_indptr), shape=(self.n, self.n))

    def solve(self, sub: QPSubproblem, d0=None, lam0=None, nu0=None, refresh: bool = False) -> QPStep:
        """Solve ``sub``, warm-started from ``(d0, lam0, nu0)`` when given; ``refresh``
        recomputes the equilibration of a reused object."""
        n, k = self.n, sub.lower.size
        rows = sp.csr_matrix(sub.C) if k else sp.csr_matrix((0, n))
        nnz = n * (n + 1) // 2 + rows.nnz + n
        if self.max_nonzeros is not None and nnz > self.max_nonzeros:
            raise QPSizeError(f"sparse QP with a dense Hessian of n = {n}: {nnz:.3g} nonzeros above "
                              f"max_qp_nonzeros = {self.max_nonzeros:.3g}")
        C = sp.vstack([rows, sp.identity(n, format="csr")], format="csc")
        C.sort_indices()
        lower = np.concatenate([sub.lower, sub.box_lower])
        upper = np.concatenate([np.full(k, np.inf), sub.box_upper])
        H = self._hessian(sub.H)
        pattern = (C.shape, C.indptr.tobytes(), C.indices.tobytes())
        pq = proxsuite.proxqp
        if self._qp is None or pattern != self._pattern:
            qp = pq.sparse.QP(n, 0, k + n)
            _configure(qp, self.eps_abs, self.max_iter)
            qp.init(H, sub.g, None, None, C, lower, upper)
            self._qp, self._pattern = qp, pattern
        else:
            qp = self._qp
            qp.update(H, sub.g, None, None, C, lower, upper, update_preconditioner=refresh)
        if d0 is not None or lam0 is not None or nu0 is not None:
            x = np.zeros(n) if d0 is None else np.asarray(d0, dtype=float)
            qp.solve(x, None, warm_duals(lam0, nu0, k, n))
        else:
            qp.settings.initial_guess = pq.InitialGuess.NO_INITIAL_GUESS
            qp.solve()
        r = qp.results
        return _finish(sub, r.x, r.z[:k], r.z[k:], r.info)
