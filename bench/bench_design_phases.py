"""Benchmark: where the default design call spends its CPU, phase by phase (issue 16).

Run from the repository root (each repeat in its own process, as a user runs it):

    .venv/bin/python bench/bench_design_phases.py [--scene fms_kr16] [--poses 60] [--repeats 3]

One repeat is ``python -m calib_oed design SCENE -n N -o DIR --json`` run in a
child process with the pipeline's steps wrapped by timers (process CPU from
``time.process_time``, wall from ``time.perf_counter``): *imports* (the
``calib_oed`` package and the command line, before the command runs), *pool*
(``candidate_pool``: the feasible pool), *column generation*
(``approximate_pool``: the approximate design and the off-pool local maxima),
*exchange* (``approximate_start``: rounding and the exchange algorithm), *SQP*
(``optimise_starts``: the refinement), *certificate*, *record* (the design's
evaluation and the files). The child's whole CPU (user + system, from
``os.wait4``) is *process*. The efficiency is the design record's.

To compare with another checkout of the package side by side, run the same
command with ``PYTHONPATH=/path/to/other/checkout``: the child imports
``calib_oed`` from there (the phase names must exist in both).
Timings taken while other jobs share the cores are inflated: rerun alone.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
from pathlib import Path

#: The child: wraps the pipeline's steps (module, function) with timers and runs the CLI.
_CHILD = r"""
import json, sys, time
t_start, c_start = time.perf_counter(), time.process_time()
import calib_oed.cli as cli
import calib_oed.oed.design as design_mod
import calib_oed.cli._common as common
phases = {}

def timed(name, fn):
    def wrapper(*args, **kwargs):
        t0, c0 = time.perf_counter(), time.process_time()
        try:
            return fn(*args, **kwargs)
        finally:
            w, c = phases.get(name, (0.0, 0.0))
            phases[name] = (w + time.perf_counter() - t0, c + time.process_time() - c0)
    return wrapper

phases["imports"] = (time.perf_counter() - t_start, time.process_time() - c_start)
for name, attr in (("pool", "candidate_pool"), ("column generation", "approximate_pool"),
                   ("exchange", "approximate_start"), ("SQP", "optimise_starts"),
                   ("certificate", "_certificate"), ("evaluate", "evaluate_design")):
    setattr(design_mod, attr, timed(name, getattr(design_mod, attr)))
t0, c0 = time.perf_counter(), time.process_time()
code = cli.main(sys.argv[1:])
phases["command"] = (time.perf_counter() - t0, time.process_time() - c0)
print("PHASES " + json.dumps(phases), file=sys.stderr)
raise SystemExit(code)
"""

PHASES = ("imports", "pool", "column generation", "exchange", "SQP", "certificate", "evaluate",
          "command")


def run_once(scene: str, n: int, extra=()) -> dict:
    """One child process: phase times, its whole CPU, the efficiency and the SQP iterations."""
    with tempfile.TemporaryDirectory() as tmp:  # the child's cwd: not this checkout's package
        argv = [sys.executable, "-c", _CHILD, "design", scene, "-n", str(n), "--criterion", "kpi", "-o",
                str(Path(tmp) / "design"), "--json", *extra]
        env = dict(os.environ, OPENBLAS_NUM_THREADS="1")
        out_path, err_path = Path(tmp) / "stdout.json", Path(tmp) / "stderr.txt"
        with open(out_path, "w") as out, open(err_path, "w") as err:
            proc = subprocess.Popen(argv, stdout=out, stderr=err, env=env, cwd=tmp)
            _, status, usage = os.wait4(proc.pid, 0)
        err_text = err_path.read_text()
        if os.waitstatus_to_exitcode(status) != 0:
            raise RuntimeError(err_text)
        record = json.loads(out_path.read_text())
        line = next(x for x in err_text.splitlines() if x.startswith("PHASES "))
        phases = json.loads(line[len("PHASES "):])
    return {"scene": record["scene"], "n": n, "phases": phases,
            "process_cpu_s": usage.ru_utime + usage.ru_stime, "peak_rss_mb": usage.ru_maxrss / 1024,
            "efficiency": record.get("efficiency"), "value": record["value"],
            "iterations": record["solver"].get("iterations"), "status": record["solver"].get("status")}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scene", default="fms_kr16")
    ap.add_argument("--poses", type=int, default=60)
    ap.add_argument("--repeats", type=int, default=1)
    ap.add_argument("--no-certificate", action="store_true")
    args = ap.parse_args(argv)
    print(f"# {platform.node()} {platform.processor() or platform.machine()}, "
          f"{os.cpu_count()} cores, Python {platform.python_version()}, "
          f"PYTHONPATH={os.environ.get('PYTHONPATH', '')!r}")
    extra = ("--no-certificate",) if args.no_certificate else ()
    rows = []
    for _ in range(args.repeats):
        row = run_once(args.scene, args.poses, extra)
        rows.append(row)
        print(json.dumps(row), flush=True)
    print()
    print("CPU seconds (wall in brackets)")
    print(f"{'phase':18s} " + " ".join(f"{'run ' + str(i + 1):>14s}" for i in range(len(rows))))
    for name in PHASES:
        cells = []
        for r in rows:
            w, c = r["phases"].get(name, (float("nan"), float("nan")))
            cells.append(f"{c:6.2f} ({w:5.2f})")
        print(f"{name:18s} " + " ".join(f"{c:>14s}" for c in cells))
    print(f"{'process':18s} " + " ".join(f"{r['process_cpu_s']:14.2f}" for r in rows))
    print(f"{'SQP iterations':18s} " + " ".join(f"{r['iterations']:14d}" for r in rows))
    effs = ["-" if r["efficiency"] is None else f"{100 * r['efficiency']:.2f}%" for r in rows]
    print(f"{'efficiency':18s} " + " ".join(f"{e:>14s}" for e in effs))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
