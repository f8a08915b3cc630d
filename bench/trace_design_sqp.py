"""Trace: the design SQP's iterations, with the curvature and agreement behind each step.

    OPENBLAS_NUM_THREADS=1 PYTHONPATH=<checkout> .venv/bin/python bench/trace_design_sqp.py \\
        [--scene fms_kr16] [--n 60] [--criterion kpi] [--every 1] [--first 0]

Runs ``calib-oed design SCENE -n N --criterion C --no-certificate`` in this process (the design
written to a temporary folder) and wraps, by monkeypatch here and not in the library, the
design SQP's ``solver.subproblem.positive_definite`` and ``solver.iteration._Run.iterate`` and
``_ratio_update``. One line per iteration of the design SQP (not of the start's local
maximisations), every ``--every``-th from ``--first``:

- ``box``, ``step``: the trust box Delta and the accepted step's inf-norm [rad];
- ``neg blocks``, ``min theta``: pose blocks of the exact Lagrangian Hessian with a negative
  eigenvalue, and its smallest eigenvalue over the largest magnitude;
- ``s'Hs``, ``s'H~s``: the curvature along the accepted step of the exact Hessian and of the
  one the QP used (made positive definite);
- ``rho``: the merit's actual over predicted reduction of the ratio rule, ``muv/prd`` the
  share of the prediction that is the removal of the penalised violation at x_k, ``v1``: the l1
  violation before and after the step, ``mu``: the single penalty, ``lam max``: the largest
  multiplier of the QP;
- ``alpha``: the factor of a longer step (``IterationRecord.extrapolated``, 1 when none or
  when the checkout predates it).

Works on any checkout with these functions (``_ratio_update`` since the ratio rule).
"""

from __future__ import annotations

import argparse
import tempfile

import numpy as np


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="fms_kr16")
    ap.add_argument("--n", type=int, default=60)
    ap.add_argument("--criterion", default="kpi")
    ap.add_argument("--every", type=int, default=1)
    ap.add_argument("--first", type=int, default=0)
    args = ap.parse_args()

    import calib_oed.solver.iteration as iteration
    import calib_oed.solver.subproblem as subproblem
    from calib_oed.cli import main as cli
    from calib_oed.solver.qp import matvec

    size = None  # variables of the design SQP (the start's maximisations have fewer)
    exact = {}  # the last exact Hessian given to the QP, and its eigenvalues
    ratio = {}  # what the last _ratio_update saw

    positive_definite = subproblem.positive_definite

    def traced_positive_definite(h, floor, normals=None):
        exact["h"], exact["theta"] = h, np.linalg.eigvalsh(0.5 * (h.blocks + h.blocks.transpose(0, 2, 1)))
        return positive_definite(h, floor, normals)

    ratio_update = iteration._Run._ratio_update

    def traced_ratio_update(self, old, new, d, delta, d_norm, backtracks):
        ratio.clear()
        if old.x.size == size:
            # the merit's penalty at x_k (one weight per row where the checkout has them)
            penalty = self._penalty(old) if hasattr(self, "_penalty") else self.mu * old.violation_l1
            predicted = -(float(old.g @ d) + 0.5 * float(d @ matvec(self._sub[0].H, d))) + penalty
            ratio.update(rho=self._agreement(old, new, d), share=penalty / predicted
                         if predicted > 0 else np.nan, v_old=old.violation_l1, v_new=new.violation_l1)
        return ratio_update(self, old, new, d, delta, d_norm, backtracks)

    iterate = iteration._Run.iterate

    def traced_iterate(self, k):
        x0 = self.pt.x.copy()
        exact.clear()
        rec = iterate(self, k)
        if self.pt.x.size != size or k < args.first or (k - args.first) % args.every:
            return rec
        s = self.pt.x - x0
        line = f"{k:4d} {rec.step_bound:8.1e} {rec.step_norm:8.1e} {rec.objective:.10e} {rec.stationarity:8.1e}"
        if "h" in exact:
            theta = exact["theta"]
            line += (f" {int((theta.min(axis=1) < -1e-6 * np.abs(theta).max()).sum()):5d}"
                     f" {theta.min() / np.abs(theta).max():+8.2f}")
            if np.any(s):
                line += f" {float(s @ (exact['h'] @ s)):+10.2e} {float(s @ matvec(self._sub[0].H, s)):10.2e}"
            else:
                line += f" {'':>10s} {'':>10s}"
        else:
            line += f" {'':>5s} {'':>8s} {'':>10s} {'':>10s}"
        if ratio:
            line += (f" {ratio['rho']:6.3f} {ratio['share']:7.3f} {ratio['v_old']:8.1e} {ratio['v_new']:8.1e}"
                     f" {self.mu:8.1e}")
        else:
            line += f" {'':>6s} {'':>7s} {'':>8s} {'':>8s} {self.mu:8.1e}"
        print(line + f" {float(np.max(self.lam, initial=0.0)):8.1e} {getattr(rec, 'extrapolated', 1.0):6.2f}",
              flush=True)
        return rec

    subproblem.positive_definite = traced_positive_definite
    iteration._Run._ratio_update = traced_ratio_update
    iteration._Run.iterate = traced_iterate
    size = 6 * args.n  # the shipped arms have 6 joints
    print(f"{'k':>4s} {'box':>8s} {'step':>8s} {'objective':>16s} {'stat':>8s} {'neg':>5s} {'min th':>8s}"
          f" {'sHs':>10s} {'sH~s':>10s} {'rho':>6s} {'muv/prd':>7s} {'v1 old':>8s} {'v1 new':>8s}"
          f" {'mu':>8s} {'lam max':>8s} {'alpha':>6s}", flush=True)
    with tempfile.TemporaryDirectory() as out:
        cli(["design", args.scene, "-n", str(args.n), "--criterion", args.criterion, "--no-certificate",
             "-o", out, "--quiet"])


if __name__ == "__main__":
    main()
