"""The assessment identify reports, on the realistic simulator (what real arms have and the model
does not): predicted against achieved error on new poses, coverage, no pose dropped."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import chi2

from calib_oed.calibration.model_error import start_prior
from calib_oed.calibration.prediction import compensation, error_covariances, new_poses
from calib_oed.calibration.realistic import sample_truth
from calib_oed.calibration.realistic_measure import measure
from calib_oed.calibration.robust import identify_robust
from calib_oed.calibration.simulation import draw_true_parameters, simulate_observations
from calib_oed.calibration.trust import assess, compensate
from calib_oed.calibration.workflow import setup
from calib_oed.measurement.base import evaluate_setup
from calib_oed.measurement.observations import ObservationBlock
from calib_oed.scene.reader import load_scene


def _case(s, truth, n_train=60, n_new=200):
    """identify's fit on 60 poses of a realistic truth, and 200 new poses in the training ranges."""
    pr = s.problem
    q = pr.robot.random_configurations(n_train, 1000 + truth)
    q_new = new_poses(q, n_new, 2000 + truth)
    rng = np.random.default_rng(truth)
    blocks = measure(sample_truth(s, rng), pr.models, np.vstack([q, q_new]), rng).blocks
    train = [ObservationBlock(b.model, b.q[:n_train], b.values[:n_train]) for b in blocks]
    test = [ObservationBlock(b.model, b.q[n_train:], b.values[n_train:]) for b in blocks]
    rob = identify_robust(pr.space, train, pr.identifiability, model_error=start_prior(s.scene, pr))
    return rob, test, q_new


CHI2_95 = float(chi2.ppf(0.95, 3))


def _score(s, rob, test, q_new, threshold=CHI2_95):
    lin, prior, res = rob.linearisation, rob.model_error.prior, rob.result
    state = evaluate_setup(s.problem.space, res.p, q_new, regressor=True, jacobian=False)
    sq = tr = inside = n = 0.0
    for b in test:
        h = b.model.compute_values(state)
        jac = b.model.compute_param_jacobian(state)[:, :, res.free_indices]
        v = error_covariances(lin, prior, jac, q_new, b.model.noise_covariance(h))
        e = b.values - h
        inside += np.sum(np.einsum("ni,nij,nj->n", e, np.linalg.inv(v), e) <= threshold)
        sq, tr, n = sq + np.sum(e**2), tr + np.trace(v, axis1=1, axis2=2).sum(), n + e.shape[0]
    return np.sqrt(tr / sq), inside / n, np.sqrt(sq / n) * 1e3


def test_realistic_kr16_predicted_accuracy_and_flags():
    """fms_kr16, one realistic truth (model error ~8x the noise): the predicted RMS on new poses
    within 0.8-1.25 of the achieved, coverage of the 95 % regions 0.9-0.98, nothing dropped; the
    predicted accuracy identify reports is that of 200 such poses; compensation data reproduce the
    conditional mean."""
    s = setup(load_scene("fms_kr16"))
    rob, test, q_new = _case(s, 0)
    assert rob.linear.sigma0 > 5 and not rob.dropped.any()
    ratio, cover, achieved = _score(s, rob, test, q_new)
    assert 0.8 < ratio < 1.25 and 0.9 <= cover <= 0.98, (ratio, cover)
    trust = assess(s.problem, rob)
    # the uncertainty of the fitted model error: a range that holds the achieved RMS, and
    # regions wider than chi2_3(0.95) that hold more of the new points
    lo, hi = trust.predicted.new_pose_rms_range_mm
    assert lo < achieved < hi and 1.05 < hi / trust.predicted.new_pose_rms_mm < 1.5, (lo, achieved, hi)
    c = trust.predicted.region_threshold
    assert c > chi2.ppf(0.95, 3) and _score(s, rob, test, q_new, c)[1] >= cover
    assert trust.predicted.new_pose_rms_mm > 3 * trust.predicted.noise_only_new_pose_rms_mm
    assert np.allclose(compensate(trust.prior, trust.configs, trust.weights, q_new),
                       compensation(rob.linearisation, trust.prior, q_new), rtol=1e-8, atol=1e-12)
    assert "model error" in trust.predicted.covers and len(trust.predicted.tcp_rms_mm) == 1


@pytest.mark.slow
@pytest.mark.parametrize("scene", ["fms_kr16", "ur5_table"])
def test_realistic_targets_over_three_truths(scene):
    """The issue's targets, 3 truths per robot (bench/bench_trust.py prints the same table):
    predicted/achieved 0.8-1.25 per truth; pooled coverage 0.9-0.98; no measurement dropped."""
    s = setup(load_scene(scene))
    covers = []
    for truth in range(3):
        rob, test, q_new = _case(s, truth)
        ratio, cover, _ = _score(s, rob, test, q_new)
        assert 0.8 < ratio < 1.25 and not rob.dropped.any(), (truth, ratio)
        covers.append(cover)
    assert 0.9 <= np.mean(covers) <= 0.98, covers


def _gp_case(s, truth, n_train=60, n_new=200):
    """As :func:`_case`, the truth under the model's own assumptions: the geometry of
    ``draw_true_parameters`` and a Gaussian-process model error of the scene's prior."""
    pr = s.problem
    q = pr.robot.random_configurations(n_train, 1000 + truth)
    q_new = new_poses(q, n_new, 2000 + truth)
    rng = np.random.default_rng(truth)
    p = draw_true_parameters(pr.space, pr.identifiability.free_indices, rng)
    blocks = simulate_observations(pr.space, pr.models, np.vstack([q, q_new]), p, rng,
                                   model_error=s.scene.discrepancy())
    train = [ObservationBlock(b.model, b.q[:n_train], b.values[:n_train]) for b in blocks]
    test = [ObservationBlock(b.model, b.q[n_train:], b.values[n_train:]) for b in blocks]
    rob = identify_robust(pr.space, train, pr.identifiability, model_error=start_prior(s.scene, pr))
    return rob, test, q_new


@pytest.mark.slow
def test_coverage_pooled_on_target_and_per_case_spread_as_under_the_models_own_assumptions():
    """The coverage claim (docs/benchmarks.md, issue 29), 6 truths x 2 robots, 60 training and
    200 new poses each, the 95 % regions identify reports (threshold widened for the fitted
    model error's uncertainty): pooled over the realistic truths 0.93-0.97. Per case the
    coverage is not held to 0.93-0.97: under the model's own assumptions (GP truths of the
    scene's prior, where every assumption holds) it spreads as far, since 60 poses size the
    model error to about +-15 %; the realistic spread is no wider than 1.5x the GP one."""
    covers = {"realistic": [], "gp": []}
    for scene in ("fms_kr16", "ur5_table"):
        s = setup(load_scene(scene))
        for truth in range(6):
            for source, make in (("realistic", _case), ("gp", _gp_case)):
                rob, test, q_new = make(s, truth)
                threshold = assess(s.problem, rob).predicted.region_threshold
                covers[source].append(_score(s, rob, test, q_new, threshold)[1])
    real, gp = np.array(covers["realistic"]), np.array(covers["gp"])
    assert 0.93 <= real.mean() <= 0.97, real
    assert 0.93 <= gp.mean() <= 0.97, gp  # the model's own assumptions: on target pooled too
    assert gp.min() < 0.93 or gp.max() > 0.97, gp  # ... and per case off target as well
    assert real.std() <= 1.5 * gp.std(), (real, gp)
