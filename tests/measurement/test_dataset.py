"""MeasurementSet.blocks: a file's per-row sigma is each measurement's covariance (issue 34)."""

from __future__ import annotations

import dataclasses

import numpy as np

from calib_oed.calibration.workflow import identify_measurements, setup, simulated_measurements


def _with_sigma(mset, sigma):
    return dataclasses.replace(mset, sigma=np.full(len(mset.q), sigma))


def test_row_sigma_replaces_the_scene_noise_model():
    s = setup("fms_kr16")
    noise = s.scene.position_noise()
    assert noise is not None  # the shipped scene has a tracker error model
    mset, _ = simulated_measurements(s, s.problem.robot.random_configurations(30, 0), 1)
    (plain,) = mset.blocks(sigma=s.scene.tracker.sigma, noise=noise)
    (rows,) = _with_sigma(mset, 2e-5).blocks(sigma=s.scene.tracker.sigma, noise=noise)
    assert plain.model.noise is noise
    assert rows.model.noise is None
    np.testing.assert_array_equal(rows.sigma, np.full((30, 3), 2e-5))


def test_identification_scales_with_the_row_sigma():
    """The parameter standard deviations are linear in a common sigma of every row: the
    column reaches the fit (with the noise model they would not change)."""
    s = setup("fms_kr16")
    mset, _ = simulated_measurements(s, s.problem.robot.random_configurations(30, 0), 1)
    one = identify_measurements(s, _with_sigma(mset, 1e-5))
    two = identify_measurements(s, _with_sigma(mset, 2e-5))
    np.testing.assert_allclose(two.std, 2 * one.std, rtol=1e-6, atol=1e-15)
    nominal = identify_measurements(s, mset)
    assert not np.allclose(nominal.std, one.std, rtol=1e-3)
