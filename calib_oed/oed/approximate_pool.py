r"""The candidate pool enriched by the approximate design: one column generation for start and certificate.

A random pool of feasible poses is a poor stand-in for the continuous
feasible set: on ``fms_kr16`` (60 poses, KPI) the approximate design
restricted to 3000 random poses is 16-21 % worse than the one that may also
use the local maxima of its sensitivity
:math:`d(x, w) = -\mathrm{tr}(\Gamma F(x)^\top F(x))` off the pool, and the
exchange algorithm, which can only pick pool poses, starts the SQP in a
correspondingly worse basin. :func:`approximate_pool` runs the column
generation once (:mod:`calib_oed.oed.approximate` on the pool, then local
maximisation of :math:`d` from separated starts, adding every maximum with
:math:`d > \bar d(1 + 10^{-3})` and re-solving,
:mod:`calib_oed.oed.sensitivity_maxima`); both the design's start and its
certificate (:func:`calib_oed.oed.certificate.certify`, ``approximate=``)
use the result, so the work is not done twice.

**The start** (:func:`approximate_start`): the approximate design's support
with weights :math:`w_i`, rounded to :math:`n` measurements by efficient
apportionment with at most ``replicates`` per pose
(:mod:`calib_oed.oed.rounding`, Pukelsheim & Rieder 1992; with too small a
support, the most sensitive other candidates once each), then the exchange
algorithm (:mod:`calib_oed.oed.exchange`) on the enriched candidates, each
repeated ``replicates`` times, from that start: an exchange on the counts
and the poses.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from calib_oed.exceptions import DesignError, NotIdentifiableError
from calib_oed.oed.approximate import ApproximateDesign, solve_approximate
from calib_oed.oed.exchange import ExchangeResult
from calib_oed.oed.objective import DesignObjective
from calib_oed.oed.rounding import efficient_rounding
from calib_oed.oed.sensitivity_maxima import _local_search, _Search
from calib_oed.oed.starts import check_pool_size, exchange_poses

__all__ = ["ENRICH_ROUNDS", "ENRICH_STARTS", "LOCAL_HESSIANS", "START_LOCAL_HESSIAN", "ApproximatePool",
           "approximate_pool", "approximate_start", "rounded_start"]

#: Local maximisations of the sensitivity per round of the column generation. On fms_kr16
#: (hull link geometry) 16 x 10 rounds reach the approximate value of 8 x 30 (9.57e-6 against
#: 9.59e-6 mm² per 60 poses) in 4.1 s instead of 5.4 s (bench/bench_approximate_start.py).
ENRICH_STARTS = 16
#: Rounds (re-solves) of the column generation before the design starts; the certificate
#: continues the search afterwards.
ENRICH_ROUNDS = 10
#: Relative duality gap of the approximate design on the candidates.
APPROXIMATE_TOL = 1e-4
#: Curvatures of the local maximisations (:func:`approximate_pool`'s ``local_hessian``).
LOCAL_HESSIANS = ("exact", "bfgs")
#: The start's model. The exact one (the certificate's) takes 32 % less CPU in the column
#: generation of seven scenes x eight pool seeds (199 against 293 s; with the SQP 431 against
#: 530 s), but its maxima lead the exchange and the SQP to other local optima: the final designs
#: moved by -1.2 to +1.3 %, +0.07 +- 0.06 % (s.e.) on average, better in 23 of 56
#: (bench/bench_approximate_start.py --local-hessian exact,bfgs --seeds 0,...,7; docs/benchmarks.md).
#: Not better, so the start keeps BFGS and every design stays what it was.
START_LOCAL_HESSIAN = "bfgs"
#: A local maximum joins the candidates when :math:`d > \bar d(1 + \text{this})`.
LOCAL_TOL = 1e-3


@dataclass(frozen=True, eq=False)
class ApproximatePool:
    r"""Candidates (the pool, then local maxima of the sensitivity) and their approximate design.

    Attributes:
        q: Candidates (N, nq) [rad]: the ``n_pool`` pool poses first, then the maxima added.
        blocks: Their rows :math:`F_i`, (N, d, p) (:meth:`DesignObjective.compute_blocks`).
        n_pool: Pool poses at the front of :attr:`q`.
        approx: The approximate design on all candidates.
        search: The column generation's state (the certificate continues it).
        seconds: Wall time [s].
        cpu_seconds: Process CPU time [s].
    """

    q: np.ndarray
    blocks: np.ndarray
    n_pool: int
    approx: ApproximateDesign
    search: _Search
    seconds: float
    cpu_seconds: float

    @property
    def n_added(self) -> int:
        """Local maxima added to the pool."""
        return int(len(self.q) - self.n_pool)

    def to_dict(self) -> dict:
        """The record's ``solver.approximate``: sizes, the normalised value, rounds and times."""
        a = self.approx
        return {"candidates": int(len(self.q)), "local_maxima_added": self.n_added,
                "rounds": int(self.search.rounds), "value_normalised": float(a.value),
                "residual": a.check(), "support": int(a.support.size),
                "seconds": float(self.seconds), "cpu_seconds": float(self.cpu_seconds)}


