"""Robust identification with an estimated scale: one gross error, clean data, unmodelled compliance."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from calib_oed.calibration.crossval import held_out_errors, noise_floor, subset
from calib_oed.calibration.problem import CalibrationProblem
from calib_oed.calibration.robust import identify_robust
from calib_oed.calibration.simulation import draw_true_parameters, simulate_observations
from calib_oed.calibration.workflow import simulated_measurements
from calib_oed.exceptions import ParameterError
from calib_oed.measurement.observations import ObservationBlock
from calib_oed.model.compliance import Compliance
from calib_oed.scene.reader import load_scene
from calib_oed.scene.records import ComplianceSpec


@pytest.fixture(scope="module")
def fms(kr16_setup):
    return kr16_setup  # the session's fms_kr16 set-up (tests/conftest.py)


def test_one_gross_error_is_exactly_the_flagged_row(fms):
    problem, tracker = fms.problem, fms.scene.tracker
    q = problem.robot.random_configurations(260, 21)
    mset, _ = simulated_measurements(fms, q, 22)
    cal, val = subset(mset, np.arange(60)), subset(mset, np.arange(60, 260))
    positions = np.array(cal.positions)
    # the 5 mm on tracker y (lateral) of row 17: ~235 sigma of the scene's lateral
    # noise plus repeatability at that range (~21 um), a gross error
    positions[17, 1] += 5e-3
    cal = dataclasses.replace(cal, positions=positions)
    noise = fms.scene.position_noise()  # the shipped scene's tracker error model + repeatability
    blocks = cal.blocks(sigma=tracker.sigma, sigma_angle=tracker.sigma_angle, noise=noise)
    rob = identify_robust(problem.space, blocks, problem.identifiability)
    assert np.flatnonzero(rob.flagged).tolist() == [17]
    # the robust loss's own weight falls as 1/residual (~0.01 at 235 sigma); the final weight is 0
    assert rob.weight[17] == 0 and rob.robust_weight[17] < 0.02 and rob.normalised[17] > 100
    assert 0.8 < rob.scale < 1.2 and rob.result.converged
    assert len(rob.linear.outliers) > 30  # the a-priori rule on the plain fit: most rows
    floor = noise_floor(val, val.blocks(noise=noise)) * 1e3  # RMS of a perfect model [mm]
    e = held_out_errors(problem.space, val, rob.result.p, fms.scene.error_model())
    ratio = np.sqrt(np.mean(e**2)) / floor
    assert ratio <= 1.2, ratio  # 200 fresh validation poses
    e_lin = held_out_errors(problem.space, val, rob.linear.p, fms.scene.error_model())
    assert np.sqrt(np.mean(e_lin**2)) / floor > 3 * ratio


def test_scale_and_false_flags_against_monte_carlo(fms):
    """Clean data: the final fit is the plain linear one, the median scale ~ 1, flags ~ alpha."""
    problem, tracker = fms.problem, fms.scene.tracker
    scales, flags, n = [], 0, 0
    for seed in range(20):
        q = problem.robot.random_configurations(60, 100 + seed)
        mset, _ = simulated_measurements(fms, q, 200 + seed)
        blocks = mset.blocks(sigma=tracker.sigma, sigma_angle=tracker.sigma_angle,
                             noise=fms.scene.position_noise())
        rob = identify_robust(problem.space, blocks, problem.identifiability)
        if not rob.flagged.any():
            assert rob.result is rob.linear and rob.scale == pytest.approx(rob.linear.sigma0)
        scales.append(rob.robust_scale)
        flags += rob.n_flagged
        n += rob.flagged.size
    # E[flags] = alpha n = 1.2; P(>= 6) < 1e-3 for a Poisson(1.2)
    assert flags <= 5
    # the median scale with the leverage correction: mean over 20 runs within 10 % of 1
    assert abs(np.mean(scales) - 1) < 0.1, np.mean(scales)


def test_unmodelled_compliance_flags_few(fms):
    """Simulated with joint compliance (~10x the noise), identified rigid: <= 5 % flagged."""
    scene = load_scene("fms_kr16")
    flexible = CalibrationProblem.from_scene(dataclasses.replace(
        scene, compliance=ComplianceSpec(True, Compliance())))
    rigid = fms.problem
    flagged = total = 0
    sigma0 = []
    for seed in range(3):
        rng = np.random.default_rng(seed)
        q = rigid.robot.random_configurations(60, rng)
        p = draw_true_parameters(flexible.space, flexible.identifiability.free_indices, rng)
        p[flexible.space.compliance_slice] *= 6  # ~10x the noise (tracker model + repeatability)
        (b,) = simulate_observations(flexible.space, flexible.models, q, p, 100 + seed)
        blocks = [ObservationBlock(rigid.models[0], b.q, b.values)]
        rob = identify_robust(rigid.space, blocks, rigid.identifiability)
        sigma0.append(rob.linear.sigma0)
        assert len(rob.linear.outliers) > 20  # the a-priori rule flags a third or more
        flagged += rob.n_flagged
        total += rob.flagged.size
    assert min(sigma0) > 4 and max(sigma0) > 8
    assert flagged <= 0.05 * total, (flagged, total)


def test_bad_options_are_named(fms):
    problem, tracker = fms.problem, fms.scene.tracker
    mset, _ = simulated_measurements(fms, problem.robot.random_configurations(40, 1), 2)
    blocks = mset.blocks(sigma=tracker.sigma, sigma_angle=tracker.sigma_angle)
    with pytest.raises(ParameterError, match="alpha"):
        identify_robust(problem.space, blocks, problem.identifiability, alpha=0.7)
    with pytest.raises(ParameterError, match="drop"):
        identify_robust(problem.space, blocks, problem.identifiability, drop="some")
