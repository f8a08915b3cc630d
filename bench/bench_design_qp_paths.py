"""Benchmark: the design SQP's QP on the lifted and on the block path, and the shares of polish and corrections.

Run from the repository root:

    .venv/bin/python bench/bench_design_qp_paths.py [--poses 30,60,120] [--criterion kpi]
        [--min-sizes default,100000] [--repeats 2]

Each case is one ``calib-oed design fms_kr16 -n N --no-certificate`` process
(``PYTHONPATH`` chooses the checkout) with ``SQPSettings.block_qp_min_size``
replaced in every SQP (``default``: left as it is; ``100000``: the lifted QP at
any n; ``1``: the block QP for every structured Hessian). The cases of one n
alternate (A B A B ...), so their ratios hold on a shared machine. Timed in
process CPU (``time.process_time``) inside the child, only for the SQPs of the
design's own size (6 n variables: for ``kpi_model`` its ``kpi`` start's SQP and its own;
the column generation's SQPs are left out):
the whole SQP, the QP solves (:meth:`calib_oed.solver.subproblem.QPSolver.solve`,
the block QP's own polish included), the dense polish of the other paths
(:func:`calib_oed.solver.polish.polish`) and the second-order corrections (their
QP and trial point); and the number of least-squares fallbacks of the polish
(all SQPs). ``--criterion ''`` is the
default criterion (``kpi_model``). Results: docs/benchmarks.md.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

_CHILD = """
import collections, dataclasses, json, sys, time
size, out = sys.argv.pop(1), sys.argv.pop(1)
import scipy.linalg
import calib_oed.solver.sqp as sqp
import calib_oed.oed.refine as refine
import calib_oed.solver.subproblem as sub
t = collections.defaultdict(float)
def add(key, n, dt, count=1):
    t[f"{n}:{key}_s"] += dt
    t[f"{n}:{key}"] += count
def timer(key, size_of):
    def wrap(fn):
        def timed(*a, **k):
            t0 = time.process_time()
            try:
                return fn(*a, **k)
            finally:
                add(key, size_of(*a), time.process_time() - t0)
        return timed
    return wrap
init = sub.QPSolver.__init__
def new_init(self, n, settings):
    init(self, n, settings if size == "default" else dataclasses.replace(settings, block_qp_min_size=int(size)))
sub.QPSolver.__init__ = new_init
sub.QPSolver.solve = timer("qp", lambda self, *a: self.n)(sub.QPSolver.solve)
sub.polish = timer("polish", lambda s, *a: s.g.size)(sub.polish)
sub._SubproblemMixin._second_order_correction = timer("soc", lambda self, *a: self.pt.x.size)(
    sub._SubproblemMixin._second_order_correction)
lstsq = scipy.linalg.lstsq
def counted(*a, **k):
    t["lstsq"] += 1
    return lstsq(*a, **k)
scipy.linalg.lstsq = counted
solve_sqp = sqp.solve_sqp
def timed_sqp(*a, **k):
    t0 = time.process_time()
    res = solve_sqp(*a, **k)
    add("sqp", res.x.size, time.process_time() - t0, res.iterations)
    used = {r.qp_backend for r in res.history if r.qp_backend}
    t[f"{res.x.size}:backends"] = sorted(used.union(t.get(f"{res.x.size}:backends", [])))
    return res
refine.solve_sqp = timed_sqp
from calib_oed.cli import main
code = main(sys.argv[1:])
json.dump(t, open(out, "w"))
sys.exit(code)
"""


def run_case(n: int, size: str, criterion: str) -> dict:
    """One design process with ``block_qp_min_size`` = ``size``: its record's figures and the child's timers."""
    with tempfile.TemporaryDirectory() as tmp:
        argv = [sys.executable, "-c", _CHILD, size, str(Path(tmp) / "t.json"), "design", "fms_kr16", "-n", str(n),
                "-o", str(Path(tmp) / "d"), "--json", "--quiet", "--no-certificate"]
        if criterion:
            argv += ["--criterion", criterion]
        env = dict(os.environ, OPENBLAS_NUM_THREADS="1")
        proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env, cwd=tmp)
        out, err = proc.communicate()
        if proc.returncode != 0:
            raise SystemExit(f"n = {n}, size {size}: {err.decode().strip().splitlines()[-1:]}")
        record, timers = json.loads(out), json.loads((Path(tmp) / "t.json").read_text())
    v = 6 * n
    get = lambda key: timers.get(f"{v}:{key}", 0.0)  # noqa: E731
    it = max(get("sqp"), 1)  # every SQP of 6 n variables (kpi_model: its kpi start's too)
    return {"n": n, "min_size": size, "status": record["solver"]["status"], "iterations": record["solver"]["iterations"],
            "sqp_iterations": int(get("sqp")),
            "value": record["value"], "backends": ",".join(timers.get(f"{v}:backends", [])),
            "sqp_cpu_s": get("sqp_s"), "qp_cpu_s": get("qp_s"), "qps": get("qp"), "polish_cpu_s": get("polish_s"),
            "soc_cpu_s": get("soc_s"), "socs": get("soc"), "qp_per_it_s": (get("qp_s") + get("polish_s")) / it,
            "lstsq_calls": timers.get("lstsq", 0.0)}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--poses", default="30,60,120")
    ap.add_argument("--criterion", default="kpi", help="'' for the default criterion (kpi_model)")
    ap.add_argument("--min-sizes", default="default,100000", help="block_qp_min_size of each case, alternated")
    ap.add_argument("--repeats", type=int, default=2)
    args = ap.parse_args(argv)
    rows = []
    for n in [int(k) for k in args.poses.split(",") if k]:
        for _ in range(args.repeats):
            for size in [s for s in args.min_sizes.split(",") if s]:
                rows.append(run_case(n, size, args.criterion))
                print(json.dumps(rows[-1]), flush=True)
    print(f"\n{'n':>4s} {'min size':>8s} {'QP':>12s} {'status':>14s} {'it':>4s} {'SQP it':>6s} {'value':>12s} {'SQP cpu':>8s} "
          f"{'QP+polish/it':>12s} {'QPs':>4s} {'polish':>7s} {'SOC cpu':>7s} {'SOCs':>4s} {'lstsq':>5s}")
    for r in rows:
        print(f"{r['n']:4d} {r['min_size']:>8s} {r['backends']:>12s} {r['status']:>14s} {r['iterations']:4d} "
              f"{r['sqp_iterations']:6d} "
              f"{r['value']:12.6e} {r['sqp_cpu_s']:8.2f} {r['qp_per_it_s']:12.3f} {r['qps']:4.0f} "
              f"{r['polish_cpu_s']:7.2f} {r['soc_cpu_s']:7.2f} {r['socs']:4.0f} {r['lstsq_calls']:5.0f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
