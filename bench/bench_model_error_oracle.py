"""How good a design can the plain fit have on the realistic simulator? An oracle bound for issue 30.

The design the criterion would choose if it knew the simulator's unmodelled errors: the
exchange algorithm on a feasible pool (the ``kpi`` design plus ``--pool`` seeded feasible
poses) minimises the linearised expected KPI error of the noise-weighted fit,

.. math::
    \\Phi = \\frac{1}{S}\\sum_s \\lVert G M^{-1}F^\\top W e^{(s)} - e_w^{(s)}\\rVert^2/(3t)
          + \\mathrm{tr}(G M^{-1} G^\\top)/(3t) \\quad [\\mathrm{m}^2],

:math:`e^{(s)}` the true-minus-model error of the reflector at every pool pose (tracker frame)
and :math:`e_w^{(s)}` of the TCP at the working configurations (world) of realistic truth
``s`` (truths ``--first`` .. ``--first + S - 1``, with the true geometry: only the unmodelled
part), :math:`F = WJ` the whitened rows, :math:`M = F^\\top F`. The design it finds is then
judged by the whole loop of ``bench_model_error_design.py`` on other truths (0 ..
``--truths - 1``), paired with the ``kpi`` design: a bound on what any criterion can reach
with this fit, not a method (it needs the truths).

    nice -n 10 python bench/bench_model_error_oracle.py [--scene fms_kr16] [-n 60] [--samples 200]
        [--pool 2000] [--sweeps 6] [--truths 40]
"""

from __future__ import annotations

import argparse
import json

import numpy as np
from bench_model_error_design import achieved_errors, paired_ratio, rms_with_error
from threadpoolctl import threadpool_limits

from calib_oed import load_scene
from calib_oed.calibration.realistic import sample_truth
from calib_oed.calibration.workflow import setup
from calib_oed.feasibility.sampling import sample_feasible
from calib_oed.measurement.base import evaluate_setup
from calib_oed.oed.design import design
from calib_oed.oed.positions import distinct_positions
from calib_oed.oed.whitening import whitening_pieces


def unmodelled_errors(s, q: np.ndarray, samples: int, first: int) -> tuple[np.ndarray, np.ndarray]:
    """True minus model (true geometry) of the reflector at ``q`` (S, n, 3) [m, tracker frame] and of
    the TCP at the working configurations (S, 3t) [m, world], per truth."""
    problem, space = s.problem, s.problem.space
    rot = space.tracker_placement(None).rotation
    point = np.asarray(problem.kpi.point, dtype=float)
    e, e_w = [], []
    for k in range(first, first + samples):
        truth = sample_truth(s, np.random.default_rng([0, k]))
        e.append(-truth.compute_model_errors(truth.p, q)[:, 0] @ rot)
        e_w.append(-truth.compute_model_errors(truth.p, problem.kpi.configurations, point=point).ravel())
    return np.array(e), np.array(e_w)


def oracle_design(s, start: np.ndarray, pool: int, samples: int, first: int, sweeps: int, seed: int):
    """The exchange design on the pool and its value per sweep [mm RMS] (module docstring)."""
    problem, space = s.problem, s.problem.space
    free = problem.identifiability.free_indices
    cand = np.vstack([start, sample_feasible(s.feasibility, pool, seed)])
    state = evaluate_setup(space, None, cand, regressor=True, jacobian=True)
    pieces = whitening_pieces(problem.models[0], state, free, 0)
    rows = np.einsum("nab,nbf->naf", pieces.w, pieces.jac)
    e, e_w = unmodelled_errors(s, cand, samples, first)
    info = np.einsum("naf,nag->nfg", rows, rows)
    cross = np.einsum("naf,nab,snb->nfs", rows, pieces.w, e)
    g = problem.kpi_jacobian(None)[:, free]

    def value(m, b):
        x = np.linalg.solve(m, g.T)
        err = np.einsum("...ft,...fs->...st", x, b) - e_w
        return (err**2).mean(axis=(-2, -1)) + np.einsum("tf,...ft->...", g, x) / g.shape[0]

    idx = list(range(len(start)))
    m, b = info[idx].sum(axis=0), cross[idx].sum(axis=0)
    best = value(m, b)
    history = [float(np.sqrt(best) * 1e3)]
    for _ in range(sweeps):
        improved = False
        for pos, out in enumerate(list(idx)):
            vals = value(m - info[out] + info, b - cross[out] + cross)
            vals[~np.isfinite(vals)] = np.inf
            c = int(np.argmin(vals))
            if vals[c] < best * (1 - 1e-9):
                m, b, best = m - info[out] + info[c], b - cross[out] + cross[c], vals[c]
                idx[pos], improved = c, True
        history.append(float(np.sqrt(best) * 1e3))
        if not improved:
            break
    return cand[idx], history


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="fms_kr16")
    ap.add_argument("-n", type=int, default=60)
    ap.add_argument("--samples", type=int, default=200)
    ap.add_argument("--first", type=int, default=100, help="first truth of the oracle's samples")
    ap.add_argument("--pool", type=int, default=2000)
    ap.add_argument("--sweeps", type=int, default=6)
    ap.add_argument("--truths", type=int, default=40)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    if args.first < args.truths:
        ap.error("--first must be >= --truths: the oracle's truths and the judged ones must differ")
    with threadpool_limits(limits=1, user_api="blas"):
        s = setup(load_scene(args.scene))
        start = design(s, args.n, "kpi", seed=args.seed, certificate=False).q
        q, history = oracle_design(s, start, args.pool, args.samples, args.first, args.sweeps, args.seed + 7)
        row = {"scene": s.scene.name, "n": args.n, "oracle_rms_per_sweep_mm": history,
               "distinct_positions": len(distinct_positions(s.problem.space, q))}
        ref = achieved_errors(s, start, args.truths, 1, args.seed, False)["fit"]
        mse = achieved_errors(s, q, args.truths, 1, args.seed, False)["fit"]
        row["kpi_achieved_rms_mm"], row["kpi_se_mm"] = rms_with_error(ref)
        row["oracle_achieved_rms_mm"], row["oracle_se_mm"] = rms_with_error(mse)
        row["ratio"], row["ratio_se"] = paired_ratio(mse, ref, args.seed)
        print(json.dumps(row), flush=True)


if __name__ == "__main__":
    main()
