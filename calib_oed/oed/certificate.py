r"""Optimality certificate of a design: a lower bound on the criterion of any n-pose design.

The bound is the approximate design's (:mod:`calib_oed.oed.approximate`:
weights :math:`w` on candidates, the sensitivity :math:`d(x, w)`, the
equivalence residual :math:`\rho = d^{\max}/\bar d - 1` and the normalised
bound), scaled to n poses:

.. math::
    \text{A: } \Phi(M_n) \ge \frac{\Phi(M(w))}{(1+\rho)\,n}, \qquad
    \text{D: } \Phi(M_n) \ge \Phi(M(w)) - p\log(1+\rho) - p\log n.

**Scope.** The bound holds for every design on the set :math:`X` over which
:math:`d^{\max}` is taken. :func:`certify` takes it over a random feasible
pool, the design's own poses, and local maxima of :math:`d(x, w)` over the
continuous feasible set (SQP from the best pool poses, exact gradient
:math:`\partial d/\partial x_k = -2\,\mathrm{tr}(F\Gamma\,\partial_k F^\top)`,
the mixed derivative of ``docs/derivations.md`` §11). It is *certified on the
pool*; on the continuous feasible set it is as good as that maximisation. An
8-start search from the pool alone on ``fms_kr16`` stopped at a bound that a
design found afterwards beat (``docs/oed.md``); with 16 starts per round and a
32-start verification (:data:`calib_oed.oed.design.CERTIFICATE_STARTS`) a search
of 64 starts per round run to its end gave the same bound to 0.01 %
(``bench/bench_certificate_slack.py``). ``approximate=`` continues a column
generation already run for the design's start
(:mod:`calib_oed.oed.approximate_pool`) instead of starting afresh.

This module owns the certificate: the candidate pool (random feasible poses
and the design's own), :func:`certify` and its :class:`Certificate`. The
off-pool maximisation of the sensitivity is
:mod:`calib_oed.oed.sensitivity_maxima`. The public names of
:mod:`calib_oed.oed.approximate` are re-exported here.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
from threadpoolctl import threadpool_limits

from calib_oed.calibration.workflow import Setup
from calib_oed.exceptions import CertificateError
from calib_oed.oed.approximate import (
    CERTIFIABLE,
    DROP_WEIGHT,
    NEWTON_REGULARISATION,
    ApproximateDesign,
    criterion_kind,
    efficiency,
    information,
    lower_bound,
    mean_sensitivity,
    scale_to_poses,
    sensitivities,
    solve_approximate,
)
from calib_oed.oed.approximate_pool import ApproximatePool
from calib_oed.oed.criterion_base import Criterion
from calib_oed.oed.objective import DesignObjective
from calib_oed.oed.sensitivity_maxima import _local_search, _Search
from calib_oed.oed.starts import candidate_pool

__all__ = [
    # this module
    "SEARCH_COMPLETE", "Certificate", "certify",
    # re-exported from calib_oed.oed.approximate
    "CERTIFIABLE", "DROP_WEIGHT", "NEWTON_REGULARISATION", "ApproximateDesign", "criterion_kind",
    "efficiency", "information", "lower_bound", "mean_sensitivity", "scale_to_poses",
    "sensitivities", "solve_approximate",
]

#: :meth:`Certificate.search_end` when the search for better poses ended by finding none.
SEARCH_COMPLETE = "no better pose found"


@dataclass(frozen=True, eq=False)
class Certificate:
    r"""Lower bound on the criterion of any n-pose design, and where a given design stands.

    Values in the criterion's unit (``kpi``: mm²; ``params``: mm², mrad²;
    ``D``: log det C) for n poses unless called *normalised* (one pose's
    worth of information, :math:`\Phi(M(w))`).

    Attributes:
        scene: Scene name.
        criterion: Criterion name.
        kind: ``"A"`` or ``"D"``.
        n: Poses of the design.
        n_params: Free parameters :math:`p`.
        pool_size: Candidates of the approximate design: random feasible
            pool, the design's poses, local maxima added.
        n_local_added: Local maxima of the sensitivity added to the pool.
        local_rounds: Re-solves after adding local maxima.
        approximate_value: :math:`\Phi(M(w))` of the approximate design (normalised).
        mean_sensitivity: :math:`\bar d` (:math:`\Phi` for A, :math:`p` for D).
        max_sensitivity_pool: :math:`\max_i d_i` over the candidates.
        max_sensitivity_local: Largest :math:`d` found by local maximisation
            over the continuous feasible set (``nan`` without it).
        gap_pool: :math:`\rho` over the candidates (the certified duality gap).
        gap: :math:`\rho` with the local maxima too.
        bound_pool: n-pose bound, certified for every design on the candidates.
        bound: n-pose bound using the local maxima: on the continuous
            feasible set as good as that maximisation (:attr:`scope`).
        support_size: Candidates with positive weight.
        support_residual: :math:`\max_{\mathrm{supp}}|d_i/\bar d - 1|`.
        design_value: The design's criterion value (n poses).
        efficiency: bound/value (A) or :math:`\exp((\text{bound}-\text{value})/p)` (D), :math:`\le 1`.
        iterations: Newton steps of the approximate design(s).
        local_iterations: SQP iterations of the local maximisations.
        local_status: The last local maximisation's SQP status.
        seconds: Wall time [s].
        converged: The approximate design met ``tol`` on the candidates.
        tol: The requested relative gap.
        scope: In words, what :attr:`bound` covers.
    """

    scene: str
    criterion: str
    kind: str
    n: int
    n_params: int
    pool_size: int
    n_local_added: int
    local_rounds: int
    approximate_value: float
    mean_sensitivity: float
    max_sensitivity_pool: float
    max_sensitivity_local: float
    gap_pool: float
    gap: float
    bound_pool: float
    bound: float
    support_size: int
    support_residual: float
    design_value: float
    efficiency: float
    iterations: int
    local_iterations: int
    local_status: str
    seconds: float
    converged: bool
    tol: float
    scope: str

    def search_end(self, round_limit: int) -> str:
        """Why the search for better poses ended: :data:`SEARCH_COMPLETE`, or what stopped it.

        Complete only when the last local maximisation found no better pose *and* converged
        (a round whose SQP stopped early, at its iteration limit or a failed QP, did not
        look everywhere it started), before ``round_limit`` re-solves (``certify``'s
        ``local_rounds``).
        """
        if self.local_rounds >= round_limit:
            return f"round limit ({round_limit} re-solves)"
        if self.local_status != "converged":
            return f"its last local maximisation did not converge ({self.local_status})"
        return SEARCH_COMPLETE

    @property
    def design_gap_pct(self) -> float:
        """How far the design is above the bound, in % of the bound's efficiency: (1/efficiency - 1)·100."""
        return 100.0 * (1.0 / self.efficiency - 1.0)

    def check(self) -> float:
        r"""Equivalence-theorem residual on the candidates, :math:`\rho = \max_i d_i/\bar d - 1` (≤ ``tol`` when converged)."""
        return float(self.gap_pool)

    def holds(self) -> bool:
        """The equivalence check holds to ``tol`` and the bounds are below the design's value."""
        return bool(self.gap_pool <= self.tol and self.bound <= self.bound_pool <= self.design_value)

    def to_dict(self) -> dict:
        out = {k: getattr(self, k) for k in self.__dataclass_fields__}
        out = {k: (float(v) if isinstance(v, (float, np.floating)) else v) for k, v in out.items()}
        out["design_gap_pct"] = self.design_gap_pct
        out["residual"] = self.check()
        return {k: (None if isinstance(v, float) and not np.isfinite(v) else v) for k, v in out.items()}

    def row(self) -> dict:
        """The columns a design table shows: bound, efficiency, gap."""
        return {"bound": self.bound, "efficiency": self.efficiency, "gap_pct": self.design_gap_pct,
                "bound_pool": self.bound_pool, "residual": self.check()}

    def summary(self) -> str:
        eff = "efficiency" if self.kind == "A" else "D-efficiency"
        return "\n".join([
            f"certificate for a {self.n}-pose {self.criterion} design of {self.scene}: value "
            f"{self.design_value:.6g} >= bound {self.bound:.6g} ({eff} {self.efficiency:.1%}, "
            f"{self.design_gap_pct:.1f} % above the bound)",
            f"  approximate design on {self.pool_size} candidates ({self.n_local_added} local maxima "
            f"added): support {self.support_size}, gap {self.gap_pool:.2e} (tol {self.tol:g}, "
            f"{'converged' if self.converged else 'NOT converged'}), {self.iterations} Newton steps",
            f"  sensitivity max / mean: pool {self.max_sensitivity_pool / self.mean_sensitivity:.6f}, "
            f"local {self.max_sensitivity_local / self.mean_sensitivity:.6f} ({self.local_iterations} "
            f"SQP iterations, {self.local_status}); pool-only bound {self.bound_pool:.6g}",
            f"  {self.scope}; {self.seconds:.1f} s",
        ])


