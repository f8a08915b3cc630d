"""Benchmark: one QP of the design SQP's shape, the interior-point block path against ProxQP's lifted QP.

Run from the repository root:

    .venv/bin/python bench/bench_block_qp.py [--poses 60,250,500] [--rank 75] [--rows-per-pose 6]
        [--paths lifted,block,warm]

A seeded random QP per pose count b: n = 6 b variables, positive definite 6 x 6
blocks plus a coupling U U^T of ``--rank`` columns, ``--rows-per-pose`` rows on
each pose (about a third of them active at the solution) and a box of +-0.1.
Both solvers run in this process, one after the other, timed in process CPU
(``time.process_time``), so the ratio holds on a shared machine. Reported: CPU
seconds, solver iterations, the step's residuals, the largest difference of the
steps, and whether the active rows and box sides (multiplier > 1e-7) agree.
``warm`` is the block QP warm-started by the active set of its own answer's duals on
the QP with its rows moved by :math:`C e`, |e| <= 1e-6 (the shape of a
second-order correction's QP; compared with the cold block solve of that QP).
The differences are against the first path run. Results: docs/benchmarks.md.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import scipy.sparse as sp

from calib_oed.solver.block_qp import BlockQPWorkspace
from calib_oed.solver.lifted import LiftedQPWorkspace
from calib_oed.solver.qp import QPSubproblem
from calib_oed.solver.result import StructuredHessian


def instance(b: int, r: int, per_pose: int, seed: int = 0) -> QPSubproblem:
    """The seeded random QP described in the module docstring."""
    rng = np.random.default_rng(seed)
    s, n = 6, 6 * b
    g0 = rng.standard_normal((b, s, s))
    blocks = np.einsum("jab,jcb->jac", g0, g0) + 0.1 * np.eye(s)
    rows = np.repeat(np.arange(b), per_pose)
    cols = (rows[:, None] * s + np.arange(s)).ravel()
    C = sp.csr_matrix((rng.standard_normal(rows.size * s), (np.repeat(np.arange(rows.size), s), cols)),
                      shape=(rows.size, n))
    return QPSubproblem(StructuredHessian(blocks, 0.3 * rng.standard_normal((n, r))), rng.standard_normal(n),
                        C, -rng.uniform(-0.02, 0.1, rows.size), np.full(n, -0.1), np.full(n, 0.1))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--poses", default="60,250,500")
    ap.add_argument("--rank", type=int, default=75)
    ap.add_argument("--rows-per-pose", type=int, default=6)
    ap.add_argument("--paths", default="lifted,block,warm", help="of lifted, block, warm")
    args = ap.parse_args(argv)
    paths = [p for p in args.paths.split(",") if p]
    print(f"{'poses':>5s} {'path':>6s} {'cpu s':>7s} {'its':>4s} {'primal':>8s} {'dual':>8s} {'compl':>8s} "
          f"{'max|dd|':>8s} {'same active':>11s}")
    for b in [int(v) for v in args.poses.split(",") if v]:
        sub = instance(b, args.rank, args.rows_per_pose)
        shifted = sub._replace(lower=sub.lower + sub.C @ (1e-6 * np.random.default_rng(1).uniform(-1, 1, 6 * b)))
        steps = {}
        for name in paths:
            t = time.process_time()
            if name == "lifted":
                step = LiftedQPWorkspace(6 * b, 1e-9, 1000).solve(sub)
            elif name == "block":
                step = BlockQPWorkspace(6 * b, 1e-9, 100).solve(sub)
            else:  # the answer's duals on the moved QP, against its cold solve (not timed)
                answer = steps.get("block") or BlockQPWorkspace(6 * b, 1e-9, 100).solve(sub)
                t = time.process_time()
                step = BlockQPWorkspace(6 * b, 1e-9, 100).solve(shifted, None, answer.lam, answer.nu)
            cpu = time.process_time() - t
            ref = (BlockQPWorkspace(6 * b, 1e-9, 100).solve(shifted) if name == "warm"
                   else steps.get(paths[0], step))
            steps[name] = step
            same = all(np.array_equal(np.flatnonzero(np.abs(a) > 1e-7), np.flatnonzero(np.abs(c) > 1e-7))
                       for a, c in ((step.lam, ref.lam), (step.nu, ref.nu)))
            print(f"{b:5d} {name:>6s} {cpu:7.2f} {step.iterations:4d} {step.primal_residual:8.1e} "
                  f"{step.dual_residual:8.1e} {step.complementarity:8.1e} "
                  f"{np.max(np.abs(step.d - ref.d)):8.1e} {str(same):>11s}", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
