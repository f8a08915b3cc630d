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

import numpy as np
from threadpoolctl import threadpool_limits

from calib_oed.calibration.workflow import Setup
from calib_oed.exceptions import AggregateError, ShapeError
from calib_oed.feasibility.constraints import FEASIBILITY_TOL
from calib_oed.feasibility.margins import margin_report
from calib_oed.feasibility.sampling import sample_feasible
from calib_oed.oed.criteria import CRITERIA, make_criterion
from calib_oed.oed.criterion_base import Criterion
from calib_oed.oed.exchange import exchange_design
from calib_oed.oed.objective import DesignObjective
from calib_oed.oed.problem import DesignProblem, WorstCaseDesignProblem
from calib_oed.oed.result import Design
from calib_oed.scene.records import Scene
from calib_oed.solver.sqp import SQPResult, SQPSettings, solve_sqp

#: SQP settings of the design problem (objective scaled to 1 at the start, x in rad).
DESIGN_SQP = SQPSettings()

#: How a KPI of several points is aggregated: weighted mean variance, or worst-case variance.
AGGREGATES = ("mean", "max")

#: Name of the worst-case KPI criterion in a design record.
KPI_MAX = "kpi_max"


def _check_aggregate(aggregate: str, criterion) -> None:
    if aggregate not in AGGREGATES:
        raise AggregateError(aggregate, AGGREGATES)
    if aggregate == "max" and criterion != "kpi":
        name = criterion if isinstance(criterion, str) else criterion.name
        raise AggregateError(aggregate, AGGREGATES, "the worst-case KPI aggregate 'max' applies to "
                             f"the criterion 'kpi' only, got criterion {name!r}; use aggregate "
                             "'mean' with it")


def project_feasible(nlp: DesignProblem, x: np.ndarray, max_iterations: int = 50) -> np.ndarray:
    r"""The nearest feasible design: :math:`\min_y \tfrac12\|y - x\|^2` s.t. the design constraints.

    Used when the SQP stops (iteration limit) at an iterate violating a
    constraint by more than :data:`FEASIBILITY_TOL`; the quadratic objective
    makes the SQP's BFGS start exact, so a few iterations suffice.
    """
    def distance(y):
        d = y - x
        return 0.5 * float(d @ d), d

    res = solve_sqp(distance, x, constraints=nlp.compute_constraints, bounds=nlp.bounds,
                    settings=SQPSettings(max_iterations=max_iterations, step_bound=0.05,
                                         tol_feasibility=0.1 * FEASIBILITY_TOL))
    return res.x


def _setup(scene: Scene | Setup) -> Setup:
    return scene if isinstance(scene, Setup) else Setup(scene)


def criterion_values(objective: DesignObjective, q: np.ndarray) -> dict[str, float]:
    """Every criterion of :data:`calib_oed.oed.criteria.CRITERIA` at design ``q``.

    ``kpi`` and ``params`` are average variances [mm², (mm or mrad)²], ``D``
    is log det C, ``E`` the largest covariance eigenvalue, ``O1..O5`` the
    observability indices (larger is better).
    """
    blocks = objective.compute_blocks(q)
    info = objective.information(blocks)
    n_rows = blocks.shape[0] * blocks.shape[1]
    out = {}
    g = objective.kpi_jacobian()
    for name in CRITERIA:
        crit = make_criterion(name, kpi_jacobian=g, n_params=objective.n_free,
                              kpi_weights=objective.kpi_weights)
        out[name] = float(crit.compute_index(info, n_rows))
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
) -> Design:
    r"""The :class:`~calib_oed.oed.result.Design` record of configurations ``q`` (n, nq).

    ``aggregate="max"`` (criterion ``kpi`` only): the value is the worst-case
    KPI variance :math:`\max_i v_i` [mm²] and the record's criterion ``kpi_max``.
    """
    s = _setup(s)
    _check_aggregate(aggregate, criterion)
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
        criteria=criterion_values(objective, q),
        kpi_sigma_mm=problem.kpi_sigma(q) * 1e3,
        kpi_names=tuple(problem.kpi.names),
        margins=tuple(margin_report(s.feasibility, res.values)),
        feasible=feasible,
        solver=solver or {},
        seconds=float(seconds),
        seed=seed,
        collisions=collisions,
        method=method,
    )


#: Named start designs of :func:`design`.
STARTS = ("heuristic", "exchange")


