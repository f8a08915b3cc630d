r"""One case of a study: its designs, their evaluation and the certificate.

A case (:class:`~calib_oed.study.config.StudyCase`: one robot in one scene,
and the plan) runs (:func:`run_case`):

1. the heuristic designs of all ``heuristic_seeds`` (random feasible poses,
   :func:`calib_oed.oed.design.heuristic_designs`) and their median KPI average
   variance;
2. for each ``collisions`` flag and each criterion, the SQP design
   (:func:`calib_oed.oed.design.design`) from the same start (the heuristic
   design of ``seed``, or the exchange start);
3. with a ``certificate`` in the plan, the optimality certificate of the
   KPI criterion for ``n`` poses (:func:`calib_oed.oed.certificate.certify`) on
   a random feasible pool plus the poses of every feasible design of the
   case, so that its lower bound holds for each of them (checked), and each
   feasible design's efficiency ``bound / V``.

Every design is evaluated on the KPI average variance
:math:`V = \mathrm{tr}(C_s)/(3t)` [mm²] (``Design.criteria["kpi"]``) and on
the full feasibility model: a pose *collides* if any self-collision, obstacle
or beam row is below :math:`-10^{-6}`
(:data:`calib_oed.feasibility.constraints.FEASIBILITY_TOL`); a design
optimised without collision constraints reports the fraction of its poses that
collide. The result is a :class:`~calib_oed.study.results.CaseResult`.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Sequence

import numpy as np
from threadpoolctl import threadpool_limits

from calib_oed.calibration.workflow import setup
from calib_oed.feasibility.constraints import FEASIBILITY_TOL, FeasibilityModel
from calib_oed.oed.design import design, heuristic_designs
from calib_oed.oed.problem import COLLISION_KINDS, NO_COLLISION_KINDS
from calib_oed.oed.result import Design
from calib_oed.study.config import StudyCase
from calib_oed.study.results import CaseResult, DesignRow, StoredDesign, design_label

__all__ = ["colliding_poses", "run_case"]

#: Rows of the feasibility model that are collisions (self, obstacle, beam).
COLLISION_ROW_KINDS = tuple(k for k in COLLISION_KINDS if k not in NO_COLLISION_KINDS)


def colliding_poses(feasibility: FeasibilityModel, q: np.ndarray) -> np.ndarray:
    """Which poses of ``q`` (n, nq) [rad] collide: a self, obstacle or beam row < -tol, (n,) bool."""
    res = feasibility.compute(q, jacobian=False)
    slices = feasibility.kind_slices()
    rows = np.concatenate([slices[k] for k in COLLISION_ROW_KINDS])
    if rows.size == 0:
        return np.zeros(len(q), dtype=bool)
    return res.values[:, rows].min(axis=1) < -FEASIBILITY_TOL


def _row(case: StudyCase, d: Design, kind: str, criterion: str, collisions: bool, seed,
         colliding: float) -> DesignRow:
    spec = case.spec
    solver = d.solver or {}
    return DesignRow(
        case_id=spec.case_id, robot=spec.robot, scene=spec.scene_label,
        lambda_mm=spec.lambda_mm, mu_mm=spec.mu_mm, kind=kind, criterion=criterion,
        collisions=bool(collisions), seed=seed, n=d.n,
        kpi_avg_variance_mm2=d.kpi_variance, kpi_sigma_mm=float(np.max(d.kpi_sigma_mm)),
        params_avg_variance=float(d.criteria["params"]), criterion_value=float(d.value),
        criterion_start_value=float(d.start_value), feasible=bool(d.feasible),
        colliding_fraction=colliding, iterations=int(solver.get("iterations", 0)),
        status=str(solver.get("status", "")), seconds=float(d.seconds),
        distinct_poses=float(len(d.multiplicity)),
        distinct_positions=float(d.distinct_positions or math.nan))


def run_case(case: StudyCase) -> CaseResult:
    """Heuristic designs, then every (collisions, criterion) SQP design of one case.

    The optimised designs all start from the same design: the heuristic
    design of ``plan.seed`` (``start: heuristic``) or the exchange algorithm's
    (``start: exchange``, per criterion). BLAS is pinned to one thread.
    """
    t0 = time.perf_counter()
    plan = case.plan
    with threadpool_limits(limits=1):
        s = setup(case.spec.load_scene())
        fm = s.feasibility
        names = tuple(s.problem.robot.joint_names)
        rows, heur = [], []
        for seed in plan.heuristic_seeds:
            t = time.perf_counter()
            d = heuristic_designs(s, plan.n, [seed])[0]
            d = dataclasses.replace(d, seconds=time.perf_counter() - t)
            heur.append(d)
            rows.append(_row(case, d, "heuristic", "", True, seed,
                             float(colliding_poses(fm, d.q).mean())))
        rows.append(_median_row(case, rows))
        values = [d.kpi_variance for d in heur]
        mid = heur[int(np.argsort(values)[(len(values) - 1) // 2])]  # the lower median
        designs = {"heuristic_median": StoredDesign("heuristic_median", names, mid.q, mid.seed,
                                                    {})}
        optimal: dict[str, Design] = {}
        start = plan.start
        if start == "heuristic" and plan.seed in plan.heuristic_seeds:
            start = heur[plan.heuristic_seeds.index(plan.seed)].q  # the same poses, not redrawn
        settings = plan.sqp_settings()
        for coll in plan.collisions:
            for crit in plan.criteria:
                # the study certifies the case itself (_certified_rows), on its own pool
                d = design(s, plan.n, crit, start=start, seed=plan.seed, collisions=coll,
                           settings=settings, certificate=False,
                           enrich=None if plan.enrich else False)  # True: the library's default
                if d.interrupted:  # Ctrl-C/SIGTERM in the SQP: a best-so-far design, not this case's
                    raise KeyboardInterrupt
                rows.append(_row(case, d, "optimal", crit, coll, plan.seed,
                                 float(colliding_poses(fm, d.q).mean())))
                label = design_label(crit, coll)
                designs[label] = StoredDesign(label, names, d.q, plan.seed, d.solver)
                optimal[label] = d
        certificate = None
        if plan.certificate is not None:
            rows, certificate = _certified_rows(s, plan, rows, heur, optimal)
    return CaseResult(case, tuple(rows), designs, time.perf_counter() - t0, certificate).check()


def _certified_rows(s, plan, rows, heuristic, optimal):
    """The case's certificate and its rows with the bound and the efficiencies.

    The pool is ``plan.certificate.pool`` random feasible poses plus the poses
    of every feasible design of the case, so the bound holds for each of them
    (:meth:`~calib_oed.study.results.CaseResult.check` verifies it); the certificate is that of the
    KPI-optimal design (with collisions if planned, else the first).
    """
    from calib_oed.oed.certificate import certify
    from calib_oed.oed.starts import candidate_pool

    cp = plan.certificate
    feasible = [d.q for d in (*heuristic, *optimal.values()) if d.feasible]
    # the same draw as the exchange start's pool when pool and seed agree (drawn once per set-up)
    pool = np.vstack([candidate_pool(s, cp.pool, cp.seed).q, *feasible])
    kpi = [optimal[k] for k in (design_label("kpi", True), design_label("kpi", False)) if k in optimal]
    q = kpi[0].q if kpi else next(iter(optimal.values())).q if optimal else heuristic[0].q
    cert = certify(s, q, "kpi", pool=pool, local_starts=cp.local_starts)
    rows = [dataclasses.replace(r, kpi_bound_mm2=cert.bound,
                                kpi_efficiency=cert.bound / r.kpi_avg_variance_mm2 if r.feasible
                                else math.nan) for r in rows]
    return rows, cert.to_dict()


def _median_row(case: StudyCase, rows: Sequence[DesignRow]) -> DesignRow:
    """The median over the heuristic rows, value by value (the tables' heuristic baseline)."""
    def med(key):
        return float(np.median([getattr(r, key) for r in rows]))

    first = rows[0]
    return dataclasses.replace(
        first, kind="heuristic_median", seed=None,
        kpi_avg_variance_mm2=med("kpi_avg_variance_mm2"), kpi_sigma_mm=med("kpi_sigma_mm"),
        params_avg_variance=med("params_avg_variance"), criterion_value=med("criterion_value"),
        criterion_start_value=med("criterion_start_value"),
        feasible=all(r.feasible for r in rows), colliding_fraction=med("colliding_fraction"),
        seconds=sum(r.seconds for r in rows), distinct_poses=med("distinct_poses"),
        distinct_positions=med("distinct_positions"))
