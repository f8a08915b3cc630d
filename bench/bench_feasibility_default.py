"""Benchmark: the default link geometry (``link_fit: hulls``) against one capsule per link.

Run from the repository root (``OPENBLAS_NUM_THREADS=1`` as the other benchmarks):

    .venv/bin/python bench/bench_feasibility_default.py                 # timing on fms_kr16
    .venv/bin/python bench/bench_feasibility_default.py --designs all   # + calib-oed design per scene

Timing (issue 17's targets, ``fms_kr16``): sampling 60 feasible poses (seed 0, <= 2 s) and
all constraint values + Jacobians of those 60 poses (<= 20 ms), best of ``--repeat``,
CPU (``time.process_time``) next to wall time, with the default fit and with
``feasibility: {link_fit: single}``. The model is built once before (its build time is
printed too: the first build in the process reads the fits from the disk cache).

Designs (``--designs``): one ``calib-oed design SCENE -n 60 --no-certificate --json``
process per scene and variant (``--fits``; ``bench_design_pipeline.run_case``): solver status,
iterations, the KPI criterion and CPU, so that the SQP's cost of the hull rows'
exact feature curvature (docs/feasibility.md §2) is measured against the single
capsules, and against ``hulls-model``: the default with the rows on convex pieces held to
the tangent-plane curvature (``HullPairs._exact`` patched out in that process). The
``single`` runs use a copy of the scene file with ``feasibility.link_fit: single`` added.
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import tempfile
import time
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parent.parent
SHIPPED = ("fms_kr16", "fms_kr16_program", "fms_kr300", "fms_kr500", "ur5_table")
OWN = (ROOT / "bench" / "scenes" / "ur10_cell.yaml", ROOT / "bench" / "scenes" / "panda_cell.yaml")


def scene_file(scene: str) -> Path:
    path = Path(scene)
    return path if path.suffix in (".yaml", ".yml") else ROOT / "calib_oed" / "scene" / "shipped" / f"{scene}.yaml"


def with_fit(scene: str, fit: str, folder: Path) -> str:
    """The scene as is (``hulls``, the default) or a copy with ``feasibility.link_fit: fit``."""
    if fit == "hulls":
        return scene
    data = yaml.safe_load(scene_file(scene).read_text())
    data.setdefault("feasibility", {})["link_fit"] = fit
    out = folder / f"{Path(scene).stem}-{fit}.yaml"
    out.write_text(yaml.safe_dump(data, sort_keys=False))
    return str(out)


#: The ``hulls-model`` variant: ``calib-oed design`` with the rows on convex pieces held to the
#: tangent-plane curvature (no exact feature Hessian), to measure what exactness gives the SQP.
MODEL_ONLY = ("import sys; from calib_oed.feasibility import hulls; "
              "hulls.HullPairs._exact = lambda self, *args: None; "
              "from calib_oed.cli import main; raise SystemExit(main(sys.argv[1:]))")


def run_model_only(scene: str, n: int) -> dict:
    """``calib-oed design`` with the tangent-plane curvature on every convex-piece row (its own
    process, as ``bench_design_pipeline.run_case``)."""
    import os
    import subprocess

    with tempfile.TemporaryDirectory() as tmp:
        argv = [sys.executable, "-c", MODEL_ONLY, "design", scene, "-n", str(n), "--criterion", "kpi", "-o", tmp, "--json",
                "--no-certificate"]
        out_path = Path(tmp) / "stdout.json"
        with open(out_path, "w") as out:
            proc = subprocess.Popen(argv, stdout=out, stderr=subprocess.DEVNULL,
                                    env=dict(os.environ, OPENBLAS_NUM_THREADS="1"))
            _, status, usage = os.wait4(proc.pid, 0)
        if os.waitstatus_to_exitcode(status) != 0:
            return {"scene": Path(scene).stem, "n": n, "error": f"exit {os.waitstatus_to_exitcode(status)}"}
        record = json.loads(out_path.read_text())
    solver = record["solver"]
    return {"scene": record["scene"], "n": n, "status": solver.get("status"), "iterations": solver.get("iterations"),
            "value": record["value"], "design_cpu_s": solver.get("cpu_seconds"),
            "process_cpu_s": usage.ru_utime + usage.ru_stime}


def best(fun, repeat: int) -> tuple[float, float]:
    """Smallest wall and CPU time [s] of ``repeat`` calls."""
    wall, cpu = [], []
    for _ in range(repeat):
        w, c = time.perf_counter(), time.process_time()
        fun()
        wall.append(time.perf_counter() - w)
        cpu.append(time.process_time() - c)
    return min(wall), min(cpu)


def timing(fit: str, repeat: int, folder: Path) -> dict:
    from calib_oed.feasibility.pairs import feasibility_from_scene
    from calib_oed.feasibility.sampling import sample_feasible
    from calib_oed.scene.reader import load_scene

    scene = load_scene(with_fit("fms_kr16", fit, folder))
    c = time.process_time()
    model, _ = feasibility_from_scene(scene)
    build = time.process_time() - c
    q = sample_feasible(model, 60, 0)
    sw, sc = best(lambda: sample_feasible(model, 60, 0), max(1, repeat // 10))
    jw, jc = best(lambda: model.compute(q), repeat)
    return {"fit": fit, "link_fit": scene.feasibility.link_fit, "rows_per_pose": model.n_constraints,
            "rows_on_pieces": len(model.hull_pairs), "build_cpu_s": build, "sample60_wall_s": sw,
            "sample60_cpu_s": sc, "values_jacobian60_wall_ms": 1e3 * jw, "values_jacobian60_cpu_ms": 1e3 * jc}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeat", type=int, default=30)
    ap.add_argument("--designs", default="", help="comma-separated scenes or files, or 'all'")
    ap.add_argument("--poses", type=int, default=60)
    ap.add_argument("--fits", default="hulls,single",
                    help="design variants: hulls (default), single, hulls-model (tangent-plane curvature)")
    args = ap.parse_args(argv)
    print(f"# {platform.node()} {platform.processor() or platform.machine()}, Python {platform.python_version()}")
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        for fit in ("hulls", "single"):
            print(json.dumps(timing(fit, args.repeat, folder)), flush=True)
        if not args.designs:
            return 0
        sys.path.insert(0, str(ROOT / "bench"))
        from bench_design_pipeline import run_case

        scenes = [*SHIPPED, *map(str, OWN)] if args.designs == "all" else args.designs.split(",")
        rows = []
        for scene in scenes:
            for fit in args.fits.split(","):
                if fit == "hulls-model":
                    row = run_model_only(scene, args.poses)
                else:
                    row = run_case(with_fit(scene, fit, folder), args.poses, False)
                row["fit"] = fit
                rows.append(row)
                print(json.dumps(row), flush=True)
    print()
    print(f"{'scene':18s} {'fit':11s} {'status':>15s} {'it':>4s} {'value':>11s} {'design cpu':>10s} {'proc cpu':>8s}")
    for r in rows:
        if "error" in r:
            print(f"{r['scene']:18s} {r['fit']:11s} ERROR {r['error']}")
            continue
        print(f"{r['scene']:18s} {r['fit']:11s} {r['status']:>15s} {r['iterations']:4d} {r['value']:11.4e} "
              f"{r['design_cpu_s']:10.1f} {r['process_cpu_s']:8.1f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
