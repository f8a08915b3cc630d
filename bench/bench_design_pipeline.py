"""Benchmark: the default design pipeline on every shipped scene and two cells of our own.

Run from the repository root:

    .venv/bin/python bench/bench_design_pipeline.py [--scenes all] [--poses 60]
        [--growth 30,60,120,250,500] [--no-certificate] [--replicates 1,2,3,5]
        [--structured-qp lifted,block] [--hessian-modification tangent,block] [--criterion kpi]
        [--seeds 0,1]

Each case runs in its own process (``python -m calib_oed design SCENE -n N -o DIR
--json``), as a user would run it: from the scene file to the written design.
The process's CPU time (user + system, from ``os.wait4``) and peak resident
memory (``ru_maxrss``) are measured from outside; the design record gives the
solver status, the iterations, the design's own wall and CPU time, the
certificate's time and the efficiency against the certified lower bound;
*approx cpu* is the column generation (approximate design and off-pool local
maxima) that both the start and the certificate use, included in *design cpu*.
``PYTHONPATH=/other/checkout`` runs that checkout's package (the child's
working directory is a temporary folder), for side-by-side comparisons.
``--replicates 1,3`` runs every scene once per K (``--replicates K``), ``--seeds 0,1`` once
per seed of the pool and the start (``--seed S``);
``--feasibility link_fit=single,joint_window=full`` runs copies of the scenes
with those ``feasibility`` keys overridden (e.g. the single capsules, the
default before the convex hulls).
``--structured-qp lifted,block`` runs every case once per QP path of the
structured Hessian (``SQPSettings.structured_qp``; the child sets it on
``DESIGN_SQP`` before the CLI runs) and adds the QP's process CPU time, the
number of QPs, the QP's and the whole SQP's CPU time per SQP iteration and the
start's share of the design's CPU (column generation and exchange), for
side-by-side figures on a shared machine (``auto``, the default, for the
default call with these timings). ``--hessian-modification tangent,block`` runs
every case once per rule of the SQP's Hessian modification
(``SQPSettings.hessian_modification``), with the same timings.

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
from importlib import resources
from pathlib import Path

import yaml
from _children import child_env, package_run  # bench/ is the script folder, first on sys.path

ROOT = Path(__file__).resolve().parent.parent
SHIPPED = ("fms_kr16", "fms_kr16_program", "fms_kr300", "fms_kr500", "ur5_table")
OWN = (str(ROOT / "bench" / "scenes" / "ur10_cell.yaml"), str(ROOT / "bench" / "scenes" / "panda_cell.yaml"))


def with_feasibility(scene: str, overrides: dict, folder: Path) -> str:
    """A copy of ``scene`` (a shipped name or a file) in ``folder`` with its ``feasibility`` keys overridden."""
    path = Path(scene)
    if not path.is_file():
        path = Path(str(resources.files("calib_oed.scene.shipped").joinpath(f"{scene}.yaml")))
    data = yaml.safe_load(path.read_text())
    data.setdefault("feasibility", {}).update(overrides)
    out = folder / path.name
    out.write_text(yaml.safe_dump(data, sort_keys=False))
    return str(out)


_WITH_QP = """
import dataclasses, json, sys, time
qp, rule, out = sys.argv.pop(1), sys.argv.pop(1), sys.argv.pop(1)
import calib_oed.oed.design as design, calib_oed.oed.refine as refine, calib_oed.solver.subproblem as sub
changes = {k: v for k, v in (("structured_qp", qp), ("hessian_modification", rule)) if v}
refine.DESIGN_SQP = design.DESIGN_SQP = dataclasses.replace(refine.DESIGN_SQP, **changes)
solve, used = sub.QPSolver.solve, [0.0, 0]
def timed(self, *a, **k):
    t = time.process_time()
    try:
        return solve(self, *a, **k)
    finally:
        used[0] += time.process_time() - t
        used[1] += 1
sub.QPSolver.solve = timed
phases = {}
def phase(name, fn):
    def wrapper(*a, **k):
        t = time.process_time()
        try:
            return fn(*a, **k)
        finally:
            phases[name] = phases.get(name, 0.0) + time.process_time() - t
    return wrapper
