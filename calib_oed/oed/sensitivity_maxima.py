r"""Local maxima of the sensitivity :math:`d(x, w)` over the continuous feasible set.

For the certificate (:mod:`calib_oed.oed.certificate`) the largest
sensitivity :math:`d^{\max}` must be taken over every feasible pose, not only
over a pool. This module owns that search: the sensitivity field
:math:`d(x) = -\mathrm{tr}(\Gamma F(x)^\top F(x))` with its exact gradient
(:func:`sensitivity_field`), its local maximisation under the design
constraints (:func:`maximise_sensitivity`, :class:`LocalMaxima`), the choice of
separated starts (:func:`spread_starts`) and the column generation that adds
the maxima to the candidates and re-solves the approximate design
(``_local_search``).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import scipy.spatial

from calib_oed.feasibility.constraints import FEASIBILITY_TOL
from calib_oed.oed.approximate import ApproximateDesign, information, solve_approximate
from calib_oed.oed.hessian import pose_blocks
from calib_oed.oed.objective import DesignObjective
from calib_oed.oed.problem import DesignProblem
from calib_oed.solver.result import StructuredHessian
from calib_oed.solver.sqp import SQPSettings, SQPStatus, solve_sqp

#: Starts per SQP of the local maximisation (with BFGS its dense QP grows with the square of the starts).
#: 16 rather than 8: the chunk's poses share the iterations, so the 16 starts of a column
#: generation round take 10 % less CPU in one SQP than in two (fms_kr16, fms_kr500).
LOCAL_CHUNK = 16
#: Two local-maximisation starts closer than this in every joint [rad] count as one.
START_SEPARATION = 1.0
#: A local maximum closer than this to a candidate in every joint [rad] is that candidate.
DUPLICATE_TOL = 1e-4


# ---------------------------------------------- the continuous feasible set
def sensitivity_field(objective: DesignObjective, gamma: np.ndarray, q) -> tuple[np.ndarray, np.ndarray]:
    r"""Sensitivity :math:`d(x) = -\mathrm{tr}(\Gamma F(x)^\top F(x))` of poses ``q`` (K, nq) and its gradient.

    .. math::
        \frac{\partial d}{\partial x_k} = -2\,\mathrm{tr}\Big(F\,\Gamma\,\frac{\partial F^\top}{\partial x_k}\Big)
        \quad [\text{unit of } d/\mathrm{rad}],

    the design gradient of ``docs/derivations.md`` §11 with :math:`\Gamma` held
    fixed (the mixed derivatives of the measurement models, batched over poses:
    :meth:`~calib_oed.oed.objective.DesignObjective.compute_row_derivatives`).

    Returns:
        ``d`` (K,) and ``grad`` (K, nv).
    """
    rows, d_rows = objective.compute_row_derivatives(q)  # (K, d, p), (K, d, p, nv)
    fg = rows @ gamma
    return _sensitivity(rows, fg), -2.0 * np.einsum("kdf,kdfv->kv", fg, d_rows)


def _sensitivity(rows: np.ndarray, fg: np.ndarray) -> np.ndarray:
    r""":math:`d = -\mathrm{tr}(\Gamma F^\top F)` per pose from the rows (K, d, p) and ``fg`` :math:`= F\Gamma`."""
    return -np.einsum("kdf,kdf->k", fg, rows)


def sensitivity_hessian(objective: DesignObjective, gamma: np.ndarray, q) -> np.ndarray | None:
    r"""The Hessian of :math:`d(x)` per pose (K, nv, nv) [unit of d/rad²], or None.

    .. math::
        \frac{\partial^2 d}{\partial x_k\,\partial x_l}
        = -2\,\mathrm{tr}\Big(\Gamma\,\big(\tilde F^\top\partial_{kl}\tilde F
          + \partial_k\tilde F^\top\partial_l\tilde F\big)\Big)_{\text{sym}},

    the pose blocks of the design Hessian (:func:`calib_oed.oed.hessian.pose_blocks`,
    ``docs/derivations.md`` §13) with :math:`\Gamma` held fixed and the sign of
    :math:`d`; symmetric, indefinite. None when a measurement model has no
    second configuration derivative
    (:meth:`~calib_oed.oed.objective.DesignObjective.compute_row_hessians`).
    """
    q = np.atleast_2d(np.asarray(q, dtype=float))
    dd_rows = objective.compute_row_hessians(q)
    if dd_rows is None:
        return None
    rows, d_rows = objective.compute_row_derivatives(q)
    return -pose_blocks(gamma, rows, d_rows, dd_rows)


@dataclass(frozen=True, eq=False)
class LocalMaxima:
    """Local maxima of the sensitivity over the feasible set, one per start.

    Attributes:
        q: End points (K, nq) [rad].
        values: :math:`d` at them (K,).
        start_values: :math:`d` at the starts (K,).
        violation: Largest constraint or bound violation per end point (K,) [m, rad, cos].
        status: The SQP's status.
        iterations: SQP iterations.
        seconds: Wall time [s].
    """

    q: np.ndarray
    values: np.ndarray
    start_values: np.ndarray
    violation: np.ndarray
    status: str
    iterations: int
    seconds: float

    @property
    def feasible(self) -> np.ndarray:
        return self.violation <= FEASIBILITY_TOL

    @property
    def max_value(self) -> float:
        """Largest :math:`d` over the feasible end points and the starts."""
        return float(max(np.max(self.values[self.feasible], initial=-np.inf), self.start_values.max()))

    def to_dict(self) -> dict:
        return {"q": self.q.tolist(), "values": self.values.tolist(),
                "start_values": self.start_values.tolist(), "violation": self.violation.tolist(),
                "max_value": self.max_value, "status": self.status, "iterations": self.iterations,
                "seconds": self.seconds}


def maximise_sensitivity(setup, objective: DesignObjective, gamma: np.ndarray, starts, scale: float, *,
                         collisions: bool = True, max_iterations: int = 80,
                         exact: bool = True) -> LocalMaxima:
    r"""Local maxima of :math:`d(x)` s.t. the design constraints, from each start (one SQP, separable).

    Maximises :math:`\sum_j d(x_j)/\text{scale}` over the K poses at once
    (:func:`calib_oed.solver.sqp.solve_sqp`): the poses share nothing, so this
    is K independent local maximisations.

    ``exact`` (default; the certificate's search) gives the SQP the design
    SQP's model of the problem: the exact Lagrangian Hessian (per pose
    :func:`sensitivity_hessian` and the active rows' curvature,
    :meth:`~calib_oed.oed.problem.DesignProblem.compute_constraint_curvature`,
    made definite as in the design SQP) and the smooth pieces of kinked
    convex-piece rows (:meth:`~calib_oed.oed.problem.DesignProblem.compute_row_pieces`).
    ``exact=False``: per-pose BFGS blocks and no pieces (the design's start,
    :data:`~calib_oed.oed.approximate_pool.START_LOCAL_HESSIAN`). From the same
    starts both reach the same largest maximum; the exact model takes a third to
    a half of the SQP iterations, and on ``ur5_table`` and ``panda_cell`` it
    converges where BFGS without the pieces stalls at the kinks
    (``bench/bench_sensitivity_maxima.py``, ``docs/benchmarks.md``).
    """
    t0 = time.perf_counter()
    starts = np.atleast_2d(np.asarray(starts, dtype=float))
    k, nq = starts.shape
    nlp = DesignProblem(objective, setup.feasibility, k, collisions=collisions)
    d0, _ = sensitivity_field(objective, gamma, starts)

    last: dict = {}  # the last point each function saw: the SQP ends at one of them

    def negative(x):
        d, g = sensitivity_field(objective, gamma, x.reshape(k, nq))
        last["d"] = (x.copy(), d)
        return -float(d.sum()) / scale, -g.ravel() / scale

    def constraints(x):
        values, jac = nlp.compute_constraints(x)
        last["g"] = (x.copy(), values.copy())
        return values, jac

    def values_only(x):
        """The trial points' values without derivatives, the same numbers bit for bit."""
        rows = objective.compute_blocks(x.reshape(k, nq))
        d = _sensitivity(rows, rows @ gamma)
        return -float(d.sum()) / scale, nlp.compute_constraint_rows(x, jacobian=False)[0].ravel()

    def at_end(key, x):
        """The value ``key`` saw at exactly ``x``, or None (keyed by the point, never stale)."""
        seen = last.get(key)
        return seen[1] if seen is not None and np.array_equal(seen[0], x) else None

    def curvature(x, lam):
        r""":math:`\nabla^2(-\sum_j d/\text{scale} - \lambda^\top g)` as per-pose blocks, or None."""
        q = x.reshape(k, nq)
        blocks = sensitivity_hessian(objective, gamma, q)
        if blocks is None:
            return None
        blocks = -blocks / scale
        rows = nlp.compute_constraint_curvature(x, lam)
        return StructuredHessian(blocks if rows is None else blocks - rows, None)

    res = solve_sqp(negative, starts.ravel(), constraints=constraints, bounds=nlp.bounds,
                    # both searches start their QPs from the last active set (docs/benchmarks.md,
                    # "The start's column generation from the last active set")
                    settings=SQPSettings(max_iterations=max_iterations, step_bound=0.2,
                                         qp_active_set_start=True),
                    block_size=nq, lagrangian_hessian=curvature if exact else None,
                    row_pieces=nlp.compute_row_pieces if exact else None, values=values_only)
    if res.status is SQPStatus.INTERRUPTED:  # Ctrl-C ends the certificate, not just this search
        raise KeyboardInterrupt
    q = res.x.reshape(k, nq)
    values = at_end("g", res.x)
    values = (nlp.compute_constraint_rows(res.x, jacobian=False)[0] if values is None
              else values.reshape(k, -1))
    lo, hi = nlp.bounds
    viol = np.maximum.reduce([np.zeros(k), -values.min(axis=1), (lo - res.x).reshape(k, nq).max(axis=1),
                              (res.x - hi).reshape(k, nq).max(axis=1)])
    d = at_end("d", res.x)
    if d is None:
        d, _ = sensitivity_field(objective, gamma, q)
    return LocalMaxima(q, d, d0, viol, str(getattr(res.status, "value", res.status)), res.iterations,
                       time.perf_counter() - t0)


