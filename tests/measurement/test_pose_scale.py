"""The pose scale of a model error: the joint prior's variance at the pose, the weight, derivatives."""

from __future__ import annotations

import numpy as np
import pytest

from calib_oed.calibration.hyper_uncertainty import prior_of, theta_of
from calib_oed.calibration.joint_prior_choice import fitted_model_error, pose_scale
from calib_oed.calibration.workflow import setup
from calib_oed.exceptions import ParameterError
from calib_oed.measurement.base import evaluate_setup
from calib_oed.measurement.discrepancy import DiscrepancyPrior
from calib_oed.scene.reader import load_scene
from tests.conftest import central_difference, relative_error


@pytest.fixture(scope="module")
def scale(kr16_setup):
    q = kr16_setup.problem.robot.random_configurations(30, 5)
    return pose_scale(kr16_setup.problem).normalised(q), q


def test_variance_is_the_joint_priors_own_at_the_point(kr16_setup, scale):
    """v(q) against the joint prior's kernels moved to the point by the set-up's own Jacobian."""
    sc, q = scale
    prior = sc.prior
    jac = evaluate_setup(kr16_setup.problem.space, None, q).tool_point_config_jacobian(
        sc.points.offsets[0], "tracker")[:, :, :prior.nq]
    own = np.einsum("knn,nck,nck->n", prior.compute_kernels(q, q), jac, jac)
    assert relative_error(sc.compute_variance(q), own) < 1e-10
    assert own.max() > 3 * own.min()  # the poses differ: the scale matters


def test_weight_blends_the_shape_with_one_and_keeps_the_training_mean(scale):
    sc, q = scale
    assert np.mean(sc.compute(q) ** 2) == pytest.approx(1.0, rel=1e-12)
    assert np.allclose(sc.with_weight(0.0).compute(q), 1.0)
    half = sc.with_weight(0.5).compute(q) ** 2
    assert np.allclose(half, 0.5 + 0.5 * sc.compute(q) ** 2)
    with pytest.raises(ParameterError, match="weight"):
        sc.with_weight(1.5)


def test_scaled_kernel_and_its_log_gradient(scale):
    """k = m(q1) k0 m(q2); the log-hyperparameter gradient (weight included) by central differences."""
    sc, q = scale
    base = DiscrepancyPrior(1e-4, tuple(np.radians([45, 45, 45, 90, 90, 90])), "matern52_harmonic",
                            harmonic=np.linspace(2e-5, 6e-5, 12))
    prior = base.with_scale(sc.with_weight(0.7))
    q1, q2 = q[:5], q[3:9]
    m1, m2 = sc.with_weight(0.7).compute(q1), sc.with_weight(0.7).compute(q2)
    assert relative_error(prior.kernel(q1, q2), m1[:, None] * base.kernel(q1, q2) * m2) < 1e-14
    assert relative_error(prior.pose_variance(q1), m1**2 * base.variance) < 1e-14
    theta = theta_of(prior)
    ana = prior.kernel_log_gradient(q1, q2)
    assert ana.shape[-1] == prior.n_kernel_hyperparameters == theta.size - 1
    num = central_difference(lambda t: prior_of(prior, np.r_[t, theta[-1]]).kernel(q1, q2), theta[:-1], 1e-6)
    assert relative_error(ana, num) < 1e-6
    with pytest.raises(ParameterError, match="stationary"):
        prior.kernel_gradient(q1, q2)


def test_json_keeps_the_scale_for_the_problem(kr16_setup, scale):
    sc, q = scale
    prior = DiscrepancyPrior(1e-4, (1.0,) * 6, "matern52").with_scale(sc.with_weight(0.4))
    data = prior.to_dict()
    assert data["pose_scale"]["weight"] == pytest.approx(0.4)
    back = fitted_model_error(data, kr16_setup.problem.space)
    assert relative_error(back.kernel(q, q), prior.kernel(q, q)) < 1e-12
    assert DiscrepancyPrior.from_dict(data).scale is None  # the stationary part alone
    data["pose_scale"] = {"weight": 0.4}
    with pytest.raises(ParameterError, match="point_mm"):
        fitted_model_error(data, kr16_setup.problem.space)


def test_json_keeps_the_load_the_scale_was_made_with():
    """fms_kr300 declares its 300 kg payload with compliance not modelled: the payload is on the
    arm in the measurements (docs/scenes.md), so it loads the prior's shape, and a fitted model
    error read back for the scene's parameter space (which has no compliance block) keeps it."""
    s = setup(load_scene("fms_kr300"))
    assert s.problem.space.compliance is None
    q = s.problem.robot.random_configurations(20, 3)
    sc = pose_scale(s.problem).normalised(q)
    assert sc.prior.gravity.load.payload_mass == pytest.approx(300.3)  # the payload and the nest
    prior = DiscrepancyPrior(1e-4, (1.0,) * 6, "matern52").with_scale(sc.with_weight(0.7))
    data = prior.to_dict()
    back = fitted_model_error(data, s.problem.space)
    assert relative_error(back.kernel(q, q), prior.kernel(q, q)) < 1e-12
    del data["pose_scale"]["load"]  # a record from before the load was written: its rule, no payload
    old = fitted_model_error(data, s.problem.space)
    assert relative_error(old.kernel(q, q), prior.kernel(q, q)) > 1e-3
