"""How the exact Lagrangian Hessian is made positive definite: per block or whole matrix, abs or floor.

Usage::

    OPENBLAS_NUM_THREADS=1 .venv/bin/python bench/bench_hessian_modification.py [SCENE] [N]
    OPENBLAS_NUM_THREADS=1 .venv/bin/python bench/bench_hessian_modification.py --active SCENE[,SCENE...] [N]

Runs the default design pipeline (no certificate) on SCENE (default
``bench/scenes/ur10_cell.yaml``) with N poses (default 60) for each
``(hessian_modification_scope, hessian_modification)`` of
:class:`calib_oed.solver.settings.SQPSettings`, the pool drawn once
beforehand, and prints value, status, iterations, CPU and the last
stationarity. With ``--active`` it compares instead, per scene, the default
(per block, ``abs``) without and with curvature along the active rows
(``active_curvature`` 0 and 1, :func:`calib_oed.solver.hessian.augment_active`).
Results in docs/benchmarks.md.
"""

from __future__ import annotations

import dataclasses
import sys
import time

from calib_oed import design, load_scene, setup
from calib_oed.oed.design import DESIGN_SQP

VARIANTS = (("block", "abs"), ("matrix", "abs"), ("block", "floor"), ("matrix", "floor"))


def active(names: list[str], n: int) -> None:
    """The default SQP without and with curvature along the active rows, per scene."""
    for name in names:
        s = setup(load_scene(name))
        design(s, 12, "kpi", certificate=False, settings=dataclasses.replace(DESIGN_SQP, max_iterations=1))
        for weight in (0.0, 1.0):
            settings = dataclasses.replace(DESIGN_SQP, active_curvature=weight)
            records = []
            t = time.process_time()
            d = design(s, n, "kpi", certificate=False, settings=settings, callback=records.append)
            print(name, f"active_curvature {weight:g}", f"{d.value:.6g}", d.solver["status"],
                  d.solver["iterations"], f"cpu {time.process_time() - t:.1f}",
                  f"stationarity {records[-1].stationarity:.1e}", flush=True)


def main() -> None:
    if len(sys.argv) > 2 and sys.argv[1] == "--active":
        active(sys.argv[2].split(","), int(sys.argv[3]) if len(sys.argv) > 3 else 60)
        return
    name = sys.argv[1] if len(sys.argv) > 1 else "bench/scenes/ur10_cell.yaml"
    n = int(sys.argv[2]) if len(sys.argv) > 2 else 60
    s = setup(load_scene(name))
    # draw and cache the pool once, so every variant starts from the same exchange design
    design(s, 12, "kpi", certificate=False, settings=dataclasses.replace(DESIGN_SQP, max_iterations=1))
    for scope, mod in VARIANTS:
        settings = dataclasses.replace(DESIGN_SQP, hessian_modification_scope=scope,
                                       hessian_modification=mod)
        records = []
        t = time.process_time()
        d = design(s, n, "kpi", certificate=False, settings=settings, callback=records.append)
        print(name, scope, mod, f"{d.value:.6g}", d.solver["status"], d.solver["iterations"],
              f"cpu {time.process_time() - t:.1f}", f"stationarity {records[-1].stationarity:.1e}",
              flush=True)


if __name__ == "__main__":
    main()