def approximate_pool(s, objective: DesignObjective, pool_q: np.ndarray, *, starts: int = ENRICH_STARTS,
                     rounds: int = ENRICH_ROUNDS, collisions: bool = True,
                     local_iterations: int = 80,
                     local_hessian: str = START_LOCAL_HESSIAN) -> ApproximatePool:
    r"""The approximate design on ``pool_q`` (N, nq) [rad], enriched by up to ``rounds`` rounds of local maxima.

    Args:
        s: The :class:`~calib_oed.calibration.workflow.Setup`.
        objective: The design objective (an A-type or D criterion, no prior).
        pool_q: Feasible candidates.
        starts: Local maximisations per round (0: the pool only).
        rounds: Most re-solves with added maxima.
        collisions: Maximise under the collision rows too (as the design).
        local_iterations: SQP iterations per local maximisation.
        local_hessian: Model of the local maximisations: ``"bfgs"`` (default,
            :data:`START_LOCAL_HESSIAN`: per-pose BFGS blocks) or ``"exact"`` (the exact
            Lagrangian Hessian and the row pieces at kinks, the certificate's;
            :func:`~calib_oed.oed.sensitivity_maxima.maximise_sensitivity`).

    Raises:
        calib_oed.exceptions.CertificateError: a criterion without an approximate design.
        calib_oed.exceptions.NotIdentifiableError: the pool does not identify the parameters.
    """
    if local_hessian not in LOCAL_HESSIANS:
        raise DesignError("local_hessian", local_hessian, f"valid choices are: {', '.join(LOCAL_HESSIANS)}")
    t0, cpu0 = time.perf_counter(), time.process_time()
    crit = objective.criterion
    blocks = objective.compute_blocks(pool_q)
    approx = solve_approximate(blocks, crit, tol=APPROXIMATE_TOL)
    search = _Search(np.array(pool_q, dtype=float), blocks, approx, approx.iterations)
    if starts and rounds:
        search = _local_search(s, objective, search, starts=int(starts), verify_starts=int(starts),
                               rounds=int(rounds), iterations=int(local_iterations),
                               collisions=collisions, tol=APPROXIMATE_TOL, local_tol=LOCAL_TOL,
                               max_iterations=500, final_maximisation=False,
                               exact=local_hessian == "exact")
    return ApproximatePool(search.cand, search.blocks, len(pool_q), search.approx, search,
                           time.perf_counter() - t0, time.process_time() - cpu0)


def rounded_start(ap: ApproximatePool, n: int, replicates: int = 1) -> np.ndarray:
    r"""Indices into the candidates repeated ``replicates`` times (candidate :math:`c + kN` is :math:`c`): the rounded approximate design.

    The support's weights are rounded to :math:`n` counts of at most
    ``replicates`` each (:func:`~calib_oed.oed.rounding.efficient_rounding`);
    if the support cannot carry :math:`n` measurements, it is filled with the
    most sensitive other candidates, once each.
    """
    w, d = ap.approx.weights, ap.approx.sensitivities
    n_cand = len(w)
    sup = np.flatnonzero(w > 0)
    fill = max(0, n - sup.size * replicates)
    if fill:
        others = np.setdiff1d(np.argsort(-d, kind="stable"), sup, assume_unique=True)[:fill]
        counts = np.concatenate([np.full(sup.size, replicates), np.ones(others.size, dtype=np.int64)])
        sup = np.concatenate([sup, others])
    else:
        counts = efficient_rounding(w[sup], n, replicates)
    return np.array([c + k * n_cand for c, m in zip(sup, counts, strict=True)
                     for k in range(m)], dtype=np.intp)


def approximate_start(objective: DesignObjective, ap: ApproximatePool, n: int, seed: int | None = None,
                      replicates: int = 1) -> tuple[np.ndarray, ExchangeResult]:
    """The exchange algorithm on the enriched candidates, each usable ``replicates`` times.

    Starts from the rounded approximate design (:func:`rounded_start`) when
    ``seed`` is None, else from a random design drawn from ``seed`` (further
    starts of a multi-start).

    Returns:
        ``(q, result)``: the design (n, nq) [rad] and the exchange record.

    Raises:
        DesignError: ``n`` larger than the candidates allow.
    """
    check_pool_size(len(ap.q), n, replicates)
    start = rounded_start(ap, n, replicates) if seed is None else None
    try:
        return exchange_poses(objective, ap.q, ap.blocks, n, replicates, start=start, rng=seed)
    except NotIdentifiableError:  # a rounding of a small n can be singular: a random start then
        if start is None:
            raise
        return exchange_poses(objective, ap.q, ap.blocks, n, replicates, rng=0)