def _start_designs(s: Setup, n: int, start, seed: int, n_starts: int, criterion,
                   pool: int) -> list[tuple[int | None, np.ndarray]]:
    if isinstance(start, str):
        if start not in STARTS:
            raise ValueError(f"start must be one of {', '.join(map(repr, STARTS))} or an (n, nq) "
                             f"array of configurations, got {start!r}")
        if start == "exchange":
            return [(seed + k, exchange_baseline(s, n, criterion, pool=pool, seed=seed + k).q)
                    for k in range(n_starts)]
        return [(seed + k, sample_feasible(s.feasibility, n, seed + k)) for k in range(n_starts)]
    q0 = s.problem.robot.check_configurations(start, "start design")
    if q0.shape[0] != n:
        raise ShapeError("start design", f"({n}, {s.problem.robot.nq})", q0.shape)
    return [(None, q0)]


def design(
    scene: Scene | Setup,
    n: int = 60,
    criterion: str | Criterion = "kpi",
    *,
    start: str | np.ndarray = "heuristic",
    seed: int = 0,
    n_starts: int = 1,
    collisions: bool = True,
    settings: SQPSettings | None = None,
    callback=None,
    pool: int = 3000,
    structured_hessian: bool = False,
    aggregate: str = "mean",
) -> Design:
    r"""An optimal design of ``n`` measurement configurations.

    Args:
        scene: A scene, or a :class:`~calib_oed.calibration.workflow.Setup` (reuses its
            feasibility model).
        n: Number of poses.
        criterion: A name of :data:`calib_oed.oed.criteria.CRITERIA` or a criterion.
        start: ``"heuristic"`` (random feasible poses from ``seed``, the
            paper's start), ``"exchange"`` (the exchange algorithm's best
            ``n`` of ``pool`` random feasible poses for the same criterion:
            a better basin, see docs/oed.md) or a design (n, nq) [rad].
        seed: Seed of the heuristic start; start ``k`` of a multi-start uses
            ``seed + k``. Same seed, same design up to rounding: ProxQP's
            results are not bitwise reproducible, so designs of one seed agree to
            about 1e-6 rad, not bit for bit.
        n_starts: Run from this many heuristic starts and keep the best.
        collisions: Impose the capsule and beam constraints (default), or only
            joint limits and incidence.
        settings: SQP settings (default :data:`DESIGN_SQP`).
        callback: Called with each SQP iteration record.
        pool: Candidate pool of the ``"exchange"`` start.
        structured_hessian: Give the SQP the criterion's exact curvature
            through M (A and D criteria) plus per-pose BFGS blocks instead of
            one dense BFGS matrix. Fewer iterations, but each QP is slower:
            measured slower overall on fms_kr16 (docs/oed.md), so off by default.
        aggregate: ``"mean"`` (default: the criterion, for ``kpi`` the weighted
            mean variance of the KPI points) or ``"max"`` (criterion ``kpi``
            only: the worst-case variance :math:`\max_i v_i`, by the epigraph
            problem :class:`~calib_oed.oed.problem.WorstCaseDesignProblem`;
            a dense BFGS Hessian, ``structured_hessian`` is ignored).

    Returns:
        The best design, with the SQP record of its run.
    """
    s = _setup(scene)
    if n_starts < 1:
        raise ValueError(f"n_starts must be >= 1, got {n_starts}")
    _check_aggregate(aggregate, criterion)
    best = None
    t0 = time.perf_counter()
    with threadpool_limits(limits=1, user_api="blas"):
        run = _optimise_worst_case if aggregate == "max" else _optimise_starts
        best = run(s, int(n), criterion, start, seed, n_starts, collisions,
                   settings, callback, pool, structured_hessian)
    value, q, phi0, result, start_seed = best
    record = result.to_dict()
    record.pop("x", None)
    record.pop("multipliers", None)
    if aggregate == "max":  # the epigraph variable at the end, t s [mm²]: bounds every v_i up to the violation
        record["epigraph_t_mm2"] = float(result.x[-1] * phi0)
    return evaluate_design(
        s, q, criterion, method="sqp", start_value=phi0, solver=record,
        seconds=time.perf_counter() - t0, seed=start_seed, collisions=collisions,
        aggregate=aggregate,
    )


