"""Compensation on realistic truths (issue 32): rigid calibration against one that identifies joint
compliance (and joint gains), compensated with the deflection (docs/compensate.md).

Per scene and realistic truth (calibration/realistic.py: geometry, transmission errors, gravity
compliance with a J2 balancer, joint gain errors, tracker systematics, the scene's noise), 60
random poses are measured and identified with ``identify_robust`` and the scene's model-error
prior, in three models: ``rigid`` (the kinematic model), ``compliance`` (plus one compliance per
joint, with the payload on the arm: the scene's payload plus the reflector nest, as the truth
carries it) and ``compliance+gains`` (plus a gain per joint). 120 random joint targets are
compensated (``compensate_joints``, with the calibration's ``JointDeflection`` for the last two);
over the targets not named, the RMS TCP error of the true robot at the compensated joints, the
predicted residual (``CalibrationUncertainty.from_robust``: covariance plus the fitted model
error) and the error without compensation [mm]; and what is left of the truth's unmodelled joint
errors (transmission, balancer torque) at the targets, in mm at the TCP (``--explain``).

    nice -n 10 .venv/bin/python bench/study_compensate_realistic.py fms_kr16 ur5_table kr120 \
        --models rigid compliance compliance+gains
"""

from __future__ import annotations

import argparse
import dataclasses
import tempfile
from pathlib import Path

import numpy as np

from calib_oed.calibration.compensation import (
    CalibrationUncertainty,
    calibrated_robot,
    compensate_joints,
)
from calib_oed.calibration.problem import CalibrationProblem
from calib_oed.calibration.realistic import sample_truth
from calib_oed.calibration.realistic_measure import measure
from calib_oed.calibration.robust import identify_robust
from calib_oed.calibration.workflow import setup
from calib_oed.model.compliance import Compliance
from calib_oed.model.deflected_kinematics import JointDeflection
from calib_oed.model.inverse_kinematics import TcpKinematics
from calib_oed.model.joint_map import JointGains
from calib_oed.scene.records import ComplianceSpec

MODELS = ("rigid", "compliance", "compliance+gains")


def rms(a) -> float:
    return float(np.sqrt(np.mean(np.square(a))))


def fit_scene(scene, truth, model: str):
    """The scene the calibration is identified in: the scene's own (``rigid``), or with compliance
    under the payload the truth carries (the scene's payload and the reflector nest), and gains."""
    if model == "rigid":
        return scene
    links = scene.compliance.payload if scene.compliance is not None else Compliance()
    payload = Compliance(truth.payload_mass, truth.payload_com, link_masses=links.link_masses,
                         link_coms=links.link_coms)
    gains = JointGains.all_joints(scene.robot.nq) if model == "compliance+gains" else scene.joint_gains
    return dataclasses.replace(scene, compliance=ComplianceSpec(True, payload), joint_gains=gains)


def study(scene_name: str, model: str, truths=(1, 2, 3), n_design: int = 60, n_targets: int = 120) -> list[dict]:
    """Per truth: TCP errors [mm] after/before compensation and predicted, over the targets not named."""
    s = setup(scene_name)
    problem = s.problem
    robot = problem.space.robot
    q_design = robot.random_configurations(n_design, 0)
    nominal = TcpKinematics(robot)
    out = []
    for seed in truths:
        rng = np.random.default_rng(seed)
        truth = sample_truth(s, rng)
        meas = measure(truth, problem.models, q_design, rng)
        fit = CalibrationProblem.from_scene(fit_scene(s.scene, truth, model))
        space = fit.space
        robust = identify_robust(space, list(meas.blocks), fit.identifiability, model_error=s.scene.discrepancy())
        p = robust.result.p
        deflection = JointDeflection.from_space(space, p)
        targets = robot.random_configurations(n_targets, 100 + seed)
        comp = compensate_joints(robot, calibrated_robot(space, p), targets,
                                 uncertainty=CalibrationUncertainty.from_robust(space, robust),
                                 deflection=deflection)
        ok = ~comp.flagged
        goal = np.array([nominal.compute_pose(q).translation for q in targets])
        out.append({"after": 1e3 * np.linalg.norm(truth.compute_tcp(comp.q[ok]) - goal[ok], axis=1),
                    "before": 1e3 * np.linalg.norm(truth.compute_tcp(targets[ok]) - goal[ok], axis=1),
                    "predicted": comp.predicted_mm[ok], "truth": truth, "q": comp.q[ok], "space": space,
                    "p": p, "sigma0": float(robust.result.sigma0), "n_named": int(comp.flagged.sum())})
    return out


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
                trials = study(scene, model, tuple(args.truths))
                after = np.concatenate([t["after"] for t in trials])
                pred = np.concatenate([t["predicted"] for t in trials])
                gains = [rms(t["before"]) / rms(t["after"]) for t in trials]
                print(f"{name:10s} {model:17s} compensated {rms(after):.4f} mm, predicted {rms(pred):.4f} mm, "
                      f"ratio {rms(after) / rms(pred):.2f}; uncompensated "
                      f"{rms(np.concatenate([t['before'] for t in trials])):.3f} mm; gain per truth "
                      + ", ".join(f"{g:.1f}x" for g in gains)
                      + "; per truth " + ", ".join(f"{rms(t['after']):.4f}/{rms(t['predicted']):.4f}/"
                                                   f"{rms(t['before']):.3f}" for t in trials)
                      + f"; named {[t['n_named'] for t in trials]}", flush=True)
                if args.explain:
                    for k, t in enumerate(trials):
                        parts = unmodelled_mm(t)
                        print("    truth", args.truths[k], ", ".join(f"{key} {v:.4f} mm" for key, v in parts.items()))


if __name__ == "__main__":
    main()
