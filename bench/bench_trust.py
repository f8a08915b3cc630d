"""Accuracy you can trust (issue 29): predicted against achieved error on new poses, with model error.

For each scene and truth: 60 training poses random in the joint limits, 200 new
poses uniform in the training joint ranges, both measured on the same true robot
(``--source realistic``: the realistic simulator, ``calib_oed.calibration.realistic``;
``--source gp``: the model's own assumptions, a Gaussian-process model error of the
scene's default prior on top of the scene's noise). The calibration is
``identify_robust`` with the scene's model-error prior, exactly what
``calib-oed identify`` runs. Reported per case:

- ``pred/ach``: predicted RMS position error on the new poses (parameter
  uncertainty + fitted model error + noise) over the achieved RMS; ``noise-only``:
  the same ratio for the old prediction (exact model);
- ``cover95``: fraction of new points inside their 95 % prediction region
  (:math:`e^\\top V^{-1}e \\le c`, ``c`` widened for the uncertainty of the fitted model error,
  ``calibration/hyper_uncertainty.py``; ``chi2``: with :math:`c = \\chi^2_3(0.95)`);
  ``range``: the 95 % range of the predicted RMS from that uncertainty; ``comp``: the achieved RMS with the
  fitted model error's mean compensated, over the uncompensated;
- ``flag %``, ``dropped``: training rows flagged and left out; ``gross``: with one
  5 mm error added to one training row, whether that row is flagged and the only one
  dropped (``+k``: k other rows flagged, suspect, kept);
- ``cv``: 5-fold cross-validation's RMS on the training data minus its expected bias
  against the achieved RMS on the new poses, in units of its own standard error (both
  under the fitted model error, ``calibration/crossval_error.py``);
- ``sigma0``: the plain fit's residual scale (how far the model error is above the noise);
- ``cpu s``: CPU seconds of the process in ``identify_robust`` (the fit, flags and model error);
- ``LL other``: restricted log-likelihood of the other kernel minus this one's (``--kernel``:
  by default what ``identify`` fits, ``model_error.start_prior``, the Matérn 5/2 with the
  harmonic part per joint, compared with the plain Matérn 5/2; any other kernel is compared
  with that default).

    nice -n 5 python bench/bench_trust.py --source realistic
    nice -n 5 python bench/bench_trust.py --source gp
    nice -n 5 python bench/bench_trust.py --cost   # CPU of the fit and assessment, both kernels
    nice -n 5 python bench/bench_trust.py --frame world --source realistic   # the world frame
    nice -n 5 python bench/bench_trust.py --frame world --source joint       # the joint prior's own truths
    nice -n 5 python bench/bench_trust.py --by-prior-variance --truths 4     # the TCP prediction by the prior's variance
    nice -n 5 python bench/bench_trust.py ... --stationary    # any of these with the stationary model error

The model error fitted is identify's (``model_error.start_prior``: pose-scaled by the joint prior,
``measurement/pose_scale.py``); ``--stationary`` fits it without the pose scale, for comparison.

``--frame world``: per truth, the expected RMS on the new poses in the world (robot base) frame
(``identify``'s assessment with the data's blocks, ``calibration/world_frame.py``) against the
achieved RMS of the true reflector positions; pooled over the truths, the TCP at the scene's
working configurations in both frames, predicted and achieved, and the gauge share (world minus
tracker) predicted and achieved.

``--cost``: on 60 realistic poses of truth 0 per scene, the CPU time of the process
(``time.process_time``, so a shared machine's load counts little) of ``identify_robust`` and
``assess`` with the plain Matérn 5/2 and with identify's kernel, alternated twice.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np
from scipy.stats import chi2

from calib_oed.calibration.crossval import cross_validate
from calib_oed.calibration.joint_prior_choice import joint_prior
from calib_oed.calibration.model_error import IDENTIFY_KERNEL, fit_model_error, start_prior
from calib_oed.calibration.prediction import compensation, error_covariances, new_poses
from calib_oed.calibration.robust import identify_robust
from calib_oed.calibration.simulation import draw_true_parameters, simulate_observations
from calib_oed.calibration.trust import assess
from calib_oed.calibration.workflow import setup
from calib_oed.calibration.world_frame import draw_joint_errors
from calib_oed.measurement.base import evaluate_setup
from calib_oed.measurement.dataset import MeasurementSet
from calib_oed.measurement.discrepancy import KERNELS, DiscrepancyPrior
from calib_oed.measurement.observations import ObservationBlock
from calib_oed.scene.reader import load_scene

#: Whether the fitted model error follows the joint prior pose by pose (``--stationary``: not).
SCALED = {"on": True}


def identify_start(s):
    """The model-error prior identify starts from (``model_error.start_prior``), pose-scaled unless
    ``--stationary``."""
    return start_prior(s.scene, s.problem, scaled=SCALED["on"])


def simulate(s, q, truth, source):
    """Blocks of every reflector at ``q`` on truth number ``truth``."""
    pr = s.problem
    if source == "gp":
        rng = np.random.default_rng(truth)
        p = draw_true_parameters(pr.space, pr.identifiability.free_indices, rng)
        return simulate_observations(pr.space, pr.models, q, p, rng,
                                     model_error=s.scene.discrepancy())
    from calib_oed.calibration.realistic import sample_truth
    from calib_oed.calibration.realistic_measure import measure

    rng = np.random.default_rng(truth)
    return list(measure(sample_truth(s, rng), pr.models, q, rng).blocks)


def split(blocks, n):
    first = [ObservationBlock(b.model, b.q[:n], b.values[:n]) for b in blocks]
    rest = [ObservationBlock(b.model, b.q[n:], b.values[n:]) for b in blocks]
    return first, rest


def as_set(robot, blocks):
    return MeasurementSet.from_arrays(robot, np.vstack([b.q for b in blocks]),
                                      np.vstack([b.values for b in blocks]),
                                      reflector=np.concatenate([np.full(b.n, b.model.reflector)
                                                                for b in blocks]))


def case(s, truth, source, n_train, n_new, kernel):
    pr = s.problem
    q = pr.robot.random_configurations(n_train, 1000 + truth)
    q_new = new_poses(q, n_new, 2000 + truth)
    train, test = split(simulate(s, np.vstack([q, q_new]), truth, source), n_train)
    d = identify_start(s)
    kernel = kernel or d.kernel_name
    prior0 = d if kernel == d.kernel_name else DiscrepancyPrior(
        d.sigma, d.length_scales, kernel, d.source, d.sigma_white, d.linear_joints, (), d.scale)
    other_kernel = "matern52" if kernel == IDENTIFY_KERNEL else IDENTIFY_KERNEL
    t0 = time.process_time()
    rob = identify_robust(pr.space, train, pr.identifiability, model_error=prior0)
    seconds = time.process_time() - t0
    lin, prior, p = rob.linearisation, rob.model_error.prior, rob.result.p
    free = rob.result.free_indices
    trust = assess(pr, rob)
    limit = trust.predicted.region_threshold
    state = evaluate_setup(pr.space, p, q_new, regressor=True, jacobian=False)
    sq = {"pred": 0.0, "noise": 0.0, "ach": 0.0, "comp": 0.0}
    inside = inside_chi2 = n = 0
    mu = compensation(lin, prior, q_new)
    for b in test:
        h = b.model.compute_values(state)
        jac = b.model.compute_param_jacobian(state)[:, :, free]
        noise = b.model.noise_covariance(h)
        v = error_covariances(lin, prior, jac, q_new, noise)
        e = b.values - h
        t = np.einsum("ni,nij,nj->n", e, np.linalg.inv(v), e)
        inside += int(np.sum(t <= limit))
        inside_chi2 += int(np.sum(t <= chi2.ppf(0.95, 3)))
        n += e.shape[0]
        sq["pred"] += np.trace(v, axis1=1, axis2=2).sum()
        sq["noise"] += np.trace(error_covariances(lin, None, jac, q_new, noise), axis1=1, axis2=2).sum()
        sq["ach"] += np.sum(e**2)
        sq["comp"] += np.sum((e - mu) ** 2)
    ach = np.sqrt(sq["ach"] / n)
    # one 5 mm gross error on training row 17 of the first reflector
    gross = [ObservationBlock(b.model, b.q, b.values) for b in train]
    v = np.array(gross[0].values)
    v[17, 1] += 5e-3
    gross[0] = ObservationBlock(gross[0].model, gross[0].q, v)
    rob_g = identify_robust(pr.space, gross, pr.identifiability, model_error=prior0)
    alone = bool(rob_g.flagged[17]) and np.flatnonzero(rob_g.dropped).tolist() == [17]
    cv = cross_validate(pr.space, as_set(pr.robot, train), pr.identifiability, 5,
                        error_model=s.scene.error_model(), model_error=prior)
    other = fit_model_error(lin, DiscrepancyPrior(prior0.sigma, prior0.length_scales, other_kernel,
                                                  "default", prior0.sigma_white, prior0.linear_joints,
                                                  (), prior0.scale))
    return {
        "scene": s.scene.name, "truth": truth, "sigma0": rob.linear.sigma0,
        "fitted": prior.describe(), "pred_over_achieved": float(np.sqrt(sq["pred"] / n) / ach),
        "noise_only_over_achieved": float(np.sqrt(sq["noise"] / n) / ach),
        "coverage95": inside / n, "coverage95_chi2": inside_chi2 / n, "region_threshold": limit,
        "log_variance_sd": trust.predicted.log_variance_sd,
        "predicted_range_mm": list(trust.predicted.new_pose_rms_range_mm),
        "predicted_mm": trust.predicted.new_pose_rms_mm,
        "achieved_in_range": bool(trust.predicted.new_pose_rms_range_mm[0] <= ach * 1e3
                                  <= trust.predicted.new_pose_rms_range_mm[1]),
        "achieved_rms_mm": float(ach * 1e3),
        "compensated_over_uncompensated": float(np.sqrt(sq["comp"] / n) / ach),
        "flagged_percent": 100.0 * rob.n_flagged / rob.flagged.size,
        "dropped": int(rob.dropped.sum()), "gross_flagged_alone": bool(alone),
        "gross_other_flags": int(rob_g.n_flagged - rob_g.flagged[17]),
        "cv_rms_mm": cv.rms_mm, "cv_se_mm": cv.se_mm, "cv_bias_mm": cv.bias_mm,
        "cv_minus_achieved_in_se": float((cv.rms_mm - ach * 1e3 - cv.bias_mm) / cv.se_mm),
        "ll_other_kernel_minus_this": float(other.log_likelihood - rob.model_error.log_likelihood),
        "identify_cpu_seconds": seconds,
    }


def world_case(s, truth, source, n_train, n_new):
    """The TCP accuracy in both frames (``--frame world``): predicted (``identify``'s assessment,
    :mod:`calib_oed.calibration.world_frame`) and achieved, at the scene's working configurations
    and on the new poses (true reflector positions, no tracker noise in the achieved error)."""
    pr = s.problem
    q = pr.robot.random_configurations(n_train, 1000 + truth)
    q_new = new_poses(q, n_new, 2000 + truth)
    q_work = pr.kpi.configurations
    kpi_point = pr.kpi.point
    if source == "joint":  # the prior's own truths: joint-angle errors drawn from the joint-space prior
        rng = np.random.default_rng(truth)
        p_true = draw_true_parameters(pr.space, pr.identifiability.free_indices, rng)
        eps = draw_joint_errors(joint_prior(pr), np.vstack([q, q_new, q_work]), rng)
        blocks = simulate_observations(pr.space, pr.models, q + eps[:n_train], p_true, rng)
        train = [ObservationBlock(b.model, q, b.values) for b in blocks]
        true_new = evaluate_setup(pr.space, p_true, q_new + eps[n_train:n_train + n_new])
        true_work = evaluate_setup(pr.space, p_true, q_work + eps[n_train + n_new:])

        def achieved(p_hat):
            est_new, est_work = evaluate_setup(pr.space, p_hat, q_new), evaluate_setup(pr.space, p_hat, q_work)
            new = {f: np.concatenate([est_new.tool_point(c, f) - true_new.tool_point(c, f)
                                      for c in pr.space.reflector_offsets(p_hat)]) for f in ("world", "tracker")}
            return new, {f: est_work.tool_point(kpi_point, f) - true_work.tool_point(kpi_point, f)
                         for f in ("world", "tracker")}
    else:
        from calib_oed.calibration.realistic import sample_truth
        from calib_oed.calibration.realistic_measure import measure
        from calib_oed.calibration.workflow import tcp_errors

        rng = np.random.default_rng(truth)
        true = sample_truth(s, rng)
        train = list(measure(true, pr.models, q, rng).blocks)

        def achieved(p_hat):
            world = true.compute_model_errors(p_hat, q_new)  # (n, k, 3) predicted - true
            est = evaluate_setup(pr.space, p_hat, q_new)
            tracker = pr.space.tracker_placement(true.p)
            true_t = (true.compute_reflector_points(q_new) - tracker.translation) @ tracker.rotation
            est_t = np.stack([est.tool_point(c, "tracker") for c in pr.space.reflector_offsets(p_hat)], axis=1)
            return ({"world": world.reshape(-1, 3), "tracker": (est_t - true_t).reshape(-1, 3)},
                    {f: tcp_errors(s, true, p_hat, f) for f in ("world", "tracker")})
    t0 = time.process_time()
    rob = identify_robust(pr.space, train, pr.identifiability, model_error=identify_start(s))
    pred = assess(pr, rob, blocks=train).predicted
    seconds = time.process_time() - t0
    new, work = achieved(rob.result.p)
    rms_new = float(np.sqrt(np.mean(np.sum(new["world"] ** 2, axis=1))) * 1e3)
    rms_new_t = float(np.sqrt(np.mean(np.sum(new["tracker"] ** 2, axis=1))) * 1e3)
    sq = {f: np.sum(e**2, axis=1) * 1e6 for f, e in work.items()}
    return {"scene": s.scene.name, "truth": truth, "source": source,
            "world_new_pred_mm": pred.world_new_pose_rms_mm, "world_new_ach_mm": rms_new,
            "world_new_ratio": pred.world_new_pose_rms_mm / rms_new,
            "tracker_new_pred_mm": pred.new_pose_rms_mm, "tracker_new_ach_mm": rms_new_t,
            "tcp_world_pred_mm2": float(np.sum(np.square(pred.world_tcp_rms_mm))),
            "tcp_world_ach_mm2": float(sq["world"].sum()),
            "tcp_tracker_pred_mm2": float(np.sum(np.square(pred.tcp_rms_mm))),
            "tcp_tracker_ach_mm2": float(sq["tracker"].sum()), "n_work": int(q_work.shape[0]),
            "gauge_share_mm2": float(np.sum(pred.gauge_share_mm2)), "prior_scale": pred.world_prior_scale,
            "new_gauge_share_mm2": pred.world_new_gauge_share_mm2, "cpu_seconds": seconds}


def world_main(args):
    """``--frame world``: per truth the new poses, pooled over truths the TCP (module docstring)."""
    rows = []
    print(f"source {args.source}, frame world: {args.n_train} training poses, {args.n_new} new poses per truth")
    print(f"{'scene':10s} {'truth':>5s} {'new: pred':>9s} {'ach':>6s} {'ratio':>5s} {'tracker pred':>12s} {'ach':>6s} "
          f"{'TCP world pred':>14s} {'ach':>6s} {'TCP tracker pred':>16s} {'ach':>6s} {'share mm2':>9s} {'scale':>5s} {'cpu s':>5s}")
    for name in args.scenes:
        s = setup(load_scene(name))
        for truth in range(args.first_truth, args.first_truth + args.truths):
            r = world_case(s, truth, args.source, args.n_train, args.n_new)
            rows.append(r)
            print(f"{name:10s} {truth:5d} {r['world_new_pred_mm']:9.4f} {r['world_new_ach_mm']:6.4f} "
                  f"{r['world_new_ratio']:5.2f} {r['tracker_new_pred_mm']:12.4f} {r['tracker_new_ach_mm']:6.4f} "
                  f"{np.sqrt(r['tcp_world_pred_mm2']):14.4f} {np.sqrt(r['tcp_world_ach_mm2']):6.4f} "
                  f"{np.sqrt(r['tcp_tracker_pred_mm2']):16.4f} {np.sqrt(r['tcp_tracker_ach_mm2']):6.4f} "
                  f"{r['gauge_share_mm2']:+9.4f} {r['prior_scale']:5.2f} {r['cpu_seconds']:5.1f}", flush=True)
        mine = [r for r in rows if r["scene"] == s.scene.name]

        def pooled(key, mine=mine):
            return float(np.sqrt(sum(r[key] for r in mine) / sum(r["n_work"] for r in mine)))

        share_ach = (sum(r["tcp_world_ach_mm2"] - r["tcp_tracker_ach_mm2"] for r in mine)
                     / sum(r["n_work"] for r in mine))
        share_pred = sum(r["gauge_share_mm2"] for r in mine) / sum(r["n_work"] for r in mine)
        print(f"{name}: TCP pooled over {len(mine)} truths: world predicted {pooled('tcp_world_pred_mm2'):.4f} mm, "
              f"achieved {pooled('tcp_world_ach_mm2'):.4f} mm (ratio "
              f"{pooled('tcp_world_pred_mm2') / pooled('tcp_world_ach_mm2'):.2f}); tracker predicted "
              f"{pooled('tcp_tracker_pred_mm2'):.4f} mm, achieved {pooled('tcp_tracker_ach_mm2'):.4f} mm "
              f"(ratio {pooled('tcp_tracker_pred_mm2') / pooled('tcp_tracker_ach_mm2'):.2f}); gauge share "
              f"predicted {share_pred:+.4f} mm2, achieved (world - tracker) {share_ach:+.4f} mm2")
        print(f"{name}: new poses pooled over {len(mine)} truths: world predicted/achieved "
              f"{np.sqrt(sum(r['world_new_pred_mm'] ** 2 for r in mine) / sum(r['world_new_ach_mm'] ** 2 for r in mine)):.2f}, "
              f"tracker {np.sqrt(sum(r['tracker_new_pred_mm'] ** 2 for r in mine) / sum(r['tracker_new_ach_mm'] ** 2 for r in mine)):.2f}")
    ratio = [r["world_new_ratio"] for r in rows]
    print(f"world frame, new poses: predicted/achieved per truth {min(ratio):.2f}..{max(ratio):.2f}, "
          f"sd of the log ratio {np.std(np.log(ratio)):.2f}")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(rows, fh, indent=2)


def by_prior_variance(scenes, truths, n_new=300):
    """``--by-prior-variance``: the tracker-frame TCP prediction over the achieved RMS on new poses,
    pooled over ``truths`` realistic truths per scene, in terciles of the joint-space prior's own
    variance of the TCP's model error at the pose (the lever arms and gravity torques of the joint
    errors there): a stationary fitted model error predicts the same size everywhere, a pose-scaled
    one follows the prior's shape with its fitted weight (printed, mean over the truths)."""
    for name in scenes:
        s = setup(load_scene(name))
        pr = s.problem
        prior = joint_prior(pr)
        c = pr.kpi.point

        def own(q, pr=pr, prior=prior, c=c):
            j = evaluate_setup(pr.space, None, q).tool_point_config_jacobian(c, "tracker")[:, :, :prior.nq]
            return np.einsum("knn,nck,nck->n", prior.compute_kernels(q, q), j, j)

        sums, weights = np.zeros((3, 2)), []
        for truth in range(truths):
            from calib_oed.calibration.realistic import sample_truth

            q = pr.robot.random_configurations(60, 1000 + truth)
            rob = identify_robust(pr.space, simulate(s, q, truth, "realistic"), pr.identifiability,
                                  model_error=identify_start(s))
            true = sample_truth(s, np.random.default_rng(truth))
            q_new = new_poses(q, n_new, 2000 + truth)
            est = evaluate_setup(pr.space, rob.result.p, q_new)
            tracker = pr.space.tracker_placement(true.p)
            e = est.tool_point(c, "tracker") - (true.compute_tcp(q_new, c) - tracker.translation) @ tracker.rotation
            g = est.tool_point_param_jacobian(c, "tracker", None)[:, :, rob.result.free_indices]
            v = np.trace(error_covariances(rob.linearisation, rob.model_error.prior, g, q_new, None), axis1=1, axis2=2)
            fitted = rob.model_error.prior.scale
            weights.append(np.nan if fitted is None else fitted.weight)
            k = own(q_new)
            edges = np.quantile(k, [1 / 3, 2 / 3])
            b = np.digitize(k, edges)
            for t in range(3):
                sums[t] += v[b == t].sum(), np.sum(e[b == t] ** 2)
        print(f"{name}: TCP predicted/achieved (tracker frame) on {n_new} new poses x {truths} truths, by tercile of "
              f"the prior's own TCP variance (low, mid, high): "
              + ", ".join(f"{x:.2f}" for x in np.sqrt(sums[:, 0] / sums[:, 1]))
              + f"; fitted pose-scale weight {np.mean(weights):.2f}"
              + f"; the working configurations' own variance {np.round(own(pr.kpi.configurations) * 1e6, 4)} mm2, "
              f"tercile edges of the last truth {np.round(edges * 1e6, 4)} mm2", flush=True)


