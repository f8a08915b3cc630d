r"""Where a design starts: the candidate pool, exchange and heuristic starts, replicates.

The default design pipeline (:func:`calib_oed.oed.design.design`, ``docs/oed.md``)
selects its start from a pool of feasible candidate configurations with the
exchange algorithm (:mod:`calib_oed.oed.exchange`), then refines it locally.
The pool is either drawn at random (feasible under the scene's full
feasibility model) or given by the user (e.g. poses known to be safe on the
real cell); user candidates that the feasibility model rejects are dropped and
counted, never silently kept.

**Replicates.** Measuring a configuration again is a legitimate, cheap
measurement: with ``replicates = K`` every candidate may be chosen up to
:math:`K` times. The exchange then runs on the pool repeated :math:`K` times
(candidate :math:`c + kN` is candidate :math:`c`), and the :math:`n`
measurements use :math:`\le n` distinct configurations. In the local
refinement a repeated pose is :math:`K` identical copies of the same
variables: the problem is symmetric under swapping copies, so copies that
start together stay together unless separating them lowers the criterion.
:func:`multiplicities` groups the final design's poses.
"""

from __future__ import annotations

import hashlib
import pickle
import weakref
from dataclasses import dataclass

import numpy as np
import scipy.spatial

from calib_oed.calibration.workflow import Setup
from calib_oed.exceptions import DesignError, ShapeError
from calib_oed.feasibility.constraints import FEASIBILITY_TOL
from calib_oed.feasibility.sampling import sample_feasible
from calib_oed.oed.exchange import ExchangeResult, exchange_design
from calib_oed.oed.model_error import MODEL_ERROR
from calib_oed.oed.objective import DesignObjective
from calib_oed.oed.positions import group_counts

#: Named start designs of :func:`calib_oed.oed.design.design`.
STARTS = ("heuristic", "exchange")

#: Default size of the random feasible pool of the exchange start and the certificate.
#: On fms_kr16 (60 poses, KPI) 1000 candidates end 17 % above the exchange value of
#: 3000, 3000 within 1 % of 6000 (docs/oed.md, "Starts"); drawing 3000 costs ~2 s.
DEFAULT_POOL = 3000

#: Random pools already drawn, per set-up: {(size, seed): CandidatePool}.
_POOLS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()

#: Exchange designs already computed in this process, {digest of every input: (q, result)}, the
#: most recent :data:`EXCHANGES_KEPT`. A study's designs with and without collisions of one
#: criterion start from the same pool (drawn under the full model), so from the same exchange:
#: in the notional90 study two of each arm's four exchanges (0.7 s each) repeated another.
_EXCHANGES: dict = {}
EXCHANGES_KEPT = 8

#: Two poses closer than this (max over joints) [rad] are one configuration measured twice.
SAME_POSE_TOL = 1e-7

#: Whether the exchange start of a ``kpi_model`` design (on ``kpi``, :func:`start_enrich`) adds the
#: local maxima of ``kpi``'s sensitivity to the random pool. Not: on the realistic simulator the
#: default designs from the pool alone reach the same KPI error (paired ratio 0.976 +- 0.031 over
#: 3 scenes x 8 seeds) for 17 % less design CPU at 60 poses, and 9.5 % less error at 250 (0.905 over
#: 3 scenes x 4 seeds; docs/benchmarks.md, "kpi_model's start on the random pool alone").
MODEL_ERROR_ENRICH = False


def start_enrich(objective: DesignObjective) -> bool:
    """Whether the design's exchange start enriches a random pool (``design(enrich=None)``): yes,
    except for ``kpi_model`` (:data:`MODEL_ERROR_ENRICH`)."""
    return MODEL_ERROR_ENRICH if objective.criterion.name == MODEL_ERROR else True


@dataclass(frozen=True)
class CandidatePool:
    """Feasible candidate configurations of the exchange start and the certificate.

    Attributes:
        q: Candidates (N, nq) [rad], all feasible under the scene's model.
        source: ``"random"`` (drawn from ``seed``) or ``"given"`` (the user's).
        seed: Seed of a random pool.
        rejected: Given candidates dropped because the model finds them infeasible.
    """

    q: np.ndarray
    source: str
    seed: int | None = None
    rejected: int = 0

    def to_dict(self) -> dict:
        return {"size": int(len(self.q)), "source": self.source, "seed": self.seed,
                "rejected": int(self.rejected)}