def _concatenate(parts: list[LocalMaxima]) -> LocalMaxima:
    """One :class:`LocalMaxima` of several, in order (status: the first not converged)."""
    worst = next((p.status for p in parts if p.status != "converged"), parts[0].status)
    return LocalMaxima(*(np.concatenate([getattr(p, f) for p in parts])
                         for f in ("q", "values", "start_values", "violation")),
                       worst, sum(p.iterations for p in parts), sum(p.seconds for p in parts))


def _maximise_in_chunks(setup, objective, gamma, starts, scale, chunk, **kwargs) -> LocalMaxima:
    """:func:`maximise_sensitivity` on chunks of ``chunk`` starts (the dense QP grows as K²), concatenated.

    A chunk whose SQP stopped without moving any start and without converging (its first QP
    failed: one pose's degenerate rows stop the other poses too) is run again one start at a
    time, so the poses that can move do; otherwise the round would end as if no better
    maximum existed.
    """
    parts = []
    for i in range(0, len(starts), chunk):
        part = starts[i:i + chunk]
        loc = maximise_sensitivity(setup, objective, gamma, part, scale, **kwargs)
        if len(part) > 1 and loc.status != "converged" and np.array_equal(loc.q, part):
            loc = _concatenate([maximise_sensitivity(setup, objective, gamma, part[j:j + 1], scale, **kwargs)
                                for j in range(len(part))])
        parts.append(loc)
    return _concatenate(parts)


