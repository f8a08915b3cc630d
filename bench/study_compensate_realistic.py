"""Compensation on realistic truths (issue 32): rigid calibration against one that identifies joint
compliance (and joint gains), compensated with the deflection (docs/compensate.md).

Per scene and realistic truth (calibration/realistic.py: geometry, transmission errors, gravity
compliance with a J2 balancer, joint gain errors, tracker systematics, the scene's noise), 60
random poses are measured and identified with ``identify_robust`` and the scene's model-error
prior, in three models: ``rigid`` (the kinematic model), ``compliance`` (plus one compliance per
joint, with the payload on the arm: the scene's payload plus the reflector nest, as the truth
carries it) and ``compliance+gains`` (plus a gain per joint). 120 random joint targets are
compensated (``compensate_joints``, with the calibration's ``JointDeflection`` for the last two;
``realistic_errors`` of tests/calibration/test_compensation_realistic.py);
over the targets not named, the RMS TCP error of the true robot at the compensated joints, the
predicted residual (``CalibrationUncertainty.from_robust``: covariance plus the fitted model
error) and the error without compensation [mm]; and what is left of the truth's unmodelled joint
errors (transmission, balancer torque) at the targets, in mm at the TCP (``--explain``).

    nice -n 10 .venv/bin/python bench/study_compensate_realistic.py fms_kr16 ur5_table kr120 \
        --models rigid compliance compliance+gains
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np

from calib_oed.calibration.compensation import calibrated_robot
from calib_oed.model.inverse_kinematics import TcpKinematics
from tests.calibration.test_compensation import _rms as rms
from tests.calibration.test_compensation_realistic import MODELS, realistic_errors


def unmodelled_mm(t: dict) -> dict:
    """RMS TCP displacement [mm] at the compensated joints of each unmodelled joint error of the
    truth (transmission, balancer torque through the compliance): what compliance and gains
    cannot remove."""
    truth, q = t["truth"], t["q"]
    kin = TcpKinematics(calibrated_robot(truth.space, truth.p))
    jac = np.array([kin.compute_jacobian(row)[1][:3] for row in q])        # (n, 3, nq), local frame

    def at_tcp(dq):
        return rms(1e3 * np.linalg.norm(np.einsum("nij,nj->ni", jac, dq), axis=1))

    parts = {"transmission": at_tcp(truth.transmission.compute_errors(q))}
    if truth.balancer is not None:
        parts["balancer"] = at_tcp(truth.compliance * truth.balancer.compute_torques(q))
    parts["gravity compliance"] = at_tcp(truth.compliance * truth.compute_gravity_torques(q))
    if truth.gain_errors is not None:
        parts["gain errors"] = at_tcp(truth.gain_errors * q)
    return parts


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scenes", nargs="+", help="scene names; kr120: KR 120 R2500 pro from the ROS-Industrial xacro")
    parser.add_argument("--models", nargs="+", default=list(MODELS), choices=MODELS)
    parser.add_argument("--truths", type=int, nargs="+", default=[1, 2, 3])
    parser.add_argument("--explain", action="store_true", help="print the unmodelled joint errors at the TCP")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        for scene in args.scenes:
            name = scene
            if scene == "kr120":
                from tests.model.ros_industrial import kr120_scene_file

                scene = str(kr120_scene_file(Path(tmp)))
            for model in args.models:
                trials = realistic_errors(scene, tuple(args.truths), model=model)
                after = np.concatenate([t["after"] for t in trials])
                pred = np.concatenate([t["predicted"] for t in trials])
                gains = [rms(t["before"]) / rms(t["after"]) for t in trials]
                print(f"{name:10s} {model:17s} compensated {rms(after):.4f} mm, predicted {rms(pred):.4f} mm, "
                      f"ratio {rms(after) / rms(pred):.2f}; marginal "
                      f"{rms(np.concatenate([t['marginal'] for t in trials])):.4f} mm, noise only "
                      f"{rms(np.concatenate([t['noise_only'] for t in trials])):.4f} mm; uncompensated "
                      f"{rms(np.concatenate([t['before'] for t in trials])):.3f} mm; gain per truth "
                      + ", ".join(f"{g:.1f}x" for g in gains)
                      + "; per truth " + ", ".join(f"{rms(t['after']):.4f}/{rms(t['predicted']):.4f}/"
                                                   f"{rms(t['before']):.3f}" for t in trials)
                      + f"; named {[int(t['comp'].flagged.sum()) for t in trials]}", flush=True)
                if args.explain:
                    for k, t in enumerate(trials):
                        parts = unmodelled_mm(t)
                        print("    truth", args.truths[k], ", ".join(f"{key} {v:.4f} mm" for key, v in parts.items()))


if __name__ == "__main__":
    main()
