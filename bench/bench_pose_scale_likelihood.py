"""The likelihood chooses the pose scale: identify's pose-scaled model error against the stationary one.

Per scene and realistic truth (60 training poses random in the joint limits, seed 1000 + truth,
as ``bench_trust.py``): ``identify_robust`` with identify's model-error prior
(``model_error.start_prior``, pose-scaled by the joint prior), then the stationary prior fitted
on the same linearisation (``start_prior(..., scaled=False)``, the pose-scaled kernel with its
weight at 0, so nested). Prints the restricted log-likelihood of the pose-scaled fit minus the
stationary one (one more hyperparameter) and the fitted weight of the pose scale.

    python bench/bench_pose_scale_likelihood.py --scenes fms_kr16 ur5_table --truths 6
"""

from __future__ import annotations

import argparse

from bench_trust import simulate

from calib_oed.calibration.model_error import fit_model_error, start_prior
from calib_oed.calibration.robust import identify_robust
from calib_oed.calibration.workflow import setup
from calib_oed.scene.reader import load_scene


def likelihood_gap(name: str, truth: int, n_train: int = 60) -> tuple[float, float]:
    """(restricted LL pose-scaled − stationary, fitted weight) of scene ``name``'s realistic truth."""
    s = setup(load_scene(name))
    pr = s.problem
    q = pr.robot.random_configurations(n_train, 1000 + truth)
    rob = identify_robust(pr.space, simulate(s, q, truth, "realistic"), pr.identifiability,
                          model_error=start_prior(s.scene, pr))
    stationary = fit_model_error(rob.linearisation, start_prior(s.scene, pr, scaled=False))
    return rob.model_error.log_likelihood - stationary.log_likelihood, rob.model_error.prior.scale.weight


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", nargs="+", default=["fms_kr16", "ur5_table"])
    ap.add_argument("--truths", type=int, default=6)
    args = ap.parse_args()
    for name in args.scenes:
        rows = [likelihood_gap(name, truth) for truth in range(args.truths)]
        print(f"{name}: LL scaled - stationary " + ", ".join(f"{gap:+.1f}" for gap, _ in rows)
              + "; fitted weight " + ", ".join(f"{w:.2f}" for _, w in rows), flush=True)


if __name__ == "__main__":
    main()
