"""The workflow's entry points take what a newcomer passes: a scene name or path, and
counts that are checked (issue 21)."""

from __future__ import annotations

from importlib import resources

import numpy as np
import pytest

from calib_oed import heuristic_design, load_scene, setup
from calib_oed.exceptions import DesignError, SceneError, UnknownSceneError


def test_setup_takes_a_name_a_path_or_a_scene(kr16):
    path = resources.files("calib_oed.scene.shipped").joinpath("fms_kr16.yaml")
    for ref in (str(path), path, load_scene("fms_kr16")):
        assert setup(ref).scene.name == kr16.scene.name == "fms_kr16"
    with pytest.raises(UnknownSceneError, match="fms_kr16"):
        setup("fms_kr61")
    with pytest.raises(SceneError, match="not int"):
        setup(3)


@pytest.mark.parametrize("n", [2.5, 0, -1, "3", True])
def test_heuristic_design_checks_the_count(kr16, n):
    with pytest.raises(DesignError, match=f"n = {n!r}: a whole number of poses >= 1"):
        heuristic_design(kr16, n, 0)


def test_heuristic_design_checks_the_seed_and_takes_a_generator(kr16):
    with pytest.raises(DesignError, match="seed = -3: an integer >= 0 or a numpy Generator"):
        heuristic_design(kr16, 3, -3)
    a = heuristic_design(kr16, 3, np.random.default_rng(5))
    np.testing.assert_array_equal(a, heuristic_design(kr16, np.int64(3), 5))


def test_identify_measurements_uses_the_scene_noise_model():
    """With tracker.noise and robot.repeatability the fit whitens with Sigma_i: data drawn
    from Sigma_i give a noise factor ~ 1 (std sqrt(2/95) = 0.15 at 40 poses)."""
    from dataclasses import replace

    from calib_oed.calibration.simulation import draw_true_parameters, simulate_observations
    from calib_oed.calibration.workflow import identify_measurements, setup
    from calib_oed.measurement.dataset import MeasurementSet
    from calib_oed.measurement.noise import TrackerNoise
    from calib_oed.scene.reader import load_scene

    shipped = load_scene("fms_kr16")
    # the isotropic 0.01 mm scene: no tracker error model, no repeatability
    base = replace(shipped, tracker=replace(shipped.tracker, noise=None), repeatability=0.0)
    assert base.position_noise() is None and np.all(base.tracker.sigma == 1e-5)
    scene = replace(base, tracker=replace(base.tracker, noise=TrackerNoise((5e-6, 1.5e-7),
                                                                           (7.5e-6, 3e-6))),
                    repeatability=1.1e-5)
    s = setup(scene)
    q = s.problem.robot.random_configurations(40, 9)
    p_true = draw_true_parameters(s.problem.space, s.problem.identifiability.free_indices, 8)
    block = simulate_observations(s.problem.space, s.problem.models, q, p_true, 7)[0]
    mset = MeasurementSet.from_arrays(s.problem.robot, q, block.values)
    result = identify_measurements(s, mset)
    assert 0.5 < result.noise_factor < 1.6
    # the same data judged by the isotropic 0.01 mm sigma look too noisy (measured 1.66,
    # more than 2 standard errors above 1)
    assert identify_measurements(setup(base), mset).noise_factor > 1.3
