"""Benchmark: design time under the full tracker error model against the isotropic model.

Run from the repository root:

    .venv/bin/python bench/bench_design_noise.py [--scene fms_kr16] [--poses 60] [--repeats 2]

The default design call (``design(s, n, "kpi")``: exchange start on the pool,
SQP with the exact Hessian, certificate) on the scene with the isotropic
``tracker.sigma`` alone (no ``tracker.noise``, no repeatability), on the same
scene with ``TrackerNoise.isotropic(sigma)`` (the same numbers through the full
model's code path: the machinery's cost at an equal problem), and with the full
model: the scene as shipped when it has ``tracker.noise`` (``fms_kr16``: the
Leica AT500's MPE and the KR 16's repeatability), else ``tracker.noise`` from
the AT500's MPE (k = 2: radial 0.005 mm + 0.00015 mm/m, lateral 0.0075 mm +
0.003 mm/m) and ``robot.repeatability`` 0.011 mm (KR 16 RP ±0.04 mm / 3.616),
alternated ``--repeats`` times in one process. Reports CPU time
(``time.process_time``, the figure to compare on a shared machine) and wall
time of each call, the SQP status and iterations, the ratios of the median CPU
times to the isotropic model's (target <= 1.3, issue 19) and the per-evaluation cost of the objective
(value + gradient + Hessian at the final design). Recorded in docs/benchmarks.md.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace

import numpy as np

from calib_oed.calibration.workflow import setup
from calib_oed.measurement.noise import TrackerNoise
from calib_oed.oed.design import design
from calib_oed.oed.objective import DesignObjective
from calib_oed.scene.reader import load_scene

#: Leica AT500 MPE read with k = 2 [m, m/m] and a KR 16's repeatability sigma [m].
AT500 = TrackerNoise((5e-6, 1.5e-7), (7.5e-6, 3e-6))
KR16_RHO = 1.1e-5


def realistic(scene):
    """The scene with the AT500 error model and the KR 16's repeatability."""
    return replace(scene, tracker=replace(scene.tracker, noise=AT500), repeatability=KR16_RHO)


def _per_evaluation(s, q, number=5) -> float:
    """CPU seconds of one value + gradient + Hessian of the KPI objective at ``q``."""
    obj = DesignObjective(s.problem, "kpi")
    start = time.process_time()
    for k in range(number):
        qq = q + 1e-9 * k  # a new point each time: no cache hit
        obj.compute(qq)
        obj.compute_hessian(qq)
    return (time.process_time() - start) / number


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default="fms_kr16")
    parser.add_argument("--poses", type=int, default=60)
    parser.add_argument("--repeats", type=int, default=2)
    args = parser.parse_args(argv)
    base = load_scene(args.scene)
    iso = replace(base, tracker=replace(base.tracker, noise=None), repeatability=0.0)
    same = replace(iso, tracker=replace(iso.tracker, noise=TrackerNoise.isotropic(float(iso.tracker.sigma[0]))))
    full = base if base.tracker.noise is not None else realistic(base)
    setups = {"isotropic": setup(iso), "isotropic, noise code path": setup(same), "full model": setup(full)}
    for s in setups.values():
        s.feasibility  # noqa: B018 (build the feasibility model outside the timing)
    cpu: dict[str, list[float]] = {k: [] for k in setups}
    parts: dict[str, list[tuple]] = {k: [] for k in setups}
    print(f"{args.scene}, design(s, {args.poses}, 'kpi'), default pipeline")
    last = {}
    for rep in range(args.repeats):
        for name, s in setups.items():
            wall, t0 = time.perf_counter(), time.process_time()
            d = design(s, args.poses, "kpi")
            t_cpu, wall = time.process_time() - t0, time.perf_counter() - wall
            cpu[name].append(t_cpu)
            last[name] = d
            its = d.solver.get("iterations")
            opt, cert = d.solver.get("cpu_seconds", 0.0), d.certificate.get("cpu_seconds", 0.0)
            parts[name].append((opt, cert, opt / max(its, 1)))
            print(f"  {rep}: {name:27s} CPU {t_cpu:6.2f} s (exchange+SQP {opt:5.2f} s, "
                  f"certificate {cert:5.2f} s), wall {wall:6.2f} s, {d.solver.get('status')}, "
                  f"{its} SQP iterations ({1e3 * opt / max(its, 1):.0f} ms CPU each), "
                  f"KPI sigma {d.kpi_sigma_mm.mean() * 1e3:.2f} um, efficiency {d.efficiency:.3f}")
    iso = np.median(cpu["isotropic"])
    for name in setups:
        med = np.median(np.array(parts[name]), axis=0)
        print(f"median CPU {name}: {np.median(cpu[name]):.2f} s, "
              f"{np.median(cpu[name]) / iso:.2f} x the isotropic model's (target <= 1.3); "
              f"exchange+SQP {med[0]:.2f} s, certificate {med[1]:.2f} s, "
              f"{1e3 * med[2]:.0f} ms per SQP iteration")
    for name, s in setups.items():
        print(f"  objective value+gradient+Hessian at the final design ({name}): "
              f"{_per_evaluation(s, last[name].q) * 1e3:.1f} ms CPU")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