@dataclass(frozen=True, eq=False)
class _Round:
    """One maximisation of the column generation: for which approximate design, from which starts."""

    approx: ApproximateDesign
    n_candidates: int
    starts: np.ndarray
    maxima: LocalMaxima


def _reusable(last: _Round | None, search: _Search, idx: np.ndarray, chunk: int) -> int:
    r"""How many leading starts of ``idx`` the maximisation ``last`` already ran, chunk for chunk.

    The same approximate design (so the same :math:`\Gamma` and :math:`\bar d`),
    the same candidates and the same leading starts in whole chunks give the
    same maxima (each chunk is one SQP): :func:`spread_starts` picks greedily,
    so the verification round's ``2k`` starts begin with the ``k`` of the round
    before it when nothing was added in between. 0 when anything differs.
    """
    if last is None or last.approx is not search.approx or last.n_candidates != len(search.cand):
        return 0
    m = last.starts.size
    if m == 0 or m % chunk or m > idx.size or not np.array_equal(idx[:m], last.starts):
        return 0
    return m


def _distinct(q: np.ndarray, values: np.ndarray, tol: float = DUPLICATE_TOL) -> np.ndarray:
    """Indices of ``q`` without near-duplicates (∞-distance < ``tol`` rad), the larger value kept."""
    keep: list[int] = []
    for i in np.argsort(-values):
        if all(np.max(np.abs(q[i] - q[j])) >= tol for j in keep):
            keep.append(int(i))
    return np.array(sorted(keep), dtype=np.intp)


