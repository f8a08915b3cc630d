"""Study: what the realistic tracker error model and robot repeatability change in the designs.

Run from the repository root (about 4 min on 2 cores):

    .venv/bin/python bench/study_design_noise.py [--scenes fms_kr16 bench/scenes/ur10_cell.yaml]
        [--poses 60] [--runs 1000] [--figures docs]

For each scene: the shipped isotropic model (``tracker.sigma`` 0.01 mm) and the
realistic one, ``tracker.noise`` from the Leica AT500's published MPE read with
k = 2 (ADM ±(10 µm + 0.3 µm/m), transverse ±(15 µm + 6 µm/m): radial
0.005 mm + 0.00015 mm/m, lateral 0.0075 mm + 0.003 mm/m) and the arm's
ISO 9283 repeatability as sigma = RP / 3.616 (KR 16: RP 0.04 mm -> 0.011 mm;
UR10: RP 0.1 mm -> 0.0277 mm). Designs of ``--poses`` poses, all by the default
pipeline (``design(s, n, criterion)``): the heuristic (seed 0), the C_p-optimal
(``params``) and KPI-optimal (``kpi``) under the realistic model, and the
KPI-optimal under the isotropic model. Every design is evaluated under the
realistic model: KPI sigma (RMS per axis, mm), the reflector's range to the
tracker (mean, min, max [m]) and the spread of the reflector positions (RMS
distance to their centroid [m]). Then the loss of the isotropic model's
KPI-optimal design and ``--runs`` Monte Carlo calibrations of the realistic
KPI-optimal design (ratio, coverage). Writes one figure per scene
(``<figures>/uncertainty_design_<scene>.png``). Recorded in docs/uncertainty.md.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from calib_oed.calibration.montecarlo import monte_carlo
from calib_oed.calibration.workflow import heuristic_design, setup
from calib_oed.measurement import evaluate_setup
from calib_oed.measurement.noise import TrackerNoise, sigma_from_mpe, sigma_from_repeatability
from calib_oed.oed.design import design
from calib_oed.scene.reader import load_scene

#: Leica AT500 user manual §2.8.2 (ISO 10360-10:2021 Annex D, 1.5" RRR), MPE as k = 2 [m, m/m].
AT500 = TrackerNoise(sigma_from_mpe(10e-6, 0.3e-6), sigma_from_mpe(15e-6, 6e-6))
#: ISO 9283 pose repeatability RP of the arms [m] (vendor data sheets; docs/uncertainty.md).
REPEATABILITY_RP = {"kr16": 0.04e-3, "ur10": 0.1e-3, "ur5": 0.1e-3}


def realistic(scene):
    """The scene with the AT500 error model and its arm's repeatability."""
    rho = sigma_from_repeatability(REPEATABILITY_RP[scene.robot.name])
    return replace(scene, tracker=replace(scene.tracker, noise=AT500), repeatability=rho)


def geometry(s, q) -> dict:
    """Reflector ranges to the tracker [m] and the spread of the positions [m]."""
    state = evaluate_setup(s.problem.space, None, q, regressor=False, jacobian=False)
    y = np.concatenate([m.compute_values(state) for m in s.problem.models])
    d = np.linalg.norm(y, axis=1)
    spread = float(np.sqrt(np.mean(np.sum((y - y.mean(axis=0)) ** 2, axis=1))))
    return {"ranges": d, "range_mean": float(d.mean()), "range_min": float(d.min()),
            "range_max": float(d.max()), "spread": spread}


def kpi_sigma_mm(s, q) -> float:
    """RMS per-axis KPI sigma over the working configurations [mm]."""
    return float(np.sqrt(np.mean(s.problem.kpi_sigma(q) ** 2)) * 1e3)


