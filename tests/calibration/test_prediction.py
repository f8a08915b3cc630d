"""Predicted accuracy against Monte Carlo of Gaussian-process model errors (the model's own assumptions)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import chi2

from calib_oed.calibration.identification import identify
from calib_oed.calibration.joint_prior_choice import pose_scale
from calib_oed.calibration.model_error import fit_model_error, linearise, start_prior
from calib_oed.calibration.prediction import (
    FEASIBLE_POSES,
    UNIFORM_POSES,
    compensation,
    error_covariances,
    feasible_new_poses,
    new_poses,
    predict_accuracy,
)
from calib_oed.calibration.simulation import draw_true_parameters, simulate_observations
from calib_oed.calibration.workflow import setup, tcp_errors
from calib_oed.measurement.base import evaluate_setup
from calib_oed.measurement.discrepancy import DiscrepancyPrior
from calib_oed.measurement.observations import ObservationBlock
from calib_oed.scene.reader import load_scene

TRUE = DiscrepancyPrior(1e-4, tuple(np.radians([45, 45, 45, 90, 90, 90])))
#: A joint's own error once and twice per revolution (the harmonic part) beside a smaller ARD part.
HARMONIC = DiscrepancyPrior(6e-5, TRUE.length_scales, "matern52_harmonic",
                            harmonic=[6e-5, 3e-5] * 3 + [3e-5, 2e-5] * 3)


@pytest.fixture(scope="module")
def fms():
    return setup(load_scene("fms_kr16"))


def _trial(fms, seed, n_train=60, n_new=100, truth=TRUE):
    """Train on n_train poses, new poses uniform in the training ranges; GP model error + noise."""
    pr = fms.problem
    rng = np.random.default_rng(seed)
    q = pr.robot.random_configurations(n_train, rng)
    q_new = new_poses(q, n_new, 1000 + seed)
    p = draw_true_parameters(pr.space, pr.identifiability.free_indices, rng)
    (b,) = simulate_observations(pr.space, pr.models, np.vstack([q, q_new]), p, rng, model_error=truth)
    train = [ObservationBlock(b.model, q, b.values[:n_train])]
    res = identify(pr.space, train, pr.identifiability)
    lin = linearise(pr.space, train, res.p, res.free_indices)
    state = evaluate_setup(pr.space, res.p, q_new, regressor=True, jacobian=False)
    h = b.model.compute_values(state)
    jac = b.model.compute_param_jacobian(state)[:, :, res.free_indices]
    return lin, q_new, jac, b.model.noise_covariance(h), b.values[n_train:] - h


def _score(errors, cov):
    t = np.einsum("ni,nij,nj->n", errors, np.linalg.inv(cov), errors)
    return np.sum(errors**2), np.trace(cov, axis1=1, axis2=2).sum(), np.sum(t <= chi2.ppf(0.95, 3))


@pytest.mark.parametrize("truth", [TRUE, pytest.param(HARMONIC, id="harmonic")])
def test_prediction_against_monte_carlo_with_the_true_model_error(fms, truth):
    """10 truths x 100 new poses, model error of 10x the noise (either kernel): the predicted mean
    squared error of new measured points is the Monte Carlo one within 10 %, and the 95 %
    prediction regions hold 95 % of the points (within 2.5 points); likewise with the model
    error's mean compensated."""
    for compensate in (False, True):
        sq = tr = inside = n = 0.0
        for seed in range(10):
            lin, q_new, jac, noise, e = _trial(fms, seed, truth=truth)
            cov = error_covariances(lin, truth, jac, q_new, noise, compensate)
            if compensate:
                e = e - compensation(lin, truth, q_new)
            a, b, c = _score(e, cov)
            sq, tr, inside, n = sq + a, tr + b, inside + c, n + e.shape[0]
        assert abs(np.sqrt(tr / sq) - 1) < 0.1, (compensate, np.sqrt(tr / sq))
        assert abs(inside / n - 0.95) < 0.025, (compensate, inside / n)


