"""Identification: recovery of known parameters, analytic Jacobian, statistics, robustness, errors."""

from __future__ import annotations

import json

import numpy as np
import pytest
from conftest import central_difference, make_space, random_parameters, relative_error

from calib_oed import load_robot
from calib_oed.calibration.identification import (
    IdentificationStatus,
    identify,
    residual_function,
)
from calib_oed.calibration.kpi import TcpKpi
from calib_oed.calibration.problem import CalibrationProblem
from calib_oed.exceptions import NotIdentifiableError, ParameterError, UnknownParameterError
from calib_oed.measurement import PoseMeasurement, TrackerPosition, evaluate_setup
from calib_oed.measurement.observations import ObservationBlock
from calib_oed.measurement.sensitivity import weighted_jacobian
from calib_oed.model.parameters import ANGLE_SCALE, LENGTH_SCALE
from calib_oed.scene.reader import load_scene


def _problem(robot_name, reflectors, models):
    robot = load_robot(robot_name)
    space = make_space(robot, reflectors)
    kpi = TcpKpi(robot.random_configurations(1, 0))
    return CalibrationProblem(space, models, kpi)


@pytest.fixture(scope="module")
def fms():
    """The shipped scene: kr16, one reflector on the A6 axis, 25 free parameters."""
    return CalibrationProblem.from_scene(load_scene("fms_kr16"))


@pytest.fixture(scope="module")
def ur5():
    return _problem("ur5", [(0.03, 0.01, 0.05)], [TrackerPosition(0)])


@pytest.fixture(scope="module")
def kr16_mixed():
    """kr16, reflector 0 measured in position, reflector 1 as a 6-D probe."""
    return _problem("kr16", [(0.03, -0.01, 0.05), (0.0, 0.04, 0.02)],
                    [TrackerPosition(0), PoseMeasurement(1)])


def true_parameters(problem, seed):
    """A random perturbation (0.5 mm, 0.5 mrad) of the free parameters; fixed ones nominal."""
    free = problem.identifiability.free_indices
    p = np.zeros(problem.space.size)
    p[free] = random_parameters(problem.space, seed)[free]
    return p


def simulate(space, model, q, p, rng=None):
    """An observation block of ``model`` at ``q``, exact at ``p``, plus noise of the model's
    sigma, or of its full error model (``model.noise``: the shipped scenes' tracker + repeatability)."""
    values = model.compute_values(evaluate_setup(space, p, q, jacobian=False))
    if rng is not None:
        noise = getattr(model, "noise", None)
        values = values + (model.sigma * rng.normal(size=values.shape) if noise is None
                           else noise.sample(values, rng))
    return ObservationBlock(model, q, values)


def distance_to_stationary_point(result):
    """Upper bound [mm, mrad] of the estimate's distance from the stationary point: |g| / sigma_min(F1 D)^2."""
    scale = np.where(np.array(result.units) == "m", LENGTH_SCALE, ANGLE_SCALE)
    sigma_min = np.linalg.svd(result.f1 * scale, compute_uv=False)[-1]
    return result.check() / sigma_min**2


def scaled_error(problem, result, p_true):
    """Largest estimation error over the free parameters, in mm or mrad."""
    free = problem.identifiability.free_indices
    return float(np.abs((result.p_free - p_true[free]) / problem.space.unit_scale[free]).max())


# ------------------------------------------------------------------ noise-free recovery
@pytest.mark.parametrize("name", ["fms", "ur5"])
def test_noise_free_data_recover_the_true_parameters(name, request):
    problem = request.getfixturevalue(name)
    p_true = true_parameters(problem, 11)
    q = problem.robot.random_configurations(40, 12)
    blocks = [simulate(problem.space, m, q, p_true) for m in problem.models]
    res = identify(problem.space, blocks, problem.identifiability)
    free = problem.identifiability.free_indices
    assert res.status is IdentificationStatus.CONVERGED
    assert np.abs(res.p_free - p_true[free]).max() < 1e-9  # [m, rad]
    assert np.all(np.delete(res.p, free) == 0.0)  # fixed parameters stay at p0
    assert res.rms_mm < 1e-6 and res.max_mm < 1e-6
    assert res.free_names == problem.identifiability.free_names