def _as_criterion(criterion: str | Criterion) -> str | Criterion:
    if isinstance(criterion, str) and criterion not in CERTIFIABLE:
        raise CertificateError("criterion", criterion, "has no certificate", CERTIFIABLE)
    return criterion


def certify(
    scene,
    q_design,
    criterion: str | Criterion = "kpi",
    pool: int | np.ndarray = 3000,
    seed: int = 0,
    *,
    tol: float = 1e-4,
    local_tol: float = 1e-3,
    local_starts: int = 32,
    verify_starts: int | None = None,
    local_rounds: int = 30,
    local_iterations: int = 80,
    collisions: bool = True,
    max_iterations: int = 500,
    approximate: ApproximatePool | None = None,
) -> Certificate:
    r"""Certificate of design ``q_design`` (n, nq) [rad]: the lower bound and the design's efficiency.

    Steps (module docstring): (1) the approximate design on the pool plus
    the design's poses, solved to :math:`\rho \le` ``tol``; (2) local
    maximisation of :math:`d(x, w)` over the continuous feasible set from the
    ``local_starts`` best separated candidates; while it finds
    :math:`d > \bar d(1 + \text{local\_tol})`, add those poses and re-solve (at most
    ``local_rounds`` times); when it finds none, check again from
    ``verify_starts`` starts; (3) the bound from the largest sensitivity
    found, scaled to n poses.

    Args:
        scene: A scene or a :class:`~calib_oed.calibration.workflow.Setup`.
        q_design: The design.
        criterion: ``"kpi"``, ``"params"``, ``"D"`` or an A-type/D criterion object.
        pool: Random feasible candidates drawn from ``seed``, or the candidates (N, nq).
        seed: Seed of the pool.
        tol: Relative duality gap of the approximate design on the candidates.
        local_tol: Stop adding local maxima when none has
            :math:`d > \bar d(1 + \text{local\_tol})`; the bound then
            loses at most this fraction (A) to the continuous optimum.
        local_starts: Starts of the local maximisation (0: pool only).
        verify_starts: Starts of the verification round (default ``4 * local_starts``).
        local_rounds: Most re-solves with added local maxima.
        local_iterations: SQP iterations per local maximisation.
        collisions: Local maximisation under the collision constraints too
            (as :func:`calib_oed.oed.design.design`).
        max_iterations: Newton steps per approximate solve.
        approximate: The column generation already run on the pool
            (:func:`calib_oed.oed.approximate_pool.approximate_pool`, e.g. for the
            design's start): its candidates replace ``pool`` (plus the design's
            poses), its weights start the solver and the search continues from there.

    Raises:
        CertificateError: criterion without certificate, bad pool or counts.
        NotIdentifiableError: the design's information matrix is singular.
    """
    t0 = time.perf_counter()
    s = scene if isinstance(scene, Setup) else Setup(scene)
    robot = s.problem.robot
    q = robot.check_configurations(q_design, "design")
    objective = DesignObjective(s.problem, _as_criterion(criterion))
    crit = objective.criterion
    kind = criterion_kind(crit)
    verify_starts = 4 * local_starts if verify_starts is None else verify_starts
    for what, v, lo in (("local_starts", local_starts, 0), ("verify_starts", verify_starts, 0),
                        ("local_rounds", local_rounds, 0), ("local_iterations", local_iterations, 1)):
        if isinstance(v, bool) or int(v) != v or v < lo:
            raise CertificateError(what, v, f"must be an integer >= {lo}")
    if approximate is not None:
        candidates = approximate.q
    elif isinstance(pool, (int, np.integer)):
        if pool < 0:
            raise CertificateError("pool", pool, "must be a number of candidates >= 0 or an (N, nq) array")
        candidates = candidate_pool(s, int(pool), seed).q if pool else np.zeros((0, robot.nq))
    else:
        candidates = robot.check_configurations(pool, "candidate pool")
    design_value = objective.compute_value(q)
    n, p = q.shape[0], objective.n_free
    cand = np.vstack([q, candidates])
    blocks = objective.compute_blocks(cand)
    with threadpool_limits(limits=1):
        if approximate is None:
            approx = solve_approximate(blocks, crit, start=np.arange(n), tol=tol,
                                       max_iterations=max_iterations)
            search = _Search(cand, blocks, approx, approx.iterations)
        else:  # warm: the design's poses join with weight 0
            w0 = np.concatenate([np.zeros(n), approximate.approx.weights])
            approx = solve_approximate(blocks, crit, weights=w0, tol=tol, max_iterations=max_iterations)
            prior = approximate.search
            # its rounds count against local_rounds: the search continues, it does not restart
            search = _Search(cand, blocks, approx, prior.iterations + approx.iterations,
                             added=approximate.n_added, rounds=prior.rounds,
                             local_iterations=prior.local_iterations)
        if local_starts:
            search = _local_search(s, objective, search, starts=int(local_starts),
                                   verify_starts=int(verify_starts), rounds=int(local_rounds),
                                   iterations=int(local_iterations), collisions=collisions, tol=tol,
                                   local_tol=local_tol, max_iterations=max_iterations)
    approx = search.approx
    dbar = approx.mean_sensitivity
    d_all = max(approx.max_sensitivity, search.d_local) if local_starts else approx.max_sensitivity
    gap_all = max(d_all / dbar - 1.0, 0.0)
    bound_pool = scale_to_poses(kind, approx.lower_bound, n, p)
    bound = scale_to_poses(kind, lower_bound(kind, approx.value, gap_all, p), n, p)
    scope = ("certified on the pool (random feasible poses, the design's poses"
             + (f", {search.added} local maxima" if search.added else "") + ")"
             + (f"; on the continuous feasible set it is as good as the local maximisation of the "
                f"sensitivity ({search.final_starts} starts)" if local_starts else
                "; poses off the pool may beat it"))
    return Certificate(
        scene=s.scene.name, criterion=crit.name, kind=kind, n=n, n_params=p, pool_size=len(search.cand),
        n_local_added=search.added, local_rounds=search.rounds, approximate_value=approx.value,
        mean_sensitivity=dbar, max_sensitivity_pool=approx.max_sensitivity,
        max_sensitivity_local=float(search.d_local), gap_pool=approx.check(), gap=gap_all,
        bound_pool=bound_pool, bound=bound, support_size=int(approx.support.size),
        support_residual=approx.support_residual(), design_value=design_value,
        efficiency=efficiency(kind, bound, design_value, p), iterations=search.iterations,
        local_iterations=search.local_iterations, local_status=search.status,
        seconds=time.perf_counter() - t0, converged=approx.converged, tol=float(tol), scope=scope)


