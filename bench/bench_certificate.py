"""Benchmark: optimality certificates (lower bounds) of fms_kr16 designs and their efficiencies.

Run from the repository root:

    .venv/bin/python bench/bench_certificate.py [--poses 60] [--pool 3000] [--seed 0]
        [--criteria kpi] [--no-sqp] [--sqp-time 300]

For each criterion: the heuristic design (random feasible poses, seed 0), the
exchange algorithm's best design of the pool, and (unless ``--no-sqp``) the
SQP design from the exchange start, each certified against the same random
feasible pool (:func:`calib_oed.oed.certificate.certify`, defaults: tol 1e-4,
local_tol 1e-3, 32 local starts, 128 for verification). The bound of every
certificate is printed with its time, and the efficiency bound/value.
"""

from __future__ import annotations

import argparse
import os
import platform
import shlex
import sys
import time

import numpy as np

from calib_oed.calibration.workflow import setup
from calib_oed.feasibility.sampling import sample_feasible
from calib_oed.oed.certificate import certify
from calib_oed.oed.design import design, exchange_baseline, heuristic_designs
from calib_oed.scene.reader import load_scene
from calib_oed.solver.sqp import SQPSettings


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default="fms_kr16")
    parser.add_argument("--poses", type=int, default=60)
    parser.add_argument("--pool", type=int, default=3000)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--criteria", nargs="+", default=["kpi"], choices=["kpi", "params", "D"])
    parser.add_argument("--no-sqp", action="store_true", help="skip the SQP design (about a minute)")
    parser.add_argument("--sqp-time", type=float, default=300.0, help="time limit of the SQP [s]")
    args = parser.parse_args(argv)
    print("$ " + shlex.join(getattr(sys, "orig_argv", [sys.executable] + sys.argv)))
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
          f"python {platform.python_version()}, numpy {np.__version__}")
    s = setup(load_scene(args.scene))
    t0 = time.perf_counter()
    pool = sample_feasible(s.feasibility, args.pool, args.seed, max_draws=50_000_000)
    print(f"{args.scene}: {args.pool} feasible poses (seed {args.seed}) in {time.perf_counter() - t0:.1f} s; "
          f"n = {args.poses}")
    for crit in args.criteria:
        designs = {"heuristic (seed 0)": heuristic_designs(s, args.poses, [0])[0],
                   "exchange (pool)": exchange_baseline(s, args.poses, crit, pool=pool, seed=args.seed)}
        if not args.no_sqp:
            t = time.perf_counter()
            designs["SQP, exchange start"] = design(
                s, args.poses, crit, start="exchange", pool=pool.shape[0], seed=args.seed,
                settings=SQPSettings(time_limit=args.sqp_time))
            print(f"  SQP design ({crit}): {time.perf_counter() - t:.1f} s, "
                  f"status {designs['SQP, exchange start'].solver.get('status')}")
        print(f"criterion {crit}:")
        print(f"  {'design':22s} {'value':>12s} {'bound':>12s} {'pool bound':>12s} {'efficiency':>10s} "
              f"{'gap pool':>9s} {'local max/mean':>14s} {'added':>5s} {'support':>7s} {'time [s]':>8s}")
        for label, d in designs.items():
            c = certify(s, d.q, crit, pool=pool)
            assert c.holds(), c.summary()
            print(f"  {label:22s} {c.design_value:12.5g} {c.bound:12.5g} {c.bound_pool:12.5g} "
                  f"{c.efficiency:10.1%} {c.gap_pool:9.1e} "
                  f"{c.max_sensitivity_local / c.mean_sensitivity:14.6f} {c.n_local_added:5d} "
                  f"{c.support_size:7d} {c.seconds:8.1f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
