"""K-fold cross-validation: balanced folds, coverage warnings, agreement with a validation set."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from calib_oed.calibration.crossval import (
    balanced_folds,
    coverage_warnings,
    cross_validate,
    held_out_errors,
    noise_floor,
    pose_index,
    subset,
)
from calib_oed.calibration.identification import identify
from calib_oed.calibration.workflow import setup, simulated_measurements
from calib_oed.exceptions import ParameterError
from calib_oed.scene.reader import load_scene

JOINTS = [f"j{i}" for i in range(1, 7)]


def test_balanced_folds_cover_every_joint_quantile():
    q = np.random.default_rng(0).uniform(-2, 2, size=(60, 6))
    fold = balanced_folds(q, 5, seed=0)
    assert np.bincount(fold).tolist() == [12] * 5
    quantile = np.argsort(np.argsort(q, axis=0), axis=0) * 5 // 60
    for j in range(6):  # each fold holds poses from at least 4 of every joint's 5 quantiles
        assert all(len(set(quantile[fold == f, j])) >= 4 for f in range(5))
    assert coverage_warnings(q, fold, JOINTS) == []
    with pytest.raises(ParameterError, match="between 2"):
        balanced_folds(q, 1)


def test_a_sweep_split_in_blocks_is_warned_about():
    """Joint sweeps, one joint after the other: contiguous folds hold out whole ranges."""
    q = np.zeros((60, 6))
    for j in range(6):
        q[10 * j:10 * (j + 1), j] = np.linspace(-1, 1, 10)
    contiguous = np.arange(60) * 5 // 60
    warnings = coverage_warnings(q, contiguous, JOINTS)
    assert warnings and "fold 1 of 5" in warnings[0] and "j1" in warnings[0]
    assert coverage_warnings(q, balanced_folds(q, 5, seed=0), JOINTS) == []


def test_pose_index_groups_rows_of_one_configuration():
    q = np.array([[0.0, 1], [2, 3], [0, 1], [4, 5], [2, 3]])
    assert pose_index(q).tolist() == [0, 1, 0, 2, 1]


def test_cross_validation_predicts_the_validation_error():
    """CV on 60 poses against 200 fresh poses with the full-data calibration (simulated)."""
    s = setup(load_scene("fms_kr16"))
    problem = s.problem
    errors = s.scene.error_model()  # the shipped tracker error model + repeatability
    mset, _ = simulated_measurements(s, problem.robot.random_configurations(260, 31), 32)
    cal, val = subset(mset, np.arange(60)), subset(mset, np.arange(60, 260))
    cv = cross_validate(problem.space, cal, problem.identifiability, 5, error_model=errors, seed=0)
    fit = identify(problem.space, cal.blocks(error_model=errors), problem.identifiability)
    e = held_out_errors(problem.space, val, fit.p, errors)
    rms = np.sqrt(np.mean(e**2))
    se = np.std(e**2, ddof=1) / np.sqrt(e.size) / (2 * rms)
    assert abs(cv.rms_mm - rms) <= 2 * np.hypot(cv.se_mm, se), (cv.rms_mm, cv.se_mm, rms, se)
    assert 1.0 < cv.rms_mm / cv.noise_floor_mm < 1.3 and cv.warnings == ()
    assert np.all(cv.fold >= 0) and np.isfinite(cv.errors_mm).all() and len(cv.fold_rms_mm) == 5
    assert "cross-validation, 5 folds" in cv.summary() and "every one of the 60 rows" in cv.summary()


def test_a_gross_row_is_held_out_and_counted_but_not_trained_on():
    """A 5 mm misreading the identification drops: every other row's held-out error is that of
    the clean data (the folds do not train on it; trained on, it spoils them), its own is ~5 mm
    and counts in the RMS."""
    s = setup(load_scene("fms_kr16"))
    problem = s.problem
    errors = s.scene.error_model()
    clean, _ = simulated_measurements(s, problem.robot.random_configurations(40, 5), 6)
    positions = clean.positions.copy()
    positions[7, 0] += 5e-3
    bad = dataclasses.replace(clean, positions=positions)
    gross = np.zeros(clean.n, bool)
    gross[7] = True
    args = (problem.space, clean, problem.identifiability, 4)
    ref = cross_validate(*args, error_model=errors, gross=gross)
    cv = cross_validate(problem.space, bad, problem.identifiability, 4, error_model=errors, gross=gross)
    assert np.allclose(np.delete(cv.errors_mm, 7), np.delete(ref.errors_mm, 7), rtol=1e-9)
    assert abs(cv.errors_mm[7] - 5.0) < 0.5 and cv.n_gross == 1
    trained = cross_validate(problem.space, bad, problem.identifiability, 4, error_model=errors)
    assert np.median(np.delete(trained.errors_mm, 7)) > 2 * np.median(np.delete(ref.errors_mm, 7))
    assert cv.rms_mm > 3 * cv.rms_without_gross_mm
    assert cv.rms_without_gross_mm == pytest.approx(np.sqrt(np.mean(np.delete(ref.errors_mm, 7) ** 2)))
    assert "1 row(s) the identification drops as gross errors" in cv.summary()
    none = cross_validate(*args, error_model=errors, gross=np.zeros(clean.n, bool))
    assert "no gross error" in none.summary() and cv.to_dict()["gross_rows"] == 1
    with pytest.raises(ParameterError, match="gross"):
        cross_validate(*args, error_model=errors, gross=gross[:5])


def test_noise_floor_is_the_rms_error_of_a_perfect_model_against_monte_carlo():
    """sqrt(mean tr Sigma_i) of the shipped scene's tracker model + repeatability equals the RMS of
    |e| for e ~ N(0, Sigma_i) drawn at the measured positions (400 rows x 100 draws); the
    isotropic sigma gives sqrt(3) sigma exactly."""
    s = setup(load_scene("fms_kr16"))
    tracker, noise = s.scene.tracker, s.scene.position_noise()
    mset, _ = simulated_measurements(s, s.problem.robot.random_configurations(400, 41), 42)
    floor = noise_floor(mset, mset.blocks(noise=noise))
    rng = np.random.default_rng(43)
    sq = np.concatenate([np.sum(noise.sample(mset.positions, rng) ** 2, axis=1) for _ in range(100)])
    se = np.std(sq, ddof=1) / np.sqrt(sq.size)  # of the mean squared norm
    assert abs(np.mean(sq) - floor**2) < 4 * se, (np.mean(sq), floor**2, se)
    assert 4 * se < 0.02 * floor**2  # the check resolves 2 %
    # the anisotropic, range-dependent floor is not the isotropic one of the same scene
    iso = noise_floor(mset, mset.blocks(sigma=tracker.sigma))
    assert iso == pytest.approx(np.sqrt(3) * 1e-5, rel=1e-12)
    assert floor > 1.5 * iso


def test_cross_validation_with_model_error_predicts_a_separate_validation_set():
    """GP-drawn model error of 10x the noise (the model's own assumptions), 3 truths: the 5-fold
    RMS on 60 poses is within two of its standard errors (combined with the validation RMS's)
    of the RMS of the full calibration on 200 separate poses in the same joint ranges."""
    from calib_oed.calibration.prediction import new_poses
    from calib_oed.calibration.simulation import draw_true_parameters, simulate_observations
    from calib_oed.measurement.dataset import MeasurementSet
    from calib_oed.measurement.discrepancy import DiscrepancyPrior

    s = setup(load_scene("fms_kr16"))
    pr, errors = s.problem, s.scene.error_model()
    prior = DiscrepancyPrior(1e-4, tuple(np.radians([45, 45, 45, 90, 90, 90])))
    for seed in range(3):
        rng = np.random.default_rng(300 + seed)
        q = pr.robot.random_configurations(60, rng)
        q_all = np.vstack([q, new_poses(q, 200, 400 + seed)])
        p = draw_true_parameters(pr.space, pr.identifiability.free_indices, rng)
        (b,) = simulate_observations(pr.space, pr.models, q_all, p, rng, model_error=prior)
        mset = MeasurementSet.from_arrays(pr.robot, q_all, b.values)
        cal, val = subset(mset, np.arange(60)), subset(mset, np.arange(60, 260))
        cv = cross_validate(pr.space, cal, pr.identifiability, 5, error_model=errors)
        fit = identify(pr.space, cal.blocks(error_model=errors), pr.identifiability)
        e = held_out_errors(pr.space, val, fit.p, errors)
        rms = np.sqrt(np.mean(e**2))
        se = np.std(e**2, ddof=1) / np.sqrt(e.size) / (2 * rms)
        assert cv.rms_mm / cv.noise_floor_mm > 4  # the model error dominates
        assert abs(cv.rms_mm - rms) <= 2 * np.hypot(cv.se_mm, se), (seed, cv.rms_mm, cv.se_mm, rms, se)
