"""How far a pose-block + low-rank form is from ``kpi_model``'s Hessian (issue 33).

    OPENBLAS_NUM_THREADS=1 PYTHONPATH=. python bench/bench_model_error_hessian_structure.py \
        [--scene fms_kr16] [-n 60] [--seed 0] [--design FILE] [--ranks 240,120,60]

A per-iteration cost linear in n needs the SQP's Hessian as pose blocks plus a coupling of few
columns (``blkdiag(D_j) + U Uᵀ``, the block QP's form). This script measures, at one design, how
well such forms stand for :math:`|H|`, the exact Hessian of ``kpi_model`` made positive definite by
the absolute value of its eigenvalues (the form the SQP takes whole up to
:data:`calib_oed.oed.model_error_hessian.FULL_COUPLING_MAX_SIZE`):

* the spectrum of :math:`H`: negative eigenvalues and their share of :math:`\\sum|\\theta|`, the
  share of the pose-diagonal blocks in :math:`\\|H\\|_F^2`;
* the *relative curvature* of a form :math:`\\tilde H`: the eigenvalues :math:`\\mu` of
  :math:`|H|^{-1/2}\\tilde H|H|^{-1/2}` (min, 5th percentile, median, 95th percentile, max). Along
  a direction with :math:`\\mu < 1` the QP's model has less curvature than :math:`|H|` and its step
  overshoots by up to :math:`1/\\mu`; :math:`\\mu > 1`, the step falls short;
* the forms: the package's lifted form (:func:`calib_oed.oed.model_error_hessian.structured_hessian`:
  the :math:`r` largest :math:`|\\theta|` as :math:`U`, the rest by its pose blocks) for
  :math:`r` = n·nv/3 (the package's) and each of ``--ranks``; the pose blocks alone (each made
  positive definite by its own eigenvalues); and a *scaled* form: with :math:`B` those blocks,
  the :math:`r` largest :math:`|\\lambda|` of :math:`B^{-1/2}OB^{-1/2}` (:math:`O` the
  off-diagonal blocks of :math:`H`), :math:`\\tilde H = B^{1/2}(I + Q\\,(\\max(|1+\\Lambda|,
  0.05) - 1)\\,Q^\\top)B^{1/2}`; the count of :math:`|\\lambda| > 0.3` says how many columns a
  coupling needs in that basis.

The design is the default call's (``design(scene, n, seed=seed, certificate=False)``, the SQP to
its budget: about 30 s at 60 poses, 5 min at 250) or ``--design FILE``, the ``--json`` output of
``calib-oed design``. The Hessian is the package's (:func:`~calib_oed.oed.model_error_hessian.design_hessian`,
its matrix taken before it is made definite); the comparisons are dense (n·nv)² matrices: a
minute at 250 poses.
"""

from __future__ import annotations

import argparse
import json

import numpy as np
import scipy.linalg

import calib_oed.oed.model_error_hessian as meh
from calib_oed import load_scene
from calib_oed.calibration.workflow import setup
from calib_oed.oed import model_error
from calib_oed.oed.design import design
from calib_oed.oed.objective import DesignObjective

#: Floor of :math:`|1 + \lambda|` in the scaled form (a direction the blocks and the coupling cancel
#: in keeps this much of the blocks' curvature).
SCALED_FLOOR = 0.05


def exact_hessian(s, q: np.ndarray) -> np.ndarray:
    """The exact Hessian of the default ``kpi_model`` objective at ``q``, before it is made definite."""
    objective = DesignObjective(s.problem, model_error.scene_criterion(s, None))
    seen = {}
    lifted = meh.structured_hessian

    def keep(h, nv, rank=None):
        seen["h"] = h
        return lifted(h, nv, rank)

    meh.structured_hessian = keep
    try:
        meh.design_hessian(objective, q)
    finally:
        meh.structured_hessian = lifted
    if "h" not in seen:
        raise SystemExit("this scene's default criterion has no exact kpi_model Hessian "
                         "(kpi_model with the joint-space prior, position measurements)")
    return seen["h"]


