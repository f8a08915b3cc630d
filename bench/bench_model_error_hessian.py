"""The ``kpi_model`` design SQP with its exact Hessian against damped BFGS, side by side.

For each scene: the default ``kpi_model`` design (joint-space prior, exchange start) of n poses
from the same seed, once with ``hessian="exact"`` (:mod:`calib_oed.oed.model_error_hessian`, the
SQP capped at :data:`calib_oed.oed.model_error.MODEL_ERROR_EXACT_ITERATIONS`) and once with
``hessian="bfgs"`` (capped at :data:`~calib_oed.oed.model_error.MODEL_ERROR_ITERATIONS`), in one
process one after the other (one BLAS thread; the machine may be
shared, so CPU seconds, not wall time, are compared). Reports per run the SQP status and
iterations, the design CPU (``solver.cpu_seconds``: pool, start and SQP), the criterion value
[mm²] and its start value, and the Hessian's fallbacks to BFGS.

    nice -n 10 python bench/bench_model_error_hessian.py [--scenes fms_kr16 ur5_table] [-n 60] [--seed 0]
        [--iterations K] [--hessians exact bfgs]
"""

from __future__ import annotations

import argparse
import json

from calib_oed import load_scene
from calib_oed.calibration.workflow import setup
from calib_oed.oed.design import design
from calib_oed.solver.sqp import SQPSettings


def run(scene: str, n: int, seed: int, hessian: str, iterations: int | None) -> dict:
    s = setup(load_scene(scene))
    settings = None if iterations is None else SQPSettings(max_iterations=iterations)
    d = design(s, n, "kpi_model", seed=seed, hessian=hessian, certificate=False, settings=settings)
    sol = d.solver
    return {"scene": scene, "hessian": hessian, "status": str(sol.get("status")),
            "iterations": sol.get("iterations"), "cpu_s": round(sol["cpu_seconds"], 2),
            "value_mm2": d.value, "start_mm2": d.start_value, "ratio_to_start": d.value / d.start_value,
            "hessian_used": sol.get("hessian"), "fallbacks": sol.get("hessian_fallbacks"),
            "distinct_positions": d.distinct_positions,
            "sqp_times_s": {k: round(v, 2) for k, v in (sol.get("times") or {}).items()}}


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenes", nargs="+", default=["fms_kr16", "ur5_table"])
    ap.add_argument("-n", type=int, default=60)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--iterations", type=int, default=None, help="SQP iteration cap (default: the design's)")
    ap.add_argument("--hessians", nargs="+", default=["exact", "bfgs"], choices=["exact", "bfgs"])
    args = ap.parse_args(argv)
    for scene in args.scenes:
        for hessian in args.hessians:
            print(json.dumps(run(scene, args.n, args.seed, hessian, args.iterations)), flush=True)


if __name__ == "__main__":
    main()