def candidate_pool(s: Setup, pool: int | np.ndarray, seed: int, collisions: bool = True) -> CandidatePool:
    """The candidate pool: ``pool`` random feasible poses from ``seed``, or the given ones (N, nq).

    Given candidates are checked against the joint limits (an error names the
    first bad one) and the feasibility model; infeasible ones are dropped and
    counted in :attr:`CandidatePool.rejected`.

    Raises:
        DesignError: a pool size < 1, or no given candidate is feasible.
        calib_oed.exceptions.SamplingError: the scene's feasible set is too small to draw the pool.
    """
    if isinstance(pool, (int, np.integer)):
        if pool < 1:
            raise DesignError("pool", int(pool), "the pool needs at least one candidate")
        key = (int(pool), int(seed))
        cache = _POOLS.setdefault(s, {})
        if key not in cache:  # several designs of one set-up (demo, study) share the draw
            # drawn under the full model also without collisions: a collision-free
            # candidate is feasible for either design
            q = sample_feasible(s.feasibility, int(pool), seed, max_draws=50_000_000)
            q.setflags(write=False)
            cache[key] = CandidatePool(q, "random", int(seed))
        return cache[key]
    q = s.problem.robot.check_configurations(pool, "candidate pool")
    values = s.feasibility.compute(q, jacobian=False).values
    if not collisions:
        keep_rows = [k in ("joint", "incidence") for k in s.feasibility.kinds]
        values = values[:, keep_rows]
    ok = values.min(axis=1, initial=np.inf) >= -FEASIBILITY_TOL
    if not ok.any():
        raise DesignError("pool", f"{len(q)} given candidates", "none is feasible under the "
                          "scene's feasibility model (check them with `calib-oed feasibility`)")
    return CandidatePool(q[ok], "given", None, int((~ok).sum()))


def exchange_start(objective: DesignObjective, pool: CandidatePool, n: int, seed: int,
                   replicates: int = 1) -> tuple[np.ndarray, ExchangeResult]:
    """The exchange algorithm's best ``n`` poses of ``pool``, each used at most ``replicates`` times.

    Returns:
        ``(q, result)``: the design (n, nq) [rad] and the exchange record.

    Raises:
        DesignError: ``n`` larger than the pool allows.
    """
    check_pool_size(len(pool.q), n, replicates)
    blocks = objective.compute_blocks(pool.q)
    if objective.prior is None and n * blocks.shape[1] < blocks.shape[2]:
        objective.information(blocks[:n])  # raises NotIdentifiableError: too few measured values
    return exchange_poses(objective, pool.q, blocks, n, replicates, rng=seed)


def check_pool_size(n_candidates: int, n: int, replicates: int) -> None:
    """Raise :class:`DesignError` if ``n`` poses cannot come from ``n_candidates``, each
    usable ``replicates`` times."""
    if n > n_candidates * replicates:
        raise DesignError("n", n, f"the pool has {n_candidates} feasible candidates, each usable "
                          f"{replicates} time(s): at most {n_candidates * replicates} poses; "
                          "give a larger pool or --replicates")


def exchange_poses(objective: DesignObjective, q: np.ndarray, blocks: np.ndarray, n: int,
                   replicates: int = 1, start=None, rng=None) -> tuple[np.ndarray, ExchangeResult]:
    """The exchange algorithm's ``n`` of the candidates ``q`` (N, nq) [rad] with their
    information blocks, each candidate usable ``replicates`` times (the blocks repeated).

    Returns:
        ``(q, result)``: the design (n, nq) [rad] and the exchange record.
    """
    key = None
    if rng is None or isinstance(rng, (int, np.integer)):  # a Generator's state is an input too
        key = hashlib.sha256(pickle.dumps((q, blocks, objective.criterion, objective.prior, int(n),
                                           int(replicates), start, rng))).digest()
        if key in _EXCHANGES:
            chosen, result = _EXCHANGES[key]
            return chosen.copy(), result
    if replicates > 1:
        blocks = np.concatenate([blocks] * replicates)
    result = exchange_design(blocks, n, objective.criterion, start=start, rng=rng,
                             prior=objective.prior)
    chosen = q[np.asarray(result.indices) % len(q)]
    if key is not None:
        while len(_EXCHANGES) >= EXCHANGES_KEPT:
            _EXCHANGES.pop(next(iter(_EXCHANGES)))
        _EXCHANGES[key] = (chosen.copy(), result)
    return chosen, result


def heuristic_start(s: Setup, n: int, seed: int) -> np.ndarray:
    """The paper's start: ``n`` random feasible poses from ``seed``."""
    return sample_feasible(s.feasibility, n, seed)


def given_start(s: Setup, q0, n: int) -> np.ndarray:
    """A start design given as configurations, checked: (n, nq) within the joint limits."""
    q0 = s.problem.robot.check_configurations(q0, "start design")
    if q0.shape[0] != n:
        raise ShapeError("start design", f"({n}, {s.problem.robot.nq})", q0.shape)
    return q0


def check_start(start) -> None:
    """A named start must be one of :data:`STARTS` (arrays are checked by :func:`given_start`)."""
    if isinstance(start, str) and start not in STARTS:
        raise DesignError("start", start, "a named start or an (n, nq) array of configurations",
                          STARTS)


def multiplicities(q: np.ndarray, tol: float = SAME_POSE_TOL) -> list[int]:
    """How often each distinct configuration of ``q`` (n, nq) occurs, in order of first occurrence.

    Poses within ``tol`` [rad] of each other (max over joints, chained) are one configuration.
    """
    q = np.asarray(q, dtype=float)
    return group_counts(len(q), scipy.spatial.cKDTree(q).query_pairs(tol, p=np.inf))


__all__ = ["DEFAULT_POOL", "MODEL_ERROR_ENRICH", "STARTS", "CandidatePool", "candidate_pool", "check_start",
           "exchange_start", "given_start", "heuristic_start", "multiplicities", "start_enrich"]