def _optimise_worst_case(s, n, criterion, start, seed, n_starts, collisions, settings, callback,
                         pool, structured_hessian):
    """The epigraph SQP from every start; the best ``(max_i v_i, q, start max, result, seed)``."""
    best = None
    for start_seed, q0 in _start_designs(s, n, start, seed, n_starts, criterion, pool):
        objective = DesignObjective(s.problem, criterion)
        v0 = float(objective.kpi_point_variances(q0).max())
        nlp = WorstCaseDesignProblem(objective, s.feasibility, len(q0), collisions=collisions,
                                     scale=max(v0, 1e-300))
        result = solve_sqp(nlp.compute_objective, nlp.start(q0), constraints=nlp.compute_constraints,
                           bounds=nlp.bounds, settings=settings or DESIGN_SQP, callback=callback)
        x = result.x
        if nlp.max_violation(x) > FEASIBILITY_TOL:
            x = np.append(project_feasible(nlp.base, x[:-1]), x[-1])
        q = nlp.configurations(x)
        value = float(objective.kpi_point_variances(q).max())
        if best is None or value < best[0]:
            best = (value, q, v0, result, start_seed)
    return best


def _optimise_starts(s, n, criterion, start, seed, n_starts, collisions, settings, callback, pool,
                     structured_hessian):
    """Run the SQP from every start; the best ``(value, q, phi0, result, seed)``."""
    best = None
    for start_seed, q0 in _start_designs(s, n, start, seed, n_starts, criterion, pool):
        objective = DesignObjective(s.problem, criterion)
        value, q, phi0, result = optimise_from(objective, s.feasibility, q0, collisions=collisions,
                                               settings=settings, callback=callback,
                                               structured_hessian=structured_hessian)
        if best is None or value < best[0]:
            best = (value, q, phi0, result, start_seed)
    return best


def optimise_from(objective: DesignObjective, feasibility, q0: np.ndarray, *, collisions: bool = True,
                  settings: SQPSettings | None = None, callback=None,
                  structured_hessian: bool = False) -> tuple[float, np.ndarray, float, SQPResult]:
    r"""One SQP run of ``objective`` (its prior and parameters included) from the design ``q0``.

    The objective is divided by :math:`|\phi(q^0)|` (log-type criteria can be
    negative) so the solver sees O(1) numbers; a last iterate that violates a
    constraint is projected back onto the feasible set.

    Returns:
        ``(value, q, start value, SQP result)``: the criterion at the final design ``q`` (n, nq).
    """
    phi0 = objective.compute_value(q0)
    nlp = DesignProblem(objective, feasibility, len(q0), collisions=collisions,
                        scale=max(abs(phi0), 1e-300))
    structured = structured_hessian and nlp.compute_curvature(q0.ravel()) is not None
    result = solve_sqp(nlp.compute_objective, q0.ravel(), constraints=nlp.compute_constraints,
                       bounds=nlp.bounds, settings=settings or DESIGN_SQP, callback=callback,
                       hessian_model=nlp.compute_curvature if structured else None,
                       block_size=nlp.nq)
    x = result.x
    if nlp.max_violation(x) > FEASIBILITY_TOL:
        x = project_feasible(nlp, x)
    q = nlp.configurations(x).copy()
    return float(objective.compute_value(q)), q, float(phi0), result


def exchange_baseline(
    scene: Scene | Setup,
    n: int = 60,
    criterion: str | Criterion = "kpi",
    *,
    pool: int | np.ndarray = 3000,
    seed: int = 0,
) -> Design:
    """The best n poses of a feasible candidate pool by the exchange algorithm.

    Args:
        pool: Number of random feasible candidates drawn from ``seed``, or the
            candidates themselves (N, nq).
    """
    s = _setup(scene)
    t0 = time.perf_counter()
    if isinstance(pool, (int, np.integer)):
        candidates = sample_feasible(s.feasibility, int(pool), seed, max_draws=50_000_000)
    else:
        candidates = s.problem.robot.check_configurations(pool, "candidate pool")
    objective = DesignObjective(s.problem, criterion)
    blocks = objective.compute_blocks(candidates)
    with threadpool_limits(limits=1, user_api="blas"):
        result = exchange_design(blocks, n, objective.criterion, rng=seed)
    q = candidates[np.asarray(result.indices)]
    record = result.to_dict()
    record["pool"] = int(len(candidates))
    return evaluate_design(
        s, q, criterion, method="exchange", start_value=result.initial_value, solver=record,
        seconds=time.perf_counter() - t0, seed=seed,
    )


def heuristic_designs(scene: Scene | Setup, n: int, seeds: Sequence[int]) -> list[Design]:
    """The paper's heuristic designs (random feasible poses), one per seed."""
    s = _setup(scene)
    return [evaluate_design(s, sample_feasible(s.feasibility, n, k), "kpi", method="heuristic",
                            seed=k) for k in seeds]
