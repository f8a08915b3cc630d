"""Model-error hyperparameters by restricted likelihood: gradient, recovery, the leave-one-out identity."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg

from calib_oed.calibration.hyper_uncertainty import prior_of, theta_of
from calib_oed.calibration.identification import identify
from calib_oed.calibration.joint_prior_choice import pose_scale
from calib_oed.calibration.model_error import (
    fit_model_error,
    leave_one_out,
    linearise,
    restricted_log_likelihood,
)
from calib_oed.calibration.simulation import draw_true_parameters, simulate_observations
from calib_oed.measurement.discrepancy import DiscrepancyPrior
from tests.conftest import central_difference, relative_error

TRUE = DiscrepancyPrior(1e-4, tuple(np.radians([45, 45, 45, 90, 90, 90])))


@pytest.fixture(scope="module")
def fms(kr16_setup):
    return kr16_setup  # the session's fms_kr16 set-up (tests/conftest.py)


def _data(fms, seed, n=60, prior=TRUE):
    pr = fms.problem
    rng = np.random.default_rng(seed)
    q = pr.robot.random_configurations(n, rng)
    p = draw_true_parameters(pr.space, pr.identifiability.free_indices, rng)
    blocks = simulate_observations(pr.space, pr.models, q, p, rng, model_error=prior)
    res = identify(pr.space, blocks, pr.identifiability)
    return blocks, res, linearise(pr.space, blocks, res.p, res.free_indices)


def test_restricted_likelihood_gradient_matches_central_differences(fms):
    _, _, lin = _data(fms, 0, 30)
    ell = np.array(TRUE.length_scales)

    def prior(theta):
        return TRUE.with_values(np.exp(theta[0]), np.exp(theta[1:-1]), "t", np.exp(theta[-1]))

    theta = np.log(np.r_[1.3e-4, ell * 1.2, 3e-5])  # with a white part
    _, grad = restricted_log_likelihood(lin, prior(theta), gradient=True)
    num = central_difference(lambda t: restricted_log_likelihood(lin, prior(t)), theta, 1e-5)
    assert relative_error(grad, num) < 1e-5


def test_restricted_likelihood_gradient_of_the_harmonic_kernel(fms):
    """The harmonic amplitudes' part of the gradient (``hyper_uncertainty.theta_of`` order)."""
    _, _, lin = _data(fms, 1, 30)
    harm = TRUE.with_values(1.3e-4, np.array(TRUE.length_scales) * 1.2, "t", 3e-5)
    harm = DiscrepancyPrior(harm.sigma, harm.length_scales, "matern52_harmonic", "t", 3e-5,
                            harmonic=np.linspace(2e-5, 6e-5, 12))
    theta = theta_of(harm)
    assert theta.size == 1 + 6 + 12 + 1
    _, grad = restricted_log_likelihood(lin, harm, gradient=True)
    num = central_difference(lambda t: restricted_log_likelihood(lin, prior_of(harm, t)), theta, 1e-5)
    assert relative_error(grad, num) < 1e-5


def test_restricted_likelihood_gradient_of_a_pose_scaled_kernel(fms):
    """The weight of the joint prior's pose scale in the gradient (``theta_of`` order)."""
    _, _, lin = _data(fms, 2, 30)
    scale = pose_scale(fms.problem).normalised(np.unique(lin.q, axis=0)).with_weight(0.6)
    scaled = TRUE.with_values(1.3e-4, np.array(TRUE.length_scales) * 1.2, "t", 3e-5).with_scale(scale)
    theta = theta_of(scaled)
    assert theta.size == 1 + 6 + 1 + 1
    _, grad = restricted_log_likelihood(lin, scaled, gradient=True)
    num = central_difference(lambda t: restricted_log_likelihood(lin, prior_of(scaled, t)), theta, 1e-5)
    assert relative_error(grad, num) < 1e-5


def test_restricted_likelihood_recovers_the_amplitude(fms):
    """Three GP-drawn model errors of sigma 0.1 mm per axis (10x the noise), 60 poses each: the
    fitted sigma within 25 % of the truth, and far more likely than no model error."""
    for seed in range(3):
        _, _, lin = _data(fms, seed)
        fit = fit_model_error(lin, fms.scene.discrepancy())
        assert abs(fit.prior.sigma / TRUE.sigma - 1) < 0.25, fit.prior.describe()
        assert fit.log_likelihood > fit.noise_only_log_likelihood + 100
        assert fit.log_likelihood >= restricted_log_likelihood(lin, TRUE) - 1e-6


def test_leave_one_out_is_the_prediction_from_the_others(fms):
    """t_i of the closed form equals the GLS prediction of measurement i from all the others,
    the parameters re-estimated (brute force on the linearised model)."""
    _, _, lin = _data(fms, 4, 25)
    t, dim = leave_one_out(lin, TRUE)
    sigma = lin.covariance(TRUE)
    for i in (0, 7, 24):
        rows = lin.measurement == i
        o = ~rows
        s_oo = scipy.linalg.cho_factor(sigma[np.ix_(o, o)])
        j_o, e_o = lin.jac[o], lin.residual[o]
        w_j = scipy.linalg.cho_solve(s_oo, j_o)
        beta = np.linalg.solve(j_o.T @ w_j, w_j.T @ e_o)  # GLS on the others
        r_o = e_o - j_o @ beta
        k_io = sigma[np.ix_(rows, o)]
        pred = lin.jac[rows] @ beta + k_io @ scipy.linalg.cho_solve(s_oo, r_o)
        g = lin.jac[rows] - k_io @ w_j  # the prediction error's sensitivity to beta
        var = (sigma[np.ix_(rows, rows)] - k_io @ scipy.linalg.cho_solve(s_oo, k_io.T)
               + g @ np.linalg.solve(j_o.T @ w_j, g.T))
        d = lin.residual[rows] - pred
        assert d @ np.linalg.solve(var, d) == pytest.approx(t[i], rel=1e-6)
    assert np.all(dim == 3)


def test_leave_one_out_statistic_is_chi2_under_the_model(fms):
    """20 truths of a GP model error (the model's own assumptions), 60 poses each: the
    leave-one-out statistics t_i the flags judge by are chi2_d, as the module says: mean t/d
    within 10 % of 1 (measured 1.003; a variance off by 1.5x gives 1.5) and the counts beyond the
    99 % and 99.9 % quantiles near 1 % and 0.1 % of 1200 (measured 15 and 2; the bounds allow for
    the correlation of measurements within one truth)."""
    from scipy.stats import chi2

    ts, ds = [], []
    for seed in range(20):
        _, _, lin = _data(fms, 100 + seed)
        t, d = leave_one_out(lin, TRUE)
        ts.append(t)
        ds.append(d)
    t, d = np.concatenate(ts), np.concatenate(ds)
    assert t.size == 1200
    assert abs(np.mean(t / d) - 1) < 0.1, np.mean(t / d)
    assert 3 <= np.sum(t > chi2.ppf(0.99, d)) <= 30
    assert np.sum(t > chi2.ppf(0.999, d)) <= 8
