"""Benchmark: how much of the off-pool column generation the design's start needs.

Run from the repository root:

    OPENBLAS_NUM_THREADS=1 .venv/bin/python bench/bench_approximate_start.py
        [--scenes fms_kr16,fms_kr500] [--grid 0:0,8:5,8:30,16:10,32:8,16:20,16:10:12] [--replicates 1,3]
        [--feasibility link_fit=single,joint_window=full]
        [--local-hessian exact,bfgs] [--seeds 0]

For each scene and pool seed of ``--seeds`` (pool 3000, 60 poses, KPI), each
curvature of the local maximisations of ``--local-hessian`` (``bfgs``, the
design start's default, or ``exact``, the certificate's) and each ``starts:rounds[:iterations]`` of ``--grid``: the column generation (:func:`calib_oed.oed.approximate_pool.approximate_pool`
with that many local maximisations per round and rounds, each maximisation's SQP stopped after
``iterations``, default 80 as the design's; ``0:0`` is the
approximate design on the pool alone), its approximate value scaled to n
[mm²], then for each K of ``--replicates`` the start (rounded approximate
design, exchange on the enriched candidates repeated K times) refined by the
default SQP: the start's and the final value, the SQP's status and
iterations, and the CPU seconds of each step (``time.process_time``). The
default pipeline uses 16:10. Results: docs/benchmarks.md.
"""

from __future__ import annotations

import argparse
import itertools
import tempfile
import time
from pathlib import Path

from bench_design_pipeline import with_feasibility  # this folder is on sys.path as a script
from threadpoolctl import threadpool_limits

from calib_oed.calibration.workflow import setup
from calib_oed.oed.approximate_pool import START_LOCAL_HESSIAN, approximate_pool, approximate_start
from calib_oed.oed.objective import DesignObjective
from calib_oed.oed.refine import optimise_from
from calib_oed.oed.starts import candidate_pool, multiplicities
from calib_oed.scene.reader import load_scene


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenes", default="fms_kr16,fms_kr500")
    ap.add_argument("--grid", default="0:0,8:5,8:30,16:10,32:8,16:20")
    ap.add_argument("--replicates", default="1,3")
    ap.add_argument("--poses", type=int, default=60)
    ap.add_argument("--local-hessian", default=START_LOCAL_HESSIAN,
                    help=f"exact, bfgs or both: exact,bfgs (default {START_LOCAL_HESSIAN}, the design's start)")
    ap.add_argument("--seeds", default="0", help="pool seeds, e.g. 0,1,2")
    ap.add_argument("--feasibility", default="",
                    help="override scene feasibility keys, e.g. link_fit=single,joint_window=full")
    args = ap.parse_args(argv)
    n = args.poses
    overrides = dict(kv.split("=", 1) for kv in args.feasibility.split(",") if kv)
    tmp = tempfile.TemporaryDirectory()
    grid = [(tuple(int(x) for x in g.split(":")) + (80,))[:3] for g in args.grid.split(",") if g]
    reps = [int(k) for k in args.replicates.split(",") if k]
    curvatures = [c for c in args.local_hessian.split(",") if c]
    seeds = [int(x) for x in args.seeds.split(",") if x]
    print(f"{'scene':10s} {'seed':>4s} {'hessian':>7s} {'starts:rounds':>13s} {'maxima':>6s} {'approx/n':>11s} {'cpu':>5s} {'K':>2s} "
          f"{'start':>11s} {'final':>11s} {'status':>15s} {'it':>4s} {'distinct':>8s} {'sqp cpu':>7s}")
    for scene in args.scenes.split(","):
        s = setup(load_scene(with_feasibility(scene, overrides, Path(tmp.name)) if overrides else scene))
        objective = DesignObjective(s.problem, "kpi")
        pools = {seed: candidate_pool(s, 3000, seed) for seed in seeds}
        for seed, curvature, (starts, rounds, its) in itertools.product(seeds, curvatures, grid):
            pool = pools[seed]
            with threadpool_limits(limits=1, user_api="blas"):
                t = time.process_time()
                enriched = approximate_pool(s, objective, pool.q, starts=starts, rounds=rounds,
                                            local_iterations=its, local_hessian=curvature)
                t_approx = time.process_time() - t
                for k in reps:
                    q0, ex = approximate_start(objective, enriched, n, None, k)
                    t = time.process_time()
                    value, q, _, res = optimise_from(objective, s.feasibility, q0)
                    print(f"{scene:10s} {seed:4d} {curvature:>7s} {f'{starts}:{rounds}:{its}':>13s} {enriched.n_added:6d} "
                          f"{enriched.approx.value / n:11.5e} {t_approx:5.1f} {k:2d} {ex.value:11.5e} "
                          f"{value:11.5e} {res.status.value:>15s} {res.iterations:4d} "
                          f"{len(multiplicities(q)):8d} {time.process_time() - t:7.1f}", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
