"""Benchmark: the approximate design's Newton QP, deterministic active set against ProxQP (issue 31).

Run from the repository root:

    OPENBLAS_NUM_THREADS=1 .venv/bin/python bench/bench_simplex_qp.py
        [--scenes fms_kr16,ur5_table] [--candidates 48,100,150,300] [--repeat 5]

For each scene and each number N of candidates (a feasible pool, seed 0), the
KPI approximate design (:func:`calib_oed.oed.approximate.solve_approximate`,
tol 1e-4, from its default start) is solved ``--repeat`` times with each QP in
turn (A B A B ...): the project's deterministic active-set QP
(:mod:`calib_oed.solver.simplex_qp`) and ProxQP 0.8 (dense, eps_abs 1e-10, as the
approximate design used before issue 31). Printed per N: Newton steps, the
largest QP (working-set size m), the median process CPU seconds
(``time.process_time``, one BLAS thread) of the whole solve and of its QPs,
the ratio, and the relative difference of the two optimal values. Results:
docs/benchmarks.md.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from threadpoolctl import threadpool_limits

import calib_oed.oed.approximate as approximate
from calib_oed.calibration.workflow import setup
from calib_oed.oed.objective import DesignObjective
from calib_oed.oed.starts import candidate_pool
from calib_oed.scene.reader import load_scene
from calib_oed.solver.proxqp_build import proxsuite

_DETERMINISTIC = approximate._newton_direction


def proxqp_direction(h, grad, w):
    """The Newton step by ProxQP, as oed/approximate.py solved it before issue 31."""
    m = w.size
    reg = approximate.NEWTON_REGULARISATION * max(float(np.max(np.diag(h))), 1e-300)
    qp = proxsuite.proxqp.dense.QP(m, 1, 0, True)
    st = qp.settings
    st.eps_abs, st.eps_rel, st.verbose = 1e-10, 0.0, False
    st.max_iter, st.max_iter_in = 500, 200
    qp.init(h + reg * np.eye(m), grad, np.ones((1, m)), np.zeros(1), None, None, None, -w, 1.0 - w)
    qp.solve()
    step = np.array(qp.results.x, dtype=float)
    if not np.all(np.isfinite(step)) or abs(step.sum()) > 1e-6 or np.min(w + step) < -1e-6:
        return None
    return step


def _run(blocks, crit, direction):
    """(result, CPU of the solve, CPU of its QPs, largest QP size)."""
    qp_cpu, sizes = [0.0], [0]

    def timed(h, grad, w):
        t = time.process_time()
        out = direction(h, grad, w)
        qp_cpu[0] += time.process_time() - t
        sizes[0] = max(sizes[0], w.size)
        return out

    approximate._newton_direction = timed
    try:
        t = time.process_time()
        res = approximate.solve_approximate(blocks, crit, tol=1e-4)
        return res, time.process_time() - t, qp_cpu[0], sizes[0]
    finally:
        approximate._newton_direction = _DETERMINISTIC


def _one_qp(blocks, crit):
    """The first Newton QP from the uniform design on all candidates: (H, g, w) as the solver makes them."""
    n, _, p = blocks.shape
    w = np.full(n, 1.0 / n)
    m = approximate.information(blocks, w)
    gamma = crit.compute_gradient(m)
    dbar = approximate.mean_sensitivity(approximate.criterion_kind(crit), crit.compute_value(m), p)
    cov = np.linalg.inv(m)
    h = approximate._hessian(blocks, gamma, cov, approximate.criterion_kind(crit)) / dbar
    return h, -approximate.sensitivities(blocks, gamma) / dbar, w


def _qp_table(objective, s, sizes, repeat):
    """Each QP alone: median CPU of ``repeat`` solves by each solver, interleaved."""
    print(f"{'':10s} {'m':>4s} {'QP det [ms]':>11s} {'QP prox [ms]':>12s} {'ratio':>5s} {'rel. obj diff':>13s}")
    for m in sizes:
        h, g, w = _one_qp(objective.compute_blocks(candidate_pool(s, m, 0).q), objective.criterion)
        t, out = {"det": [], "prox": []}, {}
        for _ in range(repeat):
            for key, fun in (("det", _DETERMINISTIC), ("prox", proxqp_direction)):
                c = time.process_time()
                out[key] = fun(h, g, w)
                t[key].append(time.process_time() - c)
        hr = h + approximate.NEWTON_REGULARISATION * np.max(np.diag(h)) * np.eye(m)
        obj = [0.5 * x @ hr @ x + g @ x for x in (out["det"], out["prox"])]
        det, prox = (1e3 * float(np.median(v)) for v in t.values())
        print(f"{'':10s} {m:4d} {det:11.2f} {prox:12.2f} {det / prox:5.2f} "
              f"{(obj[0] - obj[1]) / abs(obj[1]):13.2e}", flush=True)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenes", default="fms_kr16,ur5_table")
    ap.add_argument("--candidates", default="48,100,150,300")
    ap.add_argument("--qp-sizes", default="48,100,150,300")
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args(argv)
    print(f"{'scene':10s} {'N':>4s} {'steps':>5s} {'m':>4s} {'solve det':>9s} {'solve prox':>10s} "
          f"{'ratio':>5s} {'QP det':>7s} {'QP prox':>7s} {'ratio':>5s} {'rel. value diff':>15s}")
    for scene in args.scenes.split(","):
        s = setup(load_scene(scene))
        objective = DesignObjective(s.problem, "kpi")
        crit = objective.criterion
        for n in (int(x) for x in args.candidates.split(",")):
            blocks = objective.compute_blocks(candidate_pool(s, n, 0).q)
            rows = {"det": [], "prox": []}
            with threadpool_limits(limits=1, user_api="blas"):
                for _ in range(args.repeat):
                    rows["det"].append(_run(blocks, crit, _DETERMINISTIC))
                    rows["prox"].append(_run(blocks, crit, proxqp_direction))
            det, prox = rows["det"][0][0], rows["prox"][0][0]
            same = all(r[0].weights.tobytes() == det.weights.tobytes() for r in rows["det"])
            med = {k: (float(np.median([r[1] for r in v])), float(np.median([r[2] for r in v])))
                   for k, v in rows.items()}
            print(f"{scene:10s} {n:4d} {det.iterations:5d} {rows['det'][0][3]:4d} {med['det'][0]:9.3f} "
                  f"{med['prox'][0]:10.3f} {med['det'][0] / med['prox'][0]:5.2f} {med['det'][1]:7.3f} "
                  f"{med['prox'][1]:7.3f} {med['det'][1] / max(med['prox'][1], 1e-9):5.2f} "
                  f"{(det.value - prox.value) / prox.value:15.2e}"
                  f"{'' if same else '  (deterministic runs differ!)'}", flush=True)
        with threadpool_limits(limits=1, user_api="blas"):
            _qp_table(objective, s, [int(x) for x in args.qp_sizes.split(",") if x], args.repeat)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
