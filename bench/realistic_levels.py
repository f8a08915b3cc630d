"""What the realistic simulator's default level leaves after a fit (docs/identification.md).

For each scene and truth seed: a realistic truth (calibration/realistic.py) at
``--level``, 60 training poses and 30 held-out poses uniform in the joint
limits, the project's ``identify`` (plain least squares) with the scene's
model (geometric; ``+compliance``: with the joint compliances modelled), and
the RMS errors in mm: the nominal model and the calibrated one at the held-out
poses against the true reflector centre, the fit's residual, its sigma0, and
the held-out error over the 3-D RMS of the measurement noise.

    OPENBLAS_NUM_THREADS=1 python bench/realistic_levels.py [--level 1] [--truths 3]
"""

from __future__ import annotations

import argparse
import dataclasses

import numpy as np

from calib_oed.calibration.identification import identify
from calib_oed.calibration.realistic import sample_truth
from calib_oed.calibration.realistic_defaults import realistic_settings_from_scene
from calib_oed.calibration.realistic_measure import measure
from calib_oed.calibration.workflow import setup
from calib_oed.scene.reader import load_scene
from calib_oed.scene.records import ComplianceSpec

CASES = (("fms_kr16", False), ("ur5_table", False), ("fms_kr300", False), ("fms_kr300", True))


def run(scene_name: str, compliance: bool, level: float, truths: int) -> list[tuple]:
    scene = load_scene(scene_name)
    if compliance:
        scene = dataclasses.replace(scene, compliance=ComplianceSpec(True, scene.compliance.payload))
    s = setup(scene)
    space, robot = s.problem.space, s.problem.robot
    settings = dataclasses.replace(realistic_settings_from_scene(scene), level=level)
    rows = []
    for seed in range(truths):
        truth = sample_truth(s, seed, settings)
        q, q_new = robot.random_configurations(60, 10 + seed), robot.random_configurations(30, 50 + seed)
        meas = measure(truth, s.problem.models, q, 100 + seed)
        fit = identify(space, list(meas.blocks), s.problem.identifiability)
        nominal, held = (float(np.sqrt(np.mean(np.sum(truth.compute_model_errors(p, q_new) ** 2, axis=-1))))
                         for p in (None, fit.p))
        noise = s.problem.models[0].noise.sample(meas.exact[0], np.random.default_rng(seed))
        noise_rms = float(np.sqrt(np.mean(np.sum(noise**2, 1))))
        rows.append((seed, nominal * 1e3, float(fit.rms_mm), float(fit.sigma0), held * 1e3, held / noise_rms))
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--level", type=float, default=1.0)
    ap.add_argument("--truths", type=int, default=3)
    args = ap.parse_args()
    print(f"level {args.level:g}; 60 training, 30 held-out poses uniform in the joint limits; mm")
    print(f"{'scene':<24} {'truth':>5} {'nominal':>8} {'fit RMS':>8} {'sigma0':>7} {'held-out':>9} {'/noise':>7}")
    for name, compliance in CASES:
        label = name + (" +compliance" if compliance else "")
        for seed, nominal, fit_rms, sigma0, held, ratio in run(name, compliance, args.level, args.truths):
            print(f"{label:<24} {seed:>5} {nominal:8.3f} {fit_rms:8.4f} {sigma0:7.2f} {held:9.4f} {ratio:7.1f}")


if __name__ == "__main__":
    main()