def _blocks(h: np.ndarray, nv: int) -> np.ndarray:
    n = h.shape[0] // nv
    return np.stack([h[j * nv:(j + 1) * nv, j * nv:(j + 1) * nv] for j in range(n)])


def _definite(blocks: np.ndarray, floor: float):
    """Each block by the absolute value of its eigenvalues (floored): the block, its square root and
    inverse square root."""
    w, v = np.linalg.eigh(blocks)
    w = np.maximum(np.abs(w), floor)
    out = [np.einsum("jab,jb,jcb->jac", v, p, v) for p in (w, np.sqrt(w), 1.0 / np.sqrt(w))]
    return [scipy.linalg.block_diag(*b) for b in out]


def relative_curvature(inv_half: np.ndarray, h_form: np.ndarray) -> list[float]:
    """Min, 5th percentile, median, 95th percentile, max of the eigenvalues of
    :math:`|H|^{-1/2}\\tilde H|H|^{-1/2}`."""
    mu = np.linalg.eigvalsh(inv_half @ h_form @ inv_half)
    return [float(mu[0]), *(float(v) for v in np.percentile(mu, [5, 50, 95])), float(mu[-1])]


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", default="fms_kr16")
    ap.add_argument("-n", type=int, default=60)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--design", help="a design (calib-oed design --json) instead of computing one")
    ap.add_argument("--ranks", default="240,120,60", help="columns of the coupling, comma-separated")
    args = ap.parse_args(argv)
    if args.design:
        with open(args.design) as f:
            record = json.load(f)
        s = setup(load_scene(record["scene"]))
        q = np.asarray(record["configurations_rad"], dtype=float)
    else:
        s = setup(load_scene(args.scene))
        q = design(s, args.n, None, seed=args.seed, certificate=False).q
    h = exact_hessian(s, q)
    n, nv = q.shape
    size = n * nv
    theta, vec = np.linalg.eigh(h)
    floor = meh.EIGENVALUE_FLOOR * np.abs(theta).max()
    mag = np.maximum(np.abs(theta), floor)
    inv_half = (vec / np.sqrt(mag)) @ vec.T
    blocks = _blocks(h, nv)
    off = h - scipy.linalg.block_diag(*blocks)
    print(json.dumps({"poses": n, "size": size, "negative_eigenvalues": int((theta < 0).sum()),
                      "negative_share_of_abs_sum": round(float(np.abs(theta[theta < 0]).sum() / np.abs(theta).sum()), 4),
                      "pose_blocks_share_of_frobenius2": round(float((blocks ** 2).sum() / (h ** 2).sum()), 3)}))
    ranks = [size // 3] + [int(r) for r in args.ranks.split(",") if r and int(r) < size // 3]

    def row(form: str, rank, stats):
        print(json.dumps({"form": form, "rank": rank,
                          "relative_curvature_min_p5_median_p95_max": [round(v, 3) for v in stats]}))

    for r in [None, *ranks]:
        sh = meh.structured_hessian(h, nv, r)
        dense = scipy.linalg.block_diag(*sh.blocks) + sh.low_rank @ sh.low_rank.T
        row("lifted" if r is not None else "|H| whole", r, relative_curvature(inv_half, dense))
    b, b_half, b_inv_half = _definite(blocks, floor)
    row("pose blocks alone", 0, relative_curvature(inv_half, b))
    lam, qm = np.linalg.eigh(b_inv_half @ off @ b_inv_half)
    order = np.argsort(-np.abs(lam))
    print(json.dumps({"scaled_coupling_abs_eigenvalues_top8": [round(float(v), 2) for v in np.abs(lam[order[:8]])],
                      "scaled_coupling_count_above_0.3": int((np.abs(lam) > 0.3).sum())}))
    for r in ranks:
        k = order[:r]
        f = np.maximum(np.abs(1.0 + lam[k]), SCALED_FLOOR) - 1.0
        row("scaled", r, relative_curvature(inv_half, b_half @ (np.eye(size) + (qm[:, k] * f) @ qm[:, k].T) @ b_half))


if __name__ == "__main__":
    main()