def multistart_gap(runs, why: str) -> dict:
    r"""The certificate record of a criterion without a bound (``kpi_model``, ``kpi_kriging``):
    ``why`` there is none, and the gap of every refined start to the best of them.

    ``runs``: ``(seed, start value, value)`` per start (:func:`calib_oed.oed.refine.optimise_starts`).
    The gap of start k is :math:`\phi_k/\min_l\phi_l - 1` [1]; ``first_start_gap`` is what a
    one-start design (the default, ``--starts 1``) would have left to the best found. With one
    start there is nothing to compare: the record says to run ``--starts K``.
    """
    out = {"skipped": why}
    if not runs:
        return out
    values = np.array([r[2] for r in runs], dtype=float)
    best = float(values.min())
    gaps = values / best - 1.0 if best > 0 else np.zeros_like(values)
    out["multistart"] = {
        "starts": [{"seed": r[0], "start_value": float(r[1]), "value": float(r[2]), "gap": float(g)}
                   for r, g in zip(runs, gaps, strict=True)],
        "best_value": best, "first_start_gap": float(gaps[0]), "max_gap": float(gaps.max()),
        "note": ("the gap of each start's refined design to the best of the starts (no lower bound)"
                 if len(runs) > 1 else "one start: run --starts K (K >= 2) for the gap to the best of K starts"),
    }
    return out

