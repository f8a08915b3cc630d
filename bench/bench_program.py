"""Measurement programs (issue 20): tour, cycle times, blocked moves, generation time.

For each scene (fms_kr16, fms_kr300, ur5_table) the bench designs 60 poses with
`calib-oed design SCENE -n 60 --no-certificate` (run in-process), then
builds the program with LKH (elkai), with the design order's
blocked moves planned too (``plan_baselines``) so all three cycle times use
planned paths. It prints, per scene: the estimated cycle time of the
design order, nearest neighbour and the optimised tour (with and without the
dwells), the blocked direct moves and how the planner did, every program move
re-certified by the continuous check, and the generation time (CPU and wall;
the program alone, as `calib-oed program` runs it, is timed once more without
planning the baseline).

    .venv/bin/python bench/bench_program.py [--scenes fms_kr16 ...] [-n 60]
    .venv/bin/python bench/bench_program.py --heuristic --scenes fms_kr16 \\
        fms_kr16_program fms_kr300 fms_kr500 ur5_table
"""

from __future__ import annotations

import argparse
import resource
import subprocess
import sys
import tempfile
import time

import numpy as np

from calib_oed.cli import main as calib_oed
from calib_oed.io.design_file import read_design_file, write_design_csv
from calib_oed.program.build import build_program, move_checker
from calib_oed.program.settings import program_settings_from_scene
from calib_oed.scene.reader import load_scene


def _design(scene, n: int) -> np.ndarray:
    """`calib-oed design SCENE -n N --no-certificate -o DIR`, read back."""
    with tempfile.TemporaryDirectory() as folder:
        argv = ["design", scene.name, "-n", str(n), "--criterion", "kpi", "--no-certificate", "-o", folder, "--quiet"]
        if calib_oed(argv) != 0:
            raise SystemExit(f"calib-oed {' '.join(argv)} failed")
        return read_design_file(f"{folder}/design.csv", scene.robot)


def _timed(fn):
    cpu, wall = time.process_time(), time.perf_counter()
    out = fn()
    return out, time.process_time() - cpu, time.perf_counter() - wall


def _heuristic(scene, n: int) -> np.ndarray:
    """n random feasible poses (seed 0), the paper's heuristic design."""
    from calib_oed.feasibility.pairs import feasibility_from_scene
    from calib_oed.feasibility.sampling import sample_feasible

    return sample_feasible(feasibility_from_scene(scene)[0], n, 0)


def run(name: str, n: int, heuristic: bool = False) -> None:
    scene = load_scene(name)
    q, cpu, wall = _timed(lambda: (_heuristic if heuristic else _design)(scene, n))
    what = "random feasible poses (seed 0)" if heuristic else "KPI-optimal design"
    print(f"\n== {name}: {what}, {len(q)} poses ({cpu:.1f} s CPU, {wall:.1f} s wall)")
    settings = program_settings_from_scene(scene)
    checker = move_checker(scene, settings)
    prog, cpu, wall = _timed(lambda s=settings, c=checker: build_program(scene, q, s, c, plan_baselines=True))
    t, st = prog.cycle_times, prog.stats
    dwell = len(prog.order) * prog.dwell
    certified = all(checker.check(a, b).verified for m in prog.moves
                    for a, b in zip(m.waypoints[:-1], m.waypoints[1:], strict=True))
    print(f"-- tour kept: {prog.solver}; cycle time [s] incl. {dwell:.0f} s of dwells "
          f"(travel only in brackets):")
    for key in ("design order", "nearest neighbour", "optimised"):
        print(f"   {key:18s} {t[key]:7.1f}  ({t[key] - dwell:6.1f})")
    gain = 1 - t["optimised"] / t["design order"]
    travel_gain = 1 - (t["optimised"] - dwell) / (t["design order"] - dwell)
    print(f"   optimised vs design order: {100 * gain:.1f} % shorter cycle, {100 * travel_gain:.1f} % "
          f"shorter travel; vs nearest neighbour: {t['optimised'] - t['nearest neighbour']:+.1f} s")
    bound = _tour_lower_bound(prog, settings, scene)
    need = 0.6 * t["design order"] - dwell
    print(f"   travel of any tour >= {bound:.1f} s (each node's two quickest direct moves, halved); "
          f"a 40 % shorter cycle needs travel <= {need:.1f} s")
    if prog.skipped:
        print(f"   NOT MEASURED: poses {[k + 1 for k, _ in prog.skipped]} (no certified path from home)")
    print(f"   design order: {st['design_order_blocked']} of {len(q) + 1} direct moves blocked; all "
          f"moves checked: {st['moves_checked']}, blocked {st['blocked']}, planned {st['planned']} "
          f"(failures {st['planner_failures']}), planner CPU {st['planner_cpu_s']:.2f} s")
    print(f"   program: {st['program_blocked']} moves through {st['via_points']} via points; every "
          f"move re-certified: {certified}; line of sight lost in {st['sight_lost_moves']} moves")
    print(f"   build with baselines planned: {cpu:.2f} s CPU, {wall:.2f} s wall")
    prog2, cpu, wall = _timed(lambda s=settings: build_program(scene, q, s))
    print(f"   build_program as the command runs it (checker built, baselines not planned): "
          f"{cpu:.2f} s CPU, {wall:.2f} s wall; cycle {prog2.cycle_time:.1f} s")
    _command(scene.name, q, scene.robot)


def _tour_lower_bound(prog, settings, scene) -> float:
    r"""A lower bound on the travel time of every tour through home and the measured poses [s]:
    each node has two tour moves, each no quicker than its quickest direct move (a via point
    only adds time), so :math:`\sum_v (c_{v,1} + c_{v,2}) / 2 \le` the tour's time."""
    from calib_oed.program.timing import JointDynamics

    nodes = np.vstack([prog.home, prog.poses[np.sort(prog.order)]])
    cost = JointDynamics.from_robot(scene.robot, settings).time_matrix(nodes)
    np.fill_diagonal(cost, np.inf)
    if len(nodes) < 3:  # home and one pose: there and back
        return float(2.0 * cost[0, 1]) if len(nodes) == 2 else 0.0
    two = np.sort(cost, axis=1)[:, :2]
    return float(two.sum() / 2.0)


def _command(name: str, q: np.ndarray, robot) -> None:
    """The whole command in a fresh process (imports, scene, checker, tour, plans, KRL files)."""
    with tempfile.TemporaryDirectory() as folder:
        write_design_csv(f"{folder}/design.csv", robot, q)
        argv = [sys.executable, "-m", "calib_oed", "program", name, f"{folder}/design.csv",
                "--format", "krl", "-o", f"{folder}/prog", "--quiet"]
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        wall = time.perf_counter()
        done = subprocess.run(argv, capture_output=True, text=True)
        wall = time.perf_counter() - wall
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    print(f"   `calib-oed program {name} DESIGN --format krl -o DIR`: exit {done.returncode}, "
          f"{cpu:.2f} s CPU, {wall:.2f} s wall")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", nargs="+", default=["fms_kr16", "fms_kr300", "ur5_table"])
    parser.add_argument("-n", type=int, default=60)
    parser.add_argument("--heuristic", action="store_true", help="random feasible poses instead "
                        "of the KPI-optimal design (every shipped scene in a few minutes)")
    args = parser.parse_args()
    for name in args.scenes:
        run(name, args.n, args.heuristic)


if __name__ == "__main__":
    main()
