"""ProxQP's SSE2 build (the one calib_oed loads, ``calib_oed/solver/proxqp_build.py``) against the
build proxsuite picks itself (AVX2 on this machine): CPU per dense QP and how many different
answers one QP gets when the allocator is moved between solves.

Each build runs in its own process (two builds cannot share one). The QPs are random strictly
convex ones with a box (the SQP's trust region) and inequality rows, shaped like the design's
(n = 6 K variables for K poses). Process CPU (``time.process_time``), median of ``--repeat`` solves.

    OPENBLAS_NUM_THREADS=1 .venv/bin/python bench/bench_proxqp_build.py --repeat 5
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
import warnings

import numpy as np

SIZES = ((96, 60), (96, 300), (360, 400), (720, 800))


def _child(build: str, repeat: int, sizes) -> dict:
    if build == "native":
        import proxsuite  # noqa: F401 - first: proxsuite picks its build itself
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        from calib_oed.solver.proxqp_build import BUILD
        from calib_oed.solver.qp import DenseQPWorkspace, QPSubproblem
    rng = np.random.default_rng(1)
    rows = []
    for n, k in sizes:
        a = rng.standard_normal((n, n))
        sub = QPSubproblem(a @ a.T / n + np.eye(n), rng.standard_normal(n), rng.standard_normal((k, n)),
                           rng.standard_normal(k) - 1.0, np.full(n, -0.2), np.full(n, 0.2))
        times, answers, junk = [], set(), []
        for _ in range(repeat):
            junk.append(np.empty(int(rng.integers(1, 50_000))))  # moves the allocator
            t = time.process_time()
            step = DenseQPWorkspace(n, 1e-9, 10_000).solve(sub)
            times.append(time.process_time() - t)
            answers.add(step.d.tobytes() + step.lam.tobytes())
        rows.append({"n": n, "rows": k, "ms": 1e3 * float(np.median(times)), "answers": len(answers),
                     "status": step.status})
    return {"build": BUILD, "rows": rows}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--child", choices=("sse2", "native"), help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        print(json.dumps(_child(args.child, args.repeat, SIZES)))
        return
    runs = {b: json.loads(subprocess.run([sys.executable, __file__, "--child", b, "--repeat", str(args.repeat)],
                                         capture_output=True, text=True, check=True).stdout)
            for b in ("sse2", "native")}
    print(f"| n | rows | SSE2 [ms] | {runs['native']['build'].rsplit('_', 1)[-1]} [ms] | ratio | "
          f"answers SSE2 / other (of {args.repeat}) |")
    print("|---|---|---|---|---|---|")
    for a, b in zip(runs["sse2"]["rows"], runs["native"]["rows"], strict=True):
        print(f"| {a['n']} | {a['rows']} | {a['ms']:.1f} | {b['ms']:.1f} | {a['ms'] / b['ms']:.2f} | "
              f"{a['answers']} / {b['answers']} |")


if __name__ == "__main__":
    main()
