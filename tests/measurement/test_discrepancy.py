"""The model-error kernel: derivatives against central differences, defaults, JSON form."""

import numpy as np
import pytest

from calib_oed import load_robot
from calib_oed.exceptions import ParameterError, ShapeError
from calib_oed.measurement.discrepancy import KERNELS, DiscrepancyPrior, robot_reach
from tests.conftest import central_difference, relative_error

ELL = (0.7, 0.9, np.inf, 1.3, 0.5, 2.0)


@pytest.fixture(params=KERNELS)
def prior(request):
    return DiscrepancyPrior(2e-4, ELL, request.param)


def _points(seed=0, n1=4, n2=5):
    rng = np.random.default_rng(seed)
    q1 = rng.uniform(-1, 1, (n1, 6))
    q2 = rng.uniform(-1, 1, (n2, 6))
    q2[0] = q1[0]  # r = 0: the derivatives must be right there too
    q2[1] = q1[1] + 1e-3  # and close to it
    return q1, q2


def test_kernel_gradient_matches_central_differences(prior):
    q1, q2 = _points()
    for a in range(q1.shape[0]):
        num = central_difference(lambda x, a=a: prior.kernel(x[None], q2)[0], q1[a], 1e-6)
        assert relative_error(prior.kernel_gradient(q1, q2)[a], num) < 1e-6


def test_kernel_hessians_match_central_differences(prior):
    q1, q2 = _points(1)
    hess, cross = prior.kernel_hessian(q1, q2), prior.kernel_cross_hessian(q1, q2)
    for a in range(q1.shape[0]):
        num = central_difference(lambda x, a=a: prior.kernel_gradient(x[None], q2)[0], q1[a], 1e-6)
        assert relative_error(hess[a], num) < 1e-5
        for b in range(q2.shape[0]):  # d/dq2 of dk/dq1
            num = central_difference(
                lambda x, a=a: prior.kernel_gradient(q1[a][None], x[None])[0, 0], q2[b], 1e-6)
            assert relative_error(cross[a, b], num) < 1e-5


def test_ignored_joint_and_covariance():
    prior = DiscrepancyPrior(3e-4, ELL)
    q = np.random.default_rng(2).uniform(-2, 2, (30, 6))
    moved = q.copy()
    moved[:, 2] += 1.0  # joint 3 has length scale inf
    assert np.array_equal(prior.kernel(q, q), prior.kernel(moved, moved))
    k = prior.point_covariance(q)
    assert np.allclose(np.diag(k), prior.sigma**2)
    assert np.linalg.eigvalsh(k).min() > -1e-12 * prior.sigma**2
    assert prior.kernel_gradient(q, q)[:, :, 2].max() == 0


def test_sample_has_the_kernel_covariance():
    prior = DiscrepancyPrior(1e-3, (0.5, 0.5, np.inf, np.inf, np.inf, np.inf), "squared_exponential")
    q = np.zeros((3, 6))
    q[1, 0], q[2, 1] = 0.3, 0.8
    rng = np.random.default_rng(3)
    draws = np.stack([prior.sample(q, rng) for _ in range(4000)])  # (N, 3, 3)
    emp = np.einsum("nia,nja->ij", draws, draws) / (3 * draws.shape[0])
    assert np.allclose(emp, prior.kernel(q, q), atol=4 * prior.sigma**2 / np.sqrt(3 * 4000) * 1.5)


def test_defaults_scale_with_reach_and_json_round_trip():
    small, large = load_robot("ur5"), load_robot("kr300")
    a, b = DiscrepancyPrior.default_for(small), DiscrepancyPrior.default_for(large)
    assert a.sigma < b.sigma
    assert b.sigma == pytest.approx(1e-4 * robot_reach(large))
    assert a.nq == small.nq and a.source == "default"
    back = DiscrepancyPrior.from_dict(b.to_dict(), large.nq)
    assert back.sigma == pytest.approx(b.sigma) and np.allclose(back.length_scales, b.length_scales)
    ignored = DiscrepancyPrior.from_dict({"sigma_mm": 0.1, "length_scales_deg": [30, None, 60]})
    assert np.isinf(ignored.length_scales[1])


def test_bad_values_name_the_problem():
    with pytest.raises(ParameterError, match="kernel"):
        DiscrepancyPrior(1e-4, (1.0,), "cubic")
    with pytest.raises(ParameterError, match="length_scales"):
        DiscrepancyPrior(1e-4, (1.0, -1.0))
    with pytest.raises(ParameterError, match="at least one joint"):
        DiscrepancyPrior(1e-4, (np.inf, np.inf))
    with pytest.raises(ParameterError, match="sigma"):
        DiscrepancyPrior(-1e-4, (1.0,))
    with pytest.raises(ShapeError):
        DiscrepancyPrior(1e-4, (1.0, 1.0)).kernel(np.zeros((2, 3)), np.zeros((2, 2)))
    with pytest.raises(ParameterError, match="sigma_mm"):
        DiscrepancyPrior.from_dict({"sigma": 1})


def test_scene_key_in_file_units_and_from_an_identification(tmp_path):
    import json

    import yaml

    from calib_oed import load_scene
    from calib_oed.exceptions import SceneError
    from calib_oed.scene.reader import scene_from_dict
    from importlib import resources

    data = yaml.safe_load(resources.files("calib_oed.scene.shipped").joinpath("fms_kr16.yaml").read_text())
    assert load_scene("fms_kr16").discrepancy().source == "default"
    data["robot"]["model_error"] = {"sigma": 0.2, "length_scales": [30, 30, 30, 60, 60, float("inf")]}
    prior = scene_from_dict(data, str(tmp_path / "s.yaml")).discrepancy()
    assert prior.sigma == pytest.approx(2e-4) and np.isinf(prior.length_scales[5])
    assert prior.length_scales[0] == pytest.approx(np.radians(30)) and prior.source == "scene"
    (tmp_path / "identification.json").write_text(json.dumps(
        {"model_error": {"fitted": {"sigma_mm": 0.05, "length_scales_deg": [40] * 6}}}))
    data["robot"]["model_error"] = {"from": "identification.json"}
    prior = scene_from_dict(data, str(tmp_path / "s.yaml")).discrepancy()
    assert prior.sigma == pytest.approx(5e-5) and prior.length_scales[3] == pytest.approx(np.radians(40))
    data["robot"]["model_error"] = {"sigma": 0.2}
    with pytest.raises(SceneError, match="length_scales"):
        scene_from_dict(data, str(tmp_path / "s.yaml"))
    data["robot"]["model_error"] = {"from": "missing.json"}
    with pytest.raises(SceneError, match="identify --json"):
        scene_from_dict(data, str(tmp_path / "s.yaml"))