def test_pose_scaled_prediction_follows_the_pose_against_monte_carlo(fms):
    """A model error whose size follows the joint prior pose by pose (pose scale, weight 1): 10
    truths x 100 new poses. Predicted with the true (scaled) model error, the mean squared error is
    the Monte Carlo one within 10 % pooled and within 15 % in each tercile of the prior's variance
    at the pose, the 95 % regions hold 95 +- 2.5 %; the stationary model error of the same
    training-pose mean misses the terciles (the check can fail)."""
    pr = fms.problem
    scaled = TRUE.with_scale(pose_scale(pr).normalised(pr.robot.random_configurations(200, 99)))
    sums = {"scaled": np.zeros((3, 3)), "stationary": np.zeros((3, 3))}  # [tercile, (sq, tr, inside)]
    n = 0
    for seed in range(10):
        lin, q_new, jac, noise, e = _trial(fms, seed, truth=scaled)
        v = scaled.scale.compute_variance(q_new)
        bins = np.digitize(v, np.quantile(v, [1 / 3, 2 / 3]))
        for name, prior in (("scaled", scaled), ("stationary", TRUE)):
            cov = error_covariances(lin, prior, jac, q_new, noise)
            for t in range(3):
                sums[name][t] += _score(e[bins == t], cov[bins == t])
        n += e.shape[0]
    ratio = {k: np.sqrt(x[:, 1] / x[:, 0]) for k, x in sums.items()}
    pooled = np.sqrt(sums["scaled"][:, 1].sum() / sums["scaled"][:, 0].sum())
    assert abs(pooled - 1) < 0.1 and np.all(np.abs(ratio["scaled"] - 1) < 0.15), (pooled, ratio)
    assert abs(sums["scaled"][:, 2].sum() / n - 0.95) < 0.025, sums["scaled"][:, 2].sum() / n
    assert ratio["stationary"][0] > 1.2 and ratio["stationary"][2] < 0.9, ratio


@pytest.mark.slow  # (the realistic simulator's test_trust.py covers fitted hyperparameters fast)
def test_prediction_with_fitted_hyperparameters(fms):
    """The same with the hyperparameters fitted from each training set (restricted likelihood):
    predicted over achieved RMS within 0.8-1.25, coverage within 0.90-0.98 (400 points of 4 truths,
    correlated within a truth: a standard error of about 0.02; measured 0.97 and 0.92)."""
    sq = tr = inside = n = 0.0
    for seed in range(4):
        lin, q_new, jac, noise, e = _trial(fms, 20 + seed)
        prior = fit_model_error(lin, fms.scene.discrepancy()).prior
        a, b, c = _score(e, error_covariances(lin, prior, jac, q_new, noise))
        sq, tr, inside, n = sq + a, tr + b, inside + c, n + e.shape[0]
    assert 0.8 < np.sqrt(tr / sq) < 1.25 and 0.90 <= inside / n <= 0.98, (np.sqrt(tr / sq), inside / n)


def test_without_model_error_it_is_the_kpi_covariance(fms):
    """No model error: the TCP's predicted covariance is G C_p G^T of the problem (noise only)."""
    pr = fms.problem
    lin, *_ = _trial(fms, 3)
    free = pr.identifiability.free_indices
    g = pr.kpi_jacobian()[:, free].reshape(-1, 3, free.size)
    q_train = np.unique(lin.q, axis=0)
    lin0 = linearise(pr.space, simulate_observations(pr.space, pr.models, q_train, pr.space.zeros(), 0),
                     pr.space.zeros(), free)
    cov = error_covariances(lin0, None, g, pr.kpi.configurations)
    assert np.allclose(cov[0], pr.kpi_covariance(q_train), rtol=1e-6, atol=1e-16)


def _tcp_trial(fms, seed, n_random=50):
    """One truth: GP model error drawn jointly at the training and the working configurations
    (tracker frame), training data with it (random poses and poses within 0.1 rad of each working
    configuration, where the model error's mean is well known), identification; returns what the
    TCP prediction needs and the achieved TCP errors in the KPI's frame, uncompensated and
    compensated (n_work, 3) [m]."""
    pr = fms.problem
    rng = np.random.default_rng(seed)
    work = np.asarray(pr.kpi.configurations, dtype=float)
    near = np.repeat(work, 2, axis=0) + rng.uniform(-0.1, 0.1, (2 * work.shape[0], work.shape[1]))
    q = np.vstack([pr.robot.random_configurations(n_random, rng), near])
    n_train = q.shape[0]
    p_true = draw_true_parameters(pr.space, pr.identifiability.free_indices, rng)
    offset = TRUE.sample(np.vstack([q, work]), rng)  # (n_train + t, 3), tracker frame
    blocks = [ObservationBlock(b.model, b.q, b.values + np.pad(offset[:n_train], ((0, 0), (0, b.values.shape[1] - 3))))
              for b in simulate_observations(pr.space, pr.models, q, p_true, rng)]
    res = identify(pr.space, blocks, pr.identifiability)
    free = res.free_indices
    lin = linearise(pr.space, blocks, res.p, free)
    rot = pr.space.tracker_placement(p_true).rotation if pr.kpi.frame == "world" else np.eye(3)
    rho = max(float(m.noise.repeatability) for m in pr.models)
    truth = pr.kpi.compute_values(pr.space, p_true) + offset[n_train:] @ rot.T \
        + rho * rng.standard_normal((work.shape[0], 3))
    error = truth - pr.kpi.compute_values(pr.space, res.p)
    mu = compensation(lin, TRUE, work) @ pr.space.tracker_placement(res.p).rotation.T \
        if pr.kpi.frame == "world" else compensation(lin, TRUE, work)
    g = pr.kpi.compute_param_jacobian(pr.space, res.p)[:, free]
    return lin, res.p, g, work, rho, error, error - mu


