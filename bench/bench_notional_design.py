"""Benchmark: one notional90 design in one process, SQP and QP CPU (issue 33).

Run from any directory with the checkout to time on ``PYTHONPATH``:

    OPENBLAS_NUM_THREADS=1 PYTHONPATH=CHECKOUT python bench/bench_notional_design.py \
        [--case 0] [--criterion params] [--collisions 1] [--no-reequilibrate] [--proxsuite-default]
        [--trust-update edge|ratio] [--qp-trace]

The case is the ``notional90`` study's ``--case``-th arm (the first: lambda 650,
mu 600 mm in the scaled ``fms_kr16`` paper cell), set up as
``calib_oed.study.case.run_case`` does, and one of its designs
(``design(s, 60, criterion, start="exchange", seed=0, collisions=...)`` with the
study's SQP settings, the wall-clock limit removed so that every checkout runs
to the same iteration limit). Printed as one JSON line: process CPU
(``time.process_time``) of the whole run, of ``optimise_starts`` (the SQP) and
of the SQP's QP subproblems (``solver.subproblem.QPSolver.solve`` called inside
``optimise_starts``, the retries included; the start's QPs apart), the SQP's
iterations, status and value, ProxQP's inner iterations and build.
The dense polish of the QP steps (``solver.polish.polish``, every step since
96ef43f, before only steps of at most 1e-4) is timed apart (``polish_cpu_s``,
inside ``sqp_cpu_s``, not in ``qp_cpu_s``); ``--polish-small-only`` restores
the old rule by a monkeypatch here.
``exchange_cpu_s`` is the CPU of the exchange algorithm behind the start
(``oed.starts.exchange_poses``). ``--qp-trace`` prints one line per QP of the
SQP on stderr: the workspace, rows, row capacity (dense), ProxQP iterations and
status, residuals and CPU (QPs the active-set start answers never reach ProxQP
and are not listed), and for a QP ProxQP did not solve the least violation its
multipliers prove (``certificate``, positive: infeasible;
``solver.restoration.certified_violation``).
``--proxsuite-default`` imports ``proxsuite`` before ``calib_oed``, so that
proxsuite picks its own build (AVX2 here) instead of the SSE2 build of
``solver/proxqp_build.py`` (3386afc); the same code, the other build.

``--trust-update`` sets the design SQP's trust rule (``SQPSettings.trust_update``); by
default it is left to the design (``"ratio"`` with the exact Hessian since
``calib_oed.oed.refine.EXACT_TRUST_UPDATE``, ``"edge"`` before).

``--no-reequilibrate`` switches off, by a monkeypatch here (not in the library),
what dd25508 added: a reused dense ProxQP object recomputing its equilibration
for a QP with more rows than it was scaled on, and the ``refresh`` of the cold
retry of a failed QP. The code before dd25508 has neither (there the flag
patches nothing and ``reequilibrate_patched_off`` says so).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
import time

C0 = time.process_time()


def _certificate(sub, step) -> str:
    """`` certificate G`` for a QP ProxQP did not solve: the least violation its multipliers prove
    (``solver.restoration.certified_violation``; > 0: infeasible), '' for a solved one or a
    checkout without it."""
    try:
        from calib_oed.solver.restoration import certified_violation
    except ImportError:
        return ""
    if step.status == "solved":
        return ""
    return f" certificate {certified_violation(sub.C, sub.lower, sub.box_lower, sub.box_upper, step.lam):.1e}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--study", default="notional90")
    ap.add_argument("--case", type=int, default=0)
    ap.add_argument("--criterion", default="params")
    ap.add_argument("--collisions", type=int, default=1)
    ap.add_argument("--no-reequilibrate", action="store_true")
    ap.add_argument("--polish-small-only", action="store_true",
                    help="polish only QP steps with |d|_inf <= 1e-4, as before 96ef43f")
    ap.add_argument("--proxsuite-default", action="store_true",
                    help="import proxsuite before calib_oed: its own build choice (AVX2 here), "
                         "not the SSE2 build solver/proxqp_build.py picks")
    ap.add_argument("--qp-trace", action="store_true",
                    help="one line per QP of the SQP on stderr: backend, rows, row capacity, "
                         "ProxQP iterations, status, residuals, CPU")
    ap.add_argument("--trust-update", choices=("edge", "ratio"), default=None,
                    help="the design SQP's trust rule (default: the design's own)")
    args = ap.parse_args()
    if args.proxsuite_default:
        import warnings

        import proxsuite  # noqa: F401  (first import decides the build)
        warnings.filterwarnings("ignore", message="proxsuite loaded", category=RuntimeWarning)

    from threadpoolctl import threadpool_limits

    import calib_oed
    import calib_oed.oed.design as design_mod
    import calib_oed.solver.subproblem as subproblem
    from calib_oed.calibration.workflow import setup
    from calib_oed.study.loader import load_study_config

    cpu = {"sqp": 0.0, "qp": 0.0, "start_qp": 0.0, "polish": 0.0, "start_polish": 0.0,
           "start_exchange": 0.0}
    calls = {"qp": 0, "refresh": 0, "proxqp_iterations": 0}
    inside = []  # non-empty while optimise_starts runs (the start's own QPs are counted apart)

    def timed(key, fn):
        def wrapper(*a, **kw):
            c = time.process_time()
            if key == "sqp":
                inside.append(1)
            try:
                return fn(*a, **kw)
            finally:
                if key == "sqp":
                    inside.pop()
                cpu[key if inside or key == "sqp" else "start_" + key] += time.process_time() - c
        return wrapper

    design_mod.optimise_starts = timed("sqp", design_mod.optimise_starts)
    qp_solve = subproblem.QPSolver.solve
    patched = False
    if args.no_reequilibrate:
        import calib_oed.solver.qp as qp_mod
        if hasattr(qp_mod.DenseQPWorkspace, "scaled_rows") or "refresh" in qp_solve.__code__.co_varnames:
            dense_solve = qp_mod.DenseQPWorkspace.solve

            def dense_no_rescale(self, sub, *a, **kw):
                kw["refresh"] = False
                self.scaled_rows = 1 << 30  # never "more rows than it saw"
                return dense_solve(self, sub, *a, **kw)

            qp_mod.DenseQPWorkspace.solve = dense_no_rescale
            patched = True

    def counted(self, sub, lam0=None, nu0=None, refresh=False):
        calls["qp"] += bool(inside)
        calls["refresh"] += bool(inside) and bool(refresh)
        c = time.process_time()
        if refresh and not args.no_reequilibrate:
            step = qp_solve(self, sub, lam0, nu0, refresh)
        else:
            step = qp_solve(self, sub, lam0, nu0)
        calls["proxqp_iterations"] += int(step.iterations) if inside else 0
        if args.qp_trace and inside:
            ws = getattr(self, "_ws", {}).get(self.last_backend)
            print(f"qp {self.last_backend} rows {sub.lower.size} capacity {getattr(ws, 'capacity', '-')} "
                  f"warm {lam0 is not None} iterations {step.iterations} {step.status} "
                  f"primal {step.primal_residual:.1e} dual {step.dual_residual:.1e} "
                  f"cpu {time.process_time() - c:.3f}{_certificate(sub, step)}", file=sys.stderr)
        return step

    subproblem.QPSolver.solve = timed("qp", counted)
    import calib_oed.oed.approximate_pool as approximate_pool_mod
    import calib_oed.oed.starts as starts_mod
    starts_mod.exchange_poses = timed("exchange", starts_mod.exchange_poses)
    approximate_pool_mod.exchange_poses = starts_mod.exchange_poses
    polish = subproblem.polish

    def polish_small(sub, step, *a, **kw):
        if args.polish_small_only and float(abs(step.d).max(initial=0.0)) > 1e-4:
            return None
        return polish(sub, step, *a, **kw)

    subproblem.polish = timed("polish", polish_small)

    config = load_study_config(args.study)
    case = config.cases()[args.case]
    plan = case.plan
    settings = plan.sqp_settings()
    settings = dataclasses.replace(settings, time_limit=math.inf, trust_update=args.trust_update)
    with threadpool_limits(limits=1):
        s = setup(case.spec.load_scene())
        c_design = time.process_time()
        d = design_mod.design(s, plan.n, args.criterion, start=plan.start, seed=plan.seed,
                              collisions=bool(args.collisions), settings=settings, certificate=False,
                              enrich=plan.enrich)
        c_design = time.process_time() - c_design
    loaded = getattr(sys.modules.get("proxsuite"), "_submodule", None)
    solver = d.solver or {}
    its = int(solver.get("iterations", 0))
    print(json.dumps({
        "case": case.spec.case_id, "criterion": args.criterion, "collisions": bool(args.collisions),
        "trust_update": args.trust_update,
        "reequilibrate_patched_off": patched, "proxqp_build": getattr(loaded, "__name__", "unknown"),
        "status": str(solver.get("status", "")), "iterations": its, "value": float(d.value),
        "kpi_mm2": float(d.kpi_variance), "feasible": bool(d.feasible),
        "qp_calls": calls["qp"], "qp_refresh_calls": calls["refresh"],
        "qp_inner_iterations": calls["proxqp_iterations"],
        "process_cpu_s": time.process_time() - C0, "design_cpu_s": c_design,
        "sqp_cpu_s": cpu["sqp"], "qp_cpu_s": cpu["qp"], "start_qp_cpu_s": cpu["start_qp"],
        "polish_cpu_s": cpu["polish"], "start_polish_cpu_s": cpu["start_polish"],
        "exchange_cpu_s": cpu["start_exchange"],
        "polish_small_only": args.polish_small_only,
        "sqp_cpu_per_iteration_s": cpu["sqp"] / max(its, 1),
        "qp_share_of_sqp": cpu["qp"] / cpu["sqp"] if cpu["sqp"] else None,
        "calib_oed": calib_oed.__file__}))


if __name__ == "__main__":
    main()
