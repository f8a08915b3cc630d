"""Designing: heuristic start, SQP on the OED problem, baselines; the driver only assembles.

- :func:`design` runs the paper's problem (24a)–(24e): n poses minimising a
  criterion under all feasibility constraints, solved by
  :func:`calib_oed.solver.sqp.solve_sqp` from a heuristic start (random feasible
  poses), a given design, or the best of several seeded starts.
- :func:`evaluate_design` reports any design the same way (criteria, KPI σ,
  margins), so heuristic, exchange and optimised designs compare directly.
- :func:`exchange_baseline` selects n poses from a feasible candidate pool
  with the exchange algorithm (:mod:`calib_oed.oed.exchange`).
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from functools import partial

import numpy as np
from threadpoolctl import threadpool_limits

from calib_oed.calibration.workflow import Setup
from calib_oed.exceptions import (
    AggregateError,
    CertificateError,
    DesignError,
    NotIdentifiableError,
)
from calib_oed.feasibility.constraints import FEASIBILITY_TOL
from calib_oed.feasibility.margins import margin_report
from calib_oed.feasibility.sampling import sample_feasible
from calib_oed.oed import model_error
from calib_oed.oed.approximate import criterion_kind
from calib_oed.oed.approximate_pool import ENRICH_ROUNDS, ApproximatePool, approximate_pool
from calib_oed.oed.certificate import multistart_gap
from calib_oed.oed.criteria import CRITERIA, make_criterion
from calib_oed.oed.criterion_base import Criterion
from calib_oed.oed.hessian import has_exact_hessian
from calib_oed.oed.memory import check_memory
from calib_oed.oed.objective import DesignObjective
from calib_oed.oed.positions import POSITION_TOL, check_position_tol, distinct_positions
from calib_oed.oed.refine import (  # noqa: F401 (DESIGN_SQP, HESSIANS, optimise_from: re-exported)
    DESIGN_SQP,
    HESSIANS,
    optimise_from,
    optimise_starts,
    optimise_worst_case,
    project_feasible,
)
from calib_oed.oed.result import Design
from calib_oed.oed.staged import staged_half, staged_settings, staged_starts, start_designs
from calib_oed.oed.starts import (
    DEFAULT_POOL,
    CandidatePool,
    candidate_pool,
    check_start,
    exchange_start,
    start_enrich,
)
from calib_oed.scene.records import Scene
from calib_oed.solver.sqp import SQPSettings, SQPStatus

#: How a KPI of several points is aggregated: weighted mean variance, or worst-case variance.
AGGREGATES = ("mean", "max")

#: Name of the worst-case KPI criterion in a design record.
KPI_MAX = "kpi_max"


def _check_aggregate(aggregate: str, criterion) -> None:
    if aggregate not in AGGREGATES:
        raise AggregateError(aggregate, AGGREGATES)
    if aggregate == "max" and criterion not in (None, "kpi"):  # None: the default, kpi with max
        name = criterion if isinstance(criterion, str) else criterion.name
        raise AggregateError(aggregate, AGGREGATES, "the worst-case KPI aggregate 'max' applies to "
                             f"the criterion 'kpi' only, got criterion {name!r}; use aggregate "
                             "'mean' with it")


def _setup(scene: Scene | Setup) -> Setup:
    return scene if isinstance(scene, Setup) else Setup(scene)


@threadpool_limits.wrap(limits=1)  # one BLAS thread: the same bits whatever the environment's count
def criterion_values(objective: DesignObjective, q: np.ndarray, prior=None) -> dict[str, float]:
    """Every criterion of :data:`calib_oed.oed.criteria.CRITERIA` at design ``q``. ``kpi`` and
    ``params`` are average variances [mm², (mm or mrad)²], ``D`` is log det C, ``E`` the largest
    covariance eigenvalue, ``O1..O5`` the observability indices (larger is better),
    ``kpi_model``/``kpi_kriging`` under ``prior`` (NaN for poses)."""
    blocks = objective.compute_blocks(q)
    info = objective.information(blocks)
    n_rows = blocks.shape[0] * blocks.shape[1]
    out = {}
    g = objective.kpi_jacobian()
    for name in CRITERIA:
        if name in (model_error.MODEL_ERROR, model_error.KRIGING):  # of the design, not of M
            try:
                out[name] = (objective if objective.criterion.name == name else DesignObjective(
                    objective.problem, name, p=objective.p, model_error=prior)).compute_value(q)
            except DesignError:  # a pose measurement: not modelled
                out[name] = float("nan")
        else:
            out[name] = float(make_criterion(name, kpi_jacobian=g, n_params=objective.n_free,
                                             kpi_weights=objective.kpi_weights).compute_index(info, n_rows))
    return out


def evaluate_design(
    s: Setup | Scene,
    q: np.ndarray,
    criterion: str | Criterion = "kpi",
    *,
    method: str = "given",
    start_value: float | None = None,
    solver: dict | None = None,
    seconds: float = 0.0,
    seed: int | None = None,
    collisions: bool = True,
    aggregate: str = "mean",
    certificate: dict | None = None,
    position_tol: float = POSITION_TOL,
) -> Design:
    r"""The :class:`~calib_oed.oed.result.Design` record of configurations ``q`` (n, nq).

    ``aggregate="max"`` (criterion ``kpi`` only): the value is the worst-case
    KPI variance :math:`\max_i v_i` [mm²] and the record's criterion ``kpi_max``.
    ``position_tol`` [m]: reflector positions closer than this are one arm
    position in the record's ``distinct_positions`` (:mod:`calib_oed.oed.positions`).
    """
    s = _setup(s)
    _check_aggregate(aggregate, criterion)
    check_position_tol(position_tol)
    criterion = model_error.scene_criterion(s, criterion)
    problem = s.problem
    q = problem.robot.check_configurations(q, "design")
    objective = DesignObjective(problem, criterion)
    if aggregate == "max":
        value = float(objective.kpi_point_variances(q).max())
    else:
        value = objective.compute_value(q)
    res = s.feasibility.compute(q, jacobian=False)
    feasible = bool(res.values.min() >= -FEASIBILITY_TOL) if res.values.size else True
    return Design(
        scene=s.scene.name,
        joint_names=tuple(problem.robot.joint_names),
        q=q,
        criterion=KPI_MAX if aggregate == "max" else objective.criterion.name,
        value=value,
        start_value=value if start_value is None else float(start_value),
        criteria=criterion_values(objective, q, model_error.scene_prior(s)),
        kpi_sigma_mm=problem.kpi_sigma(q) * 1e3,
        kpi_names=tuple(problem.kpi.names),
        margins=tuple(margin_report(s.feasibility, res.values)),
        feasible=feasible,
        solver=solver or {},
        seconds=float(seconds),
        seed=seed,
        collisions=collisions,
        method=method,
        certificate=certificate or {},
        joint_window=s.pairs.window,
        position_multiplicity=tuple(distinct_positions(problem.space, q, position_tol)),
        position_tolerance=float(position_tol),
    )


#: Named criteria with an exact Hessian (the A criteria and D).
EXACT_CRITERIA = ("kpi", "params", "D")

#: Local maximisations per round of the certificate run after every design (``docs/oed.md``)
#: when it continues the column generation of the start, as there
#: (:data:`calib_oed.oed.approximate_pool.ENRICH_STARTS`); with 8, a search from the pool alone on
#: fms_kr16 stopped at a bound that a design found later beat.
CERTIFICATE_STARTS = 16
#: The same for a certificate that starts afresh (given, heuristic or pure-selection starts): 8 as
#: before (16 added 10 s CPU to examples/03 for the same bounds there).
CERTIFICATE_STARTS_FRESH = 8
#: Starts of the certificate's verification round (when a round finds no new maximum): as many
#: as the 8-start default's, twice a round's.
CERTIFICATE_VERIFY = 32
#: Most re-solves of the certificate's local search (``certify``'s default); the record says
#: when the search stopped there instead of finding no better pose.
CERTIFICATE_ROUNDS = 30


def design(
    scene: Scene | Setup,
    n: int = 60,
    criterion: str | Criterion | None = None,
    *,
    start: str | np.ndarray = "exchange",
    pool: int | np.ndarray = DEFAULT_POOL,
    seed: int = 0,
    n_starts: int = 1,
    refine: bool = True,
    replicates: int = 1,
    enrich: bool | None = None,
    certificate: bool = True,
    collisions: bool = True,
    settings: SQPSettings | None = None,
    callback=None,
    aggregate: str = "mean",
    hessian: str = "exact",
    position_tol: float = POSITION_TOL,
) -> Design:
    r"""An optimal design of ``n`` measurement configurations, and how good it is.

    The pipeline (``docs/oed.md``): (1) a pool of feasible candidates
    (``pool`` random ones, or the user's); (2) the approximate design on the
    pool, a random pool enriched by the off-pool local maxima of its
    sensitivity (:mod:`calib_oed.oed.approximate_pool`; A-type and D criteria,
    mean aggregate, with refinement); (3) the start: the exchange algorithm on
    those candidates from the approximate design rounded to ``n`` (default),
    random feasible poses, or a given design; (4) local refinement by the SQP
    inside the feasible set (``refine``); (5) the optimality certificate,
    continuing the column generation of (2): a lower bound on the criterion of
    any feasible ``n``-pose design, and this design's efficiency against it
    (``certificate``).

    Args:
        scene: A scene, or a :class:`~calib_oed.calibration.workflow.Setup` (reuses its
            feasibility model).
        n: Number of measurements (poses).
        criterion: A name of :data:`calib_oed.oed.criteria.CRITERIA` or a criterion; None: ``kpi_model``
            where it applies, else ``kpi`` (:func:`calib_oed.oed.model_error.default_criterion`).
        start: ``"exchange"`` (default: the exchange algorithm on the pool, the
            good basin; a ``kpi_model`` design of 250 poses or more with the default budget
            starts from the design of half its poses measured twice, :mod:`calib_oed.oed.staged`),
            ``"heuristic"`` (random feasible poses from ``seed``, the paper's start) or a
            design (n, nq) [rad].
        pool: Size of the random feasible pool drawn from ``seed``, or the
            candidates themselves (N, nq) [rad]; infeasible ones are dropped
            and counted in the record.
        seed: Seed of the pool and the starts; start ``k`` of a multi-start
            uses ``seed + k``. Same seed, same bits on one machine under any load
            (``tests/cli/test_reproducible_design.py``); elsewhere up to round-off, which moves a
            ``kpi_model`` design's value by percents (``docs/oed.md``).
        n_starts: Run from this many seeded starts and keep the best.
        refine: Refine the start with the SQP (default); ``False`` keeps the
            start (pure selection from the pool with ``start="exchange"``).
        replicates: Each configuration may be measured up to this many times
            (1: the start's poses are distinct); the record's ``multiplicity`` says
            how many distinct poses and how often each (the refinement may merge
            two poses where that lowers the criterion, and the record then says so).
        position_tol: Reflector positions closer than this [m] are one arm position in the
            record's ``distinct_positions`` (:mod:`calib_oed.oed.positions`, default 1 mm).
        enrich: Add the off-pool local maxima of the approximate design's
            sensitivity to a random pool before the exchange start (``True``;
            7.5 s of CPU on fms_kr16); ``False``: the approximate design on the pool
            alone. None (default): ``True``, except ``kpi_model``'s start
            (:data:`~calib_oed.oed.starts.MODEL_ERROR_ENRICH`). A given pool is never enriched.
        certificate: Compute the certificate and the efficiency (A criteria
            ``kpi``/``params`` and ``D``, mean aggregate); the record says why
            when it cannot.
        collisions: Impose the capsule and beam constraints (default), or only
            joint limits and incidence.
        settings: SQP settings (default :data:`DESIGN_SQP`).
        callback: Called with each SQP iteration record. A callback with a ``stage(poses)``
            method has it called with ``n`` before the design's SQP: a staged design runs its
            smaller designs first, and their records count iterations from 0 again.
        hessian: ``"exact"`` (default: the exact Lagrangian Hessian, per-pose
            blocks plus the low-rank coupling, where the criterion has one:
            ``kpi``, ``params``, ``D``, ``kpi_model`` with the joint-space prior) or ``"bfgs"`` (damped BFGS).
        aggregate: ``"mean"`` (default: the criterion, for ``kpi`` the weighted
            mean variance of the KPI points) or ``"max"`` (criterion ``kpi``
            only: the worst-case variance :math:`\max_i v_i`, by the epigraph
            problem :class:`~calib_oed.oed.problem.WorstCaseDesignProblem`).

    Returns:
        The best design, with the SQP record of its run and its certificate.

    Raises:
        DesignError: an unknown start, bad counts, a pool too small for ``n``.
        calib_oed.exceptions.DesignMemoryError: ``n`` too large for the memory available.
    """
    s = _setup(scene)
    check_start(start)
    n = int(n)
    if n < 1:
        raise DesignError("n", n, "a design needs at least one pose")
    if int(n_starts) != n_starts or n_starts < 1:
        raise DesignError("n_starts", n_starts, "an integer >= 1")
    if int(replicates) != replicates or replicates < 1:
        raise DesignError("replicates", replicates, "an integer >= 1 (1: every pose distinct)")
    _check_aggregate(aggregate, criterion)
    check_position_tol(position_tol)
    criterion = model_error.scene_criterion(s, "kpi" if criterion is None and aggregate == "max" else criterion)
    exact = (hessian == "exact" and aggregate == "mean"
             and (criterion in EXACT_CRITERIA if isinstance(criterion, str)
                  else has_exact_hessian(criterion)))
    check_memory(n, s.problem.robot.nq, int(len(s.feasibility.labels)), dense=not exact,
                 coupled=getattr(criterion, "needs_design", False))
    t0, cpu0, runs = time.perf_counter(), time.process_time(), []  # runs: (seed, start value, value)
    with threadpool_limits(limits=1):
        objective = DesignObjective(s.problem, criterion)
        start_objective = DesignObjective(s.problem, "kpi") if objective.needs_design else objective  # kpi's start
        enrich = start_enrich(objective) if enrich is None else bool(enrich)
        objective.check_design_size(n)
        half = staged_half(objective, exact, n, start, settings, aggregate) if refine else 0
        needs_pool = not half and ((isinstance(start, str) and start == "exchange") or certificate)
        cands = candidate_pool(s, pool, seed, collisions) if needs_pool else None
        use = refine and isinstance(start, str) and start == "exchange" and aggregate == "mean" and not half
        approx, approx_record = (_approximate(s, start_objective, cands, n, collisions, enrich) if use
                                 else (None, {"skipped": "not used by this start"}))
        if half:  # a large kpi_model design: half the poses designed, then measured twice (oed/staged.py)
            starts, staged = staged_starts(partial(
                design, s, half, criterion, pool=pool, replicates=replicates, enrich=enrich, certificate=False,
                collisions=collisions, callback=callback, hessian=hessian, position_tol=position_tol),
                s.feasibility, n, seed, int(n_starts), collisions)
        else:
            starts = start_designs(s, start_objective, n, start, seed, int(n_starts), cands, int(replicates), approx)
        if not refine:
            best = _best_start(objective, starts, aggregate)
        else:
            sqp = model_error.design_settings(objective, settings, exact, n, DESIGN_SQP)
            sqp = staged_settings(sqp) if half else sqp
            if callable(getattr(callback, "stage", None)):
                callback.stage(n)
            best = (optimise_worst_case(s, starts, criterion, collisions, sqp, callback)
                    if aggregate == "max"
                    else optimise_starts(s, starts, criterion, collisions, sqp, callback, hessian, runs))
        design_seconds, design_cpu = time.perf_counter() - t0, time.process_time() - cpu0
        value, q, phi0, result, start_seed = best
        interrupted = result is not None and result.status is SQPStatus.INTERRUPTED
        if interrupted:
            cert = {"skipped": "interrupted before the certificate"}
        elif certificate and objective.needs_design:  # no bound: the gap to the best of the starts
            cert = multistart_gap(runs, model_error.MODEL_ERROR_NO_CERTIFICATE)
        elif certificate:
            try:
                cert = _certificate(s, q, criterion, aggregate, cands, seed, collisions, approx)
            except KeyboardInterrupt:  # the design is kept; only its efficiency is lost
                cert, interrupted = {"skipped": "interrupted during the certificate"}, True
        else:
            cert = {"skipped": "not asked for (--no-certificate)"}
    record = {} if result is None else result.to_dict()
    record["interrupted"] = interrupted
    record.pop("x", None)
    record.pop("multipliers", None)
    if aggregate == "max" and result is not None:  # the epigraph variable t s [mm²]: bounds every v_i
        record["epigraph_t_mm2"] = float(result.x[-1] * phi0)
    record["start"] = ("staged" if half else start) if isinstance(start, str) else "given"
    if half:  # the smaller design(s) the start doubled (oed/staged.py)
        record["staged"] = staged
    record["pool"] = None if cands is None else cands.to_dict()
    record["approximate"] = approx_record
    if objective.needs_design:  # the model-error prior the design was made for (report units)
        record["model_error"] = objective.criterion.prior.to_dict()
    record["replicates"] = int(replicates)
    record["cpu_seconds"] = design_cpu
    named = record["start"]
    method = f"{named}+sqp" if refine else named
    return evaluate_design(
        s, q, criterion, method=method, start_value=phi0, solver=record,
        seconds=design_seconds, seed=start_seed, collisions=collisions,
        aggregate=aggregate, certificate=cert, position_tol=position_tol,
    )


def _best_start(objective: DesignObjective, starts, aggregate: str):
    """The best start design without refinement: ``(value, q, value, None, seed)``."""
    best = None
    for start_seed, q0 in starts:
        value = (float(objective.kpi_point_variances(q0).max()) if aggregate == "max"
                 else objective.compute_value(q0))
        if best is None or value < best[0]:
            best = (value, q0, value, None, start_seed)
    return best


def _approximate(s: Setup, objective: DesignObjective, cands: CandidatePool, n: int,
                 collisions: bool, enrich: bool) -> tuple[ApproximatePool | None, dict]:
    """The approximate design on the pool, a random one enriched by local maxima, and its record (or why not).

    A given pool (the user's candidates) is not enriched: the start stays on those poses.
    """
    rounds = ENRICH_ROUNDS if enrich and cands.source == "random" else 0
    try:
        criterion_kind(objective.criterion)
        few = objective.compute_blocks(cands.q[:1])
        if n * few.shape[1] < few.shape[2]:  # NotIdentifiableError: too few measured values
            objective.information(np.repeat(few, n, axis=0))
        approx = approximate_pool(s, objective, cands.q, collisions=collisions, rounds=rounds)
    except (CertificateError, NotIdentifiableError) as exc:  # E, O1-O5; a pool that cannot identify
        return None, {"skipped": f"no approximate design, the start is the exchange on the pool: {exc}"}
    return approx, approx.to_dict()


def _certificate(s: Setup, q: np.ndarray, criterion, aggregate: str, cands: CandidatePool,
                 seed: int, collisions: bool, approx: ApproximatePool | None = None) -> dict:
    """The certificate of design ``q`` on the pool already drawn, as a record (or why not)."""
    from calib_oed.oed.certificate import SEARCH_COMPLETE, certify

    if aggregate == "max":
        return {"skipped": "no certificate for the worst-case KPI aggregate 'max' (mean only)"}
    t0, cpu0 = time.perf_counter(), time.process_time()
    starts = CERTIFICATE_STARTS if approx is not None else CERTIFICATE_STARTS_FRESH
    try:
        c = certify(s, q, criterion, pool=cands.q, seed=seed, local_starts=starts,
                    verify_starts=CERTIFICATE_VERIFY, local_rounds=CERTIFICATE_ROUNDS,
                    collisions=collisions, approximate=approx)
    except CertificateError as exc:
        return {"skipped": str(exc)}
    end = c.search_end(CERTIFICATE_ROUNDS)  # else the bound is only as good as the maxima found
    return {"efficiency": float(c.efficiency), "lower_bound": float(c.bound),
            "search_complete": end == SEARCH_COMPLETE, "search_end": end, "local_status": c.local_status,
            "lower_bound_pool": float(c.bound_pool), "kind": c.kind, "scope": c.scope,
            "pool_size": int(c.pool_size), "local_starts": starts,
            "verify_starts": CERTIFICATE_VERIFY,
            "converged": bool(c.converged), "seconds": time.perf_counter() - t0,
            "cpu_seconds": time.process_time() - cpu0}


def exchange_baseline(
    scene: Scene | Setup,
    n: int = 60,
    criterion: str | Criterion = "kpi",
    *,
    pool: int | np.ndarray = DEFAULT_POOL,
    seed: int = 0,
    replicates: int = 1,
) -> Design:
    """The best n poses of a feasible candidate pool by the exchange algorithm (no refinement).

    Args:
        pool: Number of random feasible candidates drawn from ``seed``, or the
            candidates themselves (N, nq); infeasible ones are dropped.
        replicates: Each candidate may be chosen up to this many times.
    """
    s = _setup(scene)
    t0 = time.perf_counter()
    cands = candidate_pool(s, pool, seed)
    objective = DesignObjective(s.problem, criterion)
    with threadpool_limits(limits=1):
        q, result = exchange_start(objective, cands, n, seed, replicates)
    record = result.to_dict()
    record["pool"] = cands.to_dict()
    record["replicates"] = int(replicates)
    return evaluate_design(
        s, q, criterion, method="exchange", start_value=result.initial_value, solver=record,
        seconds=time.perf_counter() - t0, seed=seed,
    )


def heuristic_designs(scene: Scene | Setup, n: int, seeds: Sequence[int]) -> list[Design]:
    """The paper's heuristic designs (random feasible poses), one per seed."""
    s = _setup(scene)
    return [evaluate_design(s, sample_feasible(s.feasibility, n, k), "kpi", method="heuristic",
                            seed=k) for k in seeds]
