"""Benchmark: how much of a design's distance to its certified bound is the bound's own slack.

Run from the repository root:

    OPENBLAS_NUM_THREADS=1 .venv/bin/python bench/bench_certificate_slack.py [--scene fms_kr16]
        [--poses 60] [--replicates 1,3] [--starts 64] [--rounds 60]
        [--feasibility link_fit=single,joint_window=full]

For each K of ``--replicates`` the default design (``design(s, n, "kpi",
replicates=K)``, pool 3000, seed 0) with its certificate; then a much longer
column generation on the same pool (``--starts`` local maximisations of the
sensitivity per round, up to ``--rounds`` rounds; the default pipeline uses 16
and 10, the certificate continues with 16 and a 64-start verification). It
prints, all scaled to n measurements [mm²]:

- the default certificate's bound and each design's efficiency against it;
- the long search's approximate optimum :math:`\\Phi(M(w))/n` and its bound
  :math:`\\Phi/((1+\\rho)n)`: a lower bound found by a longer search is the
  honest reference; if it is lower than the default bound, the default bound
  was too high by that much (its search missed maxima);
- the approximate optimum rounded to n by efficient apportionment
  (Pukelsheim & Rieder 1992) with at most K per pose, without refinement:
  the rounding loss alone.

The gap between a design and the long search's approximate optimum is the
integrality (n measurements) gap plus the local optimum the SQP ends in; the
gap between the approximate optimum and its bound is the bound's slack.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
from bench_design_pipeline import (
    with_feasibility,  # this folder is on sys.path when run as a script
)
from threadpoolctl import threadpool_limits

from calib_oed.calibration.workflow import setup
from calib_oed.oed.approximate_pool import approximate_pool
from calib_oed.oed.design import design
from calib_oed.oed.objective import DesignObjective
from calib_oed.oed.rounding import efficient_rounding
from calib_oed.oed.starts import candidate_pool
from calib_oed.scene.reader import load_scene


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scene", default="fms_kr16")
    ap.add_argument("--poses", type=int, default=60)
    ap.add_argument("--replicates", default="1,3")
    ap.add_argument("--starts", type=int, default=64)
    ap.add_argument("--rounds", type=int, default=60)
    ap.add_argument("--feasibility", default="",
                    help="override scene feasibility keys, e.g. link_fit=single,joint_window=full")
    args = ap.parse_args(argv)
    n = args.poses
    overrides = dict(kv.split("=", 1) for kv in args.feasibility.split(",") if kv)
    with tempfile.TemporaryDirectory() as tmp:  # the scene is read before the folder goes
        scene = with_feasibility(args.scene, overrides, Path(tmp)) if overrides else args.scene
        s = setup(load_scene(scene))
    objective = DesignObjective(s.problem, "kpi")
    designs = {}
    for k in [int(x) for x in args.replicates.split(",") if x]:
        t = time.process_time()
        d = design(s, n, "kpi", replicates=k)
        designs[k] = d
        print(f"default design K={k}: {d.value:.5e} mm², {len(d.multiplicity)} distinct, "
              f"bound {d.certificate['lower_bound']:.5e}, efficiency {d.efficiency:.2%}, "
              f"{d.solver['status']}, {time.process_time() - t:.1f} s CPU", flush=True)
    pool = candidate_pool(s, 3000, 0)
    t = time.process_time()
    with threadpool_limits(limits=1, user_api="blas"):
        long = approximate_pool(s, objective, pool.q, starts=args.starts, rounds=args.rounds)
    a = long.approx
    rho = max(max(a.max_sensitivity, long.search.d_local) / a.mean_sensitivity - 1.0, 0.0)
    value, bound = a.value / n, a.value / ((1.0 + rho) * n)
    print(f"long search ({args.starts} starts x {long.search.rounds} rounds, {long.n_added} maxima, "
          f"{time.process_time() - t:.1f} s CPU): approximate optimum {value:.5e}, rho {rho:.2e}, "
          f"bound {bound:.5e}", flush=True)
    sup = a.support
    for k, d in designs.items():
        counts = efficient_rounding(a.weights[sup], n, k) if sup.size * k >= n else None
        rounded = ("-" if counts is None else
                   f"{objective.compute_value(np.repeat(long.q[sup], counts, axis=0)):.5e}")
        print(f"K={k}: design {d.value:.5e}; against the long bound {bound / d.value:.2%}, against "
              f"the approximate optimum {value / d.value:.2%}; default bound / long bound "
              f"{d.certificate['lower_bound'] / bound:.4f}; approximate optimum rounded to n "
              f"(no refinement) {rounded}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
