"""The fitted model error's uncertainty (Laplace) and the widened prediction regions, against
central differences and Monte Carlo (the model's own assumptions)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import chi2

from calib_oed.calibration.hyper_uncertainty import (
    laplace_covariance,
    log_spread,
    prior_of,
    region_threshold,
    theta_of,
)
from calib_oed.calibration.identification import identify
from calib_oed.calibration.model_error import fit_model_error, linearise, restricted_log_likelihood
from calib_oed.calibration.prediction import error_covariances, new_poses
from calib_oed.calibration.simulation import draw_true_parameters, simulate_observations
from calib_oed.measurement.base import evaluate_setup
from calib_oed.measurement.discrepancy import DiscrepancyPrior
from calib_oed.measurement.observations import ObservationBlock

TRUE = DiscrepancyPrior(1e-4, tuple(np.radians([45, 45, 45, 90, 90, 90])), sigma_white=1e-5)


@pytest.fixture(scope="module")
def fms(kr16_setup):
    return kr16_setup  # the session's fms_kr16 set-up (tests/conftest.py)


def _fit(fms, seed, n=60):
    """A GP truth (the model's own assumptions), the plain fit and the restricted-likelihood one;
    the mean tr V of 50 new poses as a function of the prior."""
    pr = fms.problem
    rng = np.random.default_rng(500 + seed)
    q = pr.robot.random_configurations(n, rng)
    p = draw_true_parameters(pr.space, pr.identifiability.free_indices, rng)
    (b,) = simulate_observations(pr.space, pr.models, q, p, rng, model_error=TRUE)
    res = identify(pr.space, [b], pr.identifiability)
    lin = linearise(pr.space, [ObservationBlock(b.model, q, b.values)], res.p, res.free_indices)
    q_new = new_poses(q, 50, seed)
    state = evaluate_setup(pr.space, res.p, q_new, regressor=True, jacobian=False)
    (mdl,) = pr.models
    jac = mdl.compute_param_jacobian(state)[:, :3][:, :, res.free_indices]
    noise = mdl.noise_covariance(mdl.compute_values(state))[:, :3, :3]

    def mean_trace(prior):
        return float(np.trace(error_covariances(lin, prior, jac, q_new, noise), axis1=1, axis2=2).mean())

    return lin, fit_model_error(lin, fms.scene.discrepancy()).prior, mean_trace


def test_region_threshold_against_monte_carlo():
    """No spread: chi2_3(0.95); with tau = 0.15, 0.4: the mixture e^x chi2_3 (x ~ N(0, tau^2)) has
    95 % of 400 000 draws below c (within 0.15 %), and c grows with tau."""
    assert region_threshold(0.0) == pytest.approx(chi2.ppf(0.95, 3), rel=1e-12)
    rng = np.random.default_rng(0)
    last = chi2.ppf(0.95, 3)
    for tau in (0.15, 0.4):
        c = region_threshold(tau)
        t = np.exp(tau * rng.normal(size=400_000)) * rng.chisquare(3, size=400_000)
        assert np.mean(t <= c) == pytest.approx(0.95, abs=1.5e-3), (tau, np.mean(t <= c))
        assert c > last
        last = c


def test_laplace_hessian_against_second_differences_of_the_likelihood(fms):
    """v^T H v from the returned covariance equals the second central difference of the restricted
    log-likelihood along two directions (step 0.02) within 2 %."""
    lin, prior, _ = _fit(fms, 0)
    active, cov = laplace_covariance(lin, prior)
    assert active.size >= 3 and 0 in active  # sigma and some length scales are inside their bounds
    hess = np.linalg.inv(cov)
    theta = theta_of(prior)
    rng = np.random.default_rng(1)
    for v in (np.eye(active.size)[0], rng.normal(size=active.size)):
        v = v / np.linalg.norm(v)
        d = np.zeros(theta.size)
        d[active] = 0.02 * v
        f = [restricted_log_likelihood(lin, prior_of(prior, theta + s * d)) for s in (1, 0, -1)]
        second = -(f[0] - 2 * f[1] + f[2]) / 0.02**2
        assert second == pytest.approx(v @ hess @ v, rel=0.02), (second, v @ hess @ v)


@pytest.mark.slow
def test_the_spread_of_the_predicted_rms_against_monte_carlo(fms):
    """16 GP truths: log of the predicted mean tr V with the fitted hyperparameters minus that with
    the true ones, over its Laplace sd tau, has mean square in the 99 % range of chi2_16/16
    (0.36-2.0): the range identify reports holds the prediction the true model error gives."""
    z = []
    for seed in range(16):
        lin, prior, mean_trace = _fit(fms, seed)
        tau = log_spread(prior, *laplace_covariance(lin, prior), mean_trace)
        z.append((np.log(mean_trace(prior)) - np.log(mean_trace(TRUE))) / tau)
    assert 0.36 < np.mean(np.square(z)) < 2.0, np.round(z, 2)



def test_an_exact_model_has_no_range_and_chi2_regions(fms, tmp_path):
    """Data with noise only (the model exact; the CLI's simulate of tests/cli/test_cli_inspect.py,
    which made identify fail before): the fitted model error is a few um and its size not
    determined (Laplace sd of the log variance far above TAU_MAX): no range, regions at
    chi2_3(0.95), said in the report; a huge tau still gives a finite threshold."""
    from calib_oed.calibration.hyper_uncertainty import TAU_MAX
    from calib_oed.calibration.robust import identify_robust
    from calib_oed.calibration.trust import assess
    from calib_oed.calibration.workflow import read_scene_measurements
    from calib_oed.cli import EXIT_OK, main

    path = tmp_path / "cal.csv"
    assert main(["simulate", "fms_kr16", "-n", "40", "--seed", "0", "--truth-seed", "4",
                 "-o", str(path), "--quiet"]) == EXIT_OK
    pr = fms.problem
    blocks = read_scene_measurements(fms, path).blocks(error_model=fms.scene.error_model())
    rob = identify_robust(pr.space, blocks, pr.identifiability, model_error=fms.scene.discrepancy())
    acc = assess(pr, rob).predicted
    assert rob.model_error.prior.sigma < 1e-5  # a few um: noise only
    assert acc.log_variance_sd > TAU_MAX and acc.new_pose_rms_range_mm is None
    assert acc.region_threshold == pytest.approx(chi2.ppf(0.95, 3))
    assert any("range not determined" in line for line in acc.lines())
    assert np.isfinite(region_threshold(30.0)) and region_threshold(30.0) > region_threshold(1.0)
