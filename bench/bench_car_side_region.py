"""Why the tracker-frame TCP at ``car_side`` is over-predicted on fms_kr16: the region, the truth's parts.

Default: per realistic truth (60 training poses random in the joint limits, seed 1000 + truth, as
``bench_trust.py``), ``identify_robust`` with identify's model-error prior, then the tracker-frame
TCP error predicted over achieved, pooled over the truths (RMS over RMS), at ``car_side``, at 200
poses with every joint within ±10° of it, and at 200 new poses uniform in the training ranges;
once with identify's fitted model error, once with the joint-space prior's own prediction after the
same fit (``world_frame.JointErrorModel``, tracker frame) times identify's ``prior_scale``.
``--off PART`` draws the truths with one part of the realistic simulator switched off
(``motor``: the motor-side harmonics). The running pooled ratios are printed after each truth.

``--torques``: J2's torque at ``car_side`` and RMS over 2000 random poses: gravity net of the
simulator's nominal balancer against the prior's (1 - balancer_fraction) x gravity [N m].
``--joint-errors``: the realistic truths' joint-angle errors at ``car_side``, RMS per joint over 60
truths, against the joint prior's own standard deviation there [arcsec].

    python bench/bench_car_side_region.py --truths 20
    python bench/bench_car_side_region.py --truths 10 --off transmission   # compliance, motor, balancer, tracker, gains
    python bench/bench_car_side_region.py --torques
    python bench/bench_car_side_region.py --joint-errors
"""

from __future__ import annotations

import argparse
import dataclasses

import numpy as np
from bench_trust import identify_start

from calib_oed.calibration.joint_prior_choice import joint_prior
from calib_oed.calibration.prediction import error_covariances, new_poses
from calib_oed.calibration.realistic import Balancer, _balancer_zero, sample_truth
from calib_oed.calibration.realistic_defaults import realistic_settings_from_scene
from calib_oed.calibration.realistic_measure import measure
from calib_oed.calibration.robust import identify_robust
from calib_oed.calibration.trust import assess
from calib_oed.calibration.workflow import setup
from calib_oed.calibration.world_frame import JointErrorModel, point_jacobians, row_offsets
from calib_oed.measurement.base import evaluate_setup
from calib_oed.scene.reader import load_scene

PARTS = ("compliance", "transmission", "motor", "balancer", "tracker", "gains")
ARCSEC_PER_RAD = 180 * 3600 / np.pi


def region_ratios(s, truths, off: str | None) -> None:
    pr = s.problem
    prior = joint_prior(pr)
    c = pr.kpi.point
    qw = np.atleast_2d(pr.kpi.configurations)
    lo, hi = pr.robot.model.lowerPositionLimit, pr.robot.model.upperPositionLimit
    near = np.clip(qw + np.random.default_rng(5).uniform(-1, 1, (200, 6)) * np.radians(10), lo, hi)
    base = realistic_settings_from_scene(s.scene)
    settings = (base if off is None else dataclasses.replace(base, motor_cyclic=(0.0, 0.0)) if off == "motor"
                else dataclasses.replace(base, **{off: False}))
    sums = {k: np.zeros(3) for k in ("car_side", "car_side +-10deg", "random new")}
    for truth in truths:
        q = pr.robot.random_configurations(60, 1000 + truth)
        rng = np.random.default_rng(truth)
        true = sample_truth(s, rng, settings)
        train = list(measure(true, pr.models, q, rng).blocks)
        rob = identify_robust(pr.space, train, pr.identifiability, model_error=identify_start(s))
        lam = assess(pr, rob, blocks=train).predicted.world_prior_scale
        p, free = rob.result.p, np.asarray(rob.result.free_indices)
        jm = JointErrorModel.build(pr.space, rob.linearisation, prior, p, row_offsets(pr.space, train, rob))
        tracker = pr.space.tracker_placement(true.p)
        for k, qs in (("car_side", qw), ("car_side +-10deg", near), ("random new", new_poses(q, 200, 2000 + truth))):
            est = evaluate_setup(pr.space, p, qs)
            e = est.tool_point(c, "tracker") - (true.compute_tcp(qs, c) - tracker.translation) @ tracker.rotation
            g = est.tool_point_param_jacobian(c, "tracker", None)[:, :, free]
            v = np.trace(error_covariances(rob.linearisation, rob.model_error.prior, g, qs, None), axis1=1, axis2=2)
            gt, gw, jac = point_jacobians(pr.space, p, free, qs, c)
            vt, _ = jm.compute_frames(gt, gw, qs, jac[:, :, :prior.nq])
            sums[k] += v.mean(), lam * vt.mean(), np.mean(np.sum(e**2, axis=1))
        print(off or "all on", truth, f"lambda {lam:.2f} |", " | ".join(
            f"{k}: identify {np.sqrt(x[0] / x[2]):.2f} prior {np.sqrt(x[1] / x[2]):.2f}" for k, x in sums.items()),
            flush=True)


def torques(s) -> None:
    pr = s.problem
    g = joint_prior(pr).gravity
    amp, th0 = _balancer_zero(g, 1, pr.robot.model.nq)
    balancer = Balancer(1, 0.5 * amp, th0, 0.25, 0.5)  # the simulator's nominal balancer of a medium arm
    q_random = pr.robot.random_configurations(2000, np.random.default_rng(0))
    for name, q in (("random (2000)", q_random), ("car_side", np.atleast_2d(pr.kpi.configurations))):
        gravity = g.torques(q)[:, 1]
        net = gravity + balancer.compute_torques(q)[:, 1]
        rms = lambda x: np.sqrt(np.mean(x**2))  # noqa: E731
        print(f"{name}: J2 RMS gravity {rms(gravity):.0f} N m, net of the balancer {rms(net):.0f}, "
              f"the prior's (1 - b) x gravity {0.5 * rms(gravity):.0f}")


def joint_errors(s) -> None:
    pr = s.problem
    prior = joint_prior(pr)
    qw = np.atleast_2d(pr.kpi.configurations)
    errors = np.concatenate([sample_truth(s, np.random.default_rng(t)).compute_joint_errors(qw) for t in range(60)])
    print("car_side, J1..J6, arcsec RMS: truths", np.round(np.sqrt(np.mean(errors**2, 0)) * ARCSEC_PER_RAD, 1),
          "prior", np.round(np.sqrt(np.mean(prior.compute_own_variance(qw), 0)) * ARCSEC_PER_RAD, 1))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--first-truth", type=int, default=0)
    ap.add_argument("--truths", type=int, default=20)
    ap.add_argument("--off", choices=PARTS, help="draw the truths with this part switched off")
    ap.add_argument("--torques", action="store_true", help="J2's torques at car_side and at random poses")
    ap.add_argument("--joint-errors", action="store_true", help="the truths' joint errors at car_side")
    args = ap.parse_args()
    s = setup(load_scene("fms_kr16"))
    if args.torques:
        torques(s)
    elif args.joint_errors:
        joint_errors(s)
    else:
        region_ratios(s, range(args.first_truth, args.first_truth + args.truths), args.off)


if __name__ == "__main__":
    main()
