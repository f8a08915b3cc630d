r"""Local refinement of a design by the SQP: one run from a start, the best of several starts.

:func:`optimise_from` scales the design NLP (:class:`~calib_oed.oed.problem.DesignProblem`)
to an O(1) objective and hands it to :func:`calib_oed.solver.sqp.solve_sqp` with
the exact Lagrangian Hessian where the criterion has one; a last iterate that
violates a constraint is projected back onto the feasible set
(:func:`project_feasible`). An interrupted run (Ctrl-C: status
``interrupted``) keeps its last iterate if it is feasible, else its start,
and ends a multi-start: the driver then returns the best design so far.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from calib_oed.exceptions import DesignError
from calib_oed.feasibility.constraints import FEASIBILITY_TOL
from calib_oed.oed.hessian import has_exact_hessian
from calib_oed.oed.objective import DesignObjective
from calib_oed.oed.problem import DesignProblem, WorstCaseDesignProblem
from calib_oed.solver.sqp import SQPResult, SQPSettings, SQPStatus, solve_sqp

#: :math:`\mu_m` of the design SQP's penalty, :math:`\mu \ge \|\lambda\|_\infty + \mu_m`
#: (``SQPSettings.penalty_margin``, the SQP's default 0.1). The design's multipliers are about
#: 1e-2 (objective scaled to 1): with 0.1 the merit charged a step's leftover violation over
#: curved active rows ten times what the QP's Lagrangian Hessian models, the ratio rule kept the
#: trust box small and the run crept (``fms_kr16`` n = 500: 40 iterations at boxes of 2.7e-3 to
#: 5.5e-3 rad, ``bench/trace_design_sqp.py``). Measured against 0.1 (``docs/benchmarks.md``,
#: "The design SQP's penalty margin").
DESIGN_PENALTY_MARGIN = 1e-3

#: The design SQP's first trust box :math:`\Delta_0` [rad] (``SQPSettings.step_bound``, the SQP's
#: default 0.3). The design starts at the exchange algorithm's design, close to a local optimum.
#: From 0.03 the box grows as the model earns it (``EXACT_TRUST_UPDATE``), and the SQP settles in
#: a nearby optimum in fewer iterations: every scene's ``kpi`` value the same to 0.13 %, 25 % fewer
#: iterations; ``fms_kr16`` from the random pool's exchange, 20 iterations against 36 to a value
#: 0.7 % higher (``docs/benchmarks.md``, "The design SQP's first trust box").
DESIGN_STEP_BOUND = 0.03

#: SQP settings of the design problem (objective scaled to 1 at the start, x in rad). With
#: ``extrapolate``, a step whose merit curves less than the flipped exact Hessian models is taken
#: further (``SQPSettings.extrapolate``): ``fms_kr16`` n = 250, ``kpi``, 271 -> 169 iterations to
#: the same value (``docs/benchmarks.md``, "Longer steps after a flipped eigenvalue"). With
#: ``penalty_weights="row"``, each row's violation is charged at its own multiplier plus the
#: margin, not at the largest (``docs/benchmarks.md``, "One penalty weight per row"). With
#: ``qp_active_set_start``, a QP for ProxQP (dense or lifted) is first solved on the last
#: iteration's active set: the notional90 study's CPU 1603 -> 1205 s on 2 cores, its designs'
#: values the same (``docs/benchmarks.md``, "The QP's answer from the last active set"). Its first
#: trust box is :data:`DESIGN_STEP_BOUND`.
DESIGN_SQP = SQPSettings(penalty_margin=DESIGN_PENALTY_MARGIN, extrapolate=True, penalty_weights="row",
                         qp_active_set_start=True, step_bound=DESIGN_STEP_BOUND)

#: The trust rule of a design SQP with the exact Hessian when the settings leave it to the caller
#: (``trust_update=None``): the model's agreement decides the box (``SQPSettings.trust_update``).
#: Against ``"edge"`` on 20 notional arms' four designs each (``docs/benchmarks.md``, "The trust
#: rule of the design SQP"): 22 % less design CPU, the mean value of each kind of design moved by
#: -0.004 to +0.1 %; the notional90 study 27 % less CPU.
EXACT_TRUST_UPDATE = "ratio"

#: The projection's SQP (:func:`project_feasible`, its ``max_iterations`` replaced): short steps and a
#: feasibility tolerance ten times below the one it is judged by.
PROJECTION_SQP = SQPSettings(max_iterations=50, step_bound=0.05, tol_feasibility=0.1 * FEASIBILITY_TOL)

#: Curvature models of the design SQP: the exact Lagrangian Hessian (default), or damped BFGS.
HESSIANS = ("exact", "bfgs")


def sqp_settings(settings: SQPSettings | None, exact: bool) -> SQPSettings:
    """The settings a design SQP runs with: ``settings`` (default :data:`DESIGN_SQP`), with
    :data:`EXACT_TRUST_UPDATE` when it has the exact Hessian and the trust rule is left open."""
    settings = settings or DESIGN_SQP
    if exact and settings.trust_update is None:
        settings = replace(settings, trust_update=EXACT_TRUST_UPDATE)
    return settings


def project_feasible(nlp: DesignProblem, x: np.ndarray, max_iterations: int = 50) -> np.ndarray:
    r"""The nearest feasible design: :math:`\min_y \tfrac12\|y - x\|^2` s.t. the design constraints.

    Used when the SQP stops (iteration limit) at an iterate violating a
    constraint by more than :data:`FEASIBILITY_TOL`; the quadratic objective
    makes the SQP's BFGS start exact, so a few iterations suffice. The BFGS
    matrix is one block per pose (the distance is separable, each constraint row
    is one pose's), so a large design's QPs take the block QP: at 500 poses one
    dense BFGS block of 3000 variables cost 40 s of ProxQP, the pose blocks 0.3 s
    (``docs/benchmarks.md``, "The projection onto the feasible set").
    """
    def distance(y):
        d = y - x
        return 0.5 * float(d @ d), d

    res = solve_sqp(distance, x, constraints=nlp.compute_constraints, bounds=nlp.bounds,
                    settings=replace(PROJECTION_SQP, max_iterations=max_iterations), block_size=nlp.nq)
    if res.status is SQPStatus.INTERRUPTED:  # Ctrl-C reaches the caller, as outside the SQP
        raise KeyboardInterrupt
    return res.x


def optimise_worst_case(s, starts, criterion, collisions, settings, callback):
    """The epigraph SQP from every start; the best ``(max_i v_i, q, start max, result, seed)``."""
    best = None
    for start_seed, q0 in starts:
        objective = DesignObjective(s.problem, criterion)
        v0 = float(objective.kpi_point_variances(q0).max())
        nlp = WorstCaseDesignProblem(objective, s.feasibility, len(q0), collisions=collisions,
                                     scale=max(v0, 1e-300))
        result = solve_sqp(nlp.compute_objective, nlp.start(q0), constraints=nlp.compute_constraints,
                           bounds=nlp.bounds, settings=settings or DESIGN_SQP, callback=callback)
        x = result.x
        if nlp.max_violation(x) > FEASIBILITY_TOL:
            x = (nlp.start(q0) if result.status is SQPStatus.INTERRUPTED
                 else np.append(project_feasible(nlp.base, x[:-1]), x[-1]))
        q = nlp.configurations(x)
        value = float(objective.kpi_point_variances(q).max())
        if best is None or value < best[0]:
            best = (value, q, v0, result, start_seed)
        if result.status is SQPStatus.INTERRUPTED:
            return (*best[:3], result, best[4])
    return best


def optimise_starts(s, starts, criterion, collisions, settings, callback, hessian, runs=None):
    """Run the SQP from every start; the best ``(value, q, phi0, result, seed)``. ``runs``, a list,
    gains ``(seed, start value, value)`` of every start (:func:`calib_oed.oed.certificate.multistart_gap`)."""
    best = None
    for start_seed, q0 in starts:
        objective = DesignObjective(s.problem, criterion)
        value, q, phi0, result = optimise_from(objective, s.feasibility, q0, collisions=collisions,
                                               settings=settings, callback=callback, hessian=hessian)
        if runs is not None:
            runs.append((start_seed, phi0, value))
        if best is None or value < best[0]:
            best = (value, q, phi0, result, start_seed)
        if result.status is SQPStatus.INTERRUPTED:  # no further starts: the best so far, and
            return (*best[:3], result, best[4])     # the record that says it was interrupted
    return best


def optimise_from(objective: DesignObjective, feasibility, q0: np.ndarray, *, collisions: bool = True,
                  settings: SQPSettings | None = None, callback=None,
                  hessian: str = "exact") -> tuple[float, np.ndarray, float, SQPResult]:
    r"""One SQP run of ``objective`` (its prior and parameters included) from the design ``q0``.

    The objective is divided by :math:`|\phi(q^0)|` (log-type criteria can be
    negative) so the solver sees O(1) numbers; a last iterate that violates a
    constraint is projected back onto the feasible set. ``hessian="exact"``
    gives the SQP the exact Lagrangian Hessian
    (:meth:`~calib_oed.oed.problem.DesignProblem.compute_lagrangian_hessian`)
    where the criterion has one (A, D; not with joint compliance), else
    the SQP's damped BFGS; ``"bfgs"`` always the latter.

    Returns:
        ``(value, q, start value, SQP result)``: the criterion at the final design ``q`` (n, nq).
    """
    phi0 = objective.compute_value(q0)
    nlp = DesignProblem(objective, feasibility, len(q0), collisions=collisions,
                        scale=max(abs(phi0), 1e-300))
    if hessian not in HESSIANS:
        raise DesignError("hessian", hessian, "how the SQP models curvature", HESSIANS)
    exact = hessian == "exact" and has_exact_hessian(objective.criterion)
    result = solve_sqp(nlp.compute_objective, q0.ravel(), constraints=nlp.compute_constraints,
                       bounds=nlp.bounds, settings=sqp_settings(settings, exact), callback=callback,
                       block_size=nlp.nq,
                       lagrangian_hessian=nlp.compute_lagrangian_hessian if exact else None,
                       row_pieces=nlp.compute_row_pieces, values=nlp.compute_values)
    x = result.x
    if nlp.max_violation(x) > FEASIBILITY_TOL:
        # interrupted: the (feasible) start rather than a projection the user did not wait for
        x = (q0.ravel() if result.status is SQPStatus.INTERRUPTED else project_feasible(nlp, x))
    q = nlp.configurations(x).copy()
    return float(objective.compute_value(q)), q, float(phi0), result