def test_fixed_parameters_stay_at_p0(ur5):
    """Non-nominal p0: the fixed parameters keep their p0 values, the free ones start there."""
    space, free = ur5.space, ur5.identifiability.free_indices
    p0 = random_parameters(space, 14)
    p_true = p0.copy()
    p_true[free] += true_parameters(ur5, 15)[free]
    q = ur5.robot.random_configurations(40, 16)
    res = identify(space, [simulate(space, ur5.models[0], q, p_true)], free, p0=p0)
    assert res.converged and np.abs(res.p - p_true).max() < 1e-9
    assert np.array_equal(np.delete(res.p, free), np.delete(p0, free))
    by_name = identify(space, [simulate(space, ur5.models[0], q, p_true)],
                       list(reversed(ur5.identifiability.free_names)), p0=p0)
    assert by_name.free_names == res.free_names and np.allclose(by_name.p, res.p, atol=1e-12)


def test_two_reflectors_and_mixed_position_and_pose_blocks(kr16_mixed):
    """Blocks at different configurations, one position, one pose, plus a second position block."""
    problem, space = kr16_mixed, kr16_mixed.space
    p_true = true_parameters(problem, 21)
    q_a = problem.robot.random_configurations(40, 22)
    q_b = problem.robot.random_configurations(30, 23)
    blocks = [simulate(space, TrackerPosition(0), q_a, p_true),
              simulate(space, TrackerPosition(1), q_a, p_true),
              simulate(space, PoseMeasurement(1), q_b, p_true)]
    res = identify(space, blocks, problem.identifiability)
    assert res.status is IdentificationStatus.CONVERGED
    assert np.abs(res.p_free - p_true[problem.identifiability.free_indices]).max() < 1e-9
    assert res.rms_mm < 1e-6 and res.rms_mrad < 1e-6
    assert res.angle_residuals_mrad[0] is None and res.angle_residuals_mrad[2].shape == (30,)
    assert [r.shape for r in res.block_residuals] == [(40, 3), (40, 3), (30, 6)]


# ------------------------------------------------------------------ residual Jacobian
def test_residual_jacobian_matches_central_differences(kr16_mixed):
    problem, space = kr16_mixed, kr16_mixed.space
    p_true = true_parameters(problem, 31)
    q = problem.robot.random_configurations(6, 32)
    blocks = [simulate(space, TrackerPosition(0), q, p_true),
              simulate(space, PoseMeasurement(1), q[:4], p_true)]
    p0 = random_parameters(space, 33)  # non-nominal fixed parameters too
    fun, jac = residual_function(space, blocks, problem.identifiability, p0)
    x = p0[problem.identifiability.free_indices] + 0.5 * true_parameters(problem, 34)[
        problem.identifiability.free_indices]
    err = relative_error(jac(x), central_difference(fun, x, eps=1e-7))
    print(f"residual Jacobian vs central differences: relative error {err:.1e}")
    assert err < 1e-6


def test_blocks_at_the_same_configurations_stack_like_f1(kr16_mixed):
    """Grouped evaluation equals sensitivity.weighted_jacobian (model-major rows)."""
    problem, space = kr16_mixed, kr16_mixed.space
    p = true_parameters(problem, 41)
    q = problem.robot.random_configurations(8, 42)
    blocks = [simulate(space, m, q, p) for m in problem.models]
    free = problem.identifiability.free_indices
    fun, jac = residual_function(space, blocks, free.tolist())
    f1 = weighted_jacobian(space, problem.models, q, p)[:, free]
    assert np.allclose(jac(p[free]), f1, rtol=1e-12, atol=1e-9 * np.abs(f1).max())
    assert np.abs(fun(p[free])).max() < 1e-9


# ------------------------------------------------------------------ statistics
def test_noise_factor_and_gradient_with_noise(fms):
    problem, space = fms, fms.space
    rng = np.random.default_rng(51)
    p_true = true_parameters(problem, 52)
    q = problem.robot.random_configurations(100, 53)
    res = identify(space, [simulate(space, problem.models[0], q, p_true, rng)],
                   problem.identifiability)
    print(f"100 poses, tracker error model + repeatability: noise factor {res.noise_factor:.3f}, rms {res.rms_mm:.4f} mm, "
          f"gradient {res.check():.1e} (distance {distance_to_stationary_point(res):.1e}), "
          f"{res.nfev} evaluations")
    assert res.status is IdentificationStatus.CONVERGED
    assert 0.8 < res.noise_factor < 1.25
    assert distance_to_stationary_point(res) < 1e-6  # [mm, mrad]
    assert res.std_posterior == pytest.approx(res.std * np.sqrt(res.noise_factor))
    assert res.outliers == ()


