"""The default (``kpi_model``) design's SQP iteration cost against n, in process CPU.

    nice -n 10 python bench/bench_model_error_growth.py [--scene fms_kr16] [--growth 60,120,250,500]
        [--seed 0] [--iterations K] [--full-coupling SIZE]

Each n runs in its own process (one BLAS thread), as ``calib-oed design SCENE -n N --no-certificate``
does: :func:`calib_oed.oed.design.design` with the default criterion. In the child the SQP's phase
clock (``time.perf_counter``) is the process CPU clock, so its phases (objective, constraints, exact
Hessian, QP) are CPU seconds, comparable side by side on a shared machine. Reports per n the SQP
status and iterations, the value [mm²], the process CPU and peak memory, the SQP's phases and its
CPU per iteration. ``PYTHONPATH=/other/checkout`` runs that checkout's package. ``--iterations``
sets the design's SQP iterations at every n (instead of :func:`calib_oed.oed.model_error.exact_iterations`),
``--full-coupling`` the largest Hessian given to the SQP whole
(:data:`calib_oed.oed.model_error_hessian.FULL_COUPLING_MAX_SIZE`; 0: always the lifted form).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile

_CHILD = """
import json, resource, sys, time
time.perf_counter = time.process_time  # the SQP's phases in CPU seconds
import calib_oed.oed.model_error as me
import calib_oed.oed.model_error_hessian as meh
from calib_oed import load_scene
from calib_oed.calibration.workflow import setup
from calib_oed.oed.design import design
scene, n, seed, cap, full = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4]), int(sys.argv[5])
if cap > 0:
    me.MODEL_ERROR_EXACT_ITERATIONS = me.MODEL_ERROR_MIN_ITERATIONS = me.MODEL_ERROR_ITERATIONS = cap
if full >= 0:
    meh.FULL_COUPLING_MAX_SIZE = full
d = design(setup(load_scene(scene)), n, None, seed=seed, certificate=False)
sol, it = d.solver, d.solver.get("iterations") or 0
times = {k: round(v, 2) for k, v in (sol.get("times") or {}).items()}
print(json.dumps({"scene": scene, "n": n, "full_coupling_max_size": meh.FULL_COUPLING_MAX_SIZE, "status": str(sol.get("status")), "iterations": it,
                  "value_mm2": d.value, "process_cpu_s": round(time.process_time(), 1),
                  "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss // 1024,
                  "sqp_cpu_s": times, "sqp_cpu_per_iteration_s": round(times.get("total", 0.0) / max(it, 1), 3)}))
"""


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", default="fms_kr16")
    ap.add_argument("--growth", default="60,120,250,500", help="comma-separated numbers of poses")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--iterations", type=int, default=0, help="SQP iteration cap (default: the design's)")
    ap.add_argument("--full-coupling", type=int, default=-1, metavar="SIZE",
                    help="largest Hessian the SQP gets whole (default: the package's; 0: always lifted)")
    args = ap.parse_args(argv)
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1")
    if env.get("PYTHONPATH"):  # absolute: the child runs elsewhere
        env["PYTHONPATH"] = os.pathsep.join(os.path.abspath(p) for p in env["PYTHONPATH"].split(os.pathsep))
    for n in (int(v) for v in args.growth.split(",") if v):
        # cwd: ``-c`` puts the working directory first on sys.path, which would shadow PYTHONPATH
        out = subprocess.run([sys.executable, "-c", _CHILD, args.scene, str(n), str(args.seed), str(args.iterations),
                              str(args.full_coupling)],
                             env=env, capture_output=True, text=True, check=True, cwd=tempfile.gettempdir())
        print(json.dumps(json.loads(out.stdout.strip().splitlines()[-1])), flush=True)


if __name__ == "__main__":
    main()
