"""The model-error kernel: derivatives against central differences, defaults, JSON form."""

import numpy as np
import pytest

from calib_oed import load_robot
from calib_oed.exceptions import ParameterError, ShapeError
from calib_oed.measurement.discrepancy import (
    HARMONIC_KERNELS,
    KERNELS,
    DiscrepancyPrior,
    robot_reach,
)
from tests.conftest import central_difference, relative_error

ELL = (0.7, 0.9, np.inf, 1.3, 0.5, 2.0)


@pytest.fixture(params=[(k, lin) for k in KERNELS for lin in ((), (1, 4))])
def prior(request):
    """Both kernels; revolute joints (chordal distance), and two joints measured linearly."""
    kernel, linear = request.param
    return DiscrepancyPrior(2e-4, ELL, kernel, linear_joints=linear)


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


def test_a_revolute_joint_turned_a_full_revolution_is_the_same_arm():
    prior = DiscrepancyPrior(3e-4, ELL)
    q = np.random.default_rng(5).uniform(-2, 2, (10, 6))
    turned = q.copy()
    turned[:, 0] += 2 * np.pi
    assert np.allclose(prior.kernel(q, turned), prior.kernel(q, q), rtol=1e-12)
    linear = DiscrepancyPrior(3e-4, ELL, linear_joints=(0,))
    assert np.all(linear.kernel(q, turned).diagonal() < 0.01 * linear.sigma**2)


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
    """Smooth and white parts: the white part couples only equal configurations (rows 0 and 3)."""
    prior = DiscrepancyPrior(1e-3, (0.5, 0.5, np.inf, np.inf, np.inf, np.inf), "squared_exponential",
                             sigma_white=5e-4)
    q = np.zeros((4, 6))
    q[1, 0], q[2, 1] = 0.3, 0.8
    rng = np.random.default_rng(3)
    draws = np.stack([prior.sample(q, rng) for _ in range(4000)])  # (N, 3, 3)
    emp = np.einsum("nia,nja->ij", draws, draws) / (3 * draws.shape[0])
    expected = prior.kernel(q, q) + prior.sigma_white**2 * np.array(
        [[1, 0, 0, 1], [0, 1, 0, 0], [0, 0, 1, 0], [1, 0, 0, 1]])
    assert np.allclose(prior.point_covariance(q), expected)
    assert np.allclose(emp, expected, atol=4 * prior.variance / np.sqrt(3 * 4000) * 1.5)


def test_defaults_scale_with_reach_and_json_round_trip():
    small, large = load_robot("ur5"), load_robot("kr300")
    a, b = DiscrepancyPrior.default_for(small), DiscrepancyPrior.default_for(large)
    assert a.sigma < b.sigma
    assert b.sigma == pytest.approx(1e-4 * robot_reach(large))
    assert a.nq == small.nq and a.source == "default"
    white = b.with_values(b.sigma, b.length_scales, "t", 3e-5)
    back = DiscrepancyPrior.from_dict(white.to_dict(), large.nq)
    assert back.sigma == pytest.approx(b.sigma) and np.allclose(back.length_scales, b.length_scales)
    assert back.sigma_white == pytest.approx(3e-5)
    ignored = DiscrepancyPrior.from_dict({"sigma_mm": 0.1, "length_scales_deg": [30, None, 60]})
    assert np.isinf(ignored.length_scales[1])


def test_harmonic_part_couples_one_joint_at_the_same_angle_and_round_trips():
    ell = (0.5, 0.5, 0.5, 0.5, 0.5, np.inf)
    prior = DiscrepancyPrior(1e-4, ell, "matern52_harmonic", linear_joints=(4,))
    amp = np.reshape(prior.harmonic, (6, 2))
    assert np.all(amp[[4, 5]] == 0) and np.all(amp[:4] > 0)  # none for a linear or ignored joint
    assert prior.smooth_variance == pytest.approx(1e-8 * (1 + 0.5))  # the default share
    rng = np.random.default_rng(3)
    q1 = rng.uniform(-3, 3, (1, 6))
    q2 = q1 + rng.uniform(2, 3, (1, 6)) * rng.choice([-1, 1], 6)  # far in every joint (ARD ~ 0) ...
    q2[0, 2] = q1[0, 2]  # ... but joint 3
    plain = DiscrepancyPrior(1e-4, ell, "matern52", linear_joints=(4,))
    assert plain.kernel(q1, q2)[0, 0] < 0.01 * plain.sigma**2
    d = (q1 - q2)[0]
    expected = plain.kernel(q1, q2)[0, 0] + np.sum(amp[:, 0] ** 2 * np.cos(d) + amp[:, 1] ** 2 * np.cos(2 * d))
    assert prior.kernel(q1, q2)[0, 0] == pytest.approx(expected, rel=1e-9)
    assert np.allclose(np.diag(prior.point_covariance(q1)), prior.variance)
    back = DiscrepancyPrior.from_dict(prior.to_dict(), 6)
    assert back.kernel_name == prior.kernel_name and np.allclose(back.harmonic, prior.harmonic)
    assert "harmonic" in prior.describe()
    with pytest.raises(ParameterError, match="harmonic"):
        DiscrepancyPrior(1e-4, ell, "matern52", harmonic=(1e-5,) * 12)
    with pytest.raises(ShapeError):
        DiscrepancyPrior(1e-4, ell, "matern52_harmonic", harmonic=(1e-5,) * 3)


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
    from importlib import resources

    import yaml

    from calib_oed import load_scene
    from calib_oed.exceptions import SceneError
    from calib_oed.scene.reader import scene_from_dict

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


def test_kernel_log_gradient_matches_central_differences(prior):
    q1, q2 = _points(4)
    finite = [j for j, x in enumerate(ELL) if np.isfinite(x)]
    harm = np.flatnonzero(np.asarray(prior.harmonic) > 0)  # the harmonic amplitudes it has
    if prior.kernel_name in HARMONIC_KERNELS:
        assert harm.size == 2 * int(prior.harmonic_joints.sum()) > 0

    def k_of(theta):
        ell = list(ELL)
        for j, t in zip(finite, theta[1:1 + len(finite)], strict=True):
            ell[j] = np.exp(t)
        amp = np.array(prior.harmonic)
        amp[harm] = np.exp(theta[1 + len(finite):])
        return prior.with_values(np.exp(theta[0]), tuple(ell), "fd", harmonic=amp).kernel(q1, q2)

    theta = np.log([prior.sigma] + [ELL[j] for j in finite] + [prior.harmonic[i] for i in harm])
    num = central_difference(k_of, theta, 1e-6)
    ana = prior.kernel_log_gradient(q1, q2)
    assert ana.shape[-1] == prior.n_kernel_hyperparameters
    assert relative_error(ana[..., [0] + [1 + j for j in finite] + [1 + prior.nq + i for i in harm]],
                          num) < 1e-6
    assert np.all(ana[..., 1 + 2] == 0)  # the ignored joint
