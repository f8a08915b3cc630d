"""Benchmark: the projection onto the feasible set of a large design, pose blocks against one block.

    OPENBLAS_NUM_THREADS=1 PYTHONPATH=<checkout> .venv/bin/python bench/bench_projection.py [--n 500]
        [--scale 0.03] [--seed 0]

``fms_kr16``, ``kpi``: a feasible design of ``--n`` poses (``sample_feasible``, seed ``--seed``)
pushed off the feasible set by Gaussian angles of standard deviation ``--scale`` rad (seeded), as
a design SQP that stops at its iteration limit leaves it. Then, in this process, one after the
other, :func:`calib_oed.oed.refine.project_feasible`'s SQP (min ||y - x||² / 2 on the design
constraints, its settings ``PROJECTION_SQP``) with its BFGS matrix one block per pose (``block_size = nq``: the block
QP above ``max_dense_qp_size``) and with one dense block (ProxQP, sparse above that size). Prints per
run the process CPU, status, iterations, QP backends, largest violation [1] and distance ||y - x||
[rad], and the largest difference between the two ends [rad].
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from threadpoolctl import threadpool_limits

from calib_oed.calibration.workflow import setup
from calib_oed.feasibility.sampling import sample_feasible
from calib_oed.oed.objective import DesignObjective
from calib_oed.oed.problem import DesignProblem
from calib_oed.oed.refine import PROJECTION_SQP
from calib_oed.scene.reader import load_scene
from calib_oed.solver.sqp import solve_sqp


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=500)
    ap.add_argument("--scale", type=float, default=0.03, help="standard deviation of the push [rad]")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    s = setup(load_scene("fms_kr16"))
    with threadpool_limits(limits=1):
        q = sample_feasible(s.feasibility, args.n, args.seed)
        nlp = DesignProblem(DesignObjective(s.problem, "kpi"), s.feasibility, args.n)
        x = q.ravel() + args.scale * np.random.default_rng(args.seed).standard_normal(q.size)
        print(f"n = {args.n} ({x.size} variables): violation of the pushed design {nlp.max_violation(x):.3g}")
        ends = {}
        for label, block in (("pose blocks", nlp.nq), ("one block", None)):
            c0 = time.process_time()
            res = solve_sqp(lambda y: (0.5 * float((y - x) @ (y - x)), y - x), x,
                            constraints=nlp.compute_constraints, bounds=nlp.bounds, settings=PROJECTION_SQP,
                            block_size=block)
            cpu = time.process_time() - c0
            backends = sorted({r.qp_backend for r in res.history if r.qp_backend})
            ends[label] = res.x
            print(f"  {label:11s}: {cpu:7.2f} s CPU, {res.status.name}, {res.iterations} iterations, QP "
                  f"{'/'.join(backends)}, violation {nlp.max_violation(res.x):.2e}, "
                  f"distance {np.linalg.norm(res.x - x):.6f} rad")
        print(f"  largest difference of the two ends: {np.abs(ends['pose blocks'] - ends['one block']).max():.2e} rad")


if __name__ == "__main__":
    main()
