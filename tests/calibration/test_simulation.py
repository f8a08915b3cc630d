"""Simulated calibrations: truth, noise, identification and TCP errors."""

from __future__ import annotations

import numpy as np
import pytest

from calib_oed.calibration.problem import CalibrationProblem
from calib_oed.calibration.simulation import (
    draw_true_parameters,
    simulate_calibration,
    simulate_observations,
)
from calib_oed.measurement import TrackerPosition
from calib_oed.scene.reader import load_scene


@pytest.fixture(scope="module")
def problem():
    return CalibrationProblem.from_scene(load_scene("fms_kr16"))


def test_truth_perturbs_only_free_parameters(problem):
    space = problem.space
    free = problem.identifiability.free_indices
    p = np.array([draw_true_parameters(space, free, seed, 2e-3, 3e-3) for seed in range(400)])
    fixed = np.setdiff1d(np.arange(space.size), free)
    assert not p[:, fixed].any()
    sd = p[:, free].std(axis=0)
    units = np.array([space.parameters[i].unit for i in free])
    # 400 samples: the sample sd is within ~4 standard errors (7 %) of the truth
    assert np.all(np.abs(sd[units == "m"] / 2e-3 - 1) < 0.15)
    assert np.all(np.abs(sd[units == "rad"] / 3e-3 - 1) < 0.15)


def test_simulated_noise_has_the_model_sigma(problem):
    space = problem.space
    q = problem.robot.random_configurations(2000, 1)
    model = TrackerPosition(0, 2e-5)
    exact = simulate_observations(space, [TrackerPosition(0, 1e-300)], q, np.zeros(space.size), 0)[0]
    noisy = simulate_observations(space, [model], q, np.zeros(space.size), 0)[0]
    noise = noisy.values - exact.values
    assert noise.std() == pytest.approx(2e-5, rel=0.03)
    assert abs(noise.mean()) < 4 * 2e-5 / np.sqrt(noise.size)


def test_calibration_trial_errors(problem):
    q = problem.robot.random_configurations(40, 3)
    trial = simulate_calibration(problem, q, 11)
    assert trial.converged
    space = problem.space
    s_true = problem.kpi.compute_values(space, trial.p_true)
    np.testing.assert_allclose(trial.error_before, problem.kpi.compute_values(space, None) - s_true)
    np.testing.assert_allclose(trial.error_after, problem.kpi.compute_values(space, trial.p_est) - s_true)
    # calibration reduces a ~mm error to the predicted micrometre level
    sigma = problem.kpi_sigma(q)
    assert np.linalg.norm(trial.error_before) > 0.1e-3
    assert np.linalg.norm(trial.error_after) < 6 * np.sqrt(3) * sigma.max()
    # same seed, same trial
    again = simulate_calibration(problem, q, 11)
    np.testing.assert_array_equal(again.p_est, trial.p_est)


def test_simulated_noise_has_the_full_covariance(problem):
    """With a TrackerNoise, eta - h ~ N(0, Sigma_i) at the TRUE positions: whitened draws are
    N(0, I) (3000 draws: each entry of their covariance within 5 standard errors)."""
    from calib_oed.measurement.noise import TrackerNoise

    space = problem.space
    noise = TrackerNoise((5e-6, 1.5e-7), (7.5e-6, 3e-6), 1.1e-5)
    q = problem.robot.random_configurations(3000, 4)
    p_true = draw_true_parameters(space, problem.identifiability.free_indices, 5)
    exact = simulate_observations(space, [TrackerPosition(0, 1e-300)], q, p_true, 0)[0]
    noisy = simulate_observations(space, [TrackerPosition(0, 1e-5, noise)], q, p_true, 6)[0]
    z = np.einsum("nij,nj->ni", noise.whitening(exact.values), noisy.values - exact.values)
    emp = z.T @ z / z.shape[0]
    se = np.sqrt((1 + np.eye(3)) / z.shape[0])  # var(z_a z_b) = 1 + delta_ab
    assert np.all(np.abs(emp - np.eye(3)) < 5 * se)
    # the same draws whitened with the isotropic 0.01 mm are far from N(0, I)
    assert np.mean((noisy.values - exact.values) ** 2) / 1e-10 > 2.0
