"""Benchmark: the default design pipeline on every shipped scene and two cells of our own.

Run from the repository root:

    .venv/bin/python bench/bench_design_pipeline.py [--scenes all] [--poses 60]
        [--growth 30,60,120,250,500] [--no-certificate]

Each case runs in its own process (``python -m calib_oed design SCENE -n N -o DIR
--json``), as a user would run it: from the scene file to the written design.
The process's CPU time (user + system, from ``os.wait4``) and peak resident
memory (``ru_maxrss``) are measured from outside; the design record gives the
solver status, the iterations, the design's own wall and CPU time, the
certificate's time and the efficiency against the certified lower bound.

Scenes: the five shipped ones and ``bench/scenes/ur10_cell.yaml``,
``bench/scenes/panda_cell.yaml`` (example-robot-data arms in cells of our
own making). ``--growth`` runs fms_kr16 at each n (the certificate only up to
n = 120, to keep the run short) and reports time and peak memory against n. Results: docs/benchmarks.md.
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

ROOT = Path(__file__).resolve().parent.parent
SHIPPED = ("fms_kr16", "fms_kr16_program", "fms_kr300", "fms_kr500", "ur5_table")
OWN = (str(ROOT / "bench" / "scenes" / "ur10_cell.yaml"), str(ROOT / "bench" / "scenes" / "panda_cell.yaml"))


def run_case(scene: str, n: int, certificate: bool, extra=()) -> dict:
    """One ``calib-oed design`` process: its record, CPU seconds and peak memory (``os.wait4``)."""
    with tempfile.TemporaryDirectory() as tmp:
        argv = [sys.executable, "-m", "calib_oed", "design", scene, "-n", str(n), "-o", tmp,
                "--json", *extra]
        if not certificate:
            argv.append("--no-certificate")
        env = dict(os.environ, OPENBLAS_NUM_THREADS="1")
        out_path, err_path = Path(tmp) / "stdout.json", Path(tmp) / "stderr.txt"
        with open(out_path, "w") as out, open(err_path, "w") as err:
            proc = subprocess.Popen(argv, stdout=out, stderr=err, env=env)
            _, status, usage = os.wait4(proc.pid, 0)
        cpu = usage.ru_utime + usage.ru_stime
        peak = usage.ru_maxrss / 1024  # kB -> MB on Linux
        if os.waitstatus_to_exitcode(status) != 0:
            return {"scene": Path(scene).stem, "n": n, "process_cpu_s": cpu, "peak_rss_mb": peak,
                    "error": err_path.read_text().strip().splitlines()[-1:]}
        record = json.loads(out_path.read_text())
    solver, cert = record["solver"], record["certificate"]
    return {
        "scene": record["scene"], "n": n, "status": solver.get("status"),
        "iterations": solver.get("iterations"), "value": record["value"],
        "efficiency": record.get("efficiency"), "design_cpu_s": solver.get("cpu_seconds"),
        "design_wall_s": record["seconds"], "certificate_cpu_s": cert.get("cpu_seconds"),
        "process_cpu_s": cpu, "peak_rss_mb": peak,
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenes", default="all", help="comma-separated scenes or files, or 'all'")
    ap.add_argument("--poses", type=int, default=60)
    ap.add_argument("--growth", default="", help="fms_kr16 at these n, e.g. 30,60,120,250,500")
    ap.add_argument("--no-certificate", action="store_true")
    args = ap.parse_args(argv)
    print(f"# {platform.node()} {platform.processor() or platform.machine()}, "
          f"{os.cpu_count()} cores, Python {platform.python_version()}")
    scenes = [*SHIPPED, *OWN] if args.scenes == "all" else [s for s in args.scenes.split(",") if s]
    rows = []
    for scene in scenes:
        row = run_case(scene, args.poses, not args.no_certificate)
        rows.append(row)
        print(json.dumps(row), flush=True)
    for n in [int(k) for k in args.growth.split(",") if k]:
        row = run_case("fms_kr16", n, n <= 120 and not args.no_certificate)
        row["growth"] = True
        rows.append(row)
        print(json.dumps(row), flush=True)
    print()
    print(f"{'scene':18s} {'n':>4s} {'status':>15s} {'it':>4s} {'value':>11s} {'eff':>6s} "
          f"{'design cpu':>10s} {'cert cpu':>8s} {'proc cpu':>8s} {'peak MB':>8s}")
    for r in rows:
        if "error" in r:
            print(f"{r['scene']:18s} {r['n']:4d} ERROR {r['error']}")
            continue
        eff = "-" if r["efficiency"] is None else f"{100 * r['efficiency']:.1f}%"
        cert = "-" if r["certificate_cpu_s"] is None else f"{r['certificate_cpu_s']:.1f}"
        print(f"{r['scene']:18s} {r['n']:4d} {r['status']:>15s} {r['iterations']:4d} "
              f"{r['value']:11.4e} {eff:>6s} {r['design_cpu_s']:10.1f} {cert:>8s} "
              f"{r['process_cpu_s']:8.1f} {r['peak_rss_mb']:8.0f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
