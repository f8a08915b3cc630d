"""Two design-SQP stalls (a kinked row, the penalty), reproduced (docs/benchmarks.md).

Usage::

    OPENBLAS_NUM_THREADS=1 .venv/bin/python bench/bench_sqp_stalls.py kink
    OPENBLAS_NUM_THREADS=1 .venv/bin/python bench/bench_sqp_stalls.py penalty

``kink``: the default design of ``bench/scenes/panda_cell.yaml`` (60 poses, no
certificate) with and without the pieces of kinked rows
(:mod:`calib_oed.solver.pieces`; "without" sets ``row_pieces_margin`` to 1e-300 m,
so no row is asked for its pieces). For the run without, at the last QP step
:math:`d` it prints the rows that lose *to first order* along :math:`d`:
:math:`(c(x + t\\hat d) - c(x) - t A\\hat d)/t` for :math:`t` = 1e-9, 1e-7, 1e-5
rad (:math:`\\hat d = d/\\|d\\|_\\infty`), constant in :math:`t` at a kink, O(t) for a
smooth row.

``penalty``: the SQP of ``fms_kr16_program`` (60 poses, KPI criterion) from the
stored exchange start ``bench/data/fms_kr16_program_stall_start.txt``, on
which the SQP with a nondecreasing penalty stalled (run this script at commit
584600c for that); prints status, iterations, value and the penalty's largest
and last values.
"""

from __future__ import annotations

import dataclasses
import sys
from pathlib import Path

import numpy as np

import calib_oed.solver.iteration as iteration
from calib_oed import design, load_scene, setup
from calib_oed.oed.design import DESIGN_SQP
from calib_oed.oed.objective import DesignObjective
from calib_oed.oed.problem import COLLISION_KINDS
from calib_oed.oed.refine import optimise_from

HERE = Path(__file__).resolve().parent


def kink() -> None:
    s = setup(load_scene(str(HERE / "scenes" / "panda_cell.yaml")))
    labels = [lbl for k, lbl in zip(s.feasibility.kinds, s.feasibility.labels, strict=True)
              if k in COLLISION_KINDS]
    last = {}
    search = iteration._Run._line_search

    def keep(run, rows, step):  # the iterate, its QP step and the problem of the design's last line search
        nlp = getattr(run.p.constraints, "__self__", None)  # the column generation passes a closure
        if nlp is not None and nlp.n == 60:
            last.update(x=run.pt.x.copy(), d=step.d.copy(), nlp=nlp)
        return search(run, rows, step)

    iteration._Run._line_search = keep
    for name, margin in (("with pieces", DESIGN_SQP.row_pieces_margin), ("without pieces", 1e-300)):
        d = design(s, 60, "kpi", certificate=False,
                   settings=dataclasses.replace(DESIGN_SQP, row_pieces_margin=margin))
        print(f"{name}: {d.solver['status']}, {d.solver['iterations']} iterations, "
              f"{d.value:.6e} mm², stationarity {d.solver['kkt_stationarity']:.1e}", flush=True)
    iteration._Run._line_search = search
    x, step, nlp = last["x"], last["d"], last["nlp"]
    c0, a0 = nlp.compute_constraints(x)
    unit = step / np.abs(step).max()
    m = len(labels)
    for t in (1e-9, 1e-7, 1e-5):
        loss = (nlp.compute_constraints(x + t * unit)[0] - c0 - t * (a0 @ unit)) / t
        worst = np.argsort(loss)[:3]
        print(f"  t = {t:.0e} rad: " + ", ".join(
            f"pose {r // m} {labels[r % m]} {loss[r]:+.2e} m/rad" for r in worst))


def penalty() -> None:
    s = setup(load_scene("fms_kr16_program"))
    q0 = np.loadtxt(HERE / "data" / "fms_kr16_program_stall_start.txt")
    mus = []
    step = iteration._Run.iterate

    def record(run, k):
        out = step(run, k)
        mus.append(run.mu)
        return out

    iteration._Run.iterate = record
    value, _, _, res = optimise_from(DesignObjective(s.problem, "kpi"), s.feasibility, q0)
    iteration._Run.iterate = step
    print(f"{res.status.value}, {res.iterations} iterations, {value:.6e} mm², "
          f"stationarity {res.kkt_stationarity:.1e}; penalty largest {max(mus):.3g}, last {mus[-1]:.3g}")


if __name__ == "__main__":
    {"kink": kink, "penalty": penalty}[sys.argv[1] if len(sys.argv) > 1 else "kink"]()