def test_tcp_prediction_in_the_world_frame_against_monte_carlo(fms):
    """The KPI of fms_kr16 is in the world frame, the model error a process of tracker-frame
    positions (tracker turned about 90 deg): over 60 truths the TCP's predicted mean squared error
    (trace of V per working configuration, rows turned into the tracker frame) is the Monte Carlo
    one within 8 % with the model error's mean compensated, within 15 % uncompensated (its Monte
    Carlo spread is larger). Rows left in the world frame give 1.36 and 1.19 on the same draws."""
    pr = fms.problem
    assert pr.kpi.frame == "world"
    sums = {False: [0.0, 0.0], True: [0.0, 0.0]}
    for seed in range(60):
        lin, p, g, work, rho, e_plain, e_comp = _tcp_trial(fms, 500 + seed)
        rows = pr.kpi.rows_in_tracker_frame(pr.space, g, p).reshape(-1, 3, g.shape[1])
        noise = np.broadcast_to(rho**2 * np.eye(3), (work.shape[0], 3, 3))
        for compensate, e in ((False, e_plain), (True, e_comp)):
            v = error_covariances(lin, TRUE, rows, work, noise, compensate)
            sums[compensate][0] += np.trace(v, axis1=1, axis2=2).sum()
            sums[compensate][1] += np.sum(e**2)
    for compensate, (predicted, achieved) in sums.items():
        tol = 0.08 if compensate else 0.15
        assert abs(np.sqrt(predicted / achieved) - 1) < tol, (compensate, np.sqrt(predicted / achieved))


def test_tcp_prediction_in_the_tracker_frame_against_monte_carlo(fms):
    """What identify reports (predict_accuracy) is the TCP's error in the tracker frame, the frame of
    tcp_errors: over 60 parametric truths with GP model error and repeatability (the model's own
    assumptions), the predicted mean squared TCP error is the Monte Carlo one within 8 % with the
    model error's mean compensated, within 15 % uncompensated."""
    pr = fms.problem
    sums = {False: [0.0, 0.0], True: [0.0, 0.0]}
    for seed in range(60):
        rng = np.random.default_rng(700 + seed)
        work = np.asarray(pr.kpi.configurations, dtype=float)
        near = np.repeat(work, 2, axis=0) + rng.uniform(-0.1, 0.1, (2 * work.shape[0], work.shape[1]))
        q = np.vstack([pr.robot.random_configurations(50, rng), near])
        p_true = draw_true_parameters(pr.space, pr.identifiability.free_indices, rng)
        offset = TRUE.sample(np.vstack([q, work]), rng)  # tracker frame
        blocks = [ObservationBlock(b.model, b.q, b.values + np.pad(offset[:len(q)], ((0, 0), (0, b.values.shape[1] - 3))))
                  for b in simulate_observations(pr.space, pr.models, q, p_true, rng)]
        res = identify(pr.space, blocks, pr.identifiability)
        lin = linearise(pr.space, blocks, res.p, res.free_indices)
        rho = max(float(m.noise.repeatability) for m in pr.models)
        # model minus truth, the truth with its model error and repeatability at the TCP
        error = tcp_errors(fms, p_true, res.p) - offset[len(q):] - rho * rng.standard_normal((work.shape[0], 3))
        for compensate in (False, True):
            acc = predict_accuracy(pr, lin, TRUE, res.p, np.asarray(res.free_indices), q, compensate, n_new=4)
            e = error + compensation(lin, TRUE, work) if compensate else error
            sums[compensate][0] += np.sum(np.square(acc.tcp_rms_mm))
            sums[compensate][1] += np.sum(e**2) * 1e6
    for compensate, (predicted, achieved) in sums.items():
        tol = 0.08 if compensate else 0.15
        assert abs(np.sqrt(predicted / achieved) - 1) < tol, (compensate, np.sqrt(predicted / achieved))


