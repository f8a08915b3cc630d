"""The covariance contract: one ErrorModel builds the models; noise and model error stacked."""

from __future__ import annotations

import numpy as np
import pytest

from calib_oed.exceptions import ParameterError
from calib_oed.measurement.discrepancy import DiscrepancyPrior
from calib_oed.measurement.error_model import ErrorModel
from calib_oed.measurement.noise import TrackerNoise
from calib_oed.measurement.observations import ObservationBlock
from calib_oed.measurement.pose import PoseMeasurement


def test_stacked_covariance_couples_the_reflectors_of_one_configuration():
    prior = DiscrepancyPrior(1e-4, (1.0, 1.0), sigma_white=3e-5)
    em = ErrorModel(sigma=1e-5, discrepancy=prior)
    q = np.array([[0.0, 0.0], [0.5, 0.0]])
    blocks = [ObservationBlock(m, q, np.ones((2, 3))) for m in em.models([0, 1])]
    cov = em.covariance(blocks)  # rows: block, configuration, component
    var = prior.variance
    assert cov.shape == (12, 12) and cov[0, 0] == pytest.approx(var + 1e-10)
    assert cov[0, 6] == pytest.approx(var)  # the same configuration, other reflector: shared
    assert cov[0, 3] == pytest.approx(prior.kernel(q[:1], q[1:])[0, 0])  # no white part
    assert cov[0, 1] == 0 and cov[0, 7] == 0  # components independent
    assert np.allclose(em.covariance(blocks, discrepancy=None), 1e-10 * np.eye(12))


def test_pose_models_and_bad_combinations():
    pose = ErrorModel("pose", 1e-5, 2e-5)
    (m,) = pose.models([1])
    assert isinstance(m, PoseMeasurement) and m.reflector == 1
    noise = TrackerNoise.isotropic(1e-5, 1e-5)
    assert ErrorModel(noise=noise).for_rows(True).noise is None
    with pytest.raises(ParameterError, match="position rows only"):
        ErrorModel("pose", noise=noise)
    with pytest.raises(ParameterError, match="unknown measurement"):
        ErrorModel("angle")
