r"""Settings of :func:`calib_oed.solver.sqp.solve_sqp`, validated at construction.

Units: tolerances on :math:`c` and the bounds are those of :math:`c` and
:math:`x` (for the design problem [m], cosines and [rad]); step bounds are
∞-norms in units of :math:`x` [rad]; sizes are counts of rows, variables or
nonzeros.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib_oed.exceptions import SQPSettingsError

QP_BACKENDS = ("dense", "sparse")
STRUCTURED_QPS = ("auto", "lifted", "block")
TRUST_UPDATES = ("edge", "ratio")
HESSIAN_MODIFICATIONS = ("auto", "tangent", "block")
PENALTY_WEIGHTS = ("single", "row")


@dataclass(frozen=True)
class SQPSettings:
    r"""Settings of :func:`~calib_oed.solver.sqp.solve_sqp`, validated at construction.

    Tolerances are absolute on :math:`c` and the bounds (units of :math:`c`,
    :math:`x`), relative to :math:`\max(1, \|\nabla f\|_\infty)` for stationarity.
    Step bounds are ∞-norms in units of :math:`x` ([rad] for joint angles).

    Attributes:
        max_iterations: Largest number of QP subproblems.
        time_limit: Stop after the iteration that exceeds this wall time [s]
            (default: no limit).
        tol_optimality: Scaled KKT stationarity and complementarity tolerance.
        tol_feasibility: Largest violation of :math:`c \ge 0` and of the bounds.
        tol_step: Stop (stalled) when :math:`\|d\|_\infty` falls below it.
        step_bound: Initial trust-region radius :math:`\Delta_0`.
        min_step_bound: :math:`\Delta_\min`; stop (stalled) when it must shrink below.
        max_step_bound: :math:`\Delta_\max`.
        step_bound_ratio: :math:`\kappa`: after an accepted step,
            :math:`\Delta \le \kappa \|x_{k+1} - x_k\|_\infty`, so the box, and with
            it the rows kept, follows the steps being taken (``inf`` disables).
            Used by ``trust_update="edge"``.
        trust_update: How :math:`\Delta` changes after a step: ``None`` (default) leaves
            the choice to the caller (the design: ``"ratio"`` with the exact Hessian,
            :data:`calib_oed.oed.refine.EXACT_TRUST_UPDATE`; otherwise ``"edge"``). ``"edge"``
            doubles it after a full step that reaches the box and cuts it to
            :math:`\max(\tfrac12\|\alpha d\|_\infty, \tfrac1{10}\min(\Delta, \|d\|_\infty))`
            after a backtracked one; ``"ratio"`` follows the agreement
            :math:`\rho` of the merit's actual and predicted reduction (Nocedal &
            Wright 2006, Algorithm 4.1; :mod:`calib_oed.solver.iteration`): halved
            to :math:`\tfrac12\|d\|_\infty` when :math:`\rho < \tfrac14` (a
            backtracked step counts as :math:`\rho < 0`), doubled when
            :math:`\rho > \tfrac34` at the box, else kept. The design takes ``"ratio"``:
            under ``"edge"`` a step whose model was poor still doubled the box and the next
            failure cut it tenfold, and the design crept (``docs/oed.md``, item 4 of the SQP).
        active_margin: :math:`m_a \ge 0` of the row selection (:mod:`calib_oed.solver.rows`).
        max_qp_rows: Most constraint rows in any QP, whatever :math:`\Delta`
            (:mod:`calib_oed.solver.rows`); ``None``: :math:`\max(200, 4n)`.
            At most :math:`n` linearly independent rows can be active at a QP
            solution, so :math:`4n` keeps every row that can matter plus a
            margin, and the design runs measured (200–400 rows at :math:`n = 360`)
            never reach it; at :math:`\Delta = 1` rad a Panda cell offered
            15,800 rows.
        max_dense_qp_size: The dense ProxQP backend is used only while
            :math:`n + K \le` this (:math:`K` its row capacity); larger QPs go to
            the sparse backend. Dense ProxQP's memory grows as :math:`(n + K)^2`
            (measured 260 MB at :math:`n + K = 8420`; at 16,420 it aborts the
            process under a 6 GB limit), and above ~1000 rows the sparse
            backend was as fast (``bench/bench_sqp_qp.py --rows 1600``).
        max_qp_nonzeros: Largest number of nonzeros (Hessian upper triangle,
            equality and inequality rows) of a sparse QP; a larger one is
            refused with :attr:`SQPStatus.QP_FAILED` instead of letting
            ProxQP's allocation abort the process (measured ~60 bytes per
            nonzero for a dense Hessian: 1e7 is ~600 MB).
        hessian_eigenvalue_floor: :math:`\epsilon_r` of the eigenvalue modification
            that makes an exact Hessian positive definite
            (:mod:`calib_oed.solver.hessian`): the smallest eigenvalue kept is
            :math:`\epsilon = \epsilon_r \max(1, \max|\theta|)`.
        hessian_modification: ``"tangent"``: each pose block's eigenvalues are modified on
            the tangent space of its active rows and bounds, and its Schur complement across
            them, so the curvature the step moves along stays the true one where it is
            positive; ``"block"``: the whole block's eigenvalues
            (:mod:`calib_oed.solver.hessian`); ``"auto"`` (default): tangent up to
            ``tangent_max_size`` variables, block above. On seven scenes' 60-pose ``kpi``
            designs ``"tangent"`` ends the linear tails: 16-87 SQP iterations against 29-300,
            half the SQP's CPU, every value the same to 0.03 %; at 250 and 500 poses it takes
            37-48 % more iterations for a 0.03-0.26 % lower value (``docs/benchmarks.md``,
            "The Hessian on the active constraints' tangent space", "Growth with n").
        tangent_max_size: Largest number of variables for which ``hessian_modification="auto"``
            takes the tangent rule (1000: 166 poses of 6 joints; ``fms_kr16``'s ``kpi`` design
            took fewer iterations with it at 30-120 poses, more at 250-1000).
        hessian_every: The exact Hessian (``lagrangian_hessian``, made positive definite) is
            computed at every ``hessian_every``-th accepted point, counted from the start; the
            QPs of the points between take the last one computed. 1 (default): at every point.
            More iterations fit in the same CPU where the Hessian leads an iteration's cost; for
            ``kpi_model`` every third point gained about 1 % of value at equal CPU at 500
            poses and none on average at 250 (``docs/benchmarks.md``, "The exact Hessian every k-th point").
        initial_hessian_scale: :math:`\beta` of :math:`B_0 = \beta I`.
        bfgs_damping: Powell's :math:`\delta \in (0, 1)`: :math:`s^\top r \ge \delta\, s^\top B s`.
        qp_backend: ``"dense"`` (default) or ``"sparse"`` for QPs with a dense
            Hessian (the lifted QP of an exact structured Hessian is always sparse).
        structured_qp: The QP of a structured Hessian: ``"lifted"`` (ProxQP
            sparse on the lifted QP, :mod:`calib_oed.solver.lifted`), ``"block"``
            (interior point with per-pose factors, Woodbury and an exact polish of
            its active set, :mod:`calib_oed.solver.block_qp`, linear in the number
            of poses) or ``"auto"`` (default): block from ``block_qp_min_size``
            variables on, lifted below. Both solve the same QP to the same
            residual test; the lifted one grows faster than linearly (0.11 s per
            QP at 60 poses, 5.9 s at 250, 43 s at 500; block: 0.03, 0.10, 0.24 s cold,
            0.01-0.04 s warm-started from a right active set, ``bench/bench_block_qp.py``)
            and needs the dense polish on top.
        block_qp_min_size: Number of variables from which ``structured_qp="auto"``
            uses the block QP (240: 40 poses of 6 joints, so every shipped scene's
            60-pose design takes it). In the design SQP (fms_kr16, ``--criterion
            kpi``, ``bench/bench_design_qp_paths.py``, ``docs/benchmarks.md``) the QP
            with the lifted path's polish took 0.138 s per SQP iteration at 60 poses
            on the lifted QP and 0.049 s on the block QP, the same iterations and
            value; at 120 poses 0.676 s against 0.049 s.
        qp_eps_abs: ProxQP absolute tolerance (its default 1e-3 is lax).
        qp_max_iterations: ProxQP ``max_iter``; bounds the time lost on an infeasible QP.
        qp_polish: Refine every QP step (up to ``max_dense_qp_size`` variables) on its active
            set (:func:`calib_oed.solver.polish.polish`): the exact KKT point, and the same
            bits in every process, which ProxQP's own answer is not.
        qp_active_set_start: Before ProxQP, solve the KKT system of the QP on the active set
            its warm-start multipliers name (:func:`calib_oed.solver.polish.from_active_set`,
            up to ``max_dense_qp_size`` variables, not the block QP, which does the same
            itself) and keep that point if it is a KKT point of the QP to the same
            tolerance as a polished ProxQP step. Off by default (the same steps, to the QP's
            tolerance, but not the same bits); on in the design SQP
            (:data:`calib_oed.oed.refine.DESIGN_SQP`).
        second_order_correction: Try a second-order correction before
            backtracking from a rejected full step (:mod:`calib_oed.solver.sqp`, item 4).
        extrapolate: After a full step from an exact Hessian whose eigenvalues were modified,
            try a step :math:`\alpha d`, :math:`\alpha \ge 2`, to the minimiser of the merit's
            quadratic along :math:`d`, within the box and the inactive rows' linearisations
            (:meth:`calib_oed.solver.iteration._Run._extrapolate`). Off by default; the design
            takes it (:data:`calib_oed.oed.refine.DESIGN_SQP`).
        row_pieces_margin: Rows with :math:`c_i` at most this (units of :math:`c`)
            are offered to the caller's ``row_pieces`` (:mod:`calib_oed.solver.pieces`).
        armijo: :math:`\eta \in (0, 1/2)` of the Armijo condition.
        backtrack: Factor :math:`\in (0, 1)` applied to :math:`\alpha` per backtrack.
        max_backtracks: Backtracks before the step is rejected.
        penalty_margin: :math:`\mu_m > 0` in :math:`\mu \ge \|\lambda\|_\infty + \mu_m`.
        penalty_weights: ``"single"`` (default): one penalty :math:`\mu` for every row;
            ``"row"``: one weight per row, :math:`\mu_i \ge \lambda_i + \mu_m`, Powell's update
            each, charged on the rows the last QP held (:math:`\lambda_i > 0`; the others at
            :math:`\mu`; :mod:`calib_oed.solver.sqp`, item 4). The design takes ``"row"``
            (:data:`calib_oed.oed.refine.DESIGN_SQP`): one row's large multiplier no longer
            charges the second-order violation of curved rows with small ones at its size.
        restoration_penalty: :math:`\rho` of the elastic restoration QP.
    """

    max_iterations: int = 300
    time_limit: float = float("inf")
    tol_optimality: float = 1e-6
    tol_feasibility: float = 1e-7
    tol_step: float = 1e-9
    step_bound: float = 0.3
    min_step_bound: float = 1e-8
    max_step_bound: float = 1.0
    step_bound_ratio: float = 10.0
    trust_update: str | None = None
    active_margin: float = 0.05
    max_qp_rows: int | None = None
    max_dense_qp_size: int = 3000
    max_qp_nonzeros: int = 10_000_000
    hessian_eigenvalue_floor: float = 1e-8
    hessian_modification: str = "auto"
    tangent_max_size: int = 1000
    hessian_every: int = 1
    initial_hessian_scale: float = 1.0
    bfgs_damping: float = 0.2
    qp_backend: str = "dense"
    structured_qp: str = "auto"
    block_qp_min_size: int = 240
    qp_eps_abs: float = 1e-9
    qp_max_iterations: int = 100
    qp_polish: bool = True
    qp_active_set_start: bool = False
    second_order_correction: bool = True
    extrapolate: bool = False
    row_pieces_margin: float = 1e-3
    armijo: float = 1e-4
    backtrack: float = 0.5
    max_backtracks: int = 12
    penalty_margin: float = 0.1
    penalty_weights: str = "single"
    restoration_penalty: float = 1e3

    def __post_init__(self):
        def need(name, ok, requirement):
            value = getattr(self, name)
            if isinstance(value, bool) or not ok(value):
                raise SQPSettingsError(name, value, requirement)

        def positive(v):
            return isinstance(v, (int, float)) and np.isfinite(v) and v > 0

        def integer(low):
            return lambda v: isinstance(v, (int, np.integer)) and v >= low

        for name in ("max_iterations", "qp_max_iterations", "max_dense_qp_size", "max_qp_nonzeros",
                     "block_qp_min_size", "tangent_max_size", "hessian_every"):
            need(name, integer(1), "must be an integer >= 1")
        need("max_backtracks", integer(0), "must be an integer >= 0")
        need("max_qp_rows", lambda v: v is None or integer(1)(v), "must be None (automatic) or an integer >= 1")
        for name in ("tol_optimality", "tol_feasibility", "tol_step", "step_bound", "min_step_bound",
                     "max_step_bound", "initial_hessian_scale", "qp_eps_abs", "penalty_margin",
                     "restoration_penalty", "row_pieces_margin"):
            need(name, positive, "must be a finite number > 0")
        need("hessian_eigenvalue_floor", lambda v: positive(v) and v < 1, "must lie in (0, 1)")
        need("time_limit", lambda v: isinstance(v, (int, float)) and v > 0, "must be > 0 (inf: no limit)")
        need("step_bound_ratio", lambda v: isinstance(v, (int, float)) and v >= 1,
             "must be >= 1 (inf disables)")
        need("active_margin", lambda v: isinstance(v, (int, float)) and 0 <= v < np.inf,
             "must be finite and >= 0 (a negative margin could drop rows the QP needs)")
        for name in ("bfgs_damping", "backtrack"):
            need(name, lambda v: isinstance(v, (int, float)) and 0 < v < 1, "must lie in (0, 1)")
        need("armijo", lambda v: isinstance(v, (int, float)) and 0 < v < 0.5, "must lie in (0, 0.5)")
        if not self.min_step_bound <= self.step_bound <= self.max_step_bound:
            raise SQPSettingsError(
                "step_bound", self.step_bound,
                f"must satisfy min_step_bound ({self.min_step_bound}) <= step_bound <= "
                f"max_step_bound ({self.max_step_bound})")
        for name in ("qp_polish", "qp_active_set_start", "second_order_correction", "extrapolate"):
            if not isinstance(getattr(self, name), bool):
                raise SQPSettingsError(name, getattr(self, name), "must be True or False")
        if self.penalty_weights not in PENALTY_WEIGHTS:
            raise SQPSettingsError("penalty_weights", self.penalty_weights,
                                   f"valid values are {', '.join(map(repr, PENALTY_WEIGHTS))}", PENALTY_WEIGHTS)
        if self.qp_backend not in QP_BACKENDS:
            raise SQPSettingsError("qp_backend", self.qp_backend,
                                   f"valid values are {', '.join(map(repr, QP_BACKENDS))}", QP_BACKENDS)
        if self.trust_update is not None and self.trust_update not in TRUST_UPDATES:
            raise SQPSettingsError("trust_update", self.trust_update,
                                   f"valid values are None, {', '.join(map(repr, TRUST_UPDATES))}", TRUST_UPDATES)
        if self.hessian_modification not in HESSIAN_MODIFICATIONS:
            raise SQPSettingsError("hessian_modification", self.hessian_modification,
                                   f"valid values are {', '.join(map(repr, HESSIAN_MODIFICATIONS))}",
                                   HESSIAN_MODIFICATIONS)
        if self.structured_qp not in STRUCTURED_QPS:
            raise SQPSettingsError("structured_qp", self.structured_qp,
                                   f"valid values are {', '.join(map(repr, STRUCTURED_QPS))}", STRUCTURED_QPS)

    def qp_row_limit(self, n: int) -> int:
        r"""Most rows in a QP for :math:`n` variables: ``max_qp_rows`` or :math:`\max(200, 4n)`."""
        return int(self.max_qp_rows) if self.max_qp_rows is not None else max(200, 4 * int(n))
