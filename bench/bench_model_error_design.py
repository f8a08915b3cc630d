"""The KPI criterion under model error against today's noise-only design, on the realistic simulator.

For each scene: the noise-only KPI design (criterion ``kpi``) and the model-error design
(``kpi_model``) of n poses from the same seed; then the whole loop on the
realistic simulator (:mod:`calib_oed.calibration.realistic`): for each of ``--truths`` true
robots and ``--noise`` noise draws, simulated tracker data at each design's poses, a plain
identification (``identify``, linear loss) and the TCP error at the working configurations.
Reports per design the achieved KPI error (RMS per axis over truths, noise draws and the
weighted working configurations, mm), its predicted value (sqrt of ``kpi_model``),
distinct joint vectors and arm positions, and the design CPU time.

    nice -n 5 python bench/bench_model_error_design.py [--scenes fms_kr16 ur5_table bench/scenes/ur10_cell.yaml]
        [-n 60] [--truths 5] [--noise 4] [--seed 0] [--out DIR]

``--out DIR`` also writes ``DIR/<scene>_designs.npz`` (both designs and the working
configurations) for the figure of docs/oed.md (``--figure`` draws it from there).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
from threadpoolctl import threadpool_limits

from calib_oed import load_scene
from calib_oed.calibration.identification import identify
from calib_oed.calibration.realistic import sample_truth
from calib_oed.calibration.realistic_measure import measure
from calib_oed.calibration.workflow import setup
from calib_oed.oed.design import design
from calib_oed.oed.positions import reflector_positions


def achieved_errors(s, q: np.ndarray, truths: int, noise: int, seed: int) -> np.ndarray:
    """Weighted mean squared KPI error per (truth, noise draw) [mm²], (truths, noise)."""
    problem, space = s.problem, s.problem.space
    free = problem.identifiability.free_indices
    w = problem.kpi.weights
    w = np.ones(len(problem.kpi.configurations)) if w is None else np.asarray(w, dtype=float)
    out = np.zeros((truths, noise))
    for k in range(truths):
        truth = sample_truth(s, np.random.default_rng([seed, k]))
        s_true = truth.compute_kpi_values(problem.kpi)
        for r in range(noise):
            meas = measure(truth, problem.models, q, np.random.default_rng([seed, k, r, 1]))
            p_hat = identify(space, meas.blocks, free).p
            err = (problem.kpi.compute_values(space, p_hat) - s_true) * 1e3  # (t, 3) [mm]
            out[k, r] = float(w @ np.sum(err**2, axis=1) / (3 * w.sum()))
    return out


def run_scene(scene_ref: str, n: int, truths: int, noise: int, seed: int, out: Path | None) -> dict:
    s = setup(load_scene(scene_ref))
    row = {"scene": s.scene.name, "n": n, "prior": s.scene.discrepancy().describe()}
    designs = {}
    for crit in ("kpi", "kpi_model"):
        t0, c0 = time.perf_counter(), time.process_time()
        d = design(s, n, crit, seed=seed, certificate=False)
        designs[crit] = d
        mse = achieved_errors(s, d.q, truths, noise, seed)
        row[crit] = {
            "design_cpu_s": d.solver["cpu_seconds"], "design_wall_s": time.perf_counter() - t0,
            "process_cpu_s": time.process_time() - c0, "iterations": d.solver.get("iterations"),
            "status": d.solver.get("status"), "distinct_poses": len(d.multiplicity),
            "distinct_positions": d.distinct_positions,
            "predicted_rms_mm": float(np.sqrt(d.criteria["kpi_model"])),
            "noise_only_sigma_mm": float(np.sqrt(d.criteria["kpi"])),
            "achieved_rms_mm": float(np.sqrt(mse.mean())),
            "achieved_rms_per_truth_mm": np.sqrt(mse.mean(axis=1)).round(5).tolist(),
        }
    row["achieved_ratio"] = row["kpi_model"]["achieved_rms_mm"] / row["kpi"]["achieved_rms_mm"]
    row["design_cpu_ratio"] = row["kpi_model"]["design_cpu_s"] / row["kpi"]["design_cpu_s"]
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
        space = s.problem.space
        np.savez(out / f"{s.scene.name}_designs.npz", noise_only=designs["kpi"].q,
                 model_error=designs["kpi_model"].q, working=s.problem.kpi.configurations,
                 p_noise_only=reflector_positions(space, designs["kpi"].q)[:, 0],
                 p_model_error=reflector_positions(space, designs["kpi_model"].q)[:, 0],
                 p_working=reflector_positions(space, s.problem.kpi.configurations)[:, 0])
    return row


def figure(out: Path, scene: str) -> Path:
    """Reflector positions of both designs and the working configurations (top and side views)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    data = np.load(out / f"{scene}_designs.npz")
    fig, axes = plt.subplots(1, 2, figsize=(10, 4.5))
    for ax, (i, j, label) in zip(axes, [(0, 1, "top view: x, y"), (0, 2, "side view: x, z")], strict=True):
        for key, style in (("p_noise_only", dict(marker="o", facecolors="none", edgecolors="tab:blue",
                                                   label="noise-only kpi design")),
                           ("p_model_error", dict(marker="^", color="tab:red", s=18,
                                                    label="kpi_model design")),
                           ("p_working", dict(marker="*", color="k", s=120, label="working configurations"))):
            p = data[key] * 1e3
            ax.scatter(p[:, i], p[:, j], **style)
        ax.set_xlabel("xyz"[i] + " [mm]")
        ax.set_ylabel("xyz"[j] + " [mm]")
        ax.set_title(f"{scene}: reflector positions, {label}")
        ax.set_aspect("equal", adjustable="datalim")
    axes[0].legend(loc="best", fontsize=8)
    fig.tight_layout()
    path = out / f"{scene}_model_error_designs.png"
    fig.savefig(path, dpi=110)
    return path


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", nargs="+", default=["fms_kr16", "ur5_table", "bench/scenes/ur10_cell.yaml"])
    ap.add_argument("-n", type=int, default=60)
    ap.add_argument("--truths", type=int, default=5)
    ap.add_argument("--noise", type=int, default=4)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path)
    ap.add_argument("--figure", metavar="SCENE", help="only draw the figure of SCENE from --out")
    args = ap.parse_args()
    if args.figure:
        print(figure(args.out, args.figure))
        return
    with threadpool_limits(limits=1, user_api="blas"):
        for scene in args.scenes:
            print(json.dumps(run_scene(scene, args.n, args.truths, args.noise, args.seed, args.out)), flush=True)


if __name__ == "__main__":
    main()
