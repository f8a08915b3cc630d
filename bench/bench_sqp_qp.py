"""Benchmark: the SQP's QP subproblem on ProxQP's dense and sparse backends.

Run from the repository root:

    .venv/bin/python bench/bench_sqp_qp.py [--n 360] [--rows 400] [--qps 10] [--repeat 3] [--seed 0]

A representative subproblem of the design optimisation: n = 360 variables
(60 poses x 6 joints), a dense SPD B from a few damped-BFGS updates of the
identity, ~400 kept rows with 6 nonzeros each in the block-diagonal pattern
(each row touches the 6 joints of one pose), and a box (trust region
0.3 rad inside joint limits). Both workspaces of calib_oed.solver.qp solve the
same sequence of QPs, as consecutive SQP iterations would produce them: B
updated, g shrinking, c drifting, and a few rows swapped per iteration.

Three ways are timed side by side in one process:

* cold: a new QP object per subproblem, no warm start;
* sequence: one workspace through the sequence, warm-started with the
  previous multipliers mapped to the rows' new slots (what solve_sqp does);
* same rows: the sequence without the row swaps (the sparse backend can
  then ``update`` its object instead of rebuilding it).

The sparse/dense ratio is the result (a lone time depends on the machine).
"""

from __future__ import annotations

import argparse
import functools
import os
import platform
import shlex
import sys

import numpy as np
import scipy.sparse as sp
from _timing import timed  # bench/ is the script folder, first on sys.path

from calib_oed.solver.bfgs import damped_bfgs_update
from calib_oed.solver.proxqp_build import proxsuite
from calib_oed.solver.qp import DenseQPWorkspace, QPSubproblem, SparseQPWorkspace


def make_sequence(n, n_rows, n_qps, swap, rng):
    """``n_qps`` QPs of consecutive SQP-like iterations, with each QP's row ids."""
    poses = n // 6
    pool = 3 * n_rows  # the candidate rows; n_rows of them are kept at a time
    pose = rng.integers(0, poses, pool)
    cols = pose[:, None] * 6 + np.arange(6)[None, :]
    vals = rng.standard_normal((pool, 6)) * 0.5
    c = rng.uniform(0.0, 0.3, pool)
    B = np.eye(n)
    for _ in range(8):
        s = rng.standard_normal(n) * 0.1
        B = damped_bfgs_update(B, s, s * rng.uniform(0.3, 3.0, n))
    g = rng.standard_normal(n)
    kept = np.sort(rng.choice(pool, n_rows, replace=False))
    out = []
    for k in range(n_qps):
        if k and swap:
            out_rows = rng.choice(kept, swap, replace=False)
            new_rows = rng.choice(np.setdiff1d(np.arange(pool), kept), swap, replace=False)
            kept = np.sort(np.concatenate([np.setdiff1d(kept, out_rows), new_rows]))
        A = sp.csr_matrix((vals[kept].ravel(), cols[kept].ravel(), np.arange(0, 6 * kept.size + 1, 6)),
                          shape=(kept.size, n))
        delta = 0.3
        out.append((kept.copy(), QPSubproblem(B.copy(), g.copy(), A, -c[kept], np.full(n, -delta), np.full(n, delta))))
        s = rng.standard_normal(n) * 0.05 * 0.6**k
        B = damped_bfgs_update(B, s, s * rng.uniform(0.5, 2.0, n))
        g = g * 0.6 + 0.01 * rng.standard_normal(n)
        c = c + 0.003 * 0.6**k * rng.standard_normal(pool)
    return out, pool


def run(make_ws, sequence, pool, warm):
    """Solve the sequence with one workspace (``warm``) or one per QP; return the steps."""
    ws = make_ws()
    lam_all, nu = np.zeros(pool), None
    steps = []
    for rows, sub in sequence:
        if not warm:
            ws = make_ws()
            step = ws.solve(sub)
        else:
            step = ws.solve(sub, None, lam_all[rows], nu)
            lam_all = np.zeros(pool)
            lam_all[rows] = step.lam
            nu = step.nu
        steps.append(step)
    return steps


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=360)
    parser.add_argument("--rows", type=int, default=400)
    parser.add_argument("--qps", type=int, default=10, help="QPs per sequence")
    parser.add_argument("--swap", type=int, default=8, help="rows swapped per iteration")
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--eps", type=float, default=1e-9)
    args = parser.parse_args(argv)
    print("$ " + shlex.join(getattr(sys, "orig_argv", [sys.executable] + sys.argv)))
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
          f"python {platform.python_version()}, numpy {np.__version__}, proxsuite "
          f"{getattr(proxsuite, '__version__', '?')}, "
          f"OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS', 'unset')}")
    print(f"n = {args.n}, {args.rows} rows x 6 nonzeros, box 0.3, eps_abs {args.eps:g}, "
          f"{args.qps} QPs per sequence, best of {args.repeat}")
    backends = {
        "dense": lambda: DenseQPWorkspace(args.n, args.eps, 1000),
        "sparse": lambda: SparseQPWorkspace(args.n, args.eps, 1000),
    }
    print()
    print("| scenario | dense [ms/QP] | sparse [ms/QP] | sparse / dense | dense iters | sparse iters | max |d_dense - d_sparse| |")
    print("|---|---|---|---|---|---|---|")
    for label, swap, warm in (("cold", args.swap, False), ("sequence", args.swap, True),
                              ("same rows", 0, True)):
        sequence, pool = make_sequence(args.n, args.rows, args.qps, swap, np.random.default_rng(args.seed))
        times, steps = {}, {}
        for name, make_ws in backends.items():
            t, st = timed(functools.partial(run, make_ws, sequence, pool, warm), args.repeat, 1)
            times[name], steps[name] = t / len(sequence), st
            bad = [s.status for s in st if s.status != "solved"]
            if bad:
                print(f"  warning: {name} {label}: statuses {bad}")
        diff = max(float(np.abs(a.d - b.d).max()) for a, b in zip(steps["dense"], steps["sparse"], strict=True))
        its = {k: sum(s.iterations for s in v) / len(v) for k, v in steps.items()}
        print(f"| {label} | {times['dense'] * 1e3:.1f} | {times['sparse'] * 1e3:.1f} | "
              f"{times['sparse'] / times['dense']:.1f}x | {its['dense']:.0f} | {its['sparse']:.0f} | {diff:.1e} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