for name, attr in (("pool", "candidate_pool"), ("columns", "approximate_pool"),
                   ("exchange", "approximate_start"), ("sqp", "optimise_starts")):
    setattr(design, attr, phase(name, getattr(design, attr)))
from calib_oed.cli import main
code = main(sys.argv[1:])
json.dump({"qp_cpu_s": used[0], "qps": used[1], "phases": phases}, open(out, "w"))
sys.exit(code)
"""
"""Child that sets ``DESIGN_SQP.structured_qp`` and ``hessian_modification`` (either may be
empty: the default) and times the QPs and the phases in process CPU
(``--structured-qp``): the pool, the column generation, the exchange, the SQP (as
``bench/bench_design_phases.py`` names them)."""


def run_case(scene: str, n: int, certificate: bool, extra=(), structured_qp: str = "", rule: str = "") -> dict:
    """One ``calib-oed design`` process: its record, CPU seconds and peak memory (``os.wait4``)."""
    with tempfile.TemporaryDirectory() as tmp:
        head = [sys.executable, "-m", "calib_oed"]
        if structured_qp or rule:
            head = [sys.executable, "-c", _WITH_QP, structured_qp, rule, str(Path(tmp) / "qp.json")]
        argv = [*head, "design", scene, "-n", str(n), "-o", tmp, "--json", *extra]
        if not certificate:
            argv.append("--no-certificate")
        env = child_env(OPENBLAS_NUM_THREADS="1")  # PYTHONPATH absolute: the child runs in tmp
        out_path, err_path = Path(tmp) / "stdout.json", Path(tmp) / "stderr.txt"
        with open(out_path, "w") as out, open(err_path, "w") as err:
            # cwd: the child imports calib_oed as installed (or from PYTHONPATH), not from cwd
            proc = subprocess.Popen(argv, stdout=out, stderr=err, env=env, cwd=tmp)
            _, status, usage = os.wait4(proc.pid, 0)
        cpu = usage.ru_utime + usage.ru_stime
        peak = usage.ru_maxrss / 1024  # kB -> MB on Linux
        if os.waitstatus_to_exitcode(status) != 0:
            return {"scene": Path(scene).stem, "n": n, "process_cpu_s": cpu, "peak_rss_mb": peak,
                    "error": err_path.read_text().strip().splitlines()[-1:]}
        record = json.loads(out_path.read_text())
        qp = json.loads((Path(tmp) / "qp.json").read_text()) if structured_qp or rule else {}
    solver, cert = record["solver"], record["certificate"]
    approx = solver.get("approximate") or {}
    return {
        "scene": record["scene"], "n": n, "status": solver.get("status"),
        "distinct_poses": record.get("distinct_poses"), "approximate_cpu_s": approx.get("cpu_seconds"),
        "iterations": solver.get("iterations"), "value": record["value"],
        "efficiency": record.get("efficiency"), "design_cpu_s": solver.get("cpu_seconds"),
        "design_wall_s": record["seconds"], "certificate_cpu_s": cert.get("cpu_seconds"),
        "process_cpu_s": cpu, "peak_rss_mb": peak, "structured_qp": structured_qp or None,
        "hessian_modification": rule or None,
        "qp_cpu_s": qp.get("qp_cpu_s"), "qps": qp.get("qps"), "phases_cpu_s": qp.get("phases"),
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenes", default="all", help="comma-separated scenes or files, or 'all'")
    ap.add_argument("--poses", type=int, default=60)
    ap.add_argument("--growth", default="", help="fms_kr16 at these n, e.g. 30,60,120,250,500")
    ap.add_argument("--no-certificate", action="store_true")
    ap.add_argument("--criterion", default="",
                    help="pass --criterion to every design (e.g. kpi, the noise-only criterion the figures "
                         "before kpi_model became the default were measured with); default: the default call")
    ap.add_argument("--replicates", default="1",
                    help="comma-separated K of --replicates K, each scene run once per K, e.g. 1,2,3,5")
    ap.add_argument("--feasibility", default="",
                    help="override scene feasibility keys, e.g. link_fit=single,joint_window=full")
    ap.add_argument("--structured-qp", default="",
                    help="run every case once per QP path, e.g. lifted,block (SQPSettings.structured_qp)")
    ap.add_argument("--seeds", default="0", help="every scene once per seed of the pool and the start, e.g. 0,1")
    ap.add_argument("--hessian-modification", default="",
                    help="run every case once per rule, e.g. tangent,block (SQPSettings.hessian_modification)")
    args = ap.parse_args(argv)
    qps = [q for q in args.structured_qp.split(",") if q] or [""]
    rules = [r for r in args.hessian_modification.split(",") if r] or [""]
    crit = ("--criterion", args.criterion) if args.criterion else ()
    reps = [int(k) for k in args.replicates.split(",") if k]
    overrides = dict(kv.split("=", 1) for kv in args.feasibility.split(",") if kv)
    print(f"# {platform.node()} {platform.processor() or platform.machine()}, "
          f"{os.cpu_count()} cores, Python {platform.python_version()}")
    with tempfile.TemporaryDirectory() as where:  # the package the children import, from where they run
        print(f"# code: {package_run(where)}", flush=True)
    scenes = [*SHIPPED, *OWN] if args.scenes == "all" else [s for s in args.scenes.split(",") if s]
    tmp = tempfile.TemporaryDirectory()
    if overrides:
        scenes = [with_feasibility(s, overrides, Path(tmp.name)) for s in scenes]
    rows = []
    seeds = [int(k) for k in args.seeds.split(",") if k]
    for scene in scenes:
        for seed in seeds:
            for k in reps:
                for qp in qps:
                    for rule in rules:
                        extra = (crit + (() if k == 1 else ("--replicates", str(k)))
                                 + (() if seed == 0 else ("--seed", str(seed))))
                        row = run_case(scene, args.poses, not args.no_certificate, extra, qp, rule)
                        row["replicates"], row["seed"] = k, seed
                        rows.append(row)
                        print(json.dumps(row), flush=True)
    for n in [int(k) for k in args.growth.split(",") if k]:
        for qp in qps:
            for rule in rules:
                row = run_case("fms_kr16", n, n <= 120 and not args.no_certificate, crit, qp, rule)
                row["growth"] = True
                rows.append(row)
                print(json.dumps(row), flush=True)
    print()
    print(f"{'scene':18s} {'n':>4s} {'K':>3s} {'distinct':>8s} {'status':>15s} {'it':>4s} {'value':>11s} "
          f"{'eff':>6s} {'design cpu':>10s} {'approx cpu':>10s} {'cert cpu':>8s} {'proc cpu':>8s} "
          f"{'peak MB':>8s} {'qp':>6s} {'rule':>7s} {'qp cpu/it':>9s} {'sqp cpu/it':>10s} {'start %':>7s}")
    for r in rows:
        if "error" in r:
            print(f"{r['scene']:18s} {r['n']:4d} ERROR {r['error']}")
            continue
        eff = "-" if r["efficiency"] is None else f"{100 * r['efficiency']:.1f}%"
        cert = "-" if r["certificate_cpu_s"] is None else f"{r['certificate_cpu_s']:.1f}"
        approx = "-" if r["approximate_cpu_s"] is None else f"{r['approximate_cpu_s']:.1f}"
        per_it = "-" if r.get("qp_cpu_s") is None else f"{r['qp_cpu_s'] / max(r['iterations'], 1):.3f}"
        ph = r.get("phases_cpu_s") or {}
        sqp_it = "-" if "sqp" not in ph else f"{ph['sqp'] / max(r['iterations'], 1):.3f}"
        # the start: the column generation and the exchange, as a share of the design's CPU
        start = "-" if "exchange" not in ph else \
            f"{100 * (ph.get('columns', 0.0) + ph['exchange']) / max(r['design_cpu_s'], 1e-9):.0f}"
        name = r["scene"] if len(seeds) == 1 else f"{r['scene']}:{r.get('seed', 0)}"
        print(f"{name:18s} {r['n']:4d} {r.get('replicates', 1):3d} {r['distinct_poses']:8d} "
              f"{r['status']:>15s} {r['iterations']:4d} {r['value']:11.4e} {eff:>6s} "
              f"{r['design_cpu_s']:10.1f} {approx:>10s} {cert:>8s} {r['process_cpu_s']:8.1f} "
              f"{r['peak_rss_mb']:8.0f} {r.get('structured_qp') or '-':>6s} "
              f"{r.get('hessian_modification') or '-':>7s} {per_it:>9s} {sqp_it:>10s} "
              f"{start:>7s}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
