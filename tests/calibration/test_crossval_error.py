"""Cross-validation's standard error under a smooth model error: the closed form against Monte
Carlo, and CV against separate poses (the model's own assumptions)."""

from __future__ import annotations

import numpy as np
import pytest

from calib_oed.calibration.crossval import cross_validate, held_out_errors, subset
from calib_oed.calibration.crossval_error import cv_difference, quadratic_form
from calib_oed.calibration.identification import identify
from calib_oed.calibration.model_error import linearise
from calib_oed.calibration.prediction import new_poses
from calib_oed.calibration.simulation import draw_true_parameters, simulate_observations
from calib_oed.measurement.dataset import MeasurementSet
from calib_oed.measurement.discrepancy import DiscrepancyPrior

TRUE = DiscrepancyPrior(1e-4, tuple(np.radians([45, 45, 45, 90, 90, 90])))


@pytest.fixture(scope="module")
def fms(kr16_setup):
    return kr16_setup  # the session's fms_kr16 set-up (tests/conftest.py)


def _truth(fms, seed, n=60, n_val=200):
    """A GP model error of 10x the noise on a random truth: 60 calibration poses and n_val
    separate ones uniform in their joint ranges."""
    pr = fms.problem
    rng = np.random.default_rng(300 + seed)
    q = pr.robot.random_configurations(n, rng)
    q_all = np.vstack([q, new_poses(q, n_val, 400 + seed)])
    p = draw_true_parameters(pr.space, pr.identifiability.free_indices, rng)
    (b,) = simulate_observations(pr.space, pr.models, q_all, p, rng, model_error=TRUE)
    mset = MeasurementSet.from_arrays(pr.robot, q_all, b.values)
    return subset(mset, np.arange(n)), subset(mset, np.arange(n, n + n_val))


def test_the_closed_form_is_the_monte_carlo_of_the_quadratic_form(fms):
    """E D = tr(QS), Var D = 2 tr(QSQS) against 4000 Gaussian draws of (z, u*) through the
    linear held-out and new-pose maps (mean within 4 standard errors, sd within 5 %)."""
    pr, errors = fms.problem, fms.scene.error_model()
    cal, _ = _truth(fms, 0, n=30)
    blocks = cal.blocks(error_model=errors)
    fit = identify(pr.space, blocks, pr.identifiability)
    lin = linearise(pr.space, blocks, fit.p, fit.free_indices)
    fold = np.arange(cal.n) % 3
    args = (lin, TRUE, fold, pr.space, fit.p, fit.free_indices, [b.model for b in blocks], 40)
    mean, sd = cv_difference(*args)
    m_map, cov, q_diag = quadratic_form(*args)
    w = np.linalg.cholesky(cov + 1e-30 * np.eye(cov.shape[0])) @ \
        np.random.default_rng(7).normal(size=(cov.shape[0], 4000))
    y = m_map @ w
    d = np.sum(q_diag[:, None] * y * y, axis=0)
    assert abs(d.mean() - mean) < 4 * d.std() / np.sqrt(d.size), (d.mean(), mean)
    assert d.std() == pytest.approx(sd, rel=0.05)


@pytest.mark.slow
def test_cv_within_its_uncertainty_of_separate_poses_over_24_truths(fms):
    """24 GP truths: (CV RMS - RMS of the full calibration on 200 separate poses - bias) / se has
    mean square within the 99 % range of chi2_24/24 (0.41-1.79); measured 1.28 with this se,
    2.36 with the independent-poses one."""
    pr, errors = fms.problem, fms.scene.error_model()
    z = []
    for seed in range(24):
        cal, val = _truth(fms, seed)
        cv = cross_validate(pr.space, cal, pr.identifiability, 5, error_model=errors, model_error=TRUE)
        fit = identify(pr.space, cal.blocks(error_model=errors), pr.identifiability)
        rms = np.sqrt(np.mean(held_out_errors(pr.space, val, fit.p, errors) ** 2))
        z.append((cv.rms_mm - rms - cv.bias_mm) / cv.se_mm)
    assert 0.41 < np.mean(np.square(z)) < 1.79, z


def test_cv_se_under_model_error_is_wider_than_for_independent_poses(fms):
    """Under the model error the standard error counts the shared error of nearby poses and of the
    separate set: larger than the independent-poses one, and CV within 2.5 of it of 200 separate
    poses on 3 truths."""
    pr, errors = fms.problem, fms.scene.error_model()
    for seed in range(3):
        cal, val = _truth(fms, seed)
        cv = cross_validate(pr.space, cal, pr.identifiability, 5, error_model=errors, model_error=TRUE)
        iid = cross_validate(pr.space, cal, pr.identifiability, 5, error_model=errors)
        assert cv.rms_mm == iid.rms_mm and cv.se_basis == "model error" and iid.bias_mm is None
        assert cv.se_mm > 1.1 * iid.se_mm, (cv.se_mm, iid.se_mm)
        fit = identify(pr.space, cal.blocks(error_model=errors), pr.identifiability)
        rms = np.sqrt(np.mean(held_out_errors(pr.space, val, fit.p, errors) ** 2))
        assert abs(cv.rms_mm - rms - cv.bias_mm) <= 2.5 * cv.se_mm, (seed, cv.rms_mm, rms, cv.se_mm)
    assert "CV expected" in cv.summary() and cv.to_dict()["se_basis"] == "model error"


def test_cv_within_its_uncertainty_of_separate_poses_on_the_realistic_simulator(fms):
    """fms_kr16, realistic truth 1 (what real arms have and the model does not), the model error
    fitted as identify --cv does: CV on 60 poses within 2.5 of its standard error of the full
    calibration on 200 separate poses (bench/bench_trust.py runs 6 truths per robot)."""
    from calib_oed.calibration.realistic import sample_truth
    from calib_oed.calibration.realistic_measure import measure
    from calib_oed.calibration.robust import identify_robust

    pr, errors = fms.problem, fms.scene.error_model()
    q = pr.robot.random_configurations(60, 1001)
    q_all = np.vstack([q, new_poses(q, 200, 2001)])
    rng = np.random.default_rng(1)
    (b,) = measure(sample_truth(fms, rng), pr.models, q_all, rng).blocks
    mset = MeasurementSet.from_arrays(pr.robot, q_all, b.values)
    cal, val = subset(mset, np.arange(60)), subset(mset, np.arange(60, 260))
    rob = identify_robust(pr.space, cal.blocks(error_model=errors), pr.identifiability,
                          model_error=fms.scene.discrepancy())
    cv = cross_validate(pr.space, cal, pr.identifiability, 5, error_model=errors,
                        model_error=rob.model_error.prior)
    fit = identify(pr.space, cal.blocks(error_model=errors), pr.identifiability)
    rms = np.sqrt(np.mean(held_out_errors(pr.space, val, fit.p, errors) ** 2))
    assert cv.rms_mm > 4 * cv.noise_floor_mm  # the model error dominates
    assert abs(cv.rms_mm - rms - cv.bias_mm) <= 2.5 * cv.se_mm, (cv.rms_mm, rms, cv.bias_mm, cv.se_mm)
