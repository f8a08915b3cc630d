"""Benchmark: one round of the sensitivity's local maximisation from the same starts, two models.

Run from the repository root:

    OPENBLAS_NUM_THREADS=1 .venv/bin/python bench/bench_sensitivity_maxima.py
        [--scenes fms_kr16,ur5_table,bench/scenes/panda_cell.yaml] [--rounds 0,10] [--starts 16]

For each scene (pool 3000, seed 0, KPI) and each number of column-generation
rounds of ``--rounds`` before it (the design start's search,
:func:`calib_oed.oed.approximate_pool.approximate_pool`): the approximate
design's :math:`\\Gamma` and :math:`\\bar d`, ``--starts`` separated starts
(:func:`calib_oed.oed.sensitivity_maxima.spread_starts`), and from them one
:func:`~calib_oed.oed.sensitivity_maxima.maximise_sensitivity` with each model:
``exact`` (the exact Lagrangian Hessian and the row pieces at kinks, the
certificate's) and ``bfgs`` (per-pose BFGS blocks, no pieces, the start's).
Printed per model: the SQP's status and iterations, the CPU seconds
(``time.process_time``), the largest :math:`d/\\bar d` and the mean over the
starts, the largest violation; then the largest difference of the two models'
end values per start, relative to :math:`\\bar d`. Results: docs/benchmarks.md.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from threadpoolctl import threadpool_limits

from calib_oed.calibration.workflow import setup
from calib_oed.oed.approximate import information
from calib_oed.oed.approximate_pool import approximate_pool
from calib_oed.oed.objective import DesignObjective
from calib_oed.oed.sensitivity_maxima import maximise_sensitivity, spread_starts
from calib_oed.oed.starts import candidate_pool
from calib_oed.scene.reader import load_scene


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenes", default="fms_kr16,ur5_table,bench/scenes/panda_cell.yaml")
    ap.add_argument("--rounds", default="0,10")
    ap.add_argument("--starts", type=int, default=16)
    args = ap.parse_args(argv)
    print(f"{'scene':22s} {'rounds':>6s} {'model':>5s} {'status':>15s} {'it':>4s} {'cpu':>5s} "
          f"{'max d/dbar':>10s} {'mean d/dbar':>11s} {'violation':>9s}")
    for scene in args.scenes.split(","):
        s = setup(load_scene(scene))
        objective = DesignObjective(s.problem, "kpi")
        pool = candidate_pool(s, 3000, 0)
        for rounds in (int(r) for r in args.rounds.split(",") if r):
            with threadpool_limits(limits=1, user_api="blas"):
                search = approximate_pool(s, objective, pool.q, rounds=rounds)
                gamma = objective.criterion.compute_gradient(information(search.blocks, search.approx.weights))
                dbar = search.approx.mean_sensitivity
                starts = search.q[spread_starts(search.q, search.approx.sensitivities, args.starts)]
                ends = {}
                for model in ("exact", "bfgs"):
                    t = time.process_time()
                    loc = maximise_sensitivity(s, objective, gamma, starts, dbar, exact=model == "exact")
                    ends[model] = loc.values
                    print(f"{scene.split('/')[-1]:22s} {rounds:6d} {model:>5s} {loc.status:>15s} "
                          f"{loc.iterations:4d} {time.process_time() - t:5.2f} {loc.max_value / dbar:10.5f} "
                          f"{np.mean(loc.values) / dbar:11.5f} {loc.violation.max():9.1e}", flush=True)
                gap = np.max(np.abs(ends["exact"] - ends["bfgs"])) / dbar
                print(f"{'':22s} largest |d_exact - d_bfgs| / dbar over the starts: {gap:.1e}", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