def test_noise_factor_and_covariance_against_monte_carlo(fms):
    """30 seeded runs: mean noise factor ~ 1 and mean (p - p_true)' C^-1 (p - p_true) ~ n_free."""
    problem, space = fms, fms.space
    rng = np.random.default_rng(61)
    p_true = true_parameters(problem, 62)
    q = problem.robot.random_configurations(60, 63)
    free = problem.identifiability.free_indices
    factors, chi2 = [], []
    for _ in range(30):
        res = identify(space, [simulate(space, problem.models[0], q, p_true, rng)], free)
        e = res.p_free - p_true[free]
        factors.append(res.noise_factor)
        chi2.append(e @ np.linalg.solve(res.covariance, e))
    n_f = free.size
    print(f"Monte Carlo: mean noise factor {np.mean(factors):.3f}, "
          f"mean chi2 {np.mean(chi2):.1f} for {n_f} free parameters")
    # std of the mean: sqrt(2/155/30) = 0.02 and sqrt(2*25/30) = 1.3
    assert 0.93 < np.mean(factors) < 1.07
    assert n_f - 4.5 < np.mean(chi2) < n_f + 4.5


def test_max_nfev_reached_is_a_status(ur5):
    p_true = true_parameters(ur5, 81)
    q = ur5.robot.random_configurations(40, 82)
    blocks = [simulate(ur5.space, ur5.models[0], q, p_true)]
    res = identify(ur5.space, blocks, ur5.identifiability, max_nfev=1)
    assert res.status is IdentificationStatus.MAX_ITERATIONS
    assert not res.converged and "max_iterations" in res.summary()


# ------------------------------------------------------------------ errors
def test_gauge_parameters_free_are_not_identifiable(fms):
    q = fms.robot.random_configurations(40, 91)
    blocks = [simulate(fms.space, fms.models[0], q, fms.space.zeros())]
    with pytest.raises(NotIdentifiableError) as info:
        identify(fms.space, blocks, fms.space.names)
    assert set(info.value.names) & set(fms.identifiability.fixed_names)


def test_too_few_poses_are_not_identifiable(fms):
    q = fms.robot.random_configurations(5, 92)  # 15 values for 25 free parameters
    blocks = [simulate(fms.space, fms.models[0], q, fms.space.zeros())]
    with pytest.raises(NotIdentifiableError, match="measure more configurations"):
        identify(fms.space, blocks, fms.identifiability)


def test_bad_options_list_the_valid_choices(ur5):
    q = ur5.robot.random_configurations(40, 93)
    blocks = [simulate(ur5.space, ur5.models[0], q, ur5.space.zeros())]
    with pytest.raises(ParameterError, match="valid methods are: lm, trf"):
        identify(ur5.space, blocks, ur5.identifiability, method="newton")
    with pytest.raises(TypeError):  # scipy's robust losses are gone: flags are robust.py's
        identify(ur5.space, blocks, ur5.identifiability, loss="huber")
    with pytest.raises(UnknownParameterError):
        identify(ur5.space, blocks, ["tracker.tx", "joint9.tx"])


# ------------------------------------------------------------------ the result record
@pytest.fixture(scope="module")
def noisy_result(fms):
    rng = np.random.default_rng(101)
    q = fms.robot.random_configurations(50, 102)
    blocks = [simulate(fms.space, fms.models[0], q, true_parameters(fms, 103), rng)]
    return identify(fms.space, blocks, fms.identifiability)


def test_correlation_matrix_and_strong_pairs(noisy_result):
    res = noisy_result
    corr = res.correlation
    assert np.allclose(corr, corr.T) and np.allclose(np.diag(corr), 1.0)
    assert np.allclose(corr, res.covariance / np.outer(res.std, res.std))
    names = res.free_names
    expected = {(names[i], names[j]) for i in range(len(names)) for j in range(i + 1, len(names))
                if abs(corr[i, j]) > res.correlation_threshold}
    assert {(a, b) for a, b, _ in res.strong_correlations} == expected and expected
    for a, b, rho in res.strong_correlations:
        assert rho == pytest.approx(corr[names.index(a), names.index(b)])


