"""Benchmark: exchange algorithm, rank-d (Woodbury) updates against batched recomputation.

Run from the repository root:

    .venv/bin/python bench/bench_exchange.py [--candidates 3000] [--poses 60] [--params 25] [--seed 0]

Random seeded candidate blocks F_c (N, d = 3, n_p) and a random KPI
Jacobian G (3, n_p) give the KPI A-criterion tr(G C G^T)/3. Both paths start
from the same seeded design and make the same swaps (the chosen swap is
confirmed by an exact value either way), so they end at the same design; the
wall-time ratio is the result.
"""

from __future__ import annotations

import argparse
import os
import platform
import shlex
import sys

import numpy as np

from calib_oed.oed.criteria import ACriterion
from calib_oed.oed.exchange import exchange_design


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--candidates", type=int, default=3000)
    parser.add_argument("--poses", type=int, default=60)
    parser.add_argument("--params", type=int, default=25)
    parser.add_argument("--rows", type=int, default=3, help="rows d per pose (3 for a laser tracker)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--max-sweeps", type=int, default=100)
    args = parser.parse_args(argv)
    print("$ " + shlex.join(getattr(sys, "orig_argv", [sys.executable] + sys.argv)))
    rng = np.random.default_rng(args.seed)
    blocks = rng.standard_normal((args.candidates, args.rows, args.params))
    criterion = ACriterion.kpi(rng.standard_normal((3, args.params)))
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
          f"python {platform.python_version()}, numpy {np.__version__}, "
          f"OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS', 'unset')}")
    print(f"N = {args.candidates} candidates, d = {args.rows}, n_p = {args.params}, n = {args.poses} poses, "
          f"criterion {criterion.name!r} ({criterion.label}), seed {args.seed}")
    results = {}
    for method in ("rank", "generic"):
        res = exchange_design(blocks, args.poses, criterion, rng=args.seed, method=method,
                              max_sweeps=args.max_sweeps)
        results[method] = res
        print(f"  {method:8s}: {res.time:7.2f} s, {res.n_sweeps} sweeps ({res.time / res.n_sweeps:.3f} s per sweep), "
              f"{res.n_exchanges} swaps, converged {res.converged}, "
              f"value {res.initial_value:.6g} -> {res.value:.10g} mm^2")
    fast, slow = results["rank"], results["generic"]
    same = np.array_equal(fast.indices, slow.indices)
    print(f"  speed-up rank-update / generic: {slow.time / fast.time:.1f}x; identical designs: {same}; "
          f"relative value difference {abs(fast.value - slow.value) / abs(slow.value):.1e}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