def test_new_poses_are_feasible_and_in_the_training_ranges(fms):
    """The headline's new poses: feasible (the scene's constraints) within the training joint
    ranges, seeded; uniform in the ranges, and said so, without a feasibility model."""
    q_train = fms.problem.robot.random_configurations(30, 5)
    lo, hi = q_train.min(axis=0), q_train.max(axis=0)
    q, words = feasible_new_poses(fms.feasibility, q_train, 50, 1)
    assert words == FEASIBLE_POSES and q.shape == (50, 6)
    assert np.all((q >= lo) & (q <= hi)) and fms.feasibility.compute(q, jacobian=False).feasible.all()
    assert np.array_equal(q, feasible_new_poses(fms.feasibility, q_train, 50, 1)[0])
    u, words = feasible_new_poses(None, q_train, 50, 1)
    assert words == UNIFORM_POSES and np.all((u >= lo) & (u <= hi))
    assert not fms.feasibility.compute(u, jacobian=False).feasible.all()


def _realistic_ratios(scene: str, truths: range, n_work: int = 10, n_val: int = 40,
                      settings=None) -> tuple[float, float]:
    """identify's predictions against a realistic truth (what real arms have and the model does
    not), pooled over ``truths``: predicted over achieved RMS of (1) the TCP at ``n_work`` feasible
    working configurations in the tracker frame (tcp_errors' frame), (2) the measured position on
    ``n_val`` feasible validation poses, against the headline over feasible poses."""
    from calib_oed.calibration.kpi import TcpKpi
    from calib_oed.calibration.problem import CalibrationProblem
    from calib_oed.calibration.realistic import sample_truth
    from calib_oed.calibration.realistic_measure import measure
    from calib_oed.calibration.robust import identify_robust
    from calib_oed.calibration.trust import assess
    from calib_oed.calibration.workflow import heuristic_design

    s = setup(load_scene(scene))
    pr = s.problem
    kpi = TcpKpi(heuristic_design(s, n_work, 3), pr.kpi.point, pr.kpi.frame)
    work = CalibrationProblem(pr.space, pr.models, kpi)
    q, q_val = heuristic_design(s, 60, 0), heuristic_design(s, n_val, 7)
    sums = np.zeros(4)  # predicted and achieved sums of squares: TCP, validation
    for k in truths:
        truth = sample_truth(s, np.random.default_rng([29, k]), settings)
        data = measure(truth, pr.models, np.vstack([q, q_val]), np.random.default_rng([29, k, 1]))
        train = [ObservationBlock(b.model, q, b.values[:60]) for b in data.blocks]
        rob = identify_robust(pr.space, train, pr.identifiability, model_error=start_prior(s.scene, pr))
        acc = assess(work, rob, s.feasibility).predicted
        p = rob.result.p
        tcp = kpi.in_frame("tracker")
        sums[0] += np.sum(np.square(acc.tcp_rms_mm))
        sums[1] += np.sum((tcp.compute_values(pr.space, p) - truth.compute_kpi_values(tcp)) ** 2) * 1e6
        state = evaluate_setup(pr.space, p, q_val, regressor=False, jacobian=False)
        for b in data.blocks:
            sums[2] += acc.new_pose_rms_mm**2 * n_val
            sums[3] += np.sum((b.values[60:] - b.model.compute_values(state)) ** 2) * 1e6
    return float(np.sqrt(sums[0] / sums[1])), float(np.sqrt(sums[2] / sums[3]))


def test_realistic_tcp_and_new_pose_predictions_hold():
    """fms_kr16, 3 realistic truths: the predicted RMS on feasible new poses is the achieved one
    within 0.8-1.25 and the predicted TCP error in the tracker frame within 0.8-1.4, pooled (per
    truth the TCP's ratio spreads 0.9-1.5: three truths are too few for the target band, which the
    slow variant checks over eight truths per robot)."""
    tcp, val = _realistic_ratios("fms_kr16", range(3))
    assert 0.8 < tcp < 1.4 and 0.8 < val < 1.25, (tcp, val)


@pytest.mark.slow
@pytest.mark.parametrize("scene", ["fms_kr16", "ur5_table"])
def test_realistic_tcp_and_new_pose_predictions_over_eight_truths(scene):
    """The issue's target on the realistic simulator, pooled over 8 truths: predicted over achieved
    RMS within 0.8-1.25 for the TCP at ten feasible working configurations (tracker frame) and for
    the measured position on 40 feasible validation poses (measured with identify's pose-scaled
    model error: fms_kr16 1.16 and 1.09, ur5_table 1.14 and 1.15; stationary 1.21, 1.06, 1.21, 1.11)."""
    tcp, val = _realistic_ratios(scene, range(8))
    assert 0.8 < tcp < 1.25 and 0.8 < val < 1.25, (tcp, val)
