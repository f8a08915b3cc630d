"""Benchmark: the feasibility rows' share of the design SQP's CPU time at large n.

Run from the repository root:

    .venv/bin/python bench/bench_feasibility_share.py [--scene fms_kr16] [--poses 250]
        [--criterion kpi]

One design (``calib_oed.design``, no certificate) in this process; the process CPU time of the
SQP that refines the start (``oed.refine.optimise_starts``) and, inside it, of the feasibility
rows as the SQP asks for them: values and Jacobians at each trial point
(``DesignProblem.compute_constraint_rows``), their curvature for the Lagrangian Hessian
(``FeasibilityModel.compute_lagrangian_hessian``) and the pieces of kinked convex-piece rows
(``DesignProblem.compute_row_pieces``). Prints one JSON line: value, iterations, the four CPU
times [s] and the rows' share of the SQP. ``PYTHONPATH=/other/checkout`` measures that
checkout, for side-by-side figures. Results: docs/benchmarks.md (issue 33).
"""

from __future__ import annotations

import argparse
import json
import time


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scene", default="fms_kr16")
    ap.add_argument("--poses", type=int, default=250)
    ap.add_argument("--criterion", default="kpi")
    args = ap.parse_args(argv)
    import calib_oed.feasibility.constraints as constraints
    import calib_oed.oed.design as design_module
    import calib_oed.oed.problem as problem
    from calib_oed import design, load_scene, setup

    cpu = {"rows": 0.0, "curvature": 0.0, "pieces": 0.0, "sqp": 0.0}

    def timed(name, fn):
        def wrapper(*a, **k):
            start = time.process_time()
            try:
                return fn(*a, **k)
            finally:
                cpu[name] += time.process_time() - start
        return wrapper

    problem.DesignProblem.compute_constraint_rows = timed("rows", problem.DesignProblem.compute_constraint_rows)
    problem.DesignProblem.compute_row_pieces = timed("pieces", problem.DesignProblem.compute_row_pieces)
    constraints.FeasibilityModel.compute_lagrangian_hessian = timed(
        "curvature", constraints.FeasibilityModel.compute_lagrangian_hessian)
    optimise = design_module.optimise_starts

    def sqp(*a, **k):  # the rows' time inside the SQP only (the start's column generation uses them too)
        before = dict(cpu)
        start = time.process_time()
        try:
            return optimise(*a, **k)
        finally:
            cpu["sqp"] = time.process_time() - start
            for key in ("rows", "curvature", "pieces"):
                cpu[key] -= before[key]

    design_module.optimise_starts = sqp
    s = setup(load_scene(args.scene))
    d = design(s, args.poses, criterion=args.criterion, certificate=False)
    rows = cpu["rows"] + cpu["curvature"] + cpu["pieces"]
    print(json.dumps({"scene": args.scene, "n": args.poses, "criterion": args.criterion, "value": float(d.value),
                      "iterations": d.solver.get("iterations"), **{f"{k}_cpu_s": v for k, v in cpu.items()},
                      "rows_share": rows / cpu["sqp"]}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
