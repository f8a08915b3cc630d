"""Benchmark: Monte Carlo validation on 1 worker against 2 workers (joblib), same runs.

Run from the repository root:

    .venv/bin/python bench/bench_montecarlo.py [--scene fms_kr16] [--poses 60] [--runs 1000]

The worker pool is started first (its one-off cost is printed apart), then
both settings simulate the same seeded calibrations (per-run seeds from
SeedSequence), so the results are identical and only the wall time differs;
the ratio is the result. Recorded in docs/benchmarks.md.
"""

from __future__ import annotations

import argparse
import os
import platform
import time

import numpy as np

from calib_oed.calibration.montecarlo import monte_carlo
from calib_oed.calibration.workflow import heuristic_design, setup
from calib_oed.scene.reader import load_scene


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default="fms_kr16")
    parser.add_argument("--poses", type=int, default=60)
    parser.add_argument("--runs", type=int, default=1000)
    args = parser.parse_args(argv)
    s = setup(load_scene(args.scene))
    q = heuristic_design(s, args.poses, 0)
    # joblib's worker pool starts once per process (spawn + imports); time it apart
    start = time.perf_counter()
    monte_carlo(s.problem, q, 4, 0, n_jobs=2)
    startup = time.perf_counter() - start
    times, results = {}, {}
    for jobs in (1, 2):
        start = time.perf_counter()
        results[jobs] = monte_carlo(s.problem, q, args.runs, 0, n_jobs=jobs)
        times[jobs] = time.perf_counter() - start
    same = np.array_equal(results[1].errors_after, results[2].errors_after)
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
          f"python {platform.python_version()}")
    print(f"scene {args.scene}, {args.poses} feasible poses, {args.runs} simulated calibrations")
    for jobs in (1, 2):
        print(f"  n_jobs={jobs}: {times[jobs]:6.2f} s  ({times[jobs] / args.runs * 1e3:.1f} ms per run)")
    print(f"  speed-up 2 workers / 1 worker: {times[1] / times[2]:.2f}x; identical results: {same}")
    print(f"  one-off start of the worker pool (first call in a process, 4 runs): {startup:.2f} s")
    mc = results[2]
    print(f"  ratio {mc.ratio[0]:.3f}, coverage {mc.coverage[0]:.3f}, "
          f"RMS before {mc.rms_before[0] * 1e3:.4f} mm, after {mc.rms_after[0] * 1e3:.4f} mm, "
          f"predicted sqrt(tr C_s) {mc.predicted_rms[0] * 1e3:.4f} mm")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