def test_summary_dict_and_estimates(noisy_result, fms):
    res = noisy_result
    text = res.summary()
    print(text)
    assert "converged" in text and "[  mm]" in text and "mrad" in text
    data = json.loads(json.dumps(res.to_dict()))
    assert data["status"] == "converged" and len(data["free"]) == len(res.free_names)
    name = res.free_names[3]
    e = res.estimate(name)
    assert e.free and e.value == res.p[fms.space.index(name)] and e.std == res.std[3]
    fixed = res.estimate(fms.identifiability.fixed_names[0])
    assert not fixed.free and fixed.value == 0.0 and fixed.std == 0.0
    with pytest.raises(UnknownParameterError):
        res.estimate("joint9.tx")
    with pytest.raises(ValueError):
        res.p[0] = 1.0  # read-only
    assert res.f1.shape == (150, len(res.free_names)) and res.residuals.shape == (150,)


# ------------------------------------------------------------------ full covariance (issue 19)
def _fms_full_noise():
    """fms_kr16 with the AT500-like tracker model (k = 2) and 0.011 mm repeatability."""
    from dataclasses import replace

    from calib_oed.measurement.noise import TrackerNoise

    scene = load_scene("fms_kr16")
    noise = TrackerNoise((5e-6, 1.5e-7), (7.5e-6, 3e-6))
    scene = replace(scene, tracker=replace(scene.tracker, noise=noise), repeatability=1.1e-5)
    return CalibrationProblem.from_scene(scene)


def test_full_covariance_whitening_and_noise_factor():
    """Sigma_i whitening: exact Jacobian of the frozen residual, chi-square noise factor ~ 1,
    raw residuals h - eta, and Sigma_i re-evaluated at the estimate."""
    problem = _fms_full_noise()
    space, model = problem.space, problem.models[0]
    free = problem.identifiability.free_indices
    p_true = true_parameters(problem, 72)
    q = problem.robot.random_configurations(100, 73)
    exact = model.compute_values(evaluate_setup(space, p_true, q, jacobian=False))
    eta = exact + model.noise.sample(exact, np.random.default_rng(71))
    block = ObservationBlock(model, q, eta)
    fun, jac = residual_function(space, [block], free)
    x = p_true[free] + 1e-5
    assert relative_error(jac(x), central_difference(fun, x, eps=1e-7)) < 1e-6
    res = identify(space, [block], free)
    assert res.status is IdentificationStatus.CONVERGED
    # 300 values - 25 free: the noise factor's std is sqrt(2/275) = 0.085
    assert 0.7 < res.noise_factor < 1.3
    h = model.compute_values(evaluate_setup(space, res.p, q, jacobian=False))
    np.testing.assert_allclose(res.block_residuals[0], h - eta, rtol=1e-9, atol=1e-15)
    w = model.noise.whitening(h)  # Sigma_i at the estimate
    np.testing.assert_allclose(res.residuals.reshape(-1, 3), np.einsum("nij,nj->ni", w, h - eta),
                               rtol=1e-6, atol=1e-9)
    # the isotropic model would misjudge the fit: its noise factor is far from 1
    iso = identify(space, [ObservationBlock(TrackerPosition(0), q, eta)], free)
    assert iso.noise_factor > 2.5


def test_isotropic_noise_model_equals_the_sigma_path(fms):
    from calib_oed.measurement.noise import TrackerNoise

    space = fms.space
    p_true = true_parameters(fms, 82)
    q = fms.robot.random_configurations(40, 83)
    plain = simulate(space, TrackerPosition(0, 1e-5), q, p_true, np.random.default_rng(81))
    full = ObservationBlock(TrackerPosition(0, 1e-5, TrackerNoise.isotropic(1e-5)), q, plain.values)
    free = fms.identifiability.free_indices
    a, b = identify(space, [plain], free), identify(space, [full], free)
    np.testing.assert_allclose(b.p, a.p, rtol=0, atol=1e-12)
    np.testing.assert_allclose(b.covariance, a.covariance, rtol=1e-8)