def study(scene_name: str, poses: int, runs: int, figures: Path | None) -> dict:
    base = load_scene(scene_name)
    s_iso, s_real = setup(base), setup(realistic(base))
    designs, info = {}, {}
    designs["heuristic"] = heuristic_design(s_real, poses, 0)
    for label, s, crit in (("C_p-optimal", s_real, "params"), ("KPI-optimal", s_real, "kpi"),
                           ("KPI-optimal (isotropic model)", s_iso, "kpi")):
        wall, cpu = time.perf_counter(), time.process_time()
        d = design(s, poses, crit)
        info[label] = (d.solver.get("status"), d.efficiency, time.process_time() - cpu,
                       time.perf_counter() - wall)
        designs[label] = d.q
    rows = {}
    print(f"\n{base.name}: {poses} poses; realistic model: AT500 MPE/2 + repeatability "
          f"{s_real.scene.repeatability * 1e3:.4f} mm")
    print(f"{'design':32s} {'KPI sigma [um]: realistic':>25s} {'isotropic':>9s} "
          f"{'range [m]: mean':>15s} {'min':>6s} {'max':>6s} {'spread [m]':>10s}")
    for label, q in designs.items():
        g = geometry(s_real, q)
        rows[label] = dict(g, sigma_real=kpi_sigma_mm(s_real, q), sigma_iso=kpi_sigma_mm(s_iso, q))
        r = rows[label]
        extra = "" if label not in info else (f"  [{info[label][0]}, efficiency {info[label][1]:.2f}, "
                                              f"CPU {info[label][2]:.1f} s]")
        print(f"{label:32s} {r['sigma_real'] * 1e3:25.2f} {r['sigma_iso'] * 1e3:9.2f} "
              f"{r['range_mean']:15.3f} {r['range_min']:6.3f} {r['range_max']:6.3f} "
              f"{r['spread']:10.3f}{extra}")
    loss = (rows["KPI-optimal (isotropic model)"]["sigma_real"] / rows["KPI-optimal"]["sigma_real"]) ** 2
    print(f"isotropic model's KPI-optimal design under the realistic model: {loss:.3f} x the "
          f"variance of the realistic KPI-optimal design (loss {100 * (loss - 1):.1f} %)")
    wall, cpu = time.perf_counter(), time.process_time()
    mc = monte_carlo(s_real.problem, designs["KPI-optimal"], runs, 1, n_jobs=2)
    print(f"Monte Carlo, realistic KPI-optimal design, {runs} runs: ratio {mc.ratio[0]:.3f} "
          f"(s.e. {mc.ratio_standard_error[0]:.3f}), coverage {mc.coverage[0]:.3f}, "
          f"wall {time.perf_counter() - wall:.1f} s, CPU (main process) {time.process_time() - cpu:.1f} s")
    if figures is not None:
        _figure(base.name, rows, figures / f"uncertainty_design_{base.name}.png")
    return rows


def _figure(name: str, rows: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(8.0, 3.0), dpi=90)
    bins = np.linspace(min(r["range_min"] for r in rows.values()),
                       max(r["range_max"] for r in rows.values()), 16)
    for label, color in (("KPI-optimal (isotropic model)", "tab:gray"), ("KPI-optimal", "tab:blue")):
        ax1.hist(rows[label]["ranges"], bins=bins, alpha=0.6, color=color,
                 label=label.replace("KPI-optimal", "KPI-opt."))
    ax1.set_xlabel("reflector range to the tracker [m]")
    ax1.set_ylabel("poses")
    ax1.legend(fontsize=7)
    labels = list(rows)
    ax2.barh(range(len(labels)), [rows[k]["sigma_real"] * 1e3 for k in labels], color="tab:blue")
    ax2.set_yticks(range(len(labels)),
                   [k.replace(" (isotropic model)", "\n(isotropic model)") for k in labels], fontsize=7)
    ax2.invert_yaxis()
    ax2.set_xlabel("KPI sigma, realistic model [µm]")
    fig.suptitle(f"{name}: designs under the AT500 + repeatability model", fontsize=9)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    print(f"figure: {path}")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", nargs="+", default=["fms_kr16", "bench/scenes/ur10_cell.yaml"])
    parser.add_argument("--poses", type=int, default=60)
    parser.add_argument("--runs", type=int, default=1000)
    parser.add_argument("--figures", default="docs", help="folder of the figures ('' for none)")
    args = parser.parse_args(argv)
    figures = Path(args.figures) if args.figures else None
    for name in args.scenes:
        study(name, args.poses, args.runs, figures)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
