"""Benchmark: all feasibility constraints and their Jacobian for 60 poses of kr16 in fms_kr16.

Run from the repository root:

    .venv/bin/python bench/bench_feasibility.py [--scene fms_kr16] [--poses 60] [--repeat 7]

Reports, side by side in one process on the same feasible configurations:

1. values + block Jacobian of every constraint (target <= 20 ms for 60 poses);
2. the capsule-pair distances by our batched closed-form segment distance
   against coal's capsule distance called per pair (the ratio decides which
   one production uses);
3. the time to sample 60 feasible poses by seeded rejection (target ~1 s).

Results and the command are recorded in docs/benchmarks.md.
"""

from __future__ import annotations

import argparse
import platform
import time

import coal
import numpy as np
import pinocchio as pin
from _timing import timed  # bench/ is the script folder, first on sys.path

from calib_oed.feasibility.bodies import compute_body_states
from calib_oed.feasibility.capsule_rows import CapsulePairRows
from calib_oed.feasibility.pairs import feasibility_from_scene
from calib_oed.feasibility.sampling import sample_feasible
from calib_oed.scene.reader import load_scene


def coal_pair_distances(fm, q):
    """Capsule-pair clearances with coal, one coal.distance call per pair and pose."""
    seg = fm.segments
    states = compute_body_states(fm.robot.model, q, jacobian=False)
    a = states.points(seg.body_a, seg.a_local)
    b = states.points(seg.body_b, seg.b_local)
    z = np.array([0.0, 0.0, 1.0])
    shapes, tfs = [], []
    for k in range(q.shape[0]):
        row_s, row_t = [], []
        for s in range(len(seg)):
            axis = b[k, s] - a[k, s]
            length = max(np.linalg.norm(axis), 1e-9)
            rot = pin.Quaternion.FromTwoVectors(z, axis / length).matrix()
            row_s.append(coal.Capsule(seg.radius[s], length))
            row_t.append(coal.Transform3s(rot, (a[k, s] + b[k, s]) / 2))
        shapes.append(row_s)
        tfs.append(row_t)
    req = coal.DistanceRequest()
    res = coal.DistanceResult()
    out = np.empty((q.shape[0], len(fm.pairs)))

    def run():
        for k in range(q.shape[0]):
            for p, (i, j) in enumerate(fm.pairs):
                res.clear()
                out[k, p] = coal.distance(shapes[k][i], tfs[k][i], shapes[k][j], tfs[k][j], req, res)
        return out

    return run


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default="fms_kr16")
    parser.add_argument("--poses", type=int, default=60)
    parser.add_argument("--repeat", type=int, default=7)
    args = parser.parse_args(argv)

    scene = load_scene(args.scene)
    t0 = time.perf_counter()
    fm, report = feasibility_from_scene(scene)
    t_build = time.perf_counter() - t0
    t0 = time.perf_counter()
    q = sample_feasible(fm, args.poses, 0)
    t_sample = time.perf_counter() - t0
    t_sample_again, _ = timed(lambda: sample_feasible(fm, args.poses, 1), 3, 1)

    t_all, res = timed(lambda: fm.compute(q), args.repeat, 20)
    t_values, _ = timed(lambda: fm.compute(q, jacobian=False), args.repeat, 20)
    states = compute_body_states(fm.robot.model, q, jacobian=False)
    capsules = fm.family(CapsulePairRows)  # the capsule-pair rows alone, in fm.pairs order
    t_ours, (ours, _) = timed(lambda: capsules.compute(q, states, False), args.repeat, 20)
    run_coal = coal_pair_distances(fm, q)
    t_coal, theirs = timed(run_coal, args.repeat, 3)
    n_pairs = len(fm.pairs)
    ours_pairs = ours + fm.settings.margins.clearance
    seg = fm.segments
    radii = seg.radius[fm.pairs[:, 0]] + seg.radius[fm.pairs[:, 1]]
    agree = np.abs(np.where(theirs > 0, theirs, 0) - np.where(ours_pairs > 0, ours_pairs, 0))
    print(f"machine: {platform.processor() or platform.machine()}, python {platform.python_version()}, "
          f"pin {pin.__version__}, coal {coal.__version__}")
    print(f"scene {args.scene}: {fm.n_constraints} constraints per pose {fm.count_per_pose()}; "
          f"model built (with {report.samples}-sample pruning) in {t_build:.2f} s")
    print(f"{args.poses} feasible poses sampled in {t_sample:.2f} s (seed 0), {t_sample_again:.2f} s (seed 1)")
    print(f"values + Jacobian, {args.poses} poses:  {t_all * 1e3:7.2f} ms   (target <= 20 ms)")
    print(f"values only,        {args.poses} poses:  {t_values * 1e3:7.2f} ms")
    print(f"capsule pairs ({n_pairs} per pose x {args.poses} poses), same kinematics:")
    print(f"  closed form, batched numpy : {t_ours * 1e3:8.2f} ms")
    print(f"  coal.distance per pair     : {t_coal * 1e3:8.2f} ms   ratio coal/ours = {t_coal / t_ours:.1f}x")
    print(f"  largest disagreement of positive clearances: {agree.max() * 1e3:.2e} mm "
          f"(radii summed {radii.min() * 1e3:.0f}-{radii.max() * 1e3:.0f} mm)")
    print(f"design feasible: {bool(res.feasible.all())}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
