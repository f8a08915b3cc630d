"""Monte Carlo validation: simulated calibrations against the predicted KPI covariance."""

from __future__ import annotations

import json

import numpy as np
import pytest

from calib_oed.calibration.montecarlo import monte_carlo
from calib_oed.calibration.workflow import heuristic_design, setup
from calib_oed.scene.reader import load_scene


@pytest.fixture(scope="module")
def fms():
    s = setup(load_scene("fms_kr16"))
    return s, heuristic_design(s, 30, 4)


def test_predicted_covariance_matches_simulation(fms):
    """600 seeded simulated calibrations (random truth each, joblib on 2 workers).

    Standard errors at N = 600: ratio ~0.033, coverage ~0.009; the bands
    0.85-1.15 and 0.90-0.99 are 4.5 standard errors or more from the expected
    1.0 and 0.95, so a wrong covariance (or a biased estimator) fails.
    """
    s, q = fms
    mc = monte_carlo(s.problem, q, n_runs=600, seed=2026, n_jobs=2)
    print(mc.summary())
    assert mc.converged.all()
    assert 0.85 <= mc.ratio[0] <= 1.15
    assert 0.90 <= mc.coverage[0] <= 0.99
    # per axis too, looser: each axis is a chi-square with 1 dof (s.e. ~0.06)
    axis_ratio = mc.empirical_axis_msq[0] / mc.predicted_axis_msq[0]
    assert np.all((axis_ratio > 0.7) & (axis_ratio < 1.3))
    # calibration helps by orders of magnitude
    assert mc.rms_after[0] < 0.05 * mc.rms_before[0]
    json.dumps(mc.to_dict())


def test_results_do_not_depend_on_workers(fms):
    s, q = fms
    one = monte_carlo(s.problem, q, n_runs=12, seed=5, n_jobs=1)
    two = monte_carlo(s.problem, q, n_runs=12, seed=5, n_jobs=2)
    np.testing.assert_allclose(one.errors_after, two.errors_after, rtol=0, atol=1e-15)


def test_a_wrong_prediction_fails_the_check(fms):
    """The check can fail: halving the noise in the prediction doubles the ratio."""
    s, q = fms
    mc = monte_carlo(s.problem, q, n_runs=60, seed=1, n_jobs=1)
    from dataclasses import replace

    wrong = replace(mc, predicted=mc.predicted / 4)
    assert wrong.ratio[0] > 2.5
    assert wrong.coverage[0] < 0.6


def test_bad_arguments(fms):
    s, q = fms
    with pytest.raises(ValueError, match="n_runs"):
        monte_carlo(s.problem, q, n_runs=1)
    with pytest.raises(ValueError, match="level"):
        monte_carlo(s.problem, q, n_runs=5, level=1.5)


# ------------------------------------------------------------------ full covariance (issue 19)
@pytest.fixture(scope="module")
def fms_full():
    """fms_kr16 with the AT500-like tracker model (k = 2) and 0.011 mm repeatability."""
    from dataclasses import replace

    from calib_oed.measurement.noise import TrackerNoise

    scene = load_scene("fms_kr16")
    noise = TrackerNoise((5e-6, 1.5e-7), (7.5e-6, 3e-6))
    scene = replace(scene, tracker=replace(scene.tracker, noise=noise), repeatability=1.1e-5)
    s = setup(scene)
    return s, heuristic_design(s, 30, 4)


def test_full_covariance_prediction_matches_simulation(fms_full):
    """600 runs under the anisotropic, range-dependent model with repeatability.

    Bands at 4 standard errors: ratio s.e. ~0.035 at N = 600 (measured 0.028 at N = 1000),
    coverage s.e. sqrt(0.95 * 0.05 / 600) = 0.0089. The 1000-run check is
    ``bench/bench_montecarlo_noise.py`` (docs/uncertainty.md).
    """
    s, q = fms_full
    mc = monte_carlo(s.problem, q, n_runs=600, seed=2026, n_jobs=2)
    print(mc.summary())
    assert mc.converged.all()
    assert abs(mc.ratio[0] - 1) < 4 * 0.035
    assert abs(mc.coverage[0] - 0.95) < 4 * np.sqrt(0.95 * 0.05 / 600)
    axis_ratio = mc.empirical_axis_msq[0] / mc.predicted_axis_msq[0]
    assert np.all((axis_ratio > 0.7) & (axis_ratio < 1.3))
    # the isotropic 0.01 mm prediction of the same design (the scene without tracker.noise
    # and repeatability) is far off under this noise
    from dataclasses import replace

    scene = s.scene
    iso_s = setup(replace(scene, tracker=replace(scene.tracker, noise=None), repeatability=0.0))
    assert iso_s.scene.position_noise() is None and np.all(iso_s.scene.tracker.sigma == 1e-5)
    iso = iso_s.problem.kpi_covariance(q)[:3, :3]
    assert np.mean(np.sum(mc.errors_after[:, 0] ** 2, axis=1)) / np.trace(iso) > 1.8  # 2.3
