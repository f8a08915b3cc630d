"""Benchmark: one evaluation of the n-pose design NLP, values alone against values and derivatives.

    OPENBLAS_NUM_THREADS=1 PYTHONPATH=<checkout> .venv/bin/python bench/bench_trial_points.py [--n 500]

``fms_kr16``, ``kpi``, the heuristic design of seed 0 perturbed by 1e-3 rad (seeded): process CPU
of ``DesignProblem.compute_values`` (a trial point), then of ``compute_objective`` and
``compute_constraints`` at the same point (its completion when accepted), and of the two at a
fresh point (what every trial cost before), mean of ``--repeat`` points.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from threadpoolctl import threadpool_limits

from calib_oed.calibration.workflow import setup
from calib_oed.oed.design import heuristic_designs
from calib_oed.oed.objective import DesignObjective
from calib_oed.oed.problem import DesignProblem
from calib_oed.scene.reader import load_scene


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=500)
    ap.add_argument("--repeat", type=int, default=10)
    args = ap.parse_args()
    s = setup(load_scene("fms_kr16"))
    with threadpool_limits(limits=1):
        q = heuristic_designs(s, args.n, [0])[0].q
        nlp = DesignProblem(DesignObjective(s.problem, "kpi"), s.feasibility, args.n)
        rng = np.random.default_rng(0)
        values = completion = fresh = 0.0
        for _ in range(args.repeat):
            x = q.ravel() + 1e-3 * rng.standard_normal(q.size)
            y = q.ravel() + 1e-3 * rng.standard_normal(q.size)
            c0 = time.process_time()
            nlp.compute_values(x)
            c1 = time.process_time()
            nlp.compute_objective(x), nlp.compute_constraints(x)
            c2 = time.process_time()
            nlp.compute_objective(y), nlp.compute_constraints(y)
            c3 = time.process_time()
            values, completion, fresh = values + c1 - c0, completion + c2 - c1, fresh + c3 - c2
    k = 1e3 / args.repeat
    print(f"n = {args.n}: values alone {values * k:.1f} ms, derivatives after them {completion * k:.1f} ms, "
          f"both at a fresh point {fresh * k:.1f} ms (process CPU, mean of {args.repeat})")


if __name__ == "__main__":
    main()