def spread_starts(candidates: np.ndarray, values: np.ndarray, k: int,
                  separation: float | None = None) -> np.ndarray:
    """Indices of up to ``k`` candidates of largest ``values``, pairwise at least ``separation`` apart (∞-norm, rad).

    ``separation`` defaults to :data:`START_SEPARATION`.
    """
    separation = START_SEPARATION if separation is None else separation
    chosen: list[int] = []
    for i in np.argsort(-values):
        if len(chosen) == k:
            break
        if all(np.max(np.abs(candidates[i] - candidates[j])) >= separation for j in chosen):
            chosen.append(int(i))
    return np.array(chosen, dtype=np.intp)


@dataclass
class _Search:
    """State of the column generation over the continuous feasible set (internal to :func:`~calib_oed.oed.certificate.certify`)."""

    cand: np.ndarray
    blocks: np.ndarray
    approx: ApproximateDesign
    iterations: int
    added: int = 0
    rounds: int = 0
    local_iterations: int = 0
    d_local: float = np.nan
    status: str = "not run"
    final_starts: int = 0


def _local_search(s, objective, search: _Search, *, starts: int, verify_starts: int, rounds: int,
                  iterations: int, collisions: bool, tol: float, local_tol: float,
                  max_iterations: int, final_maximisation: bool = True, exact: bool = True) -> _Search:
    r"""Add local maxima of :math:`d` with :math:`d > \bar d(1+\text{local\_tol})` and re-solve (to ``tol``) until none is found.

    A round maximises from ``starts`` separated candidates; when it finds no
    violation, a verification round uses ``verify_starts``; the search ends
    when that finds none either, or after ``rounds`` re-solves. After the
    last re-solve one more maximisation gives :attr:`_Search.d_local` (the
    certificate's largest sensitivity); ``final_maximisation=False`` skips it
    when the search is continued later (the design's start: the
    certificate's first round repeats it on the candidates plus the design).
    ``exact``: as :func:`maximise_sensitivity`.
    """
    crit, verifying, last = objective.criterion, False, None
    while True:
        if not final_maximisation and search.rounds >= rounds:
            return search
        k = verify_starts if verifying else starts
        gamma = crit.compute_gradient(information(search.blocks, search.approx.weights))
        dbar = search.approx.mean_sensitivity
        idx = spread_starts(search.cand, search.approx.sensitivities, k)
        done = _reusable(last, search, idx, LOCAL_CHUNK)  # the verification repeats the round's starts
        parts = [last.maxima] if done else []
        if idx.size > done:
            fresh = _maximise_in_chunks(s, objective, gamma, search.cand[idx[done:]], dbar, LOCAL_CHUNK,
                                        collisions=collisions, max_iterations=iterations, exact=exact)
            search.local_iterations += fresh.iterations
            parts.append(fresh)
        loc = _concatenate(parts)
        last = _Round(search.approx, len(search.cand), idx, loc)
        search.d_local, search.status, search.final_starts = loc.max_value, loc.status, idx.size
        new = np.flatnonzero(loc.feasible & (loc.values > dbar * (1.0 + local_tol)))
        if new.size:
            new = new[_distinct(loc.q[new], loc.values[new])]
            # a maximum found again (from another start or round) is not a new candidate
            near, _ = scipy.spatial.cKDTree(search.cand).query(loc.q[new], p=np.inf)
            new = new[near >= DUPLICATE_TOL]
        if new.size == 0 and not verifying and verify_starts > starts:
            verifying = True
            continue
        if new.size == 0 or search.rounds == rounds:
            return search
        search.cand = np.vstack([search.cand, loc.q[new]])
        search.blocks = np.concatenate([search.blocks, objective.compute_blocks(loc.q[new])])
        search.added += int(new.size)
        search.rounds += 1
        w0 = np.concatenate([search.approx.weights, np.zeros(new.size)])
        search.approx = solve_approximate(search.blocks, crit, weights=w0, tol=tol,
                                          max_iterations=max_iterations)
        search.iterations += search.approx.iterations
        verifying = False

