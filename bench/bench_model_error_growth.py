"""The default (``kpi_model``) design's SQP iteration cost against n, in process CPU.

    nice -n 10 python bench/bench_model_error_growth.py [--scene fms_kr16] [--growth 60,120,250,500]
        [--seed 0] [--iterations K] [--full-coupling SIZE] [--coupling-rank R]
        [--doubled FILE [--perturb SIGMA]] [--staged-min N] [--staged-iterations K]
        [--criterion kpi_model|kpi_kriging] [--hessian exact|bfgs] [--hessian-lag K]

Each n runs in its own process (one BLAS thread), as ``calib-oed design SCENE -n N --no-certificate``
does: :func:`calib_oed.oed.design.design` with the default criterion. In the child the SQP's phase
clock (``time.perf_counter``) is the process CPU clock, so its phases (objective, constraints, exact
Hessian, QP) are CPU seconds, comparable side by side on a shared machine. Reports per n the SQP
status and iterations, the value [mm²], the process CPU and peak memory, the SQP's phases and its
CPU per iteration, its trace (SQP CPU and objective after each iteration; with the staged start
every stage's, each from 0), and beside the peak the package's memory estimate
(:func:`calib_oed.oed.memory.estimate_memory`, the arrays alone, without the process's own).
``PYTHONPATH=/other/checkout`` runs that checkout's package. ``--iterations``
sets the design's SQP iterations at every n (instead of :func:`calib_oed.oed.model_error.exact_iterations`;
with the staged start those of its smaller designs, the last stage keeps ``--staged-iterations``),
``--full-coupling`` the largest Hessian given to the SQP whole
(:data:`calib_oed.oed.model_error_hessian.FULL_COUPLING_MAX_SIZE`; 0: always the lifted form),
``--coupling-rank`` caps the columns of the lifted form's low-rank factor (by a monkeypatch of
:func:`calib_oed.oed.model_error_hessian.structured_hessian` in the child; the package keeps
:data:`~calib_oed.solver.hessian.LIFTED_MAX_RANK_RATIO` of the size). ``--doubled FILE`` starts the SQP
from a smaller design measured twice (FILE: the ``--json`` output of ``calib-oed design`` on the
same scene; ``--growth`` then defaults to twice its poses): its poses, then the same poses plus
seeded normal offsets of ``--perturb`` rad (default 0: exact copies), clipped to the joint limits,
the first n of them; given as the design's start, so no pool, column generation or exchange.
``--staged-min N`` sets the fewest poses of the package's staged start
(:data:`calib_oed.oed.staged.STAGED_MIN_POSES`; a number above n: the direct design),
``--staged-iterations K`` its final stage's iterations (:data:`~calib_oed.oed.staged.STAGED_ITERATIONS`).
``--criterion`` designs another model-error criterion than the default, ``--hessian bfgs`` with damped
BFGS instead of the exact Hessian (neither is staged). ``--hessian-lag K`` computes the exact Hessian
(and its eigendecomposition) at every K-th accepted point only and gives the QPs of the points between
the last one computed (``SQPSettings.hessian_every = K`` in every design SQP of the child, by a
monkeypatch of :func:`calib_oed.oed.refine.sqp_settings`; the package's default is 1, every point).
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
import numpy as np
time.perf_counter = time.process_time  # the SQP's phases in CPU seconds
import calib_oed.oed.model_error as me
import calib_oed.oed.model_error_hessian as meh
import calib_oed.oed.staged as staged
from calib_oed import load_scene
from calib_oed.calibration.workflow import setup
from calib_oed.oed.design import design
from calib_oed.oed.memory import estimate_memory
scene, n, seed, cap, full, rank = (sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4]),
                                    int(sys.argv[5]), int(sys.argv[6]))
doubled, perturb, staged_min, staged_its = sys.argv[7], float(sys.argv[8]), int(sys.argv[9]), int(sys.argv[10])
criterion, hessian, lag = sys.argv[11] or None, sys.argv[12], int(sys.argv[13])
if lag > 1:  # the exact Hessian of every lag-th accepted point (SQPSettings.hessian_every)
    import dataclasses
    import calib_oed.oed.refine as refine
    settings_of = refine.sqp_settings
    refine.sqp_settings = lambda settings, exact: dataclasses.replace(settings_of(settings, exact), hessian_every=lag)
staged.STAGED_MIN_POSES = staged_min or staged.STAGED_MIN_POSES
staged.STAGED_ITERATIONS = staged_its or staged.STAGED_ITERATIONS
if cap > 0:
    me.MODEL_ERROR_EXACT_ITERATIONS = me.MODEL_ERROR_MIN_ITERATIONS = me.MODEL_ERROR_ITERATIONS = cap
if full >= 0:
    meh.FULL_COUPLING_MAX_SIZE = full
if rank > 0:
    lifted = meh.structured_hessian
    meh.structured_hessian = lambda h, nv, r=None: lifted(h, nv, r if r is None else min(r, rank))
s = setup(load_scene(scene))
start = "exchange"
if doubled:
    with open(doubled) as f:
        q = np.asarray(json.load(f)["configurations_rad"], dtype=float)
    model = s.problem.robot.model
    copy = q + perturb * np.random.default_rng(seed).standard_normal(q.shape)
    start = np.vstack([q, np.clip(copy, model.lowerPositionLimit, model.upperPositionLimit)])[:n]
trace = []  # (SQP CPU [s], objective) after each iteration
d = design(s, n, criterion, start=start, seed=seed, certificate=False, hessian=hessian,
           callback=lambda r: trace.append((round(r.time, 2), r.objective)))
sol, it = d.solver, d.solver.get("iterations") or 0
times = {k: round(v, 2) for k, v in (sol.get("times") or {}).items()}
print(json.dumps({"scene": scene, "n": n, "full_coupling_max_size": meh.FULL_COUPLING_MAX_SIZE,
                  "coupling_rank_cap": rank or None, "doubled": doubled or None, "perturb_rad": perturb,
                  "staged": sol.get("staged"), "start_value_mm2": d.start_value, "status": str(sol.get("status")), "iterations": it,
                  "value_mm2": d.value, "process_cpu_s": round(time.process_time(), 1),
                  "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss // 1024,
                  "memory_estimate_mb": round(estimate_memory(n, s.problem.robot.nq, len(s.feasibility.labels),
                                                              dense=sol.get("hessian") != "exact",
                                                              coupled=True) / 2**20),
                  "criterion": d.criterion, "hessian": sol.get("hessian"), "hessian_lag": max(lag, 1),
                  "sqp_cpu_s": times, "sqp_cpu_per_iteration_s": round(times.get("total", 0.0) / max(it, 1), 3),
                  "trace": trace}))
"""


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", default="fms_kr16")
    ap.add_argument("--growth", default="60,120,250,500", help="comma-separated numbers of poses")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--iterations", type=int, default=0, help="SQP iteration cap (default: the design's)")
    ap.add_argument("--full-coupling", type=int, default=-1, metavar="SIZE",
                    help="largest Hessian the SQP gets whole (default: the package's; 0: always lifted)")
    ap.add_argument("--coupling-rank", type=int, default=0, metavar="R",
                    help="cap the lifted form's low-rank columns at R (default: the package's n/3)")
    ap.add_argument("--doubled", default="", metavar="FILE",
                    help="start from this design (calib-oed design --json) measured twice")
    ap.add_argument("--perturb", type=float, default=0.0, metavar="SIGMA",
                    help="seeded normal offsets [rad] of the second copy (with --doubled)")
    ap.add_argument("--staged-min", type=int, default=0, metavar="N",
                    help="fewest poses of the staged start (default: the package's; above n: the direct design)")
    ap.add_argument("--staged-iterations", type=int, default=0, metavar="K",
                    help="SQP iterations of the staged design's final stage (default: the package's)")
    ap.add_argument("--criterion", choices=("kpi_model", "kpi_kriging"), default="",
                    help="the design criterion (default: the scene's default, kpi_model)")
    ap.add_argument("--hessian", choices=("exact", "bfgs"), default="exact",
                    help="the design SQP's Hessian (bfgs: damped BFGS)")
    ap.add_argument("--hessian-lag", type=int, default=1, metavar="K",
                    help="the exact Hessian at every K-th accepted point, reused between (default 1: every point)")
    args = ap.parse_args(argv)
    doubled = os.path.abspath(args.doubled) if args.doubled else ""
    if doubled:
        with open(doubled) as f:
            poses = len(json.load(f)["configurations_rad"])
        if args.growth == ap.get_default("growth"):
            args.growth = str(2 * poses)
        if any(int(v) > 2 * poses for v in args.growth.split(",") if v):
            ap.error(f"--doubled: {args.doubled} has {poses} poses, twice that is below --growth {args.growth}")
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1")
    if env.get("PYTHONPATH"):  # absolute: the child runs elsewhere
        env["PYTHONPATH"] = os.pathsep.join(os.path.abspath(p) for p in env["PYTHONPATH"].split(os.pathsep))
    for n in (int(v) for v in args.growth.split(",") if v):
        # cwd: ``-c`` puts the working directory first on sys.path, which would shadow PYTHONPATH
        out = subprocess.run([sys.executable, "-c", _CHILD, args.scene, str(n), str(args.seed), str(args.iterations),
                              str(args.full_coupling), str(args.coupling_rank), doubled, str(args.perturb),
                              str(args.staged_min), str(args.staged_iterations), args.criterion, args.hessian,
                              str(args.hessian_lag)],
                             env=env, capture_output=True, text=True, check=True, cwd=tempfile.gettempdir())
        print(json.dumps(json.loads(out.stdout.strip().splitlines()[-1])), flush=True)


if __name__ == "__main__":
    main()