def cost(scenes):
    """CPU seconds of the fit and the assessment per kernel (module docstring, ``--cost``)."""
    for name in scenes:
        s = setup(load_scene(name))
        pr = s.problem
        train = simulate(s, pr.robot.random_configurations(60, 1000), 0, "realistic")
        d = identify_start(s)
        for kernel in ("matern52", IDENTIFY_KERNEL) * 2:
            prior0 = DiscrepancyPrior(d.sigma, d.length_scales, kernel, d.source, d.sigma_white,
                                      d.linear_joints, (), d.scale)
            t0 = time.process_time()
            rob = identify_robust(pr.space, train, pr.identifiability, model_error=prior0)
            t1 = time.process_time()
            assess(pr, rob)
            t2 = time.process_time()
            print(f"{name:10s} {kernel:18s} identify_robust {t1 - t0:5.2f} s CPU, assess "
                  f"{t2 - t1:5.2f} s CPU, restricted log-likelihood "
                  f"{rob.model_error.log_likelihood:.1f}", flush=True)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--source", choices=("realistic", "gp", "joint"), default="realistic",
                    help="joint: the joint-space prior's own truths (with --frame world only)")
    ap.add_argument("--frame", choices=("tracker", "world"), default="tracker",
                    help="world: the TCP and new poses in both frames (the world-frame prediction)")
    ap.add_argument("--scenes", nargs="+", default=["fms_kr16", "ur5_table"])
    ap.add_argument("--truths", type=int, default=3)
    ap.add_argument("--first-truth", type=int, default=0, help="truths first..first+truths-1")
    ap.add_argument("--n-train", type=int, default=60)
    ap.add_argument("--n-new", type=int, default=200)
    ap.add_argument("--kernel", choices=KERNELS, default=None,
                    help="the kernel fitted (default: what identify fits)")
    ap.add_argument("--stationary", action="store_true",
                    help="fit the stationary model error (without the joint prior's pose scale)")
    ap.add_argument("--json", metavar="FILE")
    ap.add_argument("--cost", action="store_true", help="only the CPU cost of both kernels")
    ap.add_argument("--by-prior-variance", action="store_true",
                    help="only the TCP prediction by tercile of the joint-space prior's own variance")
    args = ap.parse_args()
    SCALED["on"] = not args.stationary
    if args.cost:
        cost(args.scenes)
        return
    if args.by_prior_variance:
        by_prior_variance(args.scenes, args.truths)
        return
    if args.frame == "world" or args.source == "joint":
        if args.source == "gp" or args.frame != "world":
            ap.error("--frame world takes --source realistic or joint; --source joint needs --frame world")
        world_main(args)
        return
    rows = []
    print(f"source {args.source}: {args.n_train} training poses, {args.n_new} new poses per truth, "
          f"kernel {args.kernel or 'as identify (' + IDENTIFY_KERNEL + ' unless the scene gives one)'}")
    print(f"{'scene':10s} {'truth':>5s} {'sigma0':>6s} {'pred/ach':>8s} {'noise-only':>10s} "
          f"{'cover95':>7s} {'chi2':>5s} {'range [mm]':>13s} {'ach mm':>7s} {'comp':>5s} {'flag %':>6s} {'drop':>4s} {'gross':>5s} "
          f"{'cv [se]':>7s} {'LL other':>9s} {'cpu s':>5s}")
    for name in args.scenes:
        s = setup(load_scene(name))
        for truth in range(args.first_truth, args.first_truth + args.truths):
            r = case(s, truth, args.source, args.n_train, args.n_new, args.kernel)
            rows.append(r)
            print(f"{name:10s} {truth:5d} {r['sigma0']:6.1f} {r['pred_over_achieved']:8.2f} "
                  f"{r['noise_only_over_achieved']:10.2f} {r['coverage95']:7.3f} "
                  f"{r['coverage95_chi2']:5.3f} "
                  f"{r['predicted_range_mm'][0]:6.4f}-{r['predicted_range_mm'][1]:6.4f} "
                  f"{r['achieved_rms_mm']:7.4f} {r['compensated_over_uncompensated']:5.2f} "
                  f"{r['flagged_percent']:6.1f} {r['dropped']:4d} "
                  f"{str(r['gross_flagged_alone'])[0] + '+' + str(r['gross_other_flags']):>5s} "
                  f"{r['cv_minus_achieved_in_se']:+7.2f} {r['ll_other_kernel_minus_this']:+9.1f} "
                  f"{r['identify_cpu_seconds']:5.1f}")
            tau = r["log_variance_sd"]
            print(f"{'':16s} {r['fitted']}; region threshold {r['region_threshold']:.2f}, tau "
                  f"{'-' if tau is None else format(tau, '.3f')}")
    ratio = [r["pred_over_achieved"] for r in rows]
    cover = [r["coverage95"] for r in rows]
    print(f"pred/ach {min(ratio):.2f}..{max(ratio):.2f} (target 0.8-1.25); coverage "
          f"{min(cover):.3f}..{max(cover):.3f}, pooled {np.mean(cover):.3f} (target 0.93-0.97); "
          f"achieved in the predicted 95 % range {sum(r['achieved_in_range'] for r in rows)}/{len(rows)}; "
          f"flagged at most {max(r['flagged_percent'] for r in rows):.1f} % (target <= 2), "
          f"dropped {sum(r['dropped'] for r in rows)} (target 0); gross error alone "
          f"{sum(r['gross_flagged_alone'] for r in rows)}/{len(rows)}; |cv - achieved| <= 2 se in "
          f"{sum(abs(r['cv_minus_achieved_in_se']) <= 2 for r in rows)}/{len(rows)}")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(rows, fh, indent=2)


if __name__ == "__main__":
    main()
